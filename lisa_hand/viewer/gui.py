"""The viewer's control panel (viser GUI): :class:`Controls`.

Folders: Hands (A, B, shape / colour / pose from A to B, swaps), Pose (global rotation, named
pose, per-finger curl, spread, thumb, joint limits, motions), Finger joints (the 45 anatomical
angles, collapsed), Shape and colour space (principal directions of the training codes),
Display (colour mode, surface, skeleton, keypoints, side), Export, and Photo (with the photo extra).

Every control sets one value of the :class:`~.state.ViewState` through
:meth:`~.server.HandViewer.set_state`; :meth:`Controls.state_changed` writes back what the
state implies (the 45 finger sliders show the resulting angles) with the callbacks muted.
Handles are in ``Controls.handles`` by name (the tests set their ``value`` through viser's
Python API, which runs the same callbacks as a browser).

Every value is checked before it is used (:func:`value_problem`): a number must be finite and
within its slider's range, a dropdown's value one of its options, a checkbox's a bool, a text a
short string. A value that fails is ignored, with a note on the status line (and in
``Controls.notes``), never a traceback on the server. A browser's change is checked before
viser even casts it (:meth:`Controls.guard_browser_updates`), and may set a control's value only
(not its range, options or callbacks).
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..handmodel.poses import JOINT_LIMITS, POSE_NAMES, SYNERGY_NAMES
from ..skeleton import JOINT_NAMES
from .display import COLOR_MODES
from .state import NUM_FINGER_VALUES, PoseEdit, finger_angles, interpolated_pose

if TYPE_CHECKING:
    from .server import HandViewer

__all__ = ["Controls", "build_controls", "value_problem", "OWN_POSE", "SIDE_OPTIONS"]

OWN_POSE = "(the hand's own)"
SIDE_OPTIONS = ("as hand A", "right", "left")
_ANGLE_NAMES = ("flexion", "abduction", "twist")
_SYNERGY_RANGE = {"spread": (-1.0, 1.5), "thumb_opposition": (-0.5, 1.2),
                  "thumb_abduction": (-0.5, 1.2)}
_LIMIT_MARGIN_DEG = 15.0
_MAX_TEXT = 1000
"""Longest text a text box takes (characters)."""


def _shown(value: Any) -> str:
    """A value for a note: a number as itself, anything else by its type (never echo text)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return repr(value)
    return f"a {type(value).__name__}"


def value_problem(handle: Any, value: Any) -> str | None:
    """Why ``value`` cannot be the value of the viser GUI input ``handle``; None: it can.

    Sliders take finite numbers (not bools) within [min, max]; dropdowns one of their options;
    checkboxes and buttons a bool; text boxes a string of at most 1000 printable characters.
    Any other input (an upload button) takes no value from a browser.
    """
    import viser

    if isinstance(handle, (viser.GuiButtonHandle, viser.GuiCheckboxHandle)):
        return None if isinstance(value, bool) else f"{_shown(value)} is not true or false"
    if isinstance(handle, viser.GuiSliderHandle):
        low, high = float(handle.min), float(handle.max)
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or not math.isfinite(value) or not low <= value <= high):
            return f"{_shown(value)} is not a number in [{low:g}, {high:g}]"
        return None
    if isinstance(handle, viser.GuiDropdownHandle):
        if isinstance(value, str) and value in handle.options:
            return None
        return f"{_shown(value)} is not one of its options"
    if isinstance(handle, viser.GuiTextHandle):
        if isinstance(value, str) and len(value) <= _MAX_TEXT and value.isprintable():
            return None
        return f"{_shown(value)} is not a line of at most {_MAX_TEXT} characters"
    return "it takes no value from a browser"


