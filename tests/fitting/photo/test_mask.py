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
    split_masks,
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


# ------------------------------------------------------------------------------------------------
# Several hands' masks made exclusive (split_masks).


def skeleton_distance(pixels: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """[M] distance, pixels, of pixel centres [M, 2] to a keypoint skeleton [21, 2] (the bones
    of HAND_BONES), from 2001 points along each bone (the reference; error < 0.05 px here)."""
    along = np.linspace(0.0, 1.0, 2001)[:, None]
    points = np.concatenate([keypoints[a] + along * (keypoints[b] - keypoints[a])
                             for a, b in HAND_BONES])
    from scipy.spatial import cKDTree

    return cKDTree(points).query(pixels)[0]


def disc(shape: tuple[int, int], centre: np.ndarray, radius: float) -> np.ndarray:
    rows, columns = np.indices(shape)
    return (columns + 0.5 - centre[0]) ** 2 + (rows + 0.5 - centre[1]) ** 2 <= radius ** 2


def check_split(masks: list[np.ndarray], split: list[np.ndarray]) -> None:
    """No pixel in two masks, the union kept, and each pixel given to a hand that claimed it
    (a pixel claimed by one hand stays its own)."""
    stack, parts = np.stack(masks), np.stack(split)
    assert parts.dtype == bool and parts.shape == stack.shape
    assert (parts.sum(0) <= 1).all()
    np.testing.assert_array_equal(parts.any(0), stack.any(0))
    assert not (parts & ~stack).any()
    alone = stack.sum(0) == 1
    np.testing.assert_array_equal(parts[:, alone], stack[:, alone])


def test_split_masks_gives_an_overlap_pixel_to_the_nearer_skeleton():
    keypoints = hand_picture("relaxed")["keypoints"]
    hands = [keypoints, keypoints + [45.0, 10.0]]  # two hands of one size, side by side
    shape = (240, 260)
    masks = [disc(shape, points.mean(0), 75.0) for points in hands]
    shared = masks[0] & masks[1]
    assert shared.sum() > 5000
    split = split_masks(masks, hands)
    check_split(masks, split)
    rows, columns = np.nonzero(shared)
    pixels = np.stack([columns + 0.5, rows + 0.5], axis=1)
    distance = np.stack([skeleton_distance(pixels, points) for points in hands])
    clear = np.abs(distance[0] - distance[1]) > 0.1  # not a tie within the reference's error
    owner = np.stack(split)[:, rows, columns].argmax(0)
    np.testing.assert_array_equal(owner[clear], distance.argmin(0)[clear])
    assert 0.2 < owner.mean() < 0.8  # both hands get part of the overlap


def test_split_masks_measures_in_each_hands_size():
    """A hand half the size of the other: an overlap pixel goes to it only when it is nearer
    than half the large hand's distance (so the large hand does not take the small one's
    pixels)."""
    keypoints = hand_picture("relaxed")["keypoints"]
    small = 0.5 * keypoints + [95.0, 70.0]
    hands = [keypoints, small]
    assert hand_scale_px(small) == pytest.approx(0.5 * hand_scale_px(keypoints))
    shape = (240, 260)
    masks = [disc(shape, keypoints.mean(0), 75.0), disc(shape, small.mean(0), 45.0)]
    split = split_masks(masks, hands)
    check_split(masks, split)
    rows, columns = np.nonzero(masks[0] & masks[1])
    pixels = np.stack([columns + 0.5, rows + 0.5], axis=1)
    large_distance = skeleton_distance(pixels, keypoints)
    small_distance = skeleton_distance(pixels, small)
    clear = np.abs(large_distance - 2.0 * small_distance) > 0.2
    to_small = split[1][rows, columns]
    np.testing.assert_array_equal(to_small[clear], (2.0 * small_distance < large_distance)[clear])
    # Some pixels nearer the small hand's skeleton still go to the large hand.
    assert (~to_small & (small_distance < large_distance - 1.0)).sum() > 50
    assert to_small.sum() > 50


def test_split_masks_of_three_hands_and_of_one():
    keypoints = hand_picture("flat")["keypoints"]
    hands = [keypoints, keypoints + [40.0, 0.0], keypoints + [20.0, 30.0]]
    shape = (240, 260)
    masks = [disc(shape, points.mean(0), 70.0) for points in hands]
    assert (np.stack(masks).sum(0) == 3).sum() > 1000
    check_split(masks, split_masks(masks, hands))
    # Hands whose masks do not meet keep them.
    apart = [disc(shape, keypoints.mean(0), 30.0), disc(shape, keypoints.mean(0) + 80.0, 30.0)]
    for got, mask in zip(split_masks(apart, [keypoints, keypoints + 80.0]), apart, strict=True):
        np.testing.assert_array_equal(got, mask)
    # One hand: its mask back (a copy), bool.
    alone = masks[0].astype(np.uint8)
    (got,) = split_masks([alone], [keypoints])
    assert got.dtype == bool and got is not alone
    np.testing.assert_array_equal(got, masks[0])
    assert split_masks([], []) == []
    with pytest.raises(ValueError, match="2 masks for 1 hands"):
        split_masks(masks[:2], hands[:1])


def test_grabcut_gives_the_same_mask_every_call():
    """OpenCV's GrabCut draws from a global generator: without seeding it, a second call on the
    same photo gave another mask (155 pixels apart on a rendered photo)."""
    pytest.importorskip("cv2")
    rng = np.random.default_rng(3)
    image = np.clip(rng.normal(0.4, 0.15, (120, 160, 3)), 0, 1).astype(np.float32)
    keypoints = rng.uniform([50, 30], [110, 90], size=(21, 2))
    image[30:90, 50:110] = np.clip(image[30:90, 50:110] + [0.3, 0.1, 0.0], 0, 1)
    first = coarse_mask(image, keypoints, use_grabcut=True)
    coarse_mask(np.ascontiguousarray(image[::-1]), keypoints, use_grabcut=True)  # moves the RNG
    assert (coarse_mask(image, keypoints, use_grabcut=True) == first).all()
