"""Depth images as point clouds (``lisa_hand.data.depth``): a plane's depth image back-projected
against its closed form, the camera's pose, masks and bad files."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from lisa_hand.data.depth import (
    DepthFrame,
    depth_points,
    read_depth_cloud,
    read_depth_image,
    read_mask_image,
)
from lisa_hand.geometry.cameras import Camera


def camera(width=40, height=30, focal=50.0, R=None, t=None) -> Camera:
    K = torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    return Camera(K=K, R=torch.eye(3) if R is None else R, t=torch.zeros(3) if t is None else t,
                  width=width, height=height)


def test_a_wall_in_millimetres_comes_back_where_it_was(tmp_path):
    depth = np.full((30, 40), 700, np.uint16)  # a wall 0.7 m away, in millimetres
    depth[:3] = 0  # no depth on the first rows
    iio.imwrite(tmp_path / "wall.png", depth)
    read = read_depth_image(tmp_path / "wall.png")
    assert read.dtype == np.float64 and read[5, 5] == pytest.approx(0.7) and read[0, 0] == 0
    points, centre = depth_points(read, camera())
    assert points.shape == (27 * 40, 3) and np.allclose(centre, 0.0)
    assert np.allclose(points[:, 2], 0.7)
    # pixel (u, v)'s centre at (u + 0.5, v + 0.5): x = z (u + 0.5 - cx) / f, row by row from row 3
    assert np.allclose(points[:40, 0], 0.7 * (np.arange(40) + 0.5 - 20.0) / 50.0)
    assert np.allclose(points[:40, 1], 0.7 * (3.5 - 15.0) / 50.0)


def test_the_cameras_pose_places_the_points_and_the_sensor():
    angle = 0.3
    R = torch.tensor([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0],
                      [-np.sin(angle), 0.0, np.cos(angle)]], dtype=torch.float32)
    t = torch.tensor([0.1, -0.2, 0.5])
    depth = np.random.default_rng(0).uniform(0.3, 0.9, (30, 40))
    world, centre = depth_points(depth, camera(R=R, t=t))
    local, _ = depth_points(depth, camera())
    # x_cam = R x_world + t: the same points seen from the camera
    assert np.allclose(world @ R.double().numpy().T + t.double().numpy(), local, atol=1e-6)
    assert np.allclose(R.double().numpy() @ centre + t.double().numpy(), 0.0, atol=1e-7)


def test_a_mask_keeps_the_hands_pixels(tmp_path):
    depth = np.full((30, 40), 0.5)
    mask = np.zeros((30, 40), np.uint8)
    mask[10:20, 5:15] = 255
    iio.imwrite(tmp_path / "mask.png", mask)
    kept = read_mask_image(tmp_path / "mask.png", (40, 30))
    points, _ = depth_points(depth, camera(), kept)
    assert len(points) == 100
    with pytest.raises(ValueError, match="the mask is 40x30 pixels, the depth image 20x30"):
        read_mask_image(tmp_path / "mask.png", (20, 30))


def test_bad_depth_images_say_why(tmp_path):
    iio.imwrite(tmp_path / "colour.png", np.zeros((30, 40, 3), np.uint8))
    iio.imwrite(tmp_path / "eight.png", np.full((30, 40), 9, np.uint8))
    iio.imwrite(tmp_path / "empty.png", np.zeros((30, 40), np.uint16))
    (tmp_path / "junk.png").write_bytes(b"not a png")
    for name, message in (("colour.png", "one channel"), ("eight.png", "8-bit"),
                          ("empty.png", "no pixel has a depth"), ("junk.png", "cannot read")):
        with pytest.raises(ValueError, match=message) as info:
            read_depth_image(tmp_path / name)
        assert str(tmp_path / name) in str(info.value)
    iio.imwrite(tmp_path / "ok.png", np.full((30, 40), 500, np.uint16))
    with pytest.raises(ValueError, match="is 40x30 pixels, its camera 20x30"):
        read_depth_cloud(tmp_path / "ok.png", DepthFrame(camera(width=20)))
    with pytest.raises(ValueError, match="depth scale must be > 0"):
        read_depth_image(tmp_path / "ok.png", 0.0)
    points, centre, note = read_depth_cloud(tmp_path / "ok.png", DepthFrame(camera(), 0.002))
    assert np.allclose(points[:, 2], 1.0) and "read 1200 pixels" in note
