"""The sphere-traced sampler: samples in a band around the surface found by sphere tracing.

Cheaper than VolSDF's error-bounded sampler (:mod:`lisa_hand.render.samplers`) where the SDF is a
distance bound: the rays are marched to the shell where the density starts to matter and on to
the surface, and the samples go in a band of a few ``beta`` around it. Several frames can be
traced in one pass (``groups``, grouped callbacks: :mod:`lisa_hand.geometry.fields`). Not
differentiable (runs under ``torch.no_grad``).
"""

from __future__ import annotations

import math

import torch

from ..geometry.fields import SdfFn, call_sdf
from .samplers import GroupGenerators, _check_groups, _check_rays, uniform_samples

__all__ = ["sphere_traced_samples"]


@torch.no_grad()
def sphere_traced_samples(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    beta: float | torch.Tensor,
    *,
    num_samples: int = 32,
    num_uniform: int = 8,
    num_steps: int = 64,
    band_outside: float = 8.0,
    band_inside: float = 16.0,
    min_step: float = 1.0,
    hit_tolerance: float = 0.1,
    stratified: bool = False,
    generator: torch.Generator | GroupGenerators | None = None,
    groups: torch.Tensor | None = None,
    full_steps: bool = False,
) -> torch.Tensor:
    """Samples concentrated where VolSDF's density matters, found by sphere tracing.

    Outside the shell ``sdf <= band_outside * beta`` the density is below
    ``exp(-band_outside) / (2 beta)``; behind the surface the transmittance falls at least as
    ``exp(-dt / (2 beta))``. So the ray is sphere traced (step = distance to the shell, then to
    the surface, at least ``min_step * beta``; only the still-active rays are evaluated) to find
    where it first enters the shell, and where it first reaches the surface
    (``sdf <= hit_tolerance * beta``). The band runs from the entry (less one minimum step) to
    ``band_inside * beta`` past that hit; a ray that crosses the shell without hitting the surface
    gets the band up to its last exit from the shell, or up to ``far`` when it ran out of
    ``num_steps`` before ``far`` (the rest of the ray is unexplored; a grazing ray that crawls
    along the shell at the minimum step ends this way, and more steps then sharpen its band).
    ``num_samples`` evenly spaced samples (stratified: one random sample per bin) go in the band
    and ``num_uniform`` uniform samples in ``[near, far]``; rays that never enter the shell get all
    ``num_samples + num_uniform`` samples uniformly (their opacity is negligible; a ray that runs
    out of ``num_steps`` before entering the shell is treated the same way).

    Assumes an SDF that does not overestimate distances (sphere tracing never steps past the
    surface by more than the minimum step). Not differentiable (runs under ``torch.no_grad``).

    sdf_fn: points [N, 3] metres -> sdf [N] metres.
    origins: [R, 3] metres. directions: [R, 3] unit. near, far: [R] metres.
    beta: the density's current Laplace scale, metres (float or [] tensor).
    full_steps: once a ray has entered the shell, step the full ``sdf`` (towards the surface)
        instead of ``sdf - shell``: fewer steps for rays that graze the shell (between fingers),
        and the end of a non-hitting ray's band found up to one step late.
    groups: [R] long, the field of each ray; ``sdf_fn`` is then a
        :class:`~lisa_hand.geometry.fields.GroupedSdfFn` called with the group of every point
        (several frames traced in one pass: one call a step for all of them).
    Returns t_vals [R, num_samples + num_uniform], sorted, in ``[near, far]``.
    """
    _check_rays(origins, directions, near, far)
    _check_groups(groups, origins.shape[0])
    if num_samples < 1 or num_uniform < 0 or num_steps < 1:
        raise ValueError(
            f"need num_samples >= 1, num_uniform >= 0, num_steps >= 1, got {num_samples}, "
            f"{num_uniform}, {num_steps}"
        )
    dtype, device = origins.dtype, origins.device
    beta_value = torch.as_tensor(beta, dtype=dtype, device=device).detach()
    shell = band_outside * beta_value
    step_min = min_step * beta_value
    tolerance = hit_tolerance * beta_value
    t_enter, t_leave, t_hit = _trace_shell(
        sdf_fn, origins, directions, near, far, shell, step_min, tolerance, num_steps, groups,
        full_steps,
    )

    entered = torch.isfinite(t_enter)
    hit = torch.isfinite(t_hit)
    band_start = torch.maximum(t_enter - step_min, near)
    band_end = torch.where(hit, t_hit + band_inside * beta_value, t_leave)
    band_end = torch.minimum(band_end, far)
    band_start = torch.where(entered, band_start, near)
    band_end = torch.where(entered, torch.maximum(band_end, band_start), far)

    total = num_samples + num_uniform
    in_band = uniform_samples(band_start, band_end, num_samples, stratified, generator, groups)
    if num_uniform > 0:
        coarse = uniform_samples(near, far, num_uniform, stratified, generator, groups)
        in_band = torch.cat([in_band, coarse], dim=-1)
    everywhere = uniform_samples(near, far, total, stratified, generator, groups)
    t_vals = torch.where(entered[:, None], in_band, everywhere)
    return torch.sort(t_vals, dim=-1).values


