"""Whole images of an analytic sphere: culling, volume against surface mode, colours, normals,
depth."""

import math

import pytest
import torch

from lisa_hand.geometry.cameras import pixel_rays
from lisa_hand.geometry.rays import ray_sphere_bounds
from lisa_hand.render import LaplaceDensity
from lisa_hand.render.image import ImageRenderConfig, grid_threshold, render_image
from lisa_hand.render.occupancy import build_occupancy_grid

from .image_scene import (
    BETA,
    HEIGHT,
    RADIUS,
    SMALL_GRID,
    WIDTH,
    analytic_hits,
    erode,
    render_sphere,
    scene_camera,
    sphere_sdf,
    textured_field,
)


@pytest.mark.parametrize(
    "mode,culling",
    [("volume", "grid"), ("volume", "box"), ("volume", "sphere"), ("surface", "grid")],
)
def test_rays_that_miss_the_bound_are_never_evaluated(mode, culling):
    camera = scene_camera()
    bound_radius = 2.0 * RADIUS
    cam_center = camera.center.double()
    evaluated_dirs, evaluated_points = [], []

    def counting_field(points, directions):
        evaluated_points.append(points.detach().double())
        evaluated_dirs.append(directions.detach().double())
        return textured_field(points, directions)

    def counting_sdf(points):
        evaluated_points.append(points.detach().double())
        return sphere_sdf(points)

    config = ImageRenderConfig(mode=mode, culling=culling, normals="none", **SMALL_GRID)
    density = LaplaceDensity(beta_init=1e-3, beta_min=0.0)
    # The grid is built beforehand (its cell centres fill the bounding cube, not the sphere).
    grid = build_occupancy_grid(
        sphere_sdf,
        torch.zeros(3),
        bound_radius,
        resolution=32,
        coarse_resolution=8,
        threshold=grid_threshold(config, 1e-3),
    )
    out = render_image(
        counting_field,
        counting_sdf,
        camera,
        torch.zeros(3),
        bound_radius,
        config,
        density,
        grid=grid,
    )
    points = torch.cat(evaluated_points)
    assert points.shape[0] > 0
    # Every evaluated point lies in the bounding sphere: no work on rays outside it.
    assert float(points.norm(dim=-1).max()) <= bound_radius * (1 + 1e-5)
    directions = torch.cat(evaluated_dirs)
    _, _, on_bound = ray_sphere_bounds(
        cam_center.expand_as(directions),
        directions,
        torch.zeros(3, dtype=torch.float64),
        bound_radius,
    )
    assert bool(on_bound.all())
    origins, all_dirs = pixel_rays(camera)
    _, _, in_bound = ray_sphere_bounds(origins, all_dirs, torch.zeros(3), bound_radius)
    assert out.num_rays_rendered <= int(in_bound.sum())
    if culling == "grid":
        # A kept ray passes a probe in a cell next to an occupied cell: within the threshold
        # plus two cell diagonals of the surface. The bound is twice the sphere: many are culled.
        reach = RADIUS + grid.threshold + 2.0 * math.sqrt(3.0) * grid.cell_size
        _, _, near_surface = ray_sphere_bounds(origins, all_dirs, torch.zeros(3), reach)
        assert out.num_rays_rendered <= int(near_surface.sum())
        assert out.num_rays_rendered < int(in_bound.sum())


def test_surface_and_volume_modes_agree_on_a_sphere():
    surface = render_sphere("surface", normals="none")
    volume = render_sphere("volume", normals="none")
    _, hit, points = analytic_hits(scene_camera())
    analytic_mask = hit.reshape(HEIGHT, WIDTH)
    intersection = (surface.mask & volume.mask).sum().item()
    union = (surface.mask | volume.mask).sum().item()
    assert intersection / union > 0.97
    # Surface mode's mask is the analytic one up to the silhouette pixels.
    assert (surface.mask ^ analytic_mask).sum().item() <= 3
    inner = erode(surface.mask & volume.mask)
    assert inner.sum().item() > 200
    difference = (surface.rgb - volume.rgb)[inner].abs()
    assert float(difference.mean()) < 0.01 and float(difference.max()) < 0.05
    # And both are the field's colour at the analytic hit.
    expected = (0.5 + 0.5 * torch.sin(40.0 * points)).reshape(HEIGHT, WIDTH, 3).float()
    torch.testing.assert_close(surface.rgb[inner], expected[inner], atol=2e-3, rtol=0)
    # Outside the bound and between: the background (black) and zero opacity.
    outside = ~(surface.mask | volume.mask)
    assert float(volume.rgb[erode(outside)].abs().max()) < 1e-3
    assert float(surface.opacity[outside].abs().max()) == 0.0


