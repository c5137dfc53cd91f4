"""Simulated scans and SDF samples on spheres, checked against closed-form distances."""

from __future__ import annotations

import math

import numpy as np
import point_cloud_utils as pcu
import pytest
import torch
import trimesh

from lisa_hand.data.scans import (
    DepthCameraConfig,
    ScanConfig,
    depth_camera_scan,
    sample_surface,
    sdf_samples,
    simulate_scan,
)
from lisa_hand.handmodel import SurfaceSamples

RADIUS = 0.1


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64)


def mesh_distance(points, vertices, faces):
    """Signed distance to the mesh: the sign from point-cloud-utils (winding number), the
    magnitude to its closest point (float64)."""
    points = np.asarray(points, np.float64)
    vertices = vertices.astype(np.float64)
    sdf, face_ids, bary = pcu.signed_distance_to_mesh(points, vertices, faces.astype(np.int32))
    closest = (bary[:, :, None] * vertices[faces[face_ids]]).sum(1)
    return np.sign(sdf) * np.linalg.norm(points - closest, axis=1)


def test_sample_surface_on_the_faces_with_outward_unit_normals(sphere):
    vertices, faces = sphere
    samples = sample_surface(vertices, faces, 5000, np.random.default_rng(0))
    points, normals, face_ids = samples.points, samples.normals, samples.face_ids
    assert samples.weights is None and samples.colors is None  # a mesh knows neither
    assert points.shape == (5000, 3) and normals.shape == (5000, 3) and face_ids.shape == (5000,)
    assert points.dtype == np.float32 and face_ids.dtype == np.int64
    assert np.abs(mesh_distance(points, vertices, faces)).max() < 1e-6
    # Each point lies in the plane of its own face.
    corners = vertices.astype(np.float64)[faces[face_ids]]
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    assert np.abs(((points - corners[:, 0]) * face_normal).sum(-1)).max() < 1e-7
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    radial = points / np.linalg.norm(points, axis=1, keepdims=True)
    assert ((normals * radial).sum(-1) > 0.999).all()
    # Flat normals are the faces' own.
    flat = sample_surface(vertices, faces, 5000, 0, smooth_normals=False)
    corners = vertices.astype(np.float64)[faces[flat.face_ids]]
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    np.testing.assert_allclose(flat.normals, face_normal, atol=1e-6)


def test_mesh_and_hand_samples_are_one_type(sphere):
    samples = sample_surface(*sphere, 10, 0)
    assert type(samples) is SurfaceSamples  # the open hand's type (lisa_hand.handmodel)
    visible = samples.points[:, 2] > 0
    picked = samples.select(visible)
    np.testing.assert_array_equal(picked.face_ids, samples.face_ids[visible])
    joined = SurfaceSamples.concatenate([picked, samples.select(~visible)])
    assert joined.points.shape == (10, 3) and joined.face_ids.dtype == np.int64


def test_sample_surface_is_area_weighted_and_uniform_in_each_triangle():
    # Two triangles with areas 1 and 3 (in units of 0.5 cm^2).
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                         [2, 0, 0], [5, 0, 0], [2, 1, 0]], np.float32) * 0.01
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    samples = sample_surface(vertices, faces, 40000, np.random.default_rng(1))
    fraction = (samples.face_ids == 0).mean()
    assert abs(fraction - 0.25) < 4 * math.sqrt(0.25 * 0.75 / 40000)
    # Uniform in a triangle: the mean is the centroid, the covariance that of the triangle.
    big = samples.points[samples.face_ids == 1].astype(np.float64)
    corners = vertices[3:].astype(np.float64)
    np.testing.assert_allclose(big.mean(0), corners.mean(0), atol=2e-4)
    centred = corners - corners.mean(0)
    expected_cov = centred.T @ centred / 12.0  # second moment of a uniform triangle
    np.testing.assert_allclose(np.cov(big.T), expected_cov, atol=2e-6)


def test_same_seed_same_samples(sphere):
    first = sample_surface(*sphere, 100, 5)
    again = sample_surface(*sphere, 100, np.random.default_rng(5))
    other = sample_surface(*sphere, 100, 6)
    np.testing.assert_array_equal(first.points, again.points)
    assert not np.array_equal(first.points, other.points)


