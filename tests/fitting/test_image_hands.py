"""Several hands in the same calibrated views (lisa_hand.fitting.images.hands.fit_image_folders):
a right and a left hand of the tiny model apart in one 3-camera rig, a frame folder each; what
is written (each hand's folder, ``hands.json``, ``hands.ply``) against the files themselves and
the true hands; and the inputs it refuses before anything is read or written."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch

from lisa_hand.data.meshio import load_mesh
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.folder import render_fitted_views
from lisa_hand.fitting.images.hands import fit_image_folders
from lisa_hand.fitting.images.views import ImageView
from lisa_hand.fitting.outputs import hand_keypoints_3d
from lisa_hand.fitting.pair.config import JointConfig
from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.geometry.cameras import make_rig
from lisa_hand.metrics.keypoints import mrrpe
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton.params import read_params
from tests.fitting.image_scene import FAST_RENDER, tiny_model, true_hand, write_frame

WIDTH, HEIGHT = 80, 60
APART_M = 0.25
"""Between the hands' keypoint centres, along x: the tiny model's blob hands (up to 19 cm
long) are then about 5 cm apart."""

FAST = FitImagesConfig(keypoint_iters=60, color_iters=4, num_rays=64, render=FAST_RENDER,
                       restarts=6, rotation_pool=512, joint=JointConfig(iters=20, samples=300),
                       device="cpu")


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


def _frame(model, hand, cameras) -> list[ImageView]:
    """Views of ``hand`` alone in ``cameras``: rendered with the model, its mask (opacity >
    0.5), its keypoints (:func:`hand_keypoints_3d`, either side) projected."""
    keypoints = torch.as_tensor(hand_keypoints_3d(hand), dtype=torch.float32)
    blank = [ImageView(name=camera.name, camera=camera, rgb=torch.zeros(HEIGHT, WIDTH, 3))
             for camera in cameras]
    views = []
    for camera, render in zip(cameras, render_fitted_views(model, hand, blank, samples=24),
                              strict=True):
        pixels, _ = camera.project(keypoints)
        views.append(ImageView(name=camera.name, camera=camera, rgb=render.rgb,
                               mask=render.opacity > 0.5, keypoints=pixels))
    return views


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The tiny model (exported), a right hand and a left hand (another hand mirrored) APART_M
    apart, and their frame folders ``right/`` and ``left/`` in the same three cameras."""
    root = tmp_path_factory.mktemp("image_hands")
    model = tiny_model()
    right = true_hand(model, seed=1)
    left = mirror_hand(true_hand(model, seed=2))
    centre = hand_keypoints_3d(right).mean(0)
    move = centre + np.array([APART_M, 0.0, 0.0]) - hand_keypoints_3d(left).mean(0)
    left = replace(left, translation=left.translation + torch.as_tensor(move).float())
    middle = 0.5 * (centre + hand_keypoints_3d(left).mean(0))
    cameras = make_rig(3, target=middle.tolist(), radius=0.8, width=WIDTH, height=HEIGHT,
                       fov_deg=45.0, seed=0)
    frames = {}
    for side, hand in (("right", right), ("left", left)):
        views = _frame(model, hand, cameras)
        for view in views:  # the whole hand in every view
            assert view.mask.sum() > 100
            assert bool(((view.keypoints >= 0) & (view.keypoints < torch.tensor(
                [WIDTH, HEIGHT]))).all())
        frames[side] = write_frame(root / side, views)
    model_path, _ = export_trained(model, root / "model.pt")
    return {"root": root, "model": model_path, "right": right, "left": left, "frames": frames}


