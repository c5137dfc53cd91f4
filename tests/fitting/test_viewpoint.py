"""The sensor position of a one-view scan found from its points
(``lisa_hand.fitting.points.viewpoint``), checked against the true sensor of simulated scans of
a hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.scans import ScanConfig, simulate_scan
from lisa_hand.fitting.points.viewpoint import ViewpointConfig, estimate_viewpoint


@pytest.fixture(scope="module")
def hand_mesh():
    """The shipped geometric prior's mean hand, fingers a little bent, 0.4 m in front of the
    origin along +z: (vertices [V, 3] metres, faces [F, 3])."""
    from lisa_hand.fitting.points.cloud import target_cloud
    from lisa_hand.fitting.points.fit import start_hand
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry", "cpu")
    _, rest_hand, _ = start_hand(model, target_cloud(torch.zeros(30, 3), None, seed=0), None)
    pose = torch.zeros(16, 3)
    pose[1:13, 2] = 0.3
    hand = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.0, 0.0, 0.4]))
    mesh = mesh_hand(model, hand, 64, MeshConfig(colors=False, skin_weights=False))
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


@pytest.mark.parametrize("offset", [(0.0, 0.45, 0.1), (0.1, -0.4, -0.2), (0.3, 0.2, 0.3)])
def test_the_sensor_of_a_one_view_scan_is_found_from_its_points(hand_mesh, offset):
    """Scans of the hand from above its back, below its palm and obliquely: the found direction
    lies within 20 degrees of the true sensor's, on its side (the opposite side would be 160+
    off), few points hide from it, and the sensor is put ``distance_m`` away (the origin is
    not in that direction)."""
    vertices, faces = hand_mesh
    centre = vertices.mean(0)
    sensor = centre + np.asarray(offset)
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000, partial=True,
                                                     viewpoint=tuple(sensor)), seed=1)
    found = estimate_viewpoint(scan.points)
    assert found.one_view and found.hidden_fraction < 0.1
    assert not found.at_origin
    assert _angle_deg(found.direction, sensor - scan.points.mean(0)) < 20.0
    assert np.linalg.norm(found.position - scan.points.mean(0)) == pytest.approx(0.5)


def test_a_scan_from_all_round_is_not_taken_for_one_view(hand_mesh):
    vertices, faces = hand_mesh
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000), seed=1)
    found = estimate_viewpoint(torch.from_numpy(scan.points))
    assert not found.one_view and found.hidden_fraction > 0.3


def test_a_depth_cameras_own_frame_gives_the_origin(hand_mesh):
    """Scanned from the origin (a depth camera's points in its own frame, 0.4 m away), the
    origin itself is the sensor; moved 1 m sideways, it is not."""
    vertices, faces = hand_mesh
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000, partial=True,
                                                     viewpoint=(0.0, 0.0, 0.0)), seed=2)
    found = estimate_viewpoint(scan.points)
    assert found.one_view and found.at_origin
    assert np.array_equal(found.position, np.zeros(3))
    moved = estimate_viewpoint(scan.points + np.array([1.0, 0.0, 0.0]))
    assert moved.one_view and not moved.at_origin
    assert _angle_deg(moved.direction, -scan.points.mean(0)) < 20.0


def test_bad_points_are_refused():
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        estimate_viewpoint(np.zeros((10, 3)))
    with pytest.raises(ValueError, match="finite"):
        estimate_viewpoint(np.full((30, 3), np.nan))
    with pytest.raises(ValueError, match="num_directions"):
        ViewpointConfig(num_directions=2)


def test_stray_points_do_not_turn_the_sensor_round(hand_mesh):
    """A fifth of the points are outliers spread over the scan's box: the side along the axis
    comes from the median bulge, which they do not sway (a mean did, on WebXR scans). (Whether
    so noisy a scan is still taken for one view is not asked: outliers in front of the surface
    hide some of it, 15% here.)"""
    vertices, faces = hand_mesh
    for seed, offset in enumerate([(0.0, 0.45, 0.1), (0.1, -0.4, -0.2)]):
        sensor = vertices.mean(0) + np.asarray(offset)
        scan = simulate_scan(vertices, faces, ScanConfig(
            num_points=4000, partial=True, viewpoint=tuple(sensor), outlier_fraction=0.2),
            seed=seed)
        found = estimate_viewpoint(scan.points)
        assert _angle_deg(found.direction, sensor - scan.points.mean(0)) < 25.0, offset


def test_scan_noise_is_the_noise_across_the_surface():
    """A flat patch (1.6 mm point spacing) with Gaussian noise of std s along its normal: the
    estimate is s to within 15 % while s is well under the spacing, and low (the nearest points
    are those at a like height) but still growing as it nears it; a noise-free sphere of radius
    5 cm gives about a tenth of a millimetre (its curvature)."""
    from lisa_hand.fitting.points.viewpoint import scan_noise

    rng = np.random.default_rng(0)
    found = []
    for std in (0.0005, 0.001, 0.002):
        flat = np.concatenate([rng.uniform(-0.05, 0.05, (4000, 2)),
                               rng.normal(0.0, std, (4000, 1))], axis=1)
        found.append(scan_noise(flat))
    assert found[:2] == [pytest.approx(0.0005, rel=0.15), pytest.approx(0.001, rel=0.15)]
    assert 1.2 * found[1] < found[2] < 0.002
    sphere = rng.normal(size=(4000, 3))
    sphere = 0.05 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True)
    assert scan_noise(sphere) < 2e-4  # the sagitta of 16 points 2.8 mm apart: 0.1 mm RMS


@pytest.mark.parametrize("noise", [0.001, 0.002])
def test_a_noisy_depth_cameras_view_is_still_one_view(hand_mesh, noise):
    """A depth camera's 1-2 mm of noise: the view is still found, within 25 degrees, on its
    side (before the points were smoothed onto their local planes, 2 mm made every one-view
    scan of the WebXR hand look like several views)."""
    vertices, faces = hand_mesh
    sensor = vertices.mean(0) + np.array([0.0, 0.45, 0.1])
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000, partial=True,
                                                     viewpoint=tuple(sensor),
                                                     noise_normal_std=noise), seed=1)
    found = estimate_viewpoint(scan.points)
    assert found.one_view
    assert _angle_deg(found.direction, sensor - scan.points.mean(0)) < 25.0
    full = simulate_scan(vertices, faces, ScanConfig(num_points=3000, noise_normal_std=noise),
                         seed=1)
    assert not estimate_viewpoint(full.points).one_view


def test_a_known_side_turns_the_axis(hand_mesh):
    """``side`` (the normal of a desk the hand rests on) decides which way along the axis the
    sensor is, instead of the bulge: the same axis, turned to it."""
    vertices, faces = hand_mesh
    sensor = vertices.mean(0) + np.array([0.1, -0.4, -0.2])
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000, partial=True,
                                                     viewpoint=tuple(sensor)), seed=1)
    found = estimate_viewpoint(scan.points)
    same = estimate_viewpoint(scan.points, side=found.direction + 0.5 * np.array([1.0, 0, 0]))
    turned = estimate_viewpoint(scan.points, side=-found.direction)
    np.testing.assert_array_equal(same.direction, found.direction)
    np.testing.assert_array_equal(turned.direction, -found.direction)
    assert turned.hidden_fraction == found.hidden_fraction
    centre = scan.points.astype(np.float64).mean(0)
    assert (turned.position - centre) @ found.direction == pytest.approx(-0.5)
