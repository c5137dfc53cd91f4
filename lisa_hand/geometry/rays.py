"""Ray bounds: where rays ``o + t d`` enter and leave a sphere or an axis-aligned box.

Used by the renderer (sampling bounds), the image renderer (culling) and the ground-truth sphere
tracer of :mod:`lisa_hand.data.images`; nothing here is learnable or differentiable in a useful
sense (the bounds are sampling limits).
"""

from __future__ import annotations

import math

import torch

__all__ = ["check_rays", "ray_sphere_bounds", "ray_box_bounds"]


def check_rays(origins: torch.Tensor, directions: torch.Tensor) -> None:
    """Refuse rays of the wrong shape: origins [R, 3] metres and directions [R, 3] (ValueError
    naming the argument and its shape)."""
    if origins.dim() != 2 or origins.shape[-1] != 3:
        raise ValueError(f"origins must have shape [R, 3], got {tuple(origins.shape)}")
    if directions.shape != origins.shape:
        raise ValueError(
            f"directions must have the shape of origins {tuple(origins.shape)}, "
            f"got {tuple(directions.shape)}"
        )


def ray_sphere_bounds(
    origins: torch.Tensor,
    directions: torch.Tensor,
    center: torch.Tensor,
    radius: float | torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays ``x(t) = o + t d`` (``t >= 0``) with a sphere.

    Solves ``|o + t d - c|^2 = radius^2``. ``t`` is in units of ``|d|``: metres for unit
    directions. A ray whose origin is inside the sphere gets ``near = 0``; a ray that misses the
    sphere, only touches it, or has it entirely behind the origin gets ``hit = False`` and
    ``near = far = 0``; such rays should be skipped (the renderer gives them the background).

    origins: [R, 3] ray origins, metres.
    directions: [R, 3] ray directions (non-zero; unit length gives ``t`` in metres).
    center: [3] or [R, 3] sphere centre, metres.
    radius: float or [] or [R] sphere radius, metres (> 0).
    Returns ``(near [R], far [R], hit [R] bool)``; not differentiable in a useful sense (use them
    as sampling bounds only).
    """
    check_rays(origins, directions)
    center = torch.as_tensor(center, dtype=origins.dtype, device=origins.device)
    if center.shape not in ((3,), origins.shape):
        raise ValueError(f"center must have shape [3] or [R, 3], got {tuple(center.shape)}")
    radius = torch.as_tensor(radius, dtype=origins.dtype, device=origins.device)
    if radius.dim() > 1 or (radius.dim() == 1 and radius.shape[0] != origins.shape[0]):
        raise ValueError(f"radius must be a float, [] or [R], got shape {tuple(radius.shape)}")

    offset = origins - center
    # |d|^2 t^2 + 2 (d . offset) t + |offset|^2 - r^2 = 0, written with the half coefficient.
    quad_a = (directions * directions).sum(-1)
    half_b = (directions * offset).sum(-1)
    quad_c = (offset * offset).sum(-1) - radius * radius
    discriminant = half_b * half_b - quad_a * quad_c
    sqrt_disc = torch.sqrt(torch.clamp(discriminant, min=0.0))
    t_enter = (-half_b - sqrt_disc) / quad_a
    t_exit = (-half_b + sqrt_disc) / quad_a
    hit = (discriminant > 0) & (t_exit > 0) & (quad_a > 0)
    zeros = torch.zeros_like(t_enter)
    near = torch.where(hit, torch.clamp(t_enter, min=0.0), zeros)
    far = torch.where(hit, t_exit, zeros)
    return near, far, hit


def ray_box_bounds(
    origins: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays ``o + t d`` (``t >= 0``) with the axis-aligned box ``[low, high]`` (slabs).

    origins: [R, 3] metres. directions: [R, 3]. low, high: [3] metres.
    Returns ``(near [R], far [R], hit [R] bool)``; near = 0 for origins inside the box;
    near = far = 0 where the ray misses.
    """
    with torch.no_grad():
        inverse = 1.0 / directions  # +-inf on axis-parallel rays: the slab test still works
        t_low = (low - origins) * inverse
        t_high = (high - origins) * inverse
        # 0 * inf = nan for origins on a slab plane parallel to the ray: treat as inside.
        t_low = torch.nan_to_num(t_low, nan=-math.inf)
        t_high = torch.nan_to_num(t_high, nan=math.inf)
        t_enter = torch.minimum(t_low, t_high).amax(dim=-1).clamp_min(0.0)
        t_exit = torch.maximum(t_low, t_high).amin(dim=-1)
        hit = t_exit > t_enter
        zeros = torch.zeros_like(t_enter)
        return torch.where(hit, t_enter, zeros), torch.where(hit, t_exit, zeros), hit