def _finger_range(index: int) -> tuple[float, float]:
    """Slider range (degrees) of finger value ``index``: its joint limits plus a margin."""
    low, high = (math.degrees(float(v)) for v in JOINT_LIMITS[index // 3, index % 3])
    return (math.floor(low - _LIMIT_MARGIN_DEG), math.ceil(high + _LIMIT_MARGIN_DEG))


class Controls:
    """The GUI of one :class:`~.server.HandViewer` (see the module docstring)."""

    def __init__(self, viewer: HandViewer, photo_fit: Callable[..., Any] | None = None) -> None:
        self.viewer = viewer
        self.handles: dict[str, Any] = {}
        self.notes: deque[str] = deque(maxlen=100)
        """The latest notes of ignored values, oldest first (the status line shows the last)."""
        self._good: dict[str, Any] = {}
        self._muted = False
        gui = viewer.server.gui
        self.gui = gui
        self._status = gui.add_markdown("starting")
        self.handles["status"] = self._status
        self._hands_folder(gui)
        self._pose_folder(gui)
        self._finger_folder(gui)
        self._space_folder(gui)
        self._display_folder(gui)
        self._export_folder(gui)
        from .photo import add_photo_panel

        self.photo = add_photo_panel(self, photo_fit)
        self.guard_browser_updates()

    # -- helpers -----------------------------------------------------------------------------
    @contextlib.contextmanager
    def muted(self) -> Iterator[None]:
        """Set GUI values without running their callbacks."""
        was, self._muted = self._muted, True
        try:
            yield
        finally:
            self._muted = was

    def note(self, text: str) -> None:
        """Show ``text`` on the status line and keep it in :attr:`notes`."""
        self.notes.append(text)
        self.show_status(text)

    def _label(self, name: str) -> str:
        return str(getattr(self.handles.get(name), "label", name))

    def _on(self, name: str, handle: Any, action: Callable[[Any], None]) -> Any:
        """Register ``handle`` as ``name``; ``action(value)`` runs on a change of a valid
        value. An invalid one (:func:`value_problem`) is a note, and the control goes back to
        its last valid value."""
        self.handles[name] = handle
        self._good[name] = handle.value

        @handle.on_update
        def _(_event) -> None:
            value = handle.value
            problem = value_problem(handle, value)
            if problem is not None:
                self.note(f"ignored {self._label(name)}: {problem}")
                with self.muted():
                    handle.value = self._good[name]
                return
            self._good[name] = value
            if self._muted:
                return
            try:
                action(value)
            except (ValueError, TypeError) as exc:  # a value the state refuses
                self.note(f"ignored {self._label(name)}: {exc}")

        return handle

    def guard_browser_updates(self) -> None:
        """Check every change a browser sends before viser handles it.

        viser applies a browser's ``GuiUpdateMessage`` by casting each property to its current
        type and setting it (``GuiApi._handle_gui_updates``): a string for a slider raises in
        viser's event loop, and any property (a range, the options, the callbacks) may be set.
        This puts a check in front of that handler (viser 1.1.1, pinned, registers it on
        ``ViserServer._websock_server``): a change passes only when it sets ``value`` alone, of
        a control of this panel, to a value :func:`value_problem` accepts; anything else is a
        note and is dropped.
        """
        from viser._messages import GuiUpdateMessage

        interface = self.viewer.server._websock_server
        handle_updates = self.gui._handle_gui_updates

        async def checked(client_id: Any, message: Any) -> None:
            problem = self._browser_problem(message)
            if problem is not None:
                self.note(f"ignored a change from a browser: {problem}")
                return
            await handle_updates(client_id, message)

        interface.unregister_handler(GuiUpdateMessage, handle_updates)
        interface.register_handler(GuiUpdateMessage, checked)

    def _browser_problem(self, message: Any) -> str | None:
        """Why the browser's GUI change ``message`` is refused (None: it is not)."""
        names = {handle._impl.uuid: name for name, handle in self.handles.items()
                 if hasattr(handle, "_impl")}
        name = names.get(getattr(message, "uuid", None))
        if name is None:
            return "not a control of this panel"
        updates = getattr(message, "updates", None)
        if not isinstance(updates, dict) or list(updates) != ["value"]:
            return f"{self._label(name)}: only its value may change"
        problem = value_problem(self.handles[name], updates["value"])
        return None if problem is None else f"{self._label(name)}: {problem}"

    def _click(self, name: str, handle: Any, action: Callable[[], None]) -> Any:
        self.handles[name] = handle

        @handle.on_click
        def _(_event) -> None:
            action()

        return handle

    def _state(self, **changes: Any) -> None:
        self.viewer.set_state(replace(self.viewer.state, **changes))
        with self.muted():  # a state the viewer refused: its sliders go back
            for key in changes:
                if key in ("shape_t", "color_t", "pose_t"):
                    self.handles[key].value = getattr(self.viewer.state, key)

    def _pose(self, **changes: Any) -> None:
        state = self.viewer.state
        self.viewer.set_state(replace(state, pose=replace(state.pose, **changes)))

    def _hand_index(self, name: str) -> int:
        return [hand.name for hand in self.viewer.hands].index(name)

    @property
    def show_skeleton(self) -> bool:
        return bool(self.handles["skeleton"].value)

    @property
    def show_keypoints(self) -> bool:
        return bool(self.handles["keypoints"].value)

    def show_status(self, text: str) -> None:
        self._status.content = text

    # -- folders -----------------------------------------------------------------------------
    def _hands_folder(self, gui: Any) -> None:
        names = [hand.name for hand in self.viewer.hands]
        with gui.add_folder("Hands"):
            self._on("hand_a", gui.add_dropdown("Hand A", names, initial_value=names[0]),
                     lambda v: self._state(hand_a=self._hand_index(v)))
            self._on("hand_b", gui.add_dropdown("Hand B", names,
                                                initial_value=names[self.viewer.state.hand_b]),
                     lambda v: self._state(hand_b=self._hand_index(v)))
            for key, label in (("shape_t", "Shape A→B"), ("color_t", "Colour A→B"),
                               ("pose_t", "Pose A→B")):
                self._on(key, gui.add_slider(label, 0.0, 1.0, 0.01, 0.0),
                         lambda v, key=key: self._state(**{key: float(v)}))
            self._click("swap_color", gui.add_button("A's shape, B's colour"),
                        lambda: self._set_weights(0.0, 1.0))
            self._click("swap_shape", gui.add_button("B's shape, A's colour"),
                        lambda: self._set_weights(1.0, 0.0))
            self._click("swap_hands", gui.add_button("Swap A and B"), self._swap_hands)

    def _set_weights(self, shape: float, color: float) -> None:
        with self.muted():
            self.handles["shape_t"].value = shape
            self.handles["color_t"].value = color
        self._state(shape_t=shape, color_t=color)

    def _swap_hands(self) -> None:
        state = self.viewer.state
        with self.muted():
            self.handles["hand_a"].value = self.viewer.hands[state.hand_b].name
            self.handles["hand_b"].value = self.viewer.hands[state.hand_a].name
        self._state(hand_a=state.hand_b, hand_b=state.hand_a)

    def _pose_folder(self, gui: Any) -> None:
        with gui.add_folder("Pose"):
            for axis in range(3):
                name = f"rotation_{'xyz'[axis]}"
                self._on(name, gui.add_slider(f"Rotate {'xyz'[axis]} (°)", -180.0, 180.0, 1.0,
                                              0.0), lambda v, axis=axis: self._rotate(axis, v))
            self._on("named_pose", gui.add_dropdown("Named pose", [OWN_POSE, *POSE_NAMES],
                                                    initial_value=OWN_POSE), self._named)
            for name in SYNERGY_NAMES:
                low, high = _SYNERGY_RANGE.get(name, (-0.3, 1.0))
                label = name.replace("_", " ").replace("pinky", "little")
                self._on(name, gui.add_slider(label, low, high, 0.01, 0.0),
                         lambda v, name=name: self._pose(
                             synergies=self.viewer.state.pose.with_synergy(name, v).synergies))
            self._on("limits", gui.add_checkbox("Joint limits", True),
                     lambda v: self._pose(limits=bool(v)))
            self._click("reset_pose", gui.add_button("Reset pose"), self._reset_pose)
            self._on("motion", gui.add_dropdown("Motion", list(POSE_NAMES),
                                                initial_value="fist"), lambda v: self._replay())
            self._on("play", gui.add_checkbox("Play motion", False), self._play)

    def _rotate(self, axis: int, degrees: float) -> None:
        rotation = list(self.viewer.state.pose.rotation_deg)
        rotation[axis] = float(degrees)
        self._pose(rotation_deg=tuple(rotation))

    def _named(self, value: str) -> None:
        with self.muted():
            for name in SYNERGY_NAMES:
                self.handles[name].value = 0.0
        limits = self.viewer.state.pose.limits
        rotation = self.viewer.state.pose.rotation_deg
        self._pose_set(PoseEdit(named=None if value == OWN_POSE else value, limits=limits,
                                rotation_deg=rotation))

    def _pose_set(self, edit: PoseEdit) -> None:
        self.viewer.set_state(replace(self.viewer.state, pose=edit))

    def _reset_pose(self) -> None:
        with self.muted():
            for name in SYNERGY_NAMES:
                self.handles[name].value = 0.0
            for axis in "xyz":
                self.handles[f"rotation_{axis}"].value = 0.0
            self.handles["named_pose"].value = OWN_POSE
        self._pose_set(PoseEdit(limits=self.viewer.state.pose.limits))

    def _play(self, value: bool) -> None:
        if value:
            self.viewer.play(self.handles["motion"].value)
        else:
            self.viewer.pause()

    def _replay(self) -> None:
        if self.handles["play"].value:
            self.viewer.play(self.handles["motion"].value)

    def _finger_folder(self, gui: Any) -> None:
        with gui.add_folder("Finger joints (45 angles, °)", expand_by_default=False):
            for index in range(NUM_FINGER_VALUES):
                low, high = _finger_range(index)
                label = f"{JOINT_NAMES[index // 3 + 1]} {_ANGLE_NAMES[index % 3]}"
                self._on(f"finger_{index}", gui.add_slider(label, low, high, 0.5, 0.0),
                         lambda v, index=index: self._finger(index, v))

    def _angles(self):
        """(before [15, 3], after [15, 3]) radians of the current state (:func:`finger_angles`)."""
        viewer = self.viewer
        state = viewer.state
        a = viewer.hands[state.hand_a].params
        pose, _ = interpolated_pose(a, viewer.hands[state.hand_b].params, state.pose_t)
        return finger_angles(state.pose, pose, a.side)

    def _finger(self, index: int, degrees: float) -> None:
        before, _ = self._angles()
        offset = float(degrees) - math.degrees(float(before.reshape(-1)[index]))
        self._pose(offsets_deg=self.viewer.state.pose.with_offset(index, offset).offsets_deg)

    def _space_folder(self, gui: Any) -> None:
        spaces = self.viewer.spaces
        with gui.add_folder("Shape and colour space", expand_by_default=False):
            for kind, space in (("shape", spaces.shape), ("color", spaces.color)):
                if space is None:
                    continue
                for k in range(space.num_dims):
                    low = math.floor(float(space.low[k]) * 10.0) / 10.0
                    high = math.ceil(float(space.high[k]) * 10.0) / 10.0
                    label = f"{'Shape' if kind == 'shape' else 'Colour'} PC{k + 1} (std)"
                    self._on(f"{kind}_pc{k}", gui.add_slider(label, low, high, 0.05, 0.0),
                             lambda v, kind=kind, k=k, n=space.num_dims: self._pc(kind, k, v, n))

    def _pc(self, kind: str, k: int, value: float, num: int) -> None:
        key = f"{kind}_pcs"
        values = list(getattr(self.viewer.state, key)) or [0.0] * num
        values[k] = float(value)
        self._state(**{key: tuple(values)})

    def _display_folder(self, gui: Any) -> None:
        with gui.add_folder("Display"):
            self._on("color_mode", gui.add_dropdown("Colours", list(COLOR_MODES),
                                                    initial_value="skin"),
                     self.viewer.set_color_mode)
            overlays = lambda _v: self.viewer.set_overlays(  # noqa: E731
                self.show_skeleton, self.show_keypoints)
            self._on("surface", gui.add_checkbox("Surface", True),
                     self.viewer.set_hand_visible)  # off: the skeleton and keypoints alone
            self._on("skeleton", gui.add_checkbox("Skeleton", False), overlays)
            self._on("keypoints", gui.add_checkbox("21 keypoints", False), overlays)
            self._on("side", gui.add_dropdown("Side", list(SIDE_OPTIONS),
                                              initial_value=SIDE_OPTIONS[0]),
                     lambda v: self._state(side=None if v == SIDE_OPTIONS[0] else v))

    def _export_folder(self, gui: Any) -> None:
        with gui.add_folder("Export"):
            root = self.viewer.export_root
            self.handles["export_dir"] = gui.add_text(
                "Folder", "", hint=f"A folder name inside {root} (empty: that folder)")
            self._click("export", gui.add_button("Export params.json + mesh.ply"),
                        self.export)
            self._click("screenshot", gui.add_button("Screenshot"), self.screenshot)
            self.handles["export_status"] = gui.add_markdown(" ")

    def _export_line(self, text: str) -> None:
        self.handles["export_status"].content = text

    def _export_target(self) -> Path | None:
        """The Export folder inside the viewer's export folder, or None (refused: a note)."""
        from .export import export_folder

        try:
            return export_folder(self.viewer.export_root, self.handles["export_dir"].value)
        except ValueError as exc:
            self._export_line(f"export refused: {exc}")
            self.notes.append(f"export refused: {exc}")
            return None

    def export(self) -> list:
        """Write the hand into the Export folder, a folder inside the viewer's export folder
        (:func:`~.export.export_folder`; errors and refusals become the export status line)."""
        from .export import export_hand

        viewer = self.viewer
        folder = self._export_target()
        if folder is None:
            return []
        self._export_line(f"exporting to {folder} ...")
        try:
            with viewer._lock:
                params, state = viewer.params, viewer.state
            paths = export_hand(folder, viewer.model, params, state, viewer.config)
        except (ValueError, OSError) as exc:
            self._export_line(f"export failed: {exc}")
            return []
        self._export_line("wrote " + ", ".join(str(path) for path in paths))
        return paths

    def screenshot(self) -> None:
        """Save the first connected browser's view as ``screenshot.png`` in the Export folder."""
        from .export import write_screenshot

        folder = self._export_target()
        if folder is None:
            return
        clients = list(self.viewer.server.get_clients().values())
        if not clients:
            self._export_line("screenshot: no browser is connected")
            return
        try:
            image = clients[0].get_render(height=720, width=960, transport_format="png",
                                          timeout=30.0)
            path = write_screenshot(folder / "screenshot.png", image)
        except (ValueError, OSError, TimeoutError, RuntimeError) as exc:
            self._export_line(f"screenshot failed: {exc}")
            return
        self._export_line(f"wrote {path}")

    # -- write-back --------------------------------------------------------------------------
    def state_changed(self) -> None:
        """Show on the 45 finger sliders the angles the state gives (callbacks muted)."""
        _, after = self._angles()
        with self.muted():
            for index, value in enumerate(after.reshape(-1).tolist()):
                low, high = _finger_range(index)
                slider = self.handles[f"finger_{index}"]
                slider.value = min(max(round(math.degrees(value), 2), low), high)

    def hands_changed(self) -> None:
        names = [hand.name for hand in self.viewer.hands]
        for key in ("hand_a", "hand_b"):
            self.handles[key].options = names

    def set_hand_a(self, index: int) -> None:
        self.handles["hand_a"].value = self.viewer.hands[index].name


def build_controls(viewer: HandViewer, photo_fit: Callable[..., Any] | None = None) -> Controls:
    """The control panel of ``viewer`` (see :class:`Controls`)."""
    return Controls(viewer, photo_fit)
