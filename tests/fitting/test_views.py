"""The image fit's input: reading a frame folder (validation, fallbacks, keypoints outside the
image), the background colour and the mirrored views of a left hand."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from lisa_hand.data.layout import write_image, write_mask
from lisa_hand.fitting.images.views import (
    KEYPOINT_MARGIN,
    ImageView,
    background_colour,
    input_notes,
    keypoints_outside,
    mirror_view,
    read_views,
)
from lisa_hand.geometry.cameras import Camera, make_rig
from lisa_hand.skeleton import KEYPOINT_NAMES, mirror_points
from tests.fitting.image_scene import HEIGHT, WIDTH, make_scene

pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory)


def test_read_views_round_trip(scene):
    views = read_views(scene["folder"])
    assert [v.name for v in views] == [v.name for v in scene["views"]]
    for read, written in zip(views, scene["views"], strict=True):
        assert read.rgb.shape == (HEIGHT, WIDTH, 3) and read.rgb.dtype == torch.float32
        assert torch.equal(read.mask, written.mask)
        assert (read.rgb - written.rgb).abs().max() <= 0.5 / 255 + 1e-6  # 8-bit PNG
        assert torch.allclose(read.keypoints, written.keypoints, atol=1e-4)
        assert bool(read.visible.all()) and torch.allclose(read.camera.K, written.camera.K)
        assert read.dropped_keypoints == ()
    subset = read_views(scene["folder"], ["cam002", "cam000"])
    assert [v.name for v in subset] == ["cam002", "cam000"]
    assert input_notes(views) == []


def _copy(scene, tmp_path):
    folder = tmp_path / "frame"
    shutil.copytree(scene["folder"], folder)
    return folder


def _drop_camera_field(folder):
    cameras = json.loads((folder / "cameras.json").read_text())
    del cameras[1]["K"]
    (folder / "cameras.json").write_text(json.dumps(cameras))


def _small_image(folder):
    write_image(folder / "images" / "cam001.png", np.zeros((30, 40, 3), np.uint8))


def _small_mask(folder):
    write_mask(folder / "masks" / "cam001.png", np.ones((30, 40), bool))


def _empty_mask(folder):
    write_mask(folder / "masks" / "cam002.png", np.zeros((HEIGHT, WIDTH), bool))


def _bad_keypoints(folder):
    data = json.loads((folder / "keypoints.json").read_text())
    data["views"]["cam000"]["keypoints"] = data["views"]["cam000"]["keypoints"][:20]
    (folder / "keypoints.json").write_text(json.dumps(data))


def _nothing_to_locate(folder):
    shutil.rmtree(folder / "masks")
    (folder / "keypoints.json").unlink()


@pytest.mark.parametrize("damage, names, message", [
    (lambda f: (f / "cameras.json").unlink(), None, r"cameras\.json: no such file"),
    (_drop_camera_field, None, r"cameras\.json: camera 1: missing camera field\(s\): K"),
    (lambda f: (f / "images" / "cam001.png").unlink(), None, r"images/cam001\.png: no such"),
    (_small_image, None, r"images/cam001\.png: image is 40x30 but camera 'cam001'"),
    (_small_mask, None, r"masks/cam001\.png: mask is 40x30 but camera 'cam001'"),
    (_empty_mask, None, r"masks/cam002\.png: the mask is empty"),
    (_bad_keypoints, None, r"keypoints\.json: view 'cam000': 'keypoints' must be \[21, 2\]"),
    (_nothing_to_locate, None, r"no view has a mask .* or keypoints"),
    (lambda f: None, ["cam000", "cam9"], r"cameras\.json: no camera named 'cam9'"),
])  # fmt: skip
def test_read_views_errors_name_the_file(scene, tmp_path, damage, names, message):
    folder = _copy(scene, tmp_path)
    damage(folder)
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        read_views(folder, names)


def test_missing_masks_and_keypoints_are_documented_fallbacks(scene, tmp_path):
    folder = _copy(scene, tmp_path)
    (folder / "masks" / "cam001.png").unlink()
    views = read_views(folder)
    assert views[1].mask is None and views[0].mask is not None
    assert any("no mask for view(s) cam001" in note for note in input_notes(views))
    (folder / "keypoints.json").unlink()
    views = read_views(folder)
    assert all(v.keypoints is None for v in views)
    assert any(note.startswith("no keypoints: the pose comes from the masks alone")
               for note in input_notes(views))
    # Background of a view without a mask: the median colour of the image border.
    rgb = torch.full((HEIGHT, WIDTH, 3), 0.25)
    rgb[10:20, 10:20] = torch.tensor([0.9, 0.1, 0.1])
    rgb[0, :5] = 1.0  # a few outliers on the border do not move the median
    view = ImageView(name="v", camera=scene["views"][0].camera, rgb=rgb)
    assert torch.allclose(background_colour(view), torch.full((3,), 0.25))
    masked = ImageView(name="v", camera=view.camera, rgb=rgb, mask=rgb[..., 0] > 0.5)
    assert torch.equal(background_colour(masked), torch.zeros(3))


def test_keypoints_outside_the_image_are_dropped_with_a_note(scene, tmp_path):
    assert keypoints_outside(torch.tensor([[-0.5, 3.0], [WIDTH * (1 + KEYPOINT_MARGIN) - 0.1,
                                                         -HEIGHT * KEYPOINT_MARGIN + 0.1],
                                           [WIDTH + 40.0, 3.0], [3.0, -5000.0]]),
                             WIDTH, HEIGHT).tolist() == [False, False, True, True]
    folder = _copy(scene, tmp_path)
    data = json.loads((folder / "keypoints.json").read_text())
    for index in (0, 8, 12):  # wrist, index tip, middle tip: thousands of pixels away
        data["views"]["cam001"]["keypoints"][index] = [4000.0 + index, -3000.0]
    (folder / "keypoints.json").write_text(json.dumps(data))
    views = read_views(folder)
    assert views[1].dropped_keypoints == (KEYPOINT_NAMES[0], KEYPOINT_NAMES[8],
                                          KEYPOINT_NAMES[12])
    assert views[1].visible.sum() == 18 and not views[1].visible[[0, 8, 12]].any()
    assert views[0].dropped_keypoints == () and bool(views[0].visible.all())
    notes = input_notes(views)
    assert any(note.startswith("view cam001: 3 keypoint(s) marked visible lie more than 10% "
                               "of the image size outside it") for note in notes)
    # The dropping survives moving and mirroring the view.
    moved = mirror_view(views[1].to("cpu"))
    assert moved.dropped_keypoints == views[1].dropped_keypoints
    assert torch.equal(moved.visible, views[1].visible)


def test_only_keypoints_outside_the_image_cannot_locate_the_hand(scene, tmp_path):
    folder = _copy(scene, tmp_path)
    shutil.rmtree(folder / "masks")
    data = json.loads((folder / "keypoints.json").read_text())
    for entry in data["views"].values():
        entry["keypoints"] = [[u + 5000.0, v] for u, v in entry["keypoints"]]
    (folder / "keypoints.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"no view has a mask .* \(63 keypoint\(s\) marked "
                                         r"visible lie outside the images\)"):
        read_views(folder)


def test_mirror_view_sees_the_mirrored_world():
    camera = make_rig(1, width=40, height=30, seed=3)[0]
    camera = Camera(K=torch.tensor([[50.0, 2.0, 18.0], [0.0, 55.0, 16.0], [0.0, 0.0, 1.0]]),
                    R=camera.R, t=camera.t, width=40, height=30, name="c")
    points = torch.randn(10, 3, generator=torch.Generator().manual_seed(0)) * 0.05
    pixels, depth = camera.project(points)
    rgb = torch.rand(30, 40, 3, generator=torch.Generator().manual_seed(1))
    keypoints = torch.rand(21, 2, generator=torch.Generator().manual_seed(2)) * 30.0
    view = ImageView(name="c", camera=camera, rgb=rgb, mask=rgb[..., 0] > 0.5,
                     keypoints=keypoints)
    mirrored = mirror_view(view)
    mirrored_pixels, mirrored_depth = mirrored.camera.project(mirror_points(points))
    assert torch.allclose(mirrored_pixels[:, 0], 40.0 - pixels[:, 0], atol=1e-4)
    assert torch.allclose(mirrored_pixels[:, 1], pixels[:, 1], atol=1e-4)
    assert torch.allclose(mirrored_depth, depth, atol=1e-6)
    assert torch.equal(mirrored.rgb[:, 0], rgb[:, -1]) and torch.equal(mirrored.mask,
                                                                        view.mask.flip(1))
    assert torch.allclose(mirrored.keypoints[:, 0], 40.0 - view.keypoints[:, 0])
    assert torch.allclose(mirror_view(mirrored).camera.K, camera.K)


def test_mirror_view_mirrors_the_landmarks_in_its_camera_axes():
    """A view's 3D landmarks are in its camera's axes: the mirrored view's are the mirrored
    points in the mirrored camera's frame."""
    camera = make_rig(1, width=40, height=30, seed=3)[0]
    points = torch.randn(21, 3, generator=torch.Generator().manual_seed(0)) * 0.05
    landmarks = points @ camera.R.T + camera.t
    view = ImageView(name="c", camera=camera, rgb=torch.zeros(30, 40, 3),
                     landmarks_3d=landmarks)
    mirrored = mirror_view(view)
    expected = mirror_points(points) @ mirrored.camera.R.T + mirrored.camera.t
    assert torch.allclose(mirrored.landmarks_3d, expected, atol=1e-6)
    assert torch.equal(view.to("cpu").landmarks_3d, landmarks)
    with pytest.raises(ValueError, match="landmarks_3d must be"):
        ImageView(name="c", camera=camera, rgb=torch.zeros(30, 40, 3),
                  landmarks_3d=landmarks[:20])


def test_folders_and_files_in_the_wrong_place_are_named(tmp_path):
    from lisa_hand.fitting.images.views import read_views

    not_a_folder = tmp_path / "frame.txt"
    not_a_folder.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file, expected a frame folder"):
        read_views(not_a_folder)
    frame = tmp_path / "frame"
    (frame / "cameras.json").mkdir(parents=True)
    with pytest.raises(IsADirectoryError, match="cameras.json: is a directory"):
        read_views(frame)
