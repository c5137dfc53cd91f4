"""Sphere tracing to the zero level set of an SDF, and unit normals from its gradient.

The one tracer and the one normal helper of the package: the image renderer's surface mode
(:mod:`lisa_hand.render.image`) and the ground-truth renderer of :mod:`lisa_hand.data.images`
both call them. The SDF comes in as a callback (:class:`~lisa_hand.geometry.fields.SdfFn`,
``points [N, 3] metres -> sdf [N] metres``), called through
:func:`~lisa_hand.geometry.fields.call_sdf`. Nothing here is differentiable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .fields import SdfFn, call_sdf, check_sdf_output

__all__ = ["GRADIENT_METHODS", "SurfaceHits", "sphere_trace", "sdf_normals"]

GRADIENT_METHODS = ("finite_difference", "autograd")
"""How :func:`sdf_normals` differentiates the SDF."""


@dataclass
class SurfaceHits:
    """Result of :func:`sphere_trace`.

    t: [R] metres along the ray to the surface (0 where there is no hit).
    hit: [R] bool. num_evaluations: SDF evaluations spent.
    """

    t: torch.Tensor
    hit: torch.Tensor
    num_evaluations: int


@torch.no_grad()
def sphere_trace(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    *,
    num_steps: int = 128,
    tolerance: float = 1e-5,
    lipschitz: float = 1.0,
    points_per_call: int = 65536,
) -> SurfaceHits:
    """First zero crossing of the SDF along each ray, by sphere tracing (Hart 1996).

    ``t <- t + sdf(o + t d) / lipschitz`` from ``near`` on the still-active rays, until
    ``sdf <= tolerance`` (a hit), ``t > far`` or ``num_steps`` run out (misses). A step that
    lands inside (``sdf < -tolerance``, possible when the SDF overestimates distances) is
    corrected by one secant step between the last two points. For an exact SDF and a ray that
    meets the surface, the hit is within ``tolerance`` (along the SDF) of the first root of
    ``|o + t d - c| = r`` for a sphere, i.e. the closed form to a depth error of about
    ``tolerance / cos(incidence)``. Not differentiable.

    sdf_fn: points [N, 3] metres -> sdf [N] metres (the :mod:`~lisa_hand.geometry.fields`
    contract). origins: [R, 3] metres. directions: [R, 3] unit. near, far: [R] metres
    (e.g. :func:`~lisa_hand.geometry.rays.ray_sphere_bounds`). tolerance: metres.
    lipschitz: >= 1, divides every step (an SDF that overestimates distances by at most this
    factor is never stepped through; ``1 / lipschitz`` is a step scale in (0, 1]).
    points_per_call: most points per ``sdf_fn`` call.
    Returns :class:`SurfaceHits`.
    """
    if origins.dim() != 2 or origins.shape[-1] != 3 or directions.shape != origins.shape:
        raise ValueError(
            f"origins and directions must have shape [R, 3], got {tuple(origins.shape)} and "
            f"{tuple(directions.shape)}"
        )
    if near.shape != origins.shape[:1] or far.shape != near.shape:
        raise ValueError(
            f"near and far must have shape [R]=({origins.shape[0]},), got {tuple(near.shape)} "
            f"and {tuple(far.shape)}"
        )
    if num_steps < 1 or not tolerance > 0 or not lipschitz >= 1:
        raise ValueError(
            f"need num_steps >= 1, tolerance > 0, lipschitz >= 1; got {num_steps}, {tolerance}, "
            f"{lipschitz}"
        )
    t_cur = near.clone()
    t_prev = near.clone()
    sdf_prev = torch.full_like(near, math.inf)
    hit = torch.zeros(near.shape, dtype=torch.bool, device=near.device)
    active = torch.arange(near.shape[0], device=near.device)
    num_evaluations = 0
    for _ in range(num_steps):
        if active.numel() == 0:
            break
        t_act = t_cur[active]
        points = origins[active] + t_act[:, None] * directions[active]
        sdf = call_sdf(sdf_fn, points, points_per_call)
        num_evaluations += points.shape[0]
        done = sdf <= tolerance
        # Overshoot: the surface lies between the previous point (sdf > 0) and this one.
        prev_sdf, prev_t = sdf_prev[active], t_prev[active]
        overshoot = (sdf < -tolerance) & torch.isfinite(prev_sdf)
        secant = prev_t + (t_act - prev_t) * prev_sdf / (prev_sdf - sdf).clamp_min(1e-30)
        t_done = torch.where(overshoot, secant, t_act)
        t_next = t_act + torch.clamp(sdf, min=tolerance) / lipschitz
        t_prev[active] = t_act
        sdf_prev[active] = sdf
        t_cur[active] = torch.where(done, t_done, t_next)
        hit[active] = done & (t_done <= far[active])
        active = active[~done & (t_next <= far[active])]
    t_hit = torch.where(hit, t_cur, torch.zeros_like(t_cur))
    return SurfaceHits(t=t_hit, hit=hit, num_evaluations=num_evaluations)


def sdf_normals(
    sdf_fn: SdfFn,
    points: torch.Tensor,
    method: str = "autograd",
    step: float = 1e-4,
    chunk_size: int = 16384,
) -> torch.Tensor:
    """Unit outward normals ``grad sdf / |grad sdf|`` at points.

    'autograd': backpropagation through ``sdf_fn`` in chunks (exact; needs a differentiable
    callback; on the LISA field about as fast as 3 forward evaluations). 'finite_difference':
    central differences ``(sdf(x + h e_i) - sdf(x - h e_i)) / 2h`` (6 evaluations a point,
    error O(h^2); the 4-point tetrahedral rule would be cheaper but its error is O(h) times the
    Hessian's off-diagonal, about a degree at a fingertip's curvature with h = 0.1 mm).

    sdf_fn: points [N, 3] metres -> sdf [N] metres. points: [N, 3] metres. method: one of
    :data:`GRADIENT_METHODS`. step: h, metres. chunk_size: most points per backward pass (per
    call: ``chunk_size // 6`` points, 6 probes each, for finite differences).
    Returns [N, 3] unit vectors (zero where the gradient vanishes). Not differentiable.
    """
    if points.dim() != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {tuple(points.shape)}")
    if method not in GRADIENT_METHODS:
        raise ValueError(f"method must be 'finite_difference' or 'autograd', got {method!r}")
    grads = []
    if method == "finite_difference":
        axes = torch.eye(3, dtype=points.dtype, device=points.device)
        offsets = torch.cat([axes, -axes]) * step  # [6, 3]: +x, +y, +z, -x, -y, -z
        per_call = max(1, chunk_size // 6)
        with torch.no_grad():
            for start in range(0, points.shape[0], per_call):
                chunk = points[start : start + per_call]
                probes = (chunk[:, None, :] + offsets).reshape(-1, 3)
                values = call_sdf(sdf_fn, probes, probes.shape[0]).reshape(-1, 6)
                grads.append((values[:, :3] - values[:, 3:]) / (2.0 * step))
    else:
        for start in range(0, points.shape[0], chunk_size):
            with torch.enable_grad():
                chunk = points[start : start + chunk_size].detach().requires_grad_(True)
                value = check_sdf_output(sdf_fn(chunk), chunk.shape[0])
                if not value.requires_grad:
                    raise ValueError(
                        "sdf_fn returned values without gradients: autograd normals need a "
                        "differentiable callback; use 'finite_difference' normals (or a "
                        "normal_fn) for this one"
                    )
                (grad,) = torch.autograd.grad(value.sum(), chunk)
            grads.append(grad.detach())
    grads = torch.cat(grads) if grads else points.new_zeros(0, 3)
    return grads / grads.norm(dim=-1, keepdim=True).clamp_min(1e-12)
