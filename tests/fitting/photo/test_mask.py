"""The photo fit's hand masks: the keypoint-only fallback (what CI runs), GrabCut seeded by the
skeleton (needs OpenCV, the [photo] extra), the forearm cut at the wrist, and the refinement with
a fitted silhouette; on pictures of the mesh template's hand with a known silhouette."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.fitting.photo.mask import (
    HAND_BONES,
    coarse_mask,
    hand_scale_px,
    keypoint_mask,
    mask_method,
    refine_mask,
)
from lisa_hand.handmodel.poses import named_pose
from lisa_hand.handmodel.template import load_template

SKIN = np.array([0.86, 0.64, 0.52])
BACKGROUND = np.array([0.16, 0.36, 0.55])


def iou(first: np.ndarray, second: np.ndarray) -> float:
    return float((first & second).sum() / (first | second).sum())


def hand_picture(pose: str = "flat", forearm: bool = False, seed: int = 0) -> dict:
    """The template's hand, palm to the camera, fingers up, in a 200 x 240 picture: skin over a
    blue background with a gradient and noise. -> {"image", "silhouette", "keypoints",
    "forearm" (the forearm's pixels, when drawn)}."""
    from PIL import Image, ImageDraw

    template = load_template()
    posed = template.forward(named_pose(pose, dtype=torch.float64)[None],
                             torch.zeros(1, template.num_betas, dtype=torch.float64))

    def project(points: np.ndarray) -> np.ndarray:  # template (x, y, z) -> camera (z, x, y)
        camera = np.stack([points[:, 2], points[:, 0], 0.45 + points[:, 1]], axis=1)
        return 400.0 * camera[:, :2] / camera[:, 2:] + [100.0, 190.0]

    vertices = project(posed.vertices[0].numpy())
    keypoints = project(posed.keypoints[0].numpy())
    width, height = 200, 240
    canvas = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(canvas)
    for face in template.faces.numpy():
        draw.polygon([tuple(vertices[index]) for index in face], fill=255)
    silhouette = np.asarray(canvas) > 0
    arm = np.zeros_like(silhouette)
    if forearm:  # a skin-coloured band from the wrist down to the picture's edge
        arm_canvas = Image.new("L", (width, height), 0)
        wrist = keypoints[0]
        ImageDraw.Draw(arm_canvas).polygon(
            [(wrist[0] - 28, wrist[1] - 4), (wrist[0] + 28, wrist[1] - 4),
             (wrist[0] + 34, height), (wrist[0] - 34, height)], fill=255)
        arm = (np.asarray(arm_canvas) > 0) & ~silhouette
    rng = np.random.default_rng(seed)
    rows = np.linspace(0.8, 1.1, height)[:, None, None]
    image = np.broadcast_to(BACKGROUND * rows, (height, width, 3)).copy()
    shade = 0.85 + 0.15 * np.cos(np.arange(width) / 25.0)[None, :, None]
    image[silhouette | arm] = (SKIN * shade * np.ones((height, width, 1)))[silhouette | arm]
    image = np.clip(image + rng.normal(0.0, 0.02, image.shape), 0.0, 1.0).astype(np.float32)
    return {"image": image, "silhouette": silhouette, "keypoints": keypoints, "forearm": arm}


def test_bones_form_the_21_keypoint_tree():
    assert len(HAND_BONES) == 20
    assert sorted(child for _, child in HAND_BONES) == list(range(1, 21))
    assert all(parent < child for parent, child in HAND_BONES)
    assert {parent for parent, child in HAND_BONES if child % 4 == 1} == {0}  # fingers' roots


def test_hand_size_is_the_least_foreshortened_palm_measure():
    picture = hand_picture()
    keypoints = picture["keypoints"]
    size = hand_scale_px(keypoints)
    wrist_to_middle = np.linalg.norm(keypoints[0] - keypoints[9])
    assert 0.95 * wrist_to_middle <= size <= 1.3 * wrist_to_middle
    assert hand_scale_px(2.0 * keypoints + 7.0) == pytest.approx(2.0 * size)
    squashed = keypoints * [1.0, 0.2]  # the palm seen nearly end on: the width still measures
    assert hand_scale_px(squashed) > 0.6 * size


@pytest.mark.parametrize("pose", ["flat", "relaxed", "fist"])
def test_keypoint_mask_covers_the_hand(pose):
    picture = hand_picture(pose)
    mask = keypoint_mask(picture["image"].shape[:2], picture["keypoints"])
    truth = picture["silhouette"]
    assert mask.dtype == bool and mask.shape == truth.shape
    assert (mask & truth).sum() / truth.sum() > 0.7  # most of the hand (measured 0.76-0.83)
    assert (mask & ~truth).sum() / mask.sum() < 0.2  # little background (0.04-0.12)
    assert iou(mask, truth) > 0.65  # 0.74-0.76
    forced = coarse_mask(picture["image"], picture["keypoints"], use_grabcut=False)
    assert np.array_equal(forced, mask)


@pytest.mark.parametrize("pose", ["flat", "relaxed", "fist"])
def test_grabcut_mask_follows_the_hand(pose):
    pytest.importorskip("cv2", reason="GrabCut needs OpenCV (the [photo] extra)")
    picture = hand_picture(pose)
    mask = coarse_mask(picture["image"], picture["keypoints"], use_grabcut=True)
    fallback = keypoint_mask(picture["image"].shape[:2], picture["keypoints"])
    assert iou(mask, picture["silhouette"]) > 0.93  # measured 0.97-0.98
    assert iou(mask, picture["silhouette"]) > iou(fallback, picture["silhouette"]) + 0.15
    assert mask_method() == "grabcut"


def test_grabcut_leaves_the_forearm_out():
    pytest.importorskip("cv2", reason="GrabCut needs OpenCV (the [photo] extra)")
    picture = hand_picture("relaxed", forearm=True)
    mask = coarse_mask(picture["image"], picture["keypoints"])
    keypoints = picture["keypoints"]
    beyond = np.zeros_like(mask)
    wrist_row = keypoints[0, 1]
    beyond[int(wrist_row + 0.45 * hand_scale_px(keypoints)):] = True  # well past the wrist
    arm = picture["forearm"] & beyond
    assert arm.sum() > 500
    assert (mask & arm).sum() / arm.sum() < 0.02  # measured 0
    assert iou(mask, picture["silhouette"]) > 0.9  # 0.94


def test_refine_mask_without_opencv_keeps_the_silhouette_and_the_coarse_mask_near_it():
    picture = hand_picture("relaxed")
    truth = picture["silhouette"]
    coarse = truth.copy()
    coarse[5:25, 5:25] = True  # a stray blob far from the hand
    fitted = np.roll(truth, 3, axis=1)  # the fitted hand, 3 px off
    refined = refine_mask(picture["image"], coarse, fitted, use_grabcut=False)
    assert not refined[5:25, 5:25].any()
    assert (refined & fitted).sum() == fitted.sum()
    assert iou(refined, truth) > iou(fitted, truth)
    empty = np.zeros_like(truth)
    assert np.array_equal(refine_mask(picture["image"], coarse, empty), coarse)


def test_refine_mask_with_grabcut_snaps_to_the_photo():
    pytest.importorskip("cv2", reason="GrabCut needs OpenCV (the [photo] extra)")
    picture = hand_picture("relaxed")
    truth = picture["silhouette"]
    from scipy import ndimage

    coarse = ndimage.binary_dilation(truth, iterations=6)  # too fat
    coarse[5:25, 5:25] = True
    fitted = np.roll(truth, 4, axis=1)
    refined = refine_mask(picture["image"], coarse, fitted)
    assert not refined[5:25, 5:25].any()
    assert iou(refined, truth) > 0.95 > 0.85 > max(iou(coarse, truth), iou(fitted, truth))


def test_bad_input_is_refused():
    picture = hand_picture()
    with pytest.raises(ValueError, match=r"keypoints must be finite \[21, 2\] pixels, got "
                                         r"\[20, 2\]"):
        coarse_mask(picture["image"], picture["keypoints"][:20])
    with pytest.raises(ValueError, match=r"image must be \[H, W, 3\]"):
        coarse_mask(picture["image"][..., 0], picture["keypoints"])
    with pytest.raises(ValueError, match="must agree"):
        refine_mask(picture["image"], picture["silhouette"], picture["silhouette"][:10])