def test_clean_full_scan_lies_on_the_surface(sphere):
    vertices, faces = sphere
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000), seed=0)
    assert scan.points.shape == (3000, 3) and not scan.is_outlier.any()
    assert scan.viewpoint is None and (scan.face_ids >= 0).all()
    assert np.abs(mesh_distance(scan.points, vertices, faces)).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(scan.normals, axis=1), 1.0, atol=1e-6)
    assert ((scan.normals * scan.points).sum(-1) > 0).all()
    # A full scan covers the whole sphere: each octant holds about an eighth.
    octant = (scan.points > 0) @ np.array([1, 2, 4])
    counts = np.bincount(octant, minlength=8)
    assert np.abs(counts / 3000 - 0.125).max() < 0.03


@pytest.mark.parametrize("normal_std, iso_std", [(1e-3, 0.0), (0.0, 1e-3), (6e-4, 8e-4)])
def test_noise_std_matches_the_config(sphere, normal_std, iso_std):
    vertices, faces = sphere
    config = ScanConfig(num_points=20000, noise_normal_std=normal_std, noise_isotropic_std=iso_std)
    scan = simulate_scan(vertices, faces, config, seed=2)
    # For noise far below the radius, the signed distance is the normal component of the
    # displacement: N(0, normal_std^2 + iso_std^2).
    distance = mesh_distance(scan.points, vertices, faces)
    expected = math.hypot(normal_std, iso_std)
    assert abs(distance.mean()) < 4 * expected / math.sqrt(20000)
    assert abs(distance.std() / expected - 1.0) < 0.03
    # The normals stay the clean surface normals.
    radial = scan.points / np.linalg.norm(scan.points, axis=1, keepdims=True)
    assert ((scan.normals * radial).sum(-1) > 0.99).all()


def test_outliers_exact_fraction_inside_the_enlarged_box(sphere):
    vertices, faces = sphere
    config = ScanConfig(num_points=1000, outlier_fraction=0.123, outlier_box_scale=1.5)
    scan = simulate_scan(vertices, faces, config, seed=3)
    assert scan.points.shape == (1000, 3)
    assert scan.is_outlier.sum() == 123
    outliers = scan.points[scan.is_outlier]
    bound = 1.5 * np.abs(vertices).max(0)
    assert (np.abs(outliers) <= bound + 1e-7).all()
    assert (np.abs(outliers) > np.abs(vertices).max(0)).any()  # some beyond the mesh's box
    assert (scan.face_ids[scan.is_outlier] == -1).all()
    assert (scan.face_ids[~scan.is_outlier] >= 0).all()
    inliers = scan.points[~scan.is_outlier]
    assert np.abs(mesh_distance(inliers, vertices, faces)).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(scan.normals, axis=1), 1.0, atol=1e-6)
    # Shuffled: the outliers are not all at the end.
    assert scan.is_outlier[:500].any() and scan.is_outlier[500:].any()


def test_partial_scan_sees_one_cap(sphere):
    vertices, faces = sphere
    viewpoint = np.array([0.0, 0.0, 0.5])
    config = ScanConfig(num_points=4000, partial=True, viewpoint=tuple(viewpoint))
    scan = simulate_scan(vertices, faces, config, seed=4)
    assert scan.points.shape == (4000, 3)
    np.testing.assert_allclose(scan.viewpoint, viewpoint, atol=1e-7)
    to_point = scan.points - viewpoint
    facing = (scan.normals * to_point).sum(-1) < 0
    assert facing.mean() > 0.99
    # From 0.5 m the visible cap is z > r^2 / 0.5 = 2 cm: 40% of the sphere.
    assert (scan.points[:, 2] > 0.02 - 5e-4).all()
    assert scan.points[:, 2].min() < 0.03  # the cap reaches the silhouette
    # Uniform on the cap: z uniform on [0.02, 0.1] (Archimedes), mean 6 cm.
    assert abs(scan.points[:, 2].mean() - 0.06) < 1e-3
    # A narrower incidence limit keeps a smaller cap.
    narrow = simulate_scan(vertices, faces, ScanConfig(num_points=2000, partial=True,
                                                       viewpoint=tuple(viewpoint),
                                                       max_incidence_deg=60.0), seed=4)
    cos = -((narrow.points - viewpoint) / np.linalg.norm(narrow.points - viewpoint, axis=1,
                                                          keepdims=True) * narrow.normals).sum(-1)
    assert (cos > 0.5 - 1e-6).all()