def test_fits_each_hand_and_writes_the_pair(scene):
    out = scene["root"] / "out"
    said = []
    written = fit_image_folders([scene["frames"]["right"], scene["frames"]["left"]], out,
                                ["right", "left"], model_path=scene["model"], resolution=32,
                                config=FAST, device="cpu", log=said.append)
    assert said[:2] == [f"hand0: {scene['frames']['right']} (right)",
                        f"hand1: {scene['frames']['left']} (left)"]
    assert said[2].startswith("2 hands fitted together: keypoint error ")
    assert sorted(p.name for p in out.iterdir()) == ["hand0", "hand1", "hands.json",
                                                     "hands.ply"]
    assert {p.resolve() for p in written} >= {(out / "hands.json").resolve(),
                                             (out / "hands.ply").resolve()}
    meshes, fitted = [], []
    for index, side in enumerate(("right", "left")):
        folder = out / f"hand{index}"
        assert sorted(p.name for p in folder.iterdir()) == ["keypoints.json", "mesh.ply",
                                                            "params.json"]
        params = read_params(folder / "params.json")
        assert params.side == side and params.color_code is not None
        assert params.extra["input"]["path"] == str(scene["frames"][side])
        keypoints = json.loads((folder / "keypoints.json").read_text())
        assert keypoints["side"] == side
        fitted.append(np.asarray(keypoints["keypoints_3d"]))
        assert np.allclose(fitted[-1], hand_keypoints_3d(params), atol=1e-6)
        meshes.append(load_mesh(folder / "mesh.ply"))
        assert meshes[-1].num_faces > 100
    record = json.loads((out / "hands.json").read_text())
    assert [(entry["folder"], entry["side"]) for entry in record["hands"]] == [
        ("hand0", "right"), ("hand1", "left")]
    for entry, keypoints in zip(record["hands"], fitted, strict=True):
        assert np.allclose(entry["root_m"], keypoints[0], atol=1e-6)
    assert np.allclose(record["right_to_left_m"], fitted[1][0] - fitted[0][0], atol=2e-6)
    # The hands are about 5 cm apart: nothing of one inside the other (measured 0.0).
    assert 0.0 <= record["penetration_mm"] < 0.5
    # Hands apart have nothing to resolve: the joint stage leaves them as fitted alone.
    joint = record["joint"]
    assert joint["iters"] == 0 and joint["penetration_start_mm"] == joint["penetration_end_mm"]
    assert len(joint["keypoint_error_end_px"]) == 2
    assert max(joint["keypoint_error_end_px"]) < 2.0  # measured 0.2 and 0.3 px
    # Against the true hands (each about 15 pixels across): measured MRRPE 8 mm.
    true = [hand_keypoints_3d(scene["right"]), hand_keypoints_3d(scene["left"])]
    assert mrrpe(fitted[0], fitted[1], true[0], true[1]) < 20.0
    joined = load_mesh(out / "hands.ply")
    assert joined.num_vertices == sum(mesh.num_vertices for mesh in meshes)
    assert joined.num_faces == sum(mesh.num_faces for mesh in meshes)


def _refused(scene, tmp_path, frames, sides, message: str) -> None:
    """``fit_image_folders`` refuses in one line naming ``message``, before the model is read
    (a missing model file) and with nothing written."""
    out = tmp_path / "out"
    with pytest.raises(ValueError) as info:
        fit_image_folders(frames, out, sides, model_path=tmp_path / "missing.pt",
                          config=FAST, device="cpu")
    text = str(info.value)
    assert message in text and "\n" not in text, text
    assert not out.exists()


def test_folders_with_other_cameras_are_refused(scene, tmp_path):
    other = tmp_path / "fewer"
    shutil.copytree(scene["frames"]["left"], other)
    cameras = json.loads((other / "cameras.json").read_text())
    (other / "cameras.json").write_text(json.dumps(cameras[:2]))  # cam000, cam001
    (other / "images" / "cam002.png").unlink()
    right = scene["frames"]["right"]
    _refused(scene, tmp_path, [right, other], ["right", "left"],
             f"the frame folders {right}, {other} must hold the same cameras")


def test_folders_with_the_same_names_but_other_calibrations_are_refused(scene, tmp_path):
    moved = tmp_path / "moved"
    shutil.copytree(scene["frames"]["left"], moved)
    cameras = json.loads((moved / "cameras.json").read_text())
    cameras[1]["t"] = [value + 0.01 for value in cameras[1]["t"]]  # cam001 moved by 1 cm
    (moved / "cameras.json").write_text(json.dumps(cameras))
    _refused(scene, tmp_path, [scene["frames"]["right"], moved], ["right", "left"],
             f"{moved}: camera cam001 is not")


@pytest.mark.parametrize("folders, sides, message", [
    (2, ["right"], "2 frame folder(s) and 1 side(s): give one --side per folder"),
    (2, ["right", "left", "left"], "2 frame folder(s) and 3 side(s)"),
    (1, ["right"], "1 frame folder(s) and 1 side(s)"),
    (2, ["right", "middle"], "side must be 'right' or 'left', got 'middle'"),
])
def test_sides_must_be_one_per_folder(scene, tmp_path, folders, sides, message):
    frames = [scene["frames"]["right"], scene["frames"]["left"]][:folders]
    _refused(scene, tmp_path, frames, sides, message)
