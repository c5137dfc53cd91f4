"""Marching cubes on analytic SDFs: radius, orientation, coarse-to-fine == dense, attributes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.geometry.meshing import (
    Mesh,
    colors_to_uint8,
    extract_mesh,
    extract_mesh_with_stats,
    mesh_attributes,
)

CENTRE = (0.02, -0.01, 0.015)
RADIUS = 0.06


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    centre = torch.tensor(CENTRE, dtype=points.dtype, device=points.device)
    return (points - centre).norm(dim=-1) - RADIUS


def torus_sdf(points: torch.Tensor) -> torch.Tensor:
    """Torus around z: major radius 0.05, minor 0.015 (an exact SDF)."""
    ring = torch.linalg.norm(points[:, :2], dim=-1) - 0.05
    return torch.stack([ring, points[:, 2]], dim=-1).norm(dim=-1) - 0.015


def capsule_sdf(points, start, end, radius):
    start = torch.tensor(start, dtype=points.dtype)
    end = torch.tensor(end, dtype=points.dtype)
    axis = end - start
    t = ((points - start) @ axis / (axis @ axis)).clamp(0.0, 1.0)
    return (points - start - t[:, None] * axis).norm(dim=-1) - radius


def capsules_sdf(points: torch.Tensor) -> torch.Tensor:
    """Union (min) of three capsules, like a finger with two neighbours: 1-Lipschitz."""
    return torch.stack([
        capsule_sdf(points, (-0.05, 0.0, 0.0), (0.05, 0.01, 0.0), 0.012),
        capsule_sdf(points, (-0.04, 0.025, 0.0), (0.03, 0.04, 0.01), 0.01),
        capsule_sdf(points, (0.0, -0.03, -0.01), (0.0, -0.03, 0.04), 0.009),
    ]).min(dim=0).values


BOX_MIN = (-0.08, -0.085, -0.07)
BOX_MAX = (0.09, 0.075, 0.08)


def test_sphere_radius_centre_and_orientation():
    resolution = 48
    mesh = extract_mesh(sphere_sdf, BOX_MIN, BOX_MAX, resolution)
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int64
    voxel = (np.array(BOX_MAX) - np.array(BOX_MIN)) / (resolution - 1)
    radii = np.linalg.norm(mesh.vertices - np.array(CENTRE), axis=1)
    assert np.abs(radii - RADIUS).mean() < 0.02 * voxel.min()
    assert np.abs(radii - RADIUS).max() < 0.1 * voxel.min()
    # Outward faces: the divergence theorem gives a positive volume close to 4/3 pi r^3.
    corners = mesh.vertices[mesh.faces].astype(np.float64)
    volume = np.einsum("fi,fi->f", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6
    assert volume == pytest.approx(4 / 3 * np.pi * RADIUS**3, rel=0.02)
    # A closed surface: every edge is shared by exactly two faces.
    edges = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)


def test_dense_matches_skimage_on_the_same_volume():
    from skimage.measure import marching_cubes

    resolution = 33
    axes = [np.linspace(lo, hi, resolution) for lo, hi in zip(BOX_MIN, BOX_MAX, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    volume = np.linalg.norm(grid - np.array(CENTRE), axis=-1) - RADIUS
    spacing = (np.array(BOX_MAX) - np.array(BOX_MIN)) / (resolution - 1)
    expected, _, _, _ = marching_cubes(volume, 0.0, spacing=tuple(spacing))
    mesh = extract_mesh(
        sphere_sdf, BOX_MIN, BOX_MAX, resolution, coarse_resolution=resolution,
        dtype=torch.float64,
    )
    np.testing.assert_allclose(mesh.vertices, expected + np.array(BOX_MIN), atol=1e-6)


@pytest.mark.parametrize(
    ("sdf_fn", "resolution", "level"),
    [(sphere_sdf, 64, 0.0), (torus_sdf, 61, 0.0), (capsules_sdf, 96, 0.002)],
)
def test_coarse_to_fine_equals_dense(sdf_fn, resolution, level):
    dense = extract_mesh(sdf_fn, BOX_MIN, BOX_MAX, resolution, level=level,
                         coarse_resolution=resolution)
    for coarse in (None, 4):
        fast = extract_mesh(sdf_fn, BOX_MIN, BOX_MAX, resolution, level=level,
                            coarse_resolution=coarse)
        np.testing.assert_array_equal(fast.faces, dense.faces)
        # Values differ at most by float32 rounding (batching), far below 0.05 mm.
        assert np.abs(fast.vertices - dense.vertices).max() < 1e-6


def test_coarse_to_fine_evaluates_far_fewer_points():
    calls = []

    def counted(points):
        calls.append(points.shape[0])
        return torus_sdf(points)

    resolution = 96
    result = extract_mesh_with_stats(counted, BOX_MIN, BOX_MAX, resolution, chunk_size=20000)
    assert sum(calls) == result.num_evaluations == sum(result.level_evaluations)
    assert max(calls) <= 20000
    assert result.num_grid_points == resolution**3
    assert sum(calls) < 0.1 * resolution**3
    # Close to the surface work: a few evaluations per vertex.
    assert sum(calls) < 6 * result.mesh.num_vertices


def test_lipschitz_argument_for_steeper_fields():
    def steep(points):
        return 3.0 * torus_sdf(points)  # gradient norm 3

    dense = extract_mesh(steep, BOX_MIN, BOX_MAX, 48, coarse_resolution=48)
    fast = extract_mesh(steep, BOX_MIN, BOX_MAX, 48, lipschitz=3.0)
    np.testing.assert_array_equal(fast.faces, dense.faces)
    assert np.abs(fast.vertices - dense.vertices).max() < 1e-6
    # The bound is what makes skipping safe: an underestimate loses parts of the surface.
    wrong = extract_mesh(steep, BOX_MIN, BOX_MAX, 48, lipschitz=1.0)
    assert wrong.num_faces < dense.num_faces


def test_level_offsets_the_surface_and_float64_points():
    seen = set()

    def sdf(points):
        seen.add(points.dtype)
        return sphere_sdf(points)[:, None]  # [N, 1] is accepted

    mesh = extract_mesh(sdf, BOX_MIN, BOX_MAX, 40, level=0.01, dtype=torch.float64)
    assert seen == {torch.float64}
    radii = np.linalg.norm(mesh.vertices - np.array(CENTRE), axis=1)
    assert np.abs(radii - (RADIUS + 0.01)).mean() < 1e-4


@pytest.mark.parametrize("coarse", [None, 40])
def test_no_surface_in_box_raises(coarse):
    def far_sphere(points):
        return (points - torch.tensor([1.0, 0.0, 0.0])).norm(dim=-1) - 0.1

    with pytest.raises(ValueError, match="not found in the box"):
        extract_mesh(far_sphere, BOX_MIN, BOX_MAX, 40, coarse_resolution=coarse)
    with pytest.raises(ValueError, match="not found in the box"):
        extract_mesh(lambda p: -torch.ones(p.shape[0]), BOX_MIN, BOX_MAX, 40,
                     coarse_resolution=coarse)


def test_argument_validation():
    with pytest.raises(ValueError, match="resolution"):
        extract_mesh(sphere_sdf, BOX_MIN, BOX_MAX, 1)
    with pytest.raises(TypeError, match="resolution"):
        extract_mesh(sphere_sdf, BOX_MIN, BOX_MAX, 32.0)
    with pytest.raises(ValueError, match="bbox_max must be greater"):
        extract_mesh(sphere_sdf, BOX_MAX, BOX_MIN, 32)
    with pytest.raises(ValueError, match=r"bbox_min must have shape \[3\]"):
        extract_mesh(sphere_sdf, (0.0, 0.0), BOX_MAX, 32)
    with pytest.raises(ValueError, match="lipschitz"):
        extract_mesh(sphere_sdf, BOX_MIN, BOX_MAX, 32, lipschitz=0.0)
    with pytest.raises(ValueError, match=r"sdf_fn must return \[N\]"):
        extract_mesh(lambda p: p, BOX_MIN, BOX_MAX, 16)
    with pytest.raises(ValueError, match="NaN"):
        extract_mesh(lambda p: sphere_sdf(p) / 0.0 * 0.0, BOX_MIN, BOX_MAX, 16)


def test_mesh_attributes_in_chunks():
    mesh = extract_mesh(sphere_sdf, BOX_MIN, BOX_MAX, 24)
    calls = []

    def color_fn(points):
        calls.append(points.shape[0])
        return (points + 0.1) * 4.0

    colors = mesh_attributes(mesh.vertices, color_fn, chunk_size=100)
    assert max(calls) == 100 and sum(calls) == mesh.num_vertices
    np.testing.assert_allclose(colors, (mesh.vertices + 0.1) * 4.0, atol=1e-6)
    # A torch input and a scalar attribute.
    radii = mesh_attributes(torch.from_numpy(mesh.vertices), lambda p: p.norm(dim=-1))
    assert radii.shape == (mesh.num_vertices, 1)
    np.testing.assert_allclose(radii[:, 0], np.linalg.norm(mesh.vertices, axis=1), rtol=1e-6)
    with pytest.raises(ValueError, match="attr_fn must return"):
        mesh_attributes(mesh.vertices, lambda p: p[:-1])


def test_colors_to_uint8_and_mesh_validation():
    np.testing.assert_array_equal(
        colors_to_uint8(np.array([[-0.5, 0.0, 0.5], [1.0, 2.0, 0.2]])),
        np.array([[0, 0, 128], [255, 255, 51]], dtype=np.uint8),
    )
    vertices = np.zeros((3, 3))
    mesh = Mesh(vertices, np.array([[0, 1, 2]], dtype=np.int32))
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int64
    with pytest.raises(ValueError, match="faces index vertices"):
        Mesh(vertices, np.array([[0, 1, 3]]))
    with pytest.raises(TypeError, match="colors must be uint8"):
        Mesh(vertices, np.array([[0, 1, 2]]), colors=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="skin_weights"):
        Mesh(vertices, np.array([[0, 1, 2]]), skin_weights=np.zeros((2, 16)))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_points_match_cpu():
    seen = set()

    def sdf(points):
        seen.add(points.device.type)
        return sphere_sdf(points)

    cpu = extract_mesh(sdf, BOX_MIN, BOX_MAX, 48)
    gpu = extract_mesh(sdf, BOX_MIN, BOX_MAX, 48, device="cuda")
    assert "cuda" in seen
    np.testing.assert_array_equal(cpu.faces, gpu.faces)
    assert np.abs(cpu.vertices - gpu.vertices).max() < 1e-6