def test_partial_scan_hides_occluded_surfaces():
    """A small sphere in the shadow of a big one is invisible: not a back-face test."""
    big = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
    small = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    small.apply_translation([0.0, 0.0, -0.3])
    both = trimesh.util.concatenate([big, small])
    config = ScanConfig(num_points=2000, partial=True, viewpoint=(0.0, 0.0, 0.5))
    scan = simulate_scan(both.vertices, both.faces, config, seed=0)
    assert (scan.face_ids < len(big.faces)).all()
    # Seen from the side, both spheres show.
    side = ScanConfig(num_points=2000, partial=True, viewpoint=(0.5, 0.0, -0.15))
    scan = simulate_scan(both.vertices, both.faces, side, seed=0)
    assert 0.05 < (scan.face_ids >= len(big.faces)).mean() < 0.5


def test_random_viewpoint_and_reproducibility(sphere):
    vertices, faces = sphere
    config = ScanConfig(num_points=1000, partial=True, viewpoint_distance=0.4,
                        noise_normal_std=1e-4, outlier_fraction=0.05)
    first = simulate_scan(vertices, faces, config, seed=11)
    again = simulate_scan(vertices, faces, config, seed=11)
    other = simulate_scan(vertices, faces, config, seed=12)
    for field in ("points", "normals", "is_outlier", "face_ids", "viewpoint"):
        np.testing.assert_array_equal(getattr(first, field), getattr(again, field))
    assert not np.allclose(first.viewpoint, other.viewpoint)
    np.testing.assert_allclose(np.linalg.norm(first.viewpoint), 0.4, atol=1e-6)
    inliers = first.points[~first.is_outlier]
    direction = first.viewpoint / np.linalg.norm(first.viewpoint)
    assert (inliers @ direction > RADIUS**2 / 0.4 - 1e-3).all()


def test_sdf_samples_from_mesh_and_callback(sphere):
    vertices, faces = sphere
    fine = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)
    surface = sample_surface(fine.vertices, fine.faces, 2000, 0)

    def sdf_fn(points):
        return points.norm(dim=-1) - RADIUS

    points, sdf = sdf_samples((fine.vertices, fine.faces), surface.points, None, 3000,
                              (0.002, 0.02), 1)
    assert points.shape == (3000, 3) and sdf.shape == (3000,) and sdf.dtype == np.float32
    analytic = np.linalg.norm(points.astype(np.float64), axis=1) - RADIUS
    # The fine icosphere's facets sit within 0.03 mm of the sphere.
    assert np.abs(sdf - analytic).max() < 5e-5
    assert (sdf < 0).mean() > 0.3 and (sdf > 0).mean() > 0.3
    # Two scales: about half the samples within a few mm, the others spread to centimetres.
    assert 0.35 < (np.abs(sdf) < 0.006).mean() < 0.75
    assert np.abs(sdf).max() > 0.03

    points, sdf = sdf_samples(sdf_fn, surface.points, surface.normals, 3000, 0.004, 2)
    np.testing.assert_allclose(sdf, np.linalg.norm(points.astype(np.float64), axis=1) - RADIUS,
                               atol=1e-6)
    # Along the normal, the signed distance is the offset: N(0, sigma^2).
    assert abs(sdf.std() / 0.004 - 1.0) < 0.06
    # A mesh object with vertices/faces attributes works too; the same seed gives the same points.
    again_points, again_sdf = sdf_samples(fine, surface.points, surface.normals, 3000, 0.004, 2)
    np.testing.assert_array_equal(again_points, points)
    assert np.abs(again_sdf - sdf).max() < 5e-5


