"""The hand found in a depth camera's colour image (``lisa_hand.fitting.points.rgbd``): its mask
against the drawn skeleton, the side and the largest hand taken, the depth cloud cut to it, and
the one-line errors. The detector is a stand-in returning known keypoints (MediaPipe itself is
tested in ``tests/fitting/photo``)."""

from __future__ import annotations

from dataclasses import dataclass

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from lisa_hand.data.depth import DepthFrame, read_depth_cloud
from lisa_hand.fitting.photo.mask import hand_scale_px, keypoint_mask
from lisa_hand.fitting.points import rgbd
from lisa_hand.geometry.cameras import Camera

WIDTH, HEIGHT = 80, 60


@dataclass
class Found:
    """What the stand-in detector returns (the fields of ``DetectedHand`` the module reads)."""

    keypoints: np.ndarray
    side: str
    score: float = 0.9


def hand_keypoints(x0: float, y0: float, size: float) -> np.ndarray:
    """[21, 2] pixels in OpenPose order: a hand pointing up, its wrist at (x0, y0), the wrist to
    the middle knuckle ``size`` pixels."""
    points = [(0.0, 0.0)]
    points += [(-0.35 - 0.2 * k, -0.3 - 0.2 * k) for k in range(4)]  # thumb
    for column in (-0.3, -0.1, 0.1, 0.3):  # index, middle, ring, little
        points += [(column, -1.0 - 0.35 * k) for k in range(4)]
    return np.array([(x0 + size * dx, y0 + size * dy) for dx, dy in points])


def colour_file(tmp_path, width=WIDTH, height=HEIGHT):
    path = tmp_path / "colour.png"
    iio.imwrite(path, np.full((height, width, 3), 128, np.uint8))
    return path


def test_the_mask_is_the_skeleton_grown_by_the_margin(tmp_path):
    small = Found(hand_keypoints(20, 55, 10), "left")
    large = Found(hand_keypoints(50, 55, 16), "right")
    found = rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT),
                                  detect=lambda image: [small, large])
    assert found.side == "right" and np.allclose(found.keypoints, large.keypoints)
    drawn = keypoint_mask((HEIGHT, WIDTH), large.keypoints)
    assert found.mask.shape == (HEIGHT, WIDTH) and found.mask[drawn].all()
    # Every kept pixel lies within the margin (0.25 hand sizes, 4-5 px here) of the drawn
    # skeleton, and every pixel half a pixel nearer is kept (distances brute-forced).
    margin = rgbd.HAND_MARGIN * hand_scale_px(large.keypoints)
    assert 4.0 <= margin <= 5.0
    rows, cols = np.nonzero(drawn)
    grid = np.stack(np.mgrid[:HEIGHT, :WIDTH], -1).reshape(-1, 1, 2)
    distance = np.sqrt(((grid - np.stack([rows, cols], -1)[None]) ** 2).sum(-1)).min(1)
    distance = distance.reshape(HEIGHT, WIDTH)
    assert distance[found.mask].max() <= margin and found.mask[distance <= margin - 0.5].all()
    assert not found.mask[:, :8].any()  # the small hand's side of the image is left out
    assert "right hand" in found.note and "the largest of 2" in found.note

    # --side left takes the left hand even though it is smaller.
    left = rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT), side="left",
                                 detect=lambda image: [small, large])
    assert left.side == "left" and np.allclose(left.keypoints, small.keypoints)


def test_the_depth_cloud_keeps_the_hands_pixels(tmp_path):
    depth = np.full((HEIGHT, WIDTH), 900, np.uint16)  # a wall 0.9 m away on the left
    depth[:, WIDTH // 2:] = 550  # a box 0.55 m away on the right, 15 cm behind the hand
    hand = Found(hand_keypoints(40, 55, 16), "right")
    drawn = keypoint_mask((HEIGHT, WIDTH), hand.keypoints)
    depth[drawn] = 400  # the hand 0.4 m away, as wide as its skeleton
    iio.imwrite(tmp_path / "depth.png", depth)
    K = torch.tensor([[60.0, 0.0, WIDTH / 2], [0.0, 60.0, HEIGHT / 2], [0.0, 0.0, 1.0]])
    frame = DepthFrame(camera=Camera(K=K, R=torch.eye(3), t=torch.zeros(3), width=WIDTH,
                                     height=HEIGHT))
    masked, found = rgbd.with_colour_hand(tmp_path / "depth.png", frame, colour_file(tmp_path),
                                          detect=lambda image: [hand])
    points, _, note = read_depth_cloud(tmp_path / "depth.png", masked)
    assert len(points) == int(found.mask.sum()) and "inside the hand's mask" in note
    grown = rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT),
                                  detect=lambda image: [hand]).mask
    # Every hand pixel; of the margin's ring, the box (within 0.3 m of the hand's depth, left to
    # the point fit) but not the wall (0.5 m behind).
    assert np.isclose(points[:, 2], 0.4).sum() == int(drawn.sum())
    ring = grown & ~drawn
    box = ring.copy()
    box[:, :WIDTH // 2] = False
    assert np.isclose(points[:, 2], 0.55).sum() == int(box.sum()) > 0
    assert not np.isclose(points[:, 2], 0.9).any() and (ring & ~box).any()
    assert f"{len(points)} of them with a depth within 0.3 m" in found.note
    everything, _, _ = read_depth_cloud(tmp_path / "depth.png", frame)
    assert len(everything) == WIDTH * HEIGHT
    with pytest.raises(ValueError, match="a colour image and a mask both say"):
        rgbd.with_colour_hand(tmp_path / "depth.png", masked, colour_file(tmp_path),
                              detect=lambda image: [hand])


def test_bad_colour_images_say_why(tmp_path, monkeypatch):
    hand = Found(hand_keypoints(40, 55, 16), "right")
    with pytest.raises(ValueError, match=r"colour image is 80x60 pixels, the depth image 64x48: "
                                         "align the colour image"):
        rgbd.find_colour_hand(colour_file(tmp_path), (64, 48), detect=lambda image: [hand])
    with pytest.raises(ValueError, match="no hand found in the colour image; pass --mask"):
        rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT), detect=lambda image: [])
    with pytest.raises(ValueError, match=r"no left hand found .* \(1 of the other side\)"):
        rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT), side="left",
                              detect=lambda image: [hand])
    monkeypatch.setattr(rgbd, "photo_extra_missing", lambda: "missing")
    with pytest.raises(ValueError, match=r"needs the photo extra \(MediaPipe\): pip install"):
        rgbd.find_colour_hand(colour_file(tmp_path), (WIDTH, HEIGHT))
