"""An analytic sphere seen by a pinhole camera, built here so the renderer tests stand alone."""

from __future__ import annotations

import math

import torch

RADIUS = 0.1  # metres, centred at the origin
EYE = (0.3, -0.2, -0.35)  # camera centre, metres (distance sqrt(0.2525) ~ 0.502 m)


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    """points [N, 3] metres -> exact signed distance [N] to the sphere (negative inside)."""
    return points.norm(dim=-1) - RADIUS


def look_at(eye, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """World-to-camera ``R [3, 3], t [3]`` (x_cam = R x + t, OpenCV axes) looking at the origin."""
    eye = torch.tensor(eye, dtype=torch.float64)
    forward = -eye / eye.norm()
    right = torch.linalg.cross(forward, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    right = right / right.norm()
    down = torch.linalg.cross(forward, right)
    rot = torch.stack([right, down, forward])
    return rot.to(dtype), (-rot @ eye).to(dtype)


def pinhole_rays(K, R, t, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through pixel centres: origins [H*W, 3], unit directions [H*W, 3] (row-major)."""
    rows, cols = torch.meshgrid(
        torch.arange(height, dtype=K.dtype) + 0.5,
        torch.arange(width, dtype=K.dtype) + 0.5,
        indexing="ij",
    )
    pixels = torch.stack([cols, rows, torch.ones_like(cols)], dim=-1).reshape(-1, 3)
    dirs_cam = pixels @ torch.linalg.inv(K).T
    directions = dirs_cam @ R  # R^T applied to each row
    directions = directions / directions.norm(dim=-1, keepdim=True)
    origins = (-R.T @ t).expand_as(directions)
    return origins, directions


def make_camera(size: int, focal: float, dtype=torch.float32):
    """K [3, 3], R, t and the silhouette radius in pixels of the sphere (centred in the image)."""
    K = torch.tensor([[focal, 0.0, size / 2], [0.0, focal, size / 2], [0.0, 0.0, 1.0]], dtype=dtype)
    R, t = look_at(EYE, dtype)
    distance = math.sqrt(sum(c * c for c in EYE))
    silhouette_px = focal * RADIUS / math.sqrt(distance**2 - RADIUS**2)
    return K, R, t, silhouette_px


def pixel_radius(size: int) -> torch.Tensor:
    """[H*W] distance of each pixel centre from the image centre, pixels."""
    rows, cols = torch.meshgrid(
        torch.arange(size) + 0.5 - size / 2, torch.arange(size) + 0.5 - size / 2, indexing="ij"
    )
    return torch.sqrt(rows**2 + cols**2).reshape(-1).double()