def test_invalid_inputs(sphere):
    vertices, faces = sphere
    with pytest.raises(ValueError, match="num_points"):
        ScanConfig(num_points=0)
    with pytest.raises(ValueError, match="outlier_fraction"):
        ScanConfig(outlier_fraction=1.5)
    with pytest.raises(ValueError, match="noise_normal_std"):
        ScanConfig(noise_normal_std=-1.0)
    with pytest.raises(ValueError, match="viewpoint"):
        ScanConfig(viewpoint=(0.0, 1.0))
    with pytest.raises(ValueError, match="faces"):
        sample_surface(vertices, faces[:, :2], 10, 0)
    with pytest.raises(TypeError, match="generator"):
        sample_surface(vertices, faces, 10, None)
    with pytest.raises(ValueError, match="partial scan"):
        simulate_scan(vertices, faces, ScanConfig(partial=True, viewpoint=(0.0, 0.0, 0.0)), 0)
    with pytest.raises(ValueError, match="sigma"):
        sdf_samples((vertices, faces), vertices, None, 10, -1.0, 0)
    with pytest.raises(ValueError, match="normals"):
        sdf_samples((vertices, faces), vertices, vertices[:5], 10, 0.01, 0)
    with pytest.raises(TypeError, match="target"):
        sdf_samples("mesh.ply", vertices, None, 10, 0.01, 0)
    with pytest.raises(ValueError, match="sdf_fn"):
        sdf_samples(lambda p: torch.zeros(len(p), 2), vertices, None, 10, 0.01, 0)


def _wall(depth: float, half: float = 5.0):
    """A square wall ``2 half`` metres across at z = ``depth``, facing the origin."""
    corners = np.array([[-half, -half, depth], [half, -half, depth], [half, half, depth],
                        [-half, half, depth]])
    return corners, np.array([[0, 2, 1], [0, 3, 2]])


def test_depth_camera_sees_a_wall_through_every_pixel():
    config = DepthCameraConfig(width=40, height=30, focal_px=35.0, noise_m=0.0)
    scan = depth_camera_scan(*_wall(0.7), config)
    assert scan.points.shape == (40 * 30, 3) and np.array_equal(scan.viewpoint, np.zeros(3))
    assert np.allclose(scan.points[:, 2], 0.7, atol=1e-6)
    u = scan.points[:, 0] / scan.points[:, 2] * 35.0 + 20.0  # back to pixel columns
    assert np.allclose(u.reshape(30, 40), np.arange(40) + 0.5, atol=1e-4)
    assert np.allclose(scan.normals, [0.0, 0.0, -1.0])  # towards the camera
    assert len(depth_camera_scan(*_wall(2.0), config).points) == 0  # beyond its range


def test_depth_camera_noise_grows_with_the_square_of_the_depth():
    config = DepthCameraConfig(width=100, height=100, focal_px=400.0, noise_m=1e-3)
    for depth in (0.4, 0.8):
        points = depth_camera_scan(*_wall(depth), config, seed=1).points.astype(np.float64)
        length = np.linalg.norm(points, axis=1)
        residual = length - depth * length / points[:, 2]  # along the ray, off the wall
        expected = 1e-3 * (depth / 0.4) ** 2
        assert np.std(residual) == pytest.approx(expected, rel=0.05), depth
        assert abs(float(np.mean(residual))) < 0.1 * expected


def test_depth_camera_sees_a_sphere_as_a_disc_of_pixels(sphere):
    vertices, faces = sphere
    centre = np.array([0.0, 0.0, 0.5])
    config = DepthCameraConfig(width=160, height=160, focal_px=200.0, noise_m=0.0)
    scan = depth_camera_scan(vertices + centre, faces, config)
    distance = np.linalg.norm(scan.points - centre, axis=1)
    assert np.abs(distance - RADIUS).max() < 2e-3  # on the (faceted) sphere
    assert (scan.points[:, 2] < 0.5).all()  # only its near half
    half_angle = math.asin(RADIUS / 0.5)  # the silhouette cone's
    disc = math.pi * (200.0 * math.tan(half_angle)) ** 2
    assert len(scan.points) == pytest.approx(disc, rel=0.03)
    assert ((scan.normals * scan.points).sum(1) < 0).all()
    with pytest.raises(ValueError, match="width"):
        DepthCameraConfig(width=0)
