"""The RGB-D benchmark's frame (``lisa_hand.bench.rgbd.rgbd_frame``): an aligned colour and depth
image of the hand, the cup touching it and the wall, and its true hand, as documented."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np

from lisa_hand.bench.rgbd import rgbd_frame
from lisa_hand.data.depth import DepthFrame, read_depth_cloud
from lisa_hand.geometry.cameras import load_cameras
from lisa_hand.metrics import load_mesh


def test_a_frame_holds_the_hand_a_cup_and_a_wall(tmp_path):
    files = rgbd_frame(0, tmp_path)
    colour, depth = iio.imread(files["colour"]), iio.imread(files["depth"])
    assert colour.shape == (480, 640, 3) and depth.shape == (480, 640)
    assert depth.dtype == np.uint16 and (depth > 0).all()  # the wall fills the view
    assert np.isclose(np.median(depth), 750, atol=1)  # the wall, 75 cm away, in millimetres
    blue = (colour[..., 2] > 1.5 * colour[..., 0]) & (depth < 500)  # the cup
    assert 2000 < blue.sum() < 40000
    truth = load_mesh(files["truth"])
    near = (depth > 0) & (depth < 600) & ~blue
    points, _, _ = read_depth_cloud(files["depth"], DepthFrame(
        camera=load_cameras(files["camera"])[0], mask=near))
    # the hand's pixels lie on the true hand's surface (1 mm depth steps)
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(truth.vertices).query(points)
    assert np.median(distance) < 0.002
    assert abs(float(np.median(truth.vertices[:, 2])) - 0.42) < 0.03
