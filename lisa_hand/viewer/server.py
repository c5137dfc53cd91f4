"""The viser scene of ``lisa view``: :class:`HandViewer` (scene, state, remeshing, motions) and
:func:`serve` (the blocking command).

The hand on screen is always ``view_params(viewer.state, viewer.hands, viewer.spaces)``
(:mod:`.state`); the GUI (:mod:`.gui`) only sets values of the state through
:meth:`HandViewer.set_state`, which redraws the skeleton and keypoints at once and asks the
:class:`~.meshing.Remesher` for a coarse, then a fine mesh. viser ships its web client in its
wheel, so the viewer works with no internet; it is imported here, lazily, so that
``import lisa_hand`` works without the view extra.

The viewer serves only its user: its web server refuses every other web page
(:mod:`.origin`), the panel ignores values no control can take (:mod:`.gui`), and exports stay
inside the export folder (:func:`.export.export_folder`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.meshing import Mesh
from ..inference.mesh import repose_mesh
from ..inference.sequences import motion_poses
from ..model.trained import TrainedModel
from ..skeleton.params import HandParams
from ..utils.threads import cpu_threads
from .config import ViewerConfig
from .display import display_colors, hand_keypoints, skeleton_segments, vertex_normals
from .meshing import MeshUpdate, Remesher
from .origin import origin_checked_servers
from .state import CodeSpaces, NamedHand, ViewState, view_params

__all__ = ["HandViewer", "serve"]


def _unique_names(hands: Sequence[NamedHand]) -> list[NamedHand]:
    seen: dict[str, int] = {}
    named = []
    for hand in hands:
        count = seen.get(hand.name, 0)
        seen[hand.name] = count + 1
        named.append(hand if count == 0 else replace(hand, name=f"{hand.name} ({count + 1})"))
    return named


class HandViewer:
    """A hand served in the browser by viser, with its controls.

    model: the trained model. hands: what the A / B dropdowns list (:class:`NamedHand`, all of
    ``model``; the first is shown). config: :class:`ViewerConfig`. model_path: the model's file
    (None: the shipped one; the photo fit loads it). photo_fit: the photo panel's fit function
    (default :func:`lisa_hand.fitting.photo.fit.fit_photo_folder`; the panel is shown only when
    MediaPipe is installed or ``photo_fit`` is given).
    """

    def __init__(self, model: TrainedModel, hands: Sequence[NamedHand],
                 config: ViewerConfig | None = None, *, model_path: str | Path | None = None,
                 photo_fit: Callable[..., Any] | None = None) -> None:
        import viser

        from .gui import build_controls

        if not hands:
            raise ValueError("the viewer needs at least one hand")
        self.model = model
        self.config = ViewerConfig() if config is None else config
        self.model_path = model_path
        self.hands: list[NamedHand] = _unique_names(hands)
        self.spaces = CodeSpaces.from_model(model)
        self.state = ViewState(hand_b=min(1, len(self.hands) - 1))  # B: the next hand
        self.params: HandParams = view_params(self.state, self.hands, self.spaces)
        self.color_mode = "skin"
        self.status = "starting"
        self.latest: dict[str, MeshUpdate] = {}
        """The newest mesh of each level ("coarse", "fine") of the current generation."""
        self._lock = threading.RLock()
        self._frozen_pose: Any = None
        self._motion: threading.Thread | None = None
        self._playing = threading.Event()
        self._template = None
        self.export_root = Path(self.config.export_dir).resolve()
        """The folder every export goes into (or into one folder inside it)."""
        with origin_checked_servers() as guard:
            self.server = viser.ViserServer(host=self.config.host, port=self.config.port,
                                            label="LISA hand", verbose=False)
        if not guard.servers:  # a viser that serves otherwise: never serve unchecked
            self.server.stop()
            raise RuntimeError("lisa view: viser started no origin-checked server (viser "
                               f"{viser.__version__}; lisa view needs viser 1.1.1)")
        self.server.gui.configure_theme(control_width="large")
        self._scene_setup()
        self.remesher = Remesher(model, self._on_mesh, self.config.remesh,
                                 on_error=self._on_error)
        self.controls = build_controls(self, photo_fit)
        self.refresh()

    # -- lifecycle ---------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        host = self.config.host if self.config.host not in ("0.0.0.0", "") else "127.0.0.1"
        return f"http://{host}:{self.port}"

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until the newest hand is meshed at every level. -> True when it is"""
        return self.remesher.wait_idle(timeout)

    def close(self) -> None:
        self._playing.clear()
        if self._motion is not None:
            self._motion.join(timeout=5.0)
        self.remesher.close()
        self.server.stop()

    # -- state -------------------------------------------------------------------------------
    def set_state(self, state: ViewState) -> None:
        """Show ``state`` (a stopped motion's frame is dropped); a new hand A is framed."""
        with self._lock:
            new_hand = state.hand_a != self.state.hand_a
            previous, self.state = self.state, state
            self._frozen_pose = None
            try:
                self.refresh()
            except ValueError as exc:  # e.g. a colour between a hand with and one without
                self.state = previous
                self.status = f"cannot show this: {exc}"
                self.controls.show_status(self.status)
                return
            if new_hand:
                self.frame_hand()

    def frame_hand(self) -> None:
        """Point every browser's camera (and that of browsers still to come) at the hand,
        keeping its direction and distance (a photo's hand lies where its camera saw it)."""
        from .display import posed_joints

        centre = posed_joints(self.params).mean(axis=0)
        initial = self.server.initial_camera
        offset = np.asarray(initial.position) - np.asarray(initial.look_at)
        initial.look_at = tuple(centre)
        initial.position = tuple(centre + offset)
        for client in self.server.get_clients().values():
            client_offset = np.asarray(client.camera.position) - np.asarray(
                client.camera.look_at)
            client.camera.look_at = centre
            client.camera.position = centre + client_offset

    def add_hand(self, hand: NamedHand, show: bool = True) -> int:
        """Add a hand to the dropdowns (and show it as hand A). -> its index"""
        with self._lock:
            self.hands = _unique_names([*self.hands, hand])
            index = len(self.hands) - 1
            self.controls.hands_changed()
            if show:
                self.controls.set_hand_a(index)
            return index

    def refresh(self) -> None:
        """Recompute the hand from the state, redraw its skeleton and keypoints, remesh it."""
        with self._lock:
            params = view_params(self.state, self.hands, self.spaces)
            if self._frozen_pose is not None:
                params = params.with_pose(self._frozen_pose)
            self.params = params
            self.latest = {}
            self._draw_overlays(params)
            self.controls.state_changed()
            self.remesher.request(params)

    def set_color_mode(self, mode: str) -> None:
        with self._lock:
            self.color_mode = mode
            update = self.latest.get("fine") or self.latest.get("coarse")
            if update is not None:
                self._draw_mesh(update.mesh)

    # -- scene -------------------------------------------------------------------------------
    def _scene_setup(self) -> None:
        from .display import posed_joints

        joints = posed_joints(self.params)
        centre = joints.mean(axis=0)
        scene = self.server.scene
        scene.set_up_direction((-1.0, 0.0, 0.0))  # MANO's fingers point along -x
        camera = self.server.initial_camera
        camera.look_at = tuple(centre)
        camera.position = tuple(centre + np.array([0.0, -0.34, 0.0]))  # palm side
        camera.up = (-1.0, 0.0, 0.0)
        camera.near = 0.01
        self._skeleton = None
        self._keypoints = None
        self._mesh_handle = None
        self._hand_visible = True

    def _template_once(self):
        if self._template is None:
            from ..handmodel.template import load_template

            self._template = load_template()
        return self._template

    def _draw_overlays(self, params: HandParams) -> None:
        scene = self.server.scene
        segments = skeleton_segments(params).astype(np.float32)
        show_skeleton = self.controls.show_skeleton if hasattr(self, "controls") else False
        show_points = self.controls.show_keypoints if hasattr(self, "controls") else False
        self._skeleton = scene.add_line_segments(
            "/skeleton", segments, colors=(30, 30, 30), thickness=0.0025,
            visible=show_skeleton)
        keypoints = hand_keypoints(params, self._template_once()).astype(np.float32)
        self._keypoints = scene.add_point_cloud(
            "/keypoints", keypoints, colors=(230, 40, 40), point_size=0.005,
            point_shape="circle", visible=show_points)

    def set_overlays(self, skeleton: bool, keypoints: bool) -> None:
        if self._skeleton is not None:
            self._skeleton.visible = skeleton
        if self._keypoints is not None:
            self._keypoints.visible = keypoints

    def _draw_mesh(self, mesh: Mesh) -> None:
        import trimesh
        from trimesh.exchange.gltf import export_glb

        colors = display_colors(mesh, self.color_mode)
        tri = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, vertex_colors=colors,
                              vertex_normals=vertex_normals(mesh.vertices, mesh.faces),
                              process=False)
        self._mesh_handle = self.server.scene.add_glb(
            "/hand", export_glb(tri, include_normals=True), visible=self._hand_visible)

    def set_hand_visible(self, visible: bool) -> None:
        """Show or hide the hand's surface (the browser check photographs the page without it,
        then with it)."""
        with self._lock:
            self._hand_visible = bool(visible)
            if self._mesh_handle is not None:
                self._mesh_handle.visible = self._hand_visible

    def _on_mesh(self, update: MeshUpdate) -> None:
        with self._lock:
            if update.generation != self.remesher.generation:
                return
            self.latest[update.level] = update
            if not self._playing.is_set():
                self._draw_mesh(update.mesh)
            self.status = (f"{update.level} mesh {update.resolution}^3: "
                           f"{update.mesh.num_vertices} vertices, {update.seconds:.2f} s")
            self.controls.show_status(self.status)

    def _on_error(self, exc: BaseException) -> None:
        self.status = f"meshing failed: {type(exc).__name__}: {exc}"
        self.controls.show_status(self.status)

    # -- motions -----------------------------------------------------------------------------
    def play(self, name: str) -> None:
        """Play the named motion (from the hand's pose to pose ``name`` and back, looping),
        re-posing the newest mesh by its skinning weights."""
        self.pause()
        with self._lock:
            self._frozen_pose = None
            base = view_params(self.state, self.hands, self.spaces)
            frames = motion_poses(base, name, self.config.motion_frames)
        self._playing.set()
        self._motion = threading.Thread(target=self._play, args=(base, frames), daemon=True,
                                        name="lisa-view-motion")
        self._motion.start()

    def pause(self) -> None:
        """Stop a playing motion at its frame (remeshed through the field)."""
        if not self._playing.is_set():
            return
        self._playing.clear()
        if self._motion is not None:
            self._motion.join(timeout=5.0)
        with self._lock:
            self._frozen_pose = self.params.pose
            self.refresh()

    def _play(self, base: HandParams, frames) -> None:
        self.remesher.wait_idle(timeout=60.0)
        update = self.latest.get("fine") or self.latest.get("coarse")
        period = 1.0 / self.config.motion_fps
        index = 0
        while self._playing.is_set() and update is not None:
            start = time.monotonic()
            pose = frames[index % len(frames)]
            with self._lock:
                if not self._playing.is_set():
                    break
                self.params = base.with_pose(pose)
                self._draw_mesh(repose_mesh(update.mesh, update.params, pose))
                self._draw_overlays(self.params)
            index += 1
            time.sleep(max(0.0, period - (time.monotonic() - start)))


def serve(model: TrainedModel, hands: Sequence[NamedHand], config: ViewerConfig | None = None,
          *, model_path: str | Path | None = None,
          log: Callable[[str], None] | None = print) -> None:
    """Serve the viewer until Ctrl-C (``lisa view``), torch on ``config.threads`` threads."""
    config = ViewerConfig() if config is None else config
    log = log or (lambda line: None)
    with cpu_threads(config.threads):
        viewer = HandViewer(model, hands, config, model_path=model_path)
        log(f"lisa view: open {viewer.url} in a browser (Ctrl-C stops)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            log("lisa view: stopped")
        finally:
            viewer.close()