def test_colour_skipping_matches_render_rays_everywhere():
    """color_weight_threshold > 0 evaluates far fewer colours and gives the same image."""
    calls = {"skip": 0, "all": 0}

    def field_for(key):
        def field_fn(points, directions):
            calls[key] += points.shape[0]
            return textured_field(points, directions)

        return field_fn

    density = LaplaceDensity(beta_init=1e-3, beta_min=0.0)
    images = {}
    for key, threshold in (("skip", 3e-3), ("all", 0.0)):
        config = ImageRenderConfig(color_weight_threshold=threshold, normals="none", **SMALL_GRID)
        images[key] = render_image(
            field_for(key), sphere_sdf, scene_camera(), torch.zeros(3), 1.2 * RADIUS, config,
            density,
        )
    assert calls["skip"] < 0.6 * calls["all"]
    mse = float(((images["skip"].rgb - images["all"].rgb) ** 2).mean())
    assert -10.0 * math.log10(mse) > 40.0
    torch.testing.assert_close(images["skip"].opacity, images["all"].opacity, atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    "mode,method",
    [
        ("surface", "finite_difference"),
        ("volume", "finite_difference"),
        ("surface", "autograd"),
        ("surface", "normal_fn"),
    ],
)
def test_normal_map_matches_the_analytic_sphere(mode, method):
    if method == "normal_fn":
        config = ImageRenderConfig(mode=mode, **SMALL_GRID)
        out = render_image(
            textured_field,
            sphere_sdf,
            scene_camera(),
            torch.zeros(3),
            1.2 * RADIUS,
            config,
            LaplaceDensity(BETA, 0.0),
            normal_fn=lambda p: 3.0 * p,
        )
    else:
        out = render_sphere(mode, normals=method)
    _, hit, points = analytic_hits(scene_camera())
    expected = (points / points.norm(dim=-1, keepdim=True)).reshape(HEIGHT, WIDTH, 3)
    mask = out.mask & hit.reshape(HEIGHT, WIDTH)
    assert mask.sum().item() > 300
    cosine = (out.normals.double()[mask] * expected[mask]).sum(-1).clamp(-1.0, 1.0)
    angle_deg = torch.rad2deg(torch.acos(cosine))
    assert float(angle_deg.max()) < 1.0
    torch.testing.assert_close(
        out.normals.norm(dim=-1)[out.mask], torch.ones(int(out.mask.sum())), atol=1e-5, rtol=0
    )
    assert float(out.normals[~out.mask].abs().max()) == 0.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_equals_the_analytic_depth(dtype):
    t_exact, hit, _ = analytic_hits(scene_camera())
    t_exact = t_exact.reshape(HEIGHT, WIDTH)
    surface = render_sphere("surface", dtype=dtype, normals="none")
    assert surface.depth.dtype == dtype and surface.rgb.dtype == dtype
    mask = surface.mask & hit.reshape(HEIGHT, WIDTH)
    error = (surface.depth.double() - t_exact)[mask].abs()
    assert float(error.median()) < 2e-5 and float(error.max()) < 3e-4
    assert float(surface.depth[~surface.mask].abs().max()) == 0.0
    # Volume mode: the expected termination depth, within a few beta of the surface.
    volume = render_sphere("volume", dtype=dtype, normals="none")
    inner = erode(volume.mask & mask)
    error = (volume.depth.double() - t_exact)[inner].abs()
    assert float(error.max()) < 5 * BETA


def test_invalid_inputs_name_the_argument():
    with pytest.raises(ValueError, match="mode"):
        ImageRenderConfig(mode="mesh")
    with pytest.raises(ValueError, match="grid_coarse_resolution"):
        ImageRenderConfig(grid_resolution=64, grid_coarse_resolution=12)
    with pytest.raises(ValueError, match="bound_center"):
        render_image(textured_field, sphere_sdf, scene_camera(), torch.zeros(2), 0.1)
    with pytest.raises(ValueError, match="bound_radius"):
        render_image(textured_field, sphere_sdf, scene_camera(), torch.zeros(3), 0.0)
    with pytest.raises(ValueError, match="sdf_fn must return"):
        render_image(textured_field, lambda p: p, scene_camera(), torch.zeros(3), 0.12)
