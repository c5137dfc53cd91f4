"""The occupancy grid: conservative cells, ray bounds that keep the surface."""

import math

import torch

from lisa_hand.geometry.cameras import pixel_rays
from lisa_hand.geometry.rays import ray_sphere_bounds
from lisa_hand.render.occupancy import build_occupancy_grid

from .image_scene import analytic_entry, scene_camera, sphere_sdf


def test_occupancy_grid_is_conservative_and_bounds_hold_the_surface():
    threshold = 0.004
    grid = build_occupancy_grid(
        sphere_sdf, torch.zeros(3), 0.2, resolution=64, coarse_resolution=16, threshold=threshold
    )
    occupied = grid.occupied.reshape(-1)
    # Every cell that holds a point of the shell |sdf| <= threshold is occupied (random points).
    generator = torch.Generator().manual_seed(0)
    points = grid.low + 0.4 * torch.rand(200_000, 3, generator=generator, dtype=torch.float64)
    cells = ((points - grid.low) / grid.cell_size).floor().long().clamp(0, 63)
    flat = (cells * torch.tensor([64 * 64, 64, 1])).sum(-1)
    in_shell = sphere_sdf(points).abs() <= threshold
    assert in_shell.sum() > 1000 and bool(occupied[flat[in_shell]].all())
    # ... and only those that may: a cell whose centre is farther than the threshold plus the
    # half diagonal from the surface is empty.
    index = torch.stack(torch.meshgrid(*[torch.arange(64)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres = grid.low + (index + 0.5) * grid.cell_size
    far_cells = sphere_sdf(centres).abs() > threshold + 0.5 * math.sqrt(3) * grid.cell_size + 1e-6
    assert not bool(occupied[far_cells].any())
    assert grid.num_evaluations < 0.4 * 64**3  # the coarse pass skipped most of the cube
    # Rays: the culled ones never come within the threshold of the surface; the others' bounds
    # contain the first surface crossing.
    origins, directions = pixel_rays(scene_camera(64, 48))
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 0.2)
    origins, directions, near, far = origins[hit], directions[hit], near[hit], far[hit]
    new_near, new_far, keep = grid.ray_bounds(origins, directions, near, far, chunk_size=1000)
    samples = near[:, None] + (far - near)[:, None] * torch.linspace(0, 1, 2000)
    sdf = sphere_sdf(origins[:, None] + samples[..., None] * directions[:, None])
    assert bool((sdf[~keep].amin(dim=-1) > threshold).all())
    t_surface, surface_hit = analytic_entry(origins, directions)
    assert bool(keep[surface_hit].all())
    assert bool((new_near[surface_hit] <= t_surface[surface_hit]).all())
    assert bool((new_far[surface_hit] >= t_surface[surface_hit]).all())
    assert bool((new_near[keep] >= near[keep]).all() and (new_far[keep] <= far[keep]).all())
    # The start moved up to the surface: the sphere tracer skips less empty space.
    gap_before = (t_surface - near)[surface_hit].mean()
    gap_after = (t_surface - new_near)[surface_hit].mean()
    assert float(gap_after) < 0.3 * float(gap_before)
