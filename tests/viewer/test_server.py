"""``lisa view``'s server in-process (lisa_hand.viewer.server, .gui, .export, .photo): GUI values
set through viser's Python API (the callbacks a browser runs), the hand and its mesh checked."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lisa_hand.data.meshio import load_mesh
from lisa_hand.handmodel.poses import pose_to_angles
from lisa_hand.inference import MeshConfig, mesh_hand
from lisa_hand.inference.sequences import motion_poses
from lisa_hand.skeleton import FINGER_JOINTS
from lisa_hand.skeleton.params import read_params
from lisa_hand.utils.io import read_json
from lisa_hand.viewer.display import posed_joints

from .conftest import PADDING, free_port

pytest.importorskip("viser", reason="the view extra (viser) is not installed: "
                                    "pip install -e '.[view]'")

from lisa_hand.viewer.config import ViewerConfig  # noqa: E402
from lisa_hand.viewer.meshing import RemeshConfig  # noqa: E402
from lisa_hand.viewer.server import HandViewer  # noqa: E402
from lisa_hand.viewer.state import NamedHand  # noqa: E402

REMESH = RemeshConfig(coarse_resolution=16, fine_resolution=28, padding=PADDING)


@pytest.fixture()
def viewer(model, hands, tmp_path):
    config = ViewerConfig(port=free_port(), remesh=REMESH, export_dir=tmp_path / "export",
                          export_resolution=24, motion_fps=50.0, motion_frames=3)
    viewer = HandViewer(model, hands, config, photo_fit=_fake_fit(hands[1].params))
    assert viewer.wait_idle(60.0)
    yield viewer
    viewer.close()


def _fake_fit(params, calls=None):
    """A stand-in for fit_photo_folder (the real fit takes ~25 s): one report with ``params``."""
    def fit(photos, out_dir, *, model_path=None, progress=True, log=print):
        if calls is not None:
            calls.append((photos, out_dir, model_path, progress))
        log("fitting the fake way")
        return [SimpleNamespace(params=params)]

    return fit


def _fine(viewer):
    assert viewer.wait_idle(60.0)
    return viewer.latest["fine"]


def test_serves_the_first_hand_coarse_then_fine(viewer, model, hands):
    update = _fine(viewer)
    assert update.params is viewer.params and update.resolution == 28
    reference = mesh_hand(model, viewer.params, 28, MeshConfig(padding=PADDING))
    assert np.array_equal(update.mesh.vertices, reference.vertices)
    assert viewer.latest["coarse"].mesh.num_vertices < update.mesh.num_vertices
    assert "fine mesh 28^3" in viewer.controls.handles["status"].content
    assert viewer.url == f"http://127.0.0.1:{viewer.config.port}"


def test_curl_slider_flexes_the_finger_and_remeshes(viewer, model):
    handles = viewer.controls.handles
    handles["named_pose"].value = "flat"
    handles["index_curl"].value = 0.5
    angles = pose_to_angles(viewer.params.pose)
    for joint, flexion in zip(FINGER_JOINTS["index"], (0.70, 0.875, 0.575), strict=True):
        assert float(angles[joint - 1, 0]) == pytest.approx(flexion, abs=1e-5)
        # The 45 finger sliders show the result, in degrees.
        slider = handles[f"finger_{3 * (joint - 1)}"].value
        assert slider == pytest.approx(math.degrees(flexion), abs=0.01)
    assert float(angles[FINGER_JOINTS["middle"][1] - 1, 0]) == pytest.approx(0.0, abs=1e-6)
    update = _fine(viewer)
    reference = mesh_hand(model, viewer.params, 28, MeshConfig(padding=PADDING))
    assert np.array_equal(update.mesh.vertices, reference.vertices)


def test_finger_slider_sets_the_joint_angle(viewer):
    handles = viewer.controls.handles
    handles["finger_3"].value = 33.0  # index2 flexion, degrees
    angles = pose_to_angles(viewer.params.pose)
    assert math.degrees(float(angles[1, 0])) == pytest.approx(33.0, abs=1e-3)
    handles["reset_pose"].value = True  # a click
    assert torch.allclose(viewer.params.pose, viewer.hands[0].params.pose)


def test_swapping_colour_keeps_shape_code_and_surface(viewer, hands):
    before = _fine(viewer).mesh
    handles = viewer.controls.handles
    handles["hand_b"].value = "B"
    handles["swap_color"].value = True
    a, b = hands[0].params, hands[1].params
    assert torch.equal(viewer.params.shape_code, a.shape_code)
    assert torch.equal(viewer.params.color_code, b.color_code)
    after = _fine(viewer).mesh
    # The SDF never sees the colour code: the same surface, other colours.
    assert np.array_equal(after.vertices, before.vertices)
    assert np.abs(after.colors.astype(int) - before.colors).mean() > 1.0
    handles["swap_shape"].value = True
    assert torch.equal(viewer.params.shape_code, b.shape_code)
    assert torch.equal(viewer.params.color_code, a.color_code)


def test_interpolation_sliders_reach_both_hands(viewer, hands):
    handles = viewer.controls.handles
    handles["hand_b"].value = "B"
    for key in ("shape_t", "color_t", "pose_t"):
        handles[key].value = 1.0
    b = hands[1].params
    for key in ("pose", "translation", "rest_joints", "shape_code", "color_code"):
        assert torch.equal(getattr(viewer.params, key), getattr(b, key)), key
    for key in ("shape_t", "color_t", "pose_t"):
        handles[key].value = 0.0
    assert torch.equal(viewer.params.shape_code, hands[0].params.shape_code)
    handles["swap_hands"].value = True
    assert handles["hand_a"].value == "B" and viewer.state.hand_a == 1


def test_export_writes_params_and_mesh(viewer, tmp_path):
    handles = viewer.controls.handles
    handles["index_curl"].value = 0.3
    handles["export_dir"].value = "out"  # a folder inside the viewer's export folder
    handles["export"].value = True
    out = tmp_path / "export" / "out"
    params = read_params(out / "params.json")
    for key in ("pose", "translation", "rest_joints", "shape_code", "color_code"):
        assert torch.equal(getattr(params, key), getattr(viewer.params, key)), key
    mesh = load_mesh(out / "mesh.ply")
    assert mesh.num_faces > 0 and mesh.skin_weights.shape == (mesh.num_vertices, 16)
    assert np.allclose(mesh.skin_weights.sum(1), 1.0, atol=1e-4)
    view = read_json(out / "view.json")
    assert view["state"]["pose"]["synergies"][0] == pytest.approx(0.3)
    assert view["mesh"]["resolution"] == 24
    assert handles["export_status"].content.startswith(f"wrote {out.resolve()}")


def test_export_to_a_file_is_one_status_line(viewer, tmp_path):
    blocker = viewer.export_root / "file"
    blocker.parent.mkdir(parents=True, exist_ok=True)
    blocker.write_text("x")
    viewer.controls.handles["export_dir"].value = "file"
    viewer.controls.handles["export"].value = True
    line = viewer.controls.handles["export_status"].content
    assert line == f"export failed: {blocker}: not a folder"
    viewer.controls.handles["screenshot"].value = True
    assert "no browser" in viewer.controls.handles["export_status"].content


def test_motion_plays_by_skinning_and_pauses_on_a_frame(viewer):
    handles = viewer.controls.handles
    base = viewer.params
    frames = motion_poses(base, "fist", viewer.config.motion_frames)
    handles["motion"].value = "fist"
    handles["play"].value = True
    deadline = time.monotonic() + 10.0
    while torch.equal(viewer.params.pose, base.pose) and time.monotonic() < deadline:
        time.sleep(0.02)
    handles["play"].value = False
    shown = viewer.params.pose
    assert not torch.equal(shown, base.pose)
    assert min(float((shown - frame).abs().max()) for frame in frames) < 1e-6
    assert torch.equal(_fine(viewer).params.pose, shown)  # the paused frame, remeshed


def test_display_controls(viewer):
    handles = viewer.controls.handles
    handles["color_mode"].value = "skinning weights"
    assert viewer.color_mode == "skinning weights"
    handles["skeleton"].value = True
    handles["keypoints"].value = True
    assert viewer._skeleton.visible and viewer._keypoints.visible
    handles["surface"].value = False
    assert not viewer._mesh_handle.visible
    viewer.refresh()
    assert viewer.wait_idle(60.0) and not viewer._mesh_handle.visible  # stays hidden
    handles["side"].value = "left"
    assert viewer.params.side == "left"
    mirrored = -viewer.hands[0].params.rest_joints[:, 0]
    assert torch.allclose(viewer.params.rest_joints[:, 0], mirrored)
    handles["shape_pc0"].value = 0.5
    assert viewer.state.shape_pcs == (0.5,)


def test_photo_upload_fits_in_the_background_and_shows_the_hand(viewer, hands):
    from viser import UploadedFile

    def upload(name: str, content: bytes) -> None:
        # What viser does when a browser's upload finishes (_finish_file_upload): the value is
        # set and the callbacks run (a value cannot be assigned to an upload button).
        handle = viewer.controls.handles["photo_upload"]
        handle._impl.value = UploadedFile(name, content)
        for callback in handle._impl.update_cb:
            callback(None)

    calls = []
    viewer.controls.photo.fit = _fake_fit(hands[1].params, calls)
    upload("hand.jpg", b"\xff\xd8jpeg")
    viewer.controls.photo.thread.join(30.0)
    assert calls and calls[0][0][0].read_bytes() == b"\xff\xd8jpeg" and calls[0][3] is False
    assert viewer.hands[-1].name == "photo hand" and viewer.state.hand_a == len(viewer.hands) - 1
    assert torch.equal(viewer.params.shape_code, hands[1].params.shape_code)
    # The camera now looks at the new hand A (B's place: 5 cm off A's).
    centre = posed_joints(viewer.params).mean(axis=0)
    assert np.allclose(viewer.server.initial_camera.look_at, centre, atol=1e-6)
    assert "fitted 1 hand" in viewer.controls.handles["photo_status"].content
    upload("notes.txt", b"hello")
    assert "not a photo" in viewer.controls.handles["photo_status"].content


def test_no_photo_panel_without_the_extra(model, hands, monkeypatch):
    import lisa_hand.viewer.photo as photo

    monkeypatch.setattr(photo, "photo_available", lambda: False)
    viewer = HandViewer(model, [hands[0], NamedHand("A", hands[1].params)],
                        ViewerConfig(port=free_port(), remesh=REMESH))
    try:
        assert viewer.controls.photo is None and "photo_upload" not in viewer.controls.handles
        assert [hand.name for hand in viewer.hands] == ["A", "A (2)"]
    finally:
        viewer.close()


def test_a_state_that_cannot_be_shown_is_one_status_line(viewer, hands):
    from dataclasses import replace

    bare = NamedHand("no colour", replace(hands[1].params, color_code=None))
    index = viewer.add_hand(bare, show=False)
    viewer.controls.handles["hand_b"].value = "no colour"
    assert viewer.state.hand_b == index
    viewer.controls.handles["color_t"].value = 0.5
    assert viewer.state.color_t == 0.0  # kept the state it could show
    assert viewer.controls.handles["color_t"].value == 0.0  # and its slider went back
    assert viewer.controls.handles["status"].content.startswith(
        "cannot show this: cannot interpolate color_code: hand B has none")
