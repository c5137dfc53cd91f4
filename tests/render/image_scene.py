"""The analytic sphere of the image tests, its camera, exact hits and a small render."""

from __future__ import annotations

import torch

from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov, look_at, pixel_rays
from lisa_hand.geometry.rays import ray_sphere_bounds
from lisa_hand.render import LaplaceDensity
from lisa_hand.render.image import ImageRenderConfig, render_image

RADIUS = 0.1  # analytic sphere at the origin, metres
EYE = (0.3, -0.2, -0.35)
WIDTH, HEIGHT = 48, 32
BETA = 1e-4  # small enough that the volume silhouette matches the surface (pixels ~7 mm)
# A coarser occupancy grid than the default keeps these tiny renders fast (the default 64^3 grid
# is tested on its own).
SMALL_GRID = {"grid_resolution": 32, "grid_coarse_resolution": 8}


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    return points.norm(dim=-1) - RADIUS


def textured_field(points: torch.Tensor, directions: torch.Tensor):
    """Colour varying in space, so a misplaced sample changes the image."""
    return sphere_sdf(points), 0.5 + 0.5 * torch.sin(40.0 * points)


def scene_camera(width=WIDTH, height=HEIGHT, dtype=torch.float32) -> Camera:
    """A 40 degree camera at EYE looking at the sphere's centre."""
    rotation, translation = look_at(torch.tensor(EYE, dtype=torch.float64), torch.zeros(3))
    K = intrinsics_from_fov(40.0, width, height, dtype=torch.float64)
    return Camera(
        K=K.to(dtype), R=rotation.to(dtype), t=translation.to(dtype), width=width, height=height
    )


def analytic_hits(camera: Camera, dtype=torch.float64):
    """Exact ray-sphere intersections: (t [H*W], hit [H*W], points [H*W, 3]) in float64."""
    origins, directions = pixel_rays(camera, dtype=torch.float64)
    near, far, hit = ray_sphere_bounds(
        origins, directions, torch.zeros(3, dtype=torch.float64), RADIUS
    )
    points = origins + near[:, None] * directions
    return near, hit, points


def analytic_entry(origins, directions):
    """Distance [R] to the analytic sphere and whether each ray hits it [R]."""
    near, _, hit = ray_sphere_bounds(
        origins.double(), directions.double(), torch.zeros(3, dtype=torch.float64), RADIUS
    )
    return near.float(), hit


def render_sphere(mode, dtype=torch.float32, **options):
    """render_image of the textured sphere in ``mode`` (small grid, Laplace scale BETA)."""
    config = ImageRenderConfig(mode=mode, **SMALL_GRID, **options)
    density = LaplaceDensity(beta_init=BETA, beta_min=0.0)
    center = torch.zeros(3, dtype=dtype)
    return render_image(
        textured_field, sphere_sdf, scene_camera(), center, 1.2 * RADIUS, config, density.to(dtype)
    )


def erode(mask: torch.Tensor) -> torch.Tensor:
    """Pixels whose 4 neighbours are also in the mask (away from the silhouette)."""
    inner = mask.clone()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return inner