def _trace_shell(sdf_fn, origins, directions, near, far, shell, step_min, tolerance, num_steps,
                 groups=None, full_steps=False):
    """The sphere-tracing walk of :func:`sphere_traced_samples`.

    Steps ``sdf - shell`` outside the shell ``sdf <= shell``, ``sdf`` inside it (at least
    ``step_min``; with ``full_steps``, ``sdf`` everywhere after the first entry), on the
    still-active rays, until the surface (``sdf <= tolerance``), ``far``
    or ``num_steps``. shell, step_min, tolerance: [] metres.
    Returns ``(t_enter [R], t_leave [R], t_hit [R])`` metres: the first entry into the shell
    (inf: never), the band end of a ray that does not hit (its last exit from the shell, or
    ``far`` while it is still inside or still marching), the surface hit (inf: none).
    """
    num_rays, device = origins.shape[0], origins.device
    t_cur = near.clone()
    t_enter = torch.full_like(near, math.inf)  # first entry into the shell
    t_leave = far.clone()  # band end for rays that never hit
    t_hit = torch.full_like(near, math.inf)
    inside = torch.zeros(num_rays, dtype=torch.bool, device=device)  # currently in the shell
    active = torch.arange(num_rays, device=device)
    for _ in range(num_steps):
        if active.numel() == 0:
            break
        t_act = t_cur[active]
        points = origins[active] + t_act[:, None] * directions[active]
        sdf = call_sdf(sdf_fn, points, groups=None if groups is None else groups[active])
        in_shell = sdf <= shell
        t_enter[active] = torch.where(
            in_shell, torch.minimum(t_enter[active], t_act), t_enter[active]
        )
        left_shell = inside[active] & ~in_shell
        t_leave[active] = torch.where(left_shell, t_act, t_leave[active])
        # A ray that re-enters after leaving goes back to 'band up to far' until it leaves again.
        t_leave[active] = torch.where(in_shell & ~inside[active], far[active], t_leave[active])
        inside[active] = in_shell
        hit_now = sdf <= tolerance
        t_hit[active] = torch.where(hit_now, t_act, t_hit[active])
        # Full sphere-tracing steps inside the shell (and, with full_steps, once it was entered:
        # only the surface is looked for then, not the shell's boundary, which a ray grazing
        # between the fingers would otherwise approach at the minimum step).
        full = torch.isfinite(t_enter[active]) if full_steps else in_shell
        step = torch.where(full, sdf, sdf - shell)
        t_next = t_act + torch.clamp(step, min=step_min)
        t_cur[active] = t_next
        keep = ~hit_now & (t_next <= far[active])
        active = active[keep]
    # Rays still marching when the steps ran out (e.g. grazing the shell at the minimum step)
    # have not seen the rest of the ray: their band runs up to far, not to their last exit.
    t_leave[active] = far[active]
    return t_enter, t_leave, t_hit
