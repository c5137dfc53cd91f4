"""Sample distances along rays: uniform and VolSDF's error-bounded sampler (the sphere-traced band
is :mod:`lisa_hand.render.sphere_tracing`; it shares the checks and the grouped generators here).

All samplers return sorted ``t_vals [R, S]`` inside ``[near, far]`` and are *not* differentiable:
they run under ``torch.no_grad`` and only choose where the field is evaluated afterwards. The
SDF callbacks (:class:`~lisa_hand.geometry.fields.SdfFn`) take ``points [N, 3]`` (metres) and
return ``sdf [N]`` (metres, negative inside), checked by
:func:`~lisa_hand.geometry.fields.call_sdf`. Ray directions must have unit length so that ``t``
is a distance in metres (the SDF bounds below compare ``t`` intervals with signed distances).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..geometry.fields import SdfFn, call_sdf
from ..geometry.rays import check_rays
from .density import volsdf_density

__all__ = [
    "ErrorBoundedSamples",
    "GroupGenerators",
    "uniform_samples",
    "error_bounded_sampling",
    "error_bounded_samples",
    "opacity_error_bound",
    "distance_lower_bound",
]

def _check_rays(origins, directions, near, far) -> None:
    check_rays(origins, directions)
    _check_near_far(near, far)
    if near.shape[0] != origins.shape[0]:
        raise ValueError(f"near must have shape [R]=({origins.shape[0]},), got {tuple(near.shape)}")


def _check_near_far(near, far) -> None:
    if not isinstance(near, torch.Tensor) or near.dim() != 1:
        raise ValueError(f"near must be a tensor of shape [R], got {getattr(near, 'shape', near)}")
    if not isinstance(far, torch.Tensor) or far.shape != near.shape:
        raise ValueError(
            f"far must have the shape of near {tuple(near.shape)}, got {getattr(far, 'shape', far)}"
        )


def _check_groups(groups: torch.Tensor | None, num_rays: int) -> None:
    if groups is None:
        return
    if not isinstance(groups, torch.Tensor) or groups.shape != (num_rays,) \
            or groups.dtype != torch.long:
        raise ValueError(f"groups must be a long tensor of shape [R]=({num_rays},), got "
                         f"{getattr(groups, 'dtype', type(groups).__name__)} "
                         f"{tuple(getattr(groups, 'shape', ()))}")


def _eval_sdf(sdf_fn: SdfFn, origins, directions, t_vals) -> torch.Tensor:
    """sdf at ``o + t d`` for t_vals [R, M] -> [R, M] (same dtype as t_vals)."""
    points = origins[:, None, :] + t_vals[..., None] * directions[:, None, :]
    return call_sdf(sdf_fn, points.reshape(-1, 3)).reshape(t_vals.shape)


class GroupGenerators:
    """One ``torch.Generator`` per group of rays (a frame), for stratified sampling of several
    frames in one pass: the draws of a group's rays come from that group's generator alone, so
    a frame gets the same samples whichever frames it is rendered with (one process or several
    under torchrun). Pass it as ``generator`` together with the rays' ``groups``."""

    def __init__(self, generators: list[torch.Generator]) -> None:
        self.generators = list(generators)

    def rand(self, shape: tuple[int, ...], groups: torch.Tensor, *, device, dtype) -> torch.Tensor:
        """Uniform [0, 1) values of ``shape`` (rows = rays), row ``i`` drawn from the generator of
        ``groups[i]`` (each group's rows in their order)."""
        if groups is None or groups.shape != shape[:1]:
            raise ValueError("GroupGenerators needs the rays' groups [R]")
        out = torch.empty(shape, device=device, dtype=dtype)
        for group in torch.unique(groups).tolist():
            rows = (groups == group).nonzero()[:, 0]
            out[rows] = torch.rand((rows.numel(), *shape[1:]), device=device, dtype=dtype,
                                   generator=self.generators[group])
        return out


def _rand(shape, generator, groups, *, device, dtype) -> torch.Tensor:
    """``torch.rand`` from a generator, or per group from :class:`GroupGenerators`."""
    if isinstance(generator, GroupGenerators):
        return generator.rand(tuple(shape), groups, device=device, dtype=dtype)
    return torch.rand(shape, generator=generator, device=device, dtype=dtype)


def uniform_samples(
    near: torch.Tensor,
    far: torch.Tensor,
    num_samples: int,
    stratified: bool = False,
    generator: torch.Generator | GroupGenerators | None = None,
    groups: torch.Tensor | None = None,
) -> torch.Tensor:
    """Split ``[near, far]`` into ``num_samples`` equal bins and take one sample per bin.

    Deterministic: the left edge of each bin, so that with the last interval running up to
    ``far`` the composite quadrature is the left Riemann sum over exactly ``[near, far]``.
    Stratified (training): a uniform random position inside each bin.

    near, far: [R] metres. generator: optional torch.Generator on the tensors' device, or
    :class:`GroupGenerators` with ``groups`` [R] long (the group of each ray).
    Returns t_vals [R, num_samples], sorted, in ``[near, far)``.
    """
    _check_near_far(near, far)
    if num_samples < 1:
        raise ValueError(f"num_samples must be >= 1, got {num_samples}")
    steps = torch.arange(num_samples, device=near.device, dtype=near.dtype)
    steps = steps.expand(near.shape[0], num_samples)
    if stratified:
        steps = steps + _rand(steps.shape, generator, groups, device=near.device,
                              dtype=near.dtype)
    return near[:, None] + (far - near)[:, None] * (steps / num_samples)


def _sample_inverse_cdf(
    bins: torch.Tensor, weights: torch.Tensor, unit: torch.Tensor
) -> torch.Tensor:
    """Invert the piecewise-linear CDF of a piecewise-constant pdf.

    bins: [R, M] sorted bin edges. weights: [R, M-1] non-negative, not all zero, per bin.
    unit: [R, N] values in [0, 1]. Returns [R, N] positions inside ``[bins_0, bins_{M-1}]``.
    """
    pdf = weights / weights.sum(-1, keepdim=True)
    cdf = torch.cumsum(pdf, dim=-1)
    cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf], dim=-1)
    cdf[:, -1] = 1.0
    index = torch.searchsorted(cdf.contiguous(), unit.contiguous(), right=True)
    last = bins.shape[-1] - 1
    below = torch.clamp(index - 1, 0, last)
    above = torch.clamp(index, 0, last)
    cdf_below, cdf_above = cdf.gather(-1, below), cdf.gather(-1, above)
    bin_below, bin_above = bins.gather(-1, below), bins.gather(-1, above)
    span = cdf_above - cdf_below
    span = torch.where(span < 1e-12, torch.ones_like(span), span)
    frac = torch.clamp((unit - cdf_below) / span, 0.0, 1.0)
    return bin_below + frac * (bin_above - bin_below)


def _unit_positions(num_rays, num, stratified, generator, like) -> torch.Tensor:
    """[R, num] in [0, 1): bin midpoints, or uniform random inside each bin when stratified."""
    steps = torch.arange(num, device=like.device, dtype=like.dtype).expand(num_rays, num)
    if stratified:
        offsets = torch.rand(steps.shape, generator=generator, device=like.device, dtype=like.dtype)
    else:
        offsets = torch.full_like(steps, 0.5)
    return (steps + offsets) / num


def distance_lower_bound(t_vals: torch.Tensor, sdf: torch.Tensor) -> torch.Tensor:
    """VolSDF's ``d*_i``: a lower bound of the distance to the surface on ``[t_i, t_{i+1}]``.

    For an exact SDF the surface avoids the balls ``B(x_i, |s_i|)`` and ``B(x_{i+1}, |s_{i+1}|)``;
    ``d*`` is the distance from the segment to the complement of their union: ``|s_i|`` or
    ``|s_{i+1}|`` when the other ball's boundary is not reached above the segment (obtuse angle),
    the height of the triangle (segment, two radii) otherwise, and 0 when the balls do not cover
    the segment or the sign changes (VolSDF Section 3.3, Theorem 1).

    t_vals: [R, M] sorted metres (unit directions); sdf: [R, M] metres. Returns [R, M-1] >= 0.
    """
    seg = t_vals[:, 1:] - t_vals[:, :-1]
    rad_a, rad_b = sdf[:, :-1].abs(), sdf[:, 1:].abs()
    seg2, rad_a2, rad_b2 = seg * seg, rad_a * rad_a, rad_b * rad_b
    obtuse_at_a = seg2 + rad_a2 <= rad_b2
    obtuse_at_b = seg2 + rad_b2 <= rad_a2
    covered = rad_a + rad_b > seg
    # Foot of the triangle's height, measured from x_i along the segment, then the height itself.
    foot = (seg2 + rad_a2 - rad_b2) / (2.0 * torch.clamp(seg, min=1e-20))
    height = torch.sqrt(torch.clamp(rad_a2 - foot * foot, min=0.0))
    d_star = torch.where(covered, height, torch.zeros_like(height))
    d_star = torch.where(obtuse_at_b, rad_b, d_star)
    d_star = torch.where(obtuse_at_a, rad_a, d_star)
    same_sign = (sdf[:, :-1] * sdf[:, 1:]) > 0
    return torch.where(same_sign, d_star, torch.zeros_like(d_star))


def opacity_error_bound(
    t_vals: torch.Tensor,
    sdf: torch.Tensor,
    beta: torch.Tensor,
    d_star: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """VolSDF's bound on the opacity error of the left Riemann sum on ``t_vals``.

    With ``sigma = volsdf_density(sdf, beta)`` (``alpha = 1 / beta``), ``R_hat(t_k)`` the left
    Riemann sum of ``sigma`` up to ``t_k`` and (VolSDF Theorem 1, Eq. 13)

        E_hat(t_{k+1}) = 1 / (4 beta^2) * sum_{i<=k} delta_i^2 exp(-d*_i / beta),

    the opacity error on ``[t_k, t_{k+1}]`` is at most (VolSDF Eq. 14)
    ``B_k = (exp(E_hat(t_{k+1})) - 1) exp(-R_hat(t_k))``; ``B = max_k B_k``.

    t_vals: [R, M] sorted metres, covering the interval of interest. sdf: [R, M] metres.
    beta: [R, 1] or [] metres. d_star: [R, M-1] from the SDF (computed when None).
    Returns ``(bound [R], per_section [R, M-1])``.
    """
    if d_star is None:
        d_star = distance_lower_bound(t_vals, sdf)
    return _ErrorBoundTerms(t_vals, sdf, d_star)(beta)


class _ErrorBoundTerms:
    """The beta-independent parts of :func:`opacity_error_bound`, for bisection on beta.

    Per call only three exponentials of ``[R, M-1]`` tensors are evaluated: the density as
    ``Psi_beta(-s) = 0.5 exp(-|s|/beta)`` outside, ``1 - 0.5 exp(-|s|/beta)`` inside.
    """

    def __init__(self, t_vals: torch.Tensor, sdf: torch.Tensor, d_star: torch.Tensor) -> None:
        self.deltas = t_vals[:, 1:] - t_vals[:, :-1]
        self.deltas_sq = self.deltas * self.deltas
        self.neg_abs_sdf = -sdf[:, :-1].abs()
        self.inside = sdf[:, :-1] < 0
        self.neg_d_star = -d_star

    def __call__(self, beta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        half_tail = 0.5 * torch.exp(self.neg_abs_sdf / beta)
        sigma = torch.where(self.inside, 1.0 - half_tail, half_tail) / beta
        section_depth = sigma * self.deltas
        # Exclusive cumulative sum (R_hat at the start of each section); the rounding of the
        # subtraction only matters where exp(-R_hat) is already negligible.
        riemann = torch.cumsum(section_depth, dim=-1) - section_depth
        error = torch.cumsum(self.deltas_sq * torch.exp(self.neg_d_star / beta), dim=-1)
        error = error / (4.0 * beta * beta)
        # exp(60) is finite in float32; past that the bound is meaningless anyway.
        per_section = torch.expm1(torch.clamp(error, max=60.0)) * torch.exp(-riemann)
        return per_section.max(dim=-1).values, per_section


def _section_weights(t_vals, sdf, beta) -> torch.Tensor:
    """Composite weights of the sections ``[t_i, t_{i+1})``: [R, M-1]."""
    deltas = t_vals[:, 1:] - t_vals[:, :-1]
    depth = volsdf_density(sdf[:, :-1], beta) * deltas
    before = torch.cat([torch.zeros_like(depth[:, :1]), torch.cumsum(depth[:, :-1], dim=-1)], -1)
    return torch.exp(-before) * -torch.expm1(-depth)


@dataclass
class ErrorBoundedSamples:
    """Result of :func:`error_bounded_sampling`.

    t_vals: [R, S] final samples, sorted (``S = num_samples + num_samples_extra``).
    t_bound: [R, M] the set ``T`` on which the opacity error bound was computed (sorted; starts
        at ``near`` and ends at ``far``). Rays that converged before the last upsampling are
        padded at the end with copies of ``far`` (zero-length sections).
    sdf_bound: [R, M] sdf at ``t_bound``, metres.
    beta_plus: [R] the ``beta+`` of Algorithm 1: the smallest scale found for which the bound on
        ``T`` is ``<= eps``; equals the target beta on converged rays.
    error_bound: [R] the bound ``B_{T, beta+}``.
    converged: [R] bool, True where ``B_{T, beta} <= eps`` for the target beta.
    num_bound: [R] long, number of SDF evaluations of each ray (real members of ``T``).
    """

    t_vals: torch.Tensor
    t_bound: torch.Tensor
    sdf_bound: torch.Tensor
    beta_plus: torch.Tensor
    error_bound: torch.Tensor
    converged: torch.Tensor
    num_bound: torch.Tensor


@torch.no_grad()
def error_bounded_sampling(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    beta: float | torch.Tensor,
    *,
    num_samples: int = 64,
    num_samples_eval: int = 128,
    num_samples_extra: int = 32,
    eps: float = 0.1,
    num_bisection: int = 10,
    max_iters: int = 5,
    stratified: bool = False,
    generator: torch.Generator | None = None,
) -> ErrorBoundedSamples:
    """VolSDF's error-bounded sampler (VolSDF Algorithm 1, Section 3.4).

    1. ``T`` = ``num_samples_eval`` uniform samples from ``near`` to ``far`` (inclusive); the SDF
       is evaluated there without gradients.
    2. ``beta+`` from VolSDF Lemma 2, ``sqrt(sum delta^2 / (4 log(1 + eps)))``, which makes the
       bound ``<= eps`` whatever the SDF.
    3. Up to ``max_iters`` times: if ``B_{T, beta} <= eps`` the ray has converged
       (``beta+ = beta``); otherwise ``beta+`` is lowered by ``num_bisection`` bisection steps
       on ``(beta, beta+)`` keeping ``B_{T, beta+} <= eps``, and ``num_samples_eval`` samples
       are added to ``T`` by inverting the CDF of the per-section error bound (the SDF is
       evaluated at them). Converged rays are left alone (no further SDF evaluations).
    4. ``num_samples`` fresh samples are drawn by inverting the opacity ``O_hat_{T, beta+}``
       (bin midpoints, or stratified), and ``num_samples_extra`` samples of ``T`` (evenly spaced
       indices) are added, as VolSDF does.

    The density is assumed to be :func:`volsdf_density` with ``alpha = 1 / beta``. The final
    inverse CDF uses the section weights plus a floor of total mass 1e-3 spread by length (VolSDF
    adds 1e-5 per section). Not differentiable (runs under ``torch.no_grad``).

    sdf_fn: points [N, 3] metres -> sdf [N] metres.
    origins: [R, 3] metres. directions: [R, 3] unit. near, far: [R] metres, ``far > near``.
    beta: target Laplace scale (float or [] tensor), metres.
    eps: bound on the opacity error. generator: for the stratified draws.
    """
    _check_rays(origins, directions, near, far)
    if num_samples < 1 or num_samples_eval < 2 or num_samples_extra < 0:
        raise ValueError(
            "need num_samples >= 1, num_samples_eval >= 2, num_samples_extra >= 0, got "
            f"{num_samples}, {num_samples_eval}, {num_samples_extra}"
        )
    if not eps > 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    num_rays, dtype, device = origins.shape[0], origins.dtype, origins.device
    beta_t = torch.as_tensor(beta, dtype=dtype, device=device).detach().reshape(1, 1)
    beta_t = beta_t.expand(num_rays, 1)
    unit = torch.linspace(0.0, 1.0, num_samples_eval, dtype=dtype, device=device)
    t_bound = near[:, None] + (far - near)[:, None] * unit
    sdf_bound = _eval_sdf(sdf_fn, origins, directions, t_bound)
    bound_set = _refine_bound_set(
        sdf_fn, origins, directions, t_bound, sdf_bound, beta_t, eps, num_bisection, max_iters
    )
    t_bound, sdf_bound, beta_plus, converged, num_bound = bound_set
    error_bound, _ = opacity_error_bound(t_bound, sdf_bound, beta_plus)
    t_vals = _final_samples(
        t_bound, sdf_bound, beta_plus, num_bound, num_samples, num_samples_extra, stratified,
        generator,
    )
    return ErrorBoundedSamples(
        t_vals=t_vals,
        t_bound=t_bound,
        sdf_bound=sdf_bound,
        beta_plus=beta_plus[:, 0],
        error_bound=error_bound,
        converged=converged,
        num_bound=num_bound,
    )


def _refine_bound_set(
    sdf_fn, origins, directions, t_bound, sdf_bound, beta_t, eps, num_bisection, max_iters
):
    """Steps 2 and 3 of :func:`error_bounded_sampling` (VolSDF Algorithm 1): ``beta+`` and the
    upsampling of T until the bound holds for the target beta or ``max_iters`` run out.

    t_bound, sdf_bound: [R, M0] the initial T and its sdf. beta_t: [R, 1] the target beta.
    Returns ``(t_bound [R, M], sdf_bound [R, M], beta_plus [R, 1], converged [R] bool,
    num_bound [R] long)``.
    """
    num_rays, device = t_bound.shape[0], t_bound.device
    num_samples_eval = t_bound.shape[1]
    log_eps = math.log1p(eps)
    beta_plus = torch.maximum(_lemma2_beta(t_bound, log_eps), beta_t)
    converged = torch.zeros(num_rays, dtype=torch.bool, device=device)
    num_bound = torch.full((num_rays,), num_samples_eval, dtype=torch.long, device=device)
    for iteration in range(max_iters):
        # Only unconverged rays are worked on; converged ones keep their T and beta+ = beta.
        rows = torch.nonzero(~converged).squeeze(-1)
        if rows.numel() == 0:
            break
        t_rows, sdf_rows, beta_rows = t_bound[rows], sdf_bound[rows], beta_t[rows]
        d_star = distance_lower_bound(t_rows, sdf_rows)
        bound_of = _ErrorBoundTerms(t_rows, sdf_rows, d_star)
        rows_converged = bound_of(beta_rows)[0] <= eps
        high = _bisect_beta_plus(
            bound_of, beta_rows, beta_plus[rows], t_rows, eps, log_eps, num_bisection
        )
        beta_rows_plus = torch.where(rows_converged[:, None], beta_rows, high)
        beta_plus[rows] = beta_rows_plus
        converged[rows] = rows_converged
        if bool(rows_converged.all()) or iteration == max_iters - 1:
            break

        # Upsample the unconverged rays where the error bound is largest (VolSDF Algorithm 1).
        keep = ~rows_converged
        rows = rows[keep]
        per_section = bound_of(beta_rows_plus)[1][keep]
        t_bound, sdf_bound = _upsample_bound_set(
            sdf_fn, origins, directions, t_bound, sdf_bound, rows, t_rows[keep],
            sdf_rows[keep], per_section, num_samples_eval,
        )
        num_bound[rows] += num_samples_eval
    return t_bound, sdf_bound, beta_plus, converged, num_bound


def _lemma2_beta(t_vals: torch.Tensor, log_eps: float) -> torch.Tensor:
    """VolSDF Lemma 2's ``beta+ = sqrt(sum delta^2 / (4 log(1 + eps)))`` of t_vals [R, M]:
    [R, 1] metres, a scale for which the error bound is ``<= eps`` whatever the SDF."""
    deltas = t_vals[:, 1:] - t_vals[:, :-1]
    return torch.sqrt((deltas * deltas).sum(-1, keepdim=True) / (4.0 * log_eps))


def _bisect_beta_plus(bound_of, low, high, t_rows, eps, log_eps, num_bisection):
    """Lower ``beta+`` by bisection on ``(beta, beta+)`` keeping ``B_{T, beta+} <= eps``.

    bound_of: the rays' :class:`_ErrorBoundTerms`. low: [R, 1] the target beta. high: [R, 1]
    the previous ``beta+`` (replaced by Lemma 2 on the current T where it no longer satisfies
    the bound after upsampling). t_rows: [R, M] the rays' T. Returns the new ``beta+`` [R, 1].
    """
    high_fails = bound_of(high)[0] > eps
    high = torch.where(high_fails[:, None], _lemma2_beta(t_rows, log_eps), high)
    low = low.clone()
    for _ in range(num_bisection):
        mid = 0.5 * (low + high)
        ok = (bound_of(mid)[0] <= eps)[:, None]
        high = torch.where(ok, mid, high)
        low = torch.where(ok, low, mid)
    return high


def _upsample_bound_set(
    sdf_fn, origins, directions, t_bound, sdf_bound, rows, t_rows, sdf_rows, per_section,
    num_samples_eval,
):
    """Add ``num_samples_eval`` samples to the T of the rays ``rows`` where their error bound is
    largest (inverting the bound's CDF at bin midpoints; the SDF is evaluated there).

    t_bound, sdf_bound: [R, M] every ray's T and its sdf. rows: [K] the rays to upsample;
    t_rows, sdf_rows: [K, M] their T; per_section: [K, M-1] their per-section bounds.
    Returns ``(t_bound, sdf_bound)`` [R, M + num_samples_eval]: the other rays are padded with
    copies of their last sample (t = far): zero-length sections that change neither the bound
    nor the weights.
    """
    unit_new = _unit_positions(rows.shape[0], num_samples_eval, False, None, t_rows)
    t_new = _sample_inverse_cdf(t_rows, per_section + 1e-6, unit_new)
    sdf_new = _eval_sdf(sdf_fn, origins[rows], directions[rows], t_new)
    t_rows, order = torch.sort(torch.cat([t_rows, t_new], dim=-1), dim=-1)
    sdf_rows = torch.cat([sdf_rows, sdf_new], dim=-1).gather(-1, order)
    t_bound = torch.cat([t_bound, t_bound[:, -1:].expand(-1, num_samples_eval)], dim=-1)
    sdf_bound = torch.cat([sdf_bound, sdf_bound[:, -1:].expand(-1, num_samples_eval)], dim=-1)
    t_bound[rows] = t_rows
    sdf_bound[rows] = sdf_rows
    return t_bound, sdf_bound


def _final_samples(
    t_bound, sdf_bound, beta_plus, num_bound, num_samples, num_samples_extra, stratified,
    generator,
):
    """VolSDF Algorithm 1's last step: ``num_samples`` samples inverting the opacity
    ``O_hat_{T, beta+}`` plus ``num_samples_extra`` members of each ray's T, sorted: [R, S]."""
    num_rays, dtype, device = t_bound.shape[0], t_bound.dtype, t_bound.device
    weights = _section_weights(t_bound, sdf_bound, beta_plus)
    # A floor of total mass 1e-3, spread by length, keeps the pdf positive on empty rays.
    section = t_bound[:, 1:] - t_bound[:, :-1]
    floor = 1e-3 * section / torch.clamp(section.sum(-1, keepdim=True), min=1e-20)
    unit_final = _unit_positions(num_rays, num_samples, stratified, generator, t_bound)
    t_vals = _sample_inverse_cdf(t_bound, weights + floor + 1e-20, unit_final)
    if num_samples_extra > 0:
        # Evenly spaced (or, stratified, random) members of each ray's own T.
        if stratified:
            frac = torch.rand(
                num_rays, num_samples_extra, generator=generator, device=device, dtype=dtype
            )
        else:
            frac = torch.linspace(0.0, 1.0, num_samples_extra, dtype=dtype, device=device)
            frac = frac.expand(num_rays, num_samples_extra)
        pick = torch.round(frac * (num_bound[:, None] - 1).to(dtype)).long()
        t_vals = torch.cat([t_vals, t_bound.gather(-1, pick)], dim=-1)
    t_vals, _ = torch.sort(t_vals, dim=-1)
    return t_vals


def error_bounded_samples(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    beta: float | torch.Tensor,
    **kwargs,
) -> torch.Tensor:
    """The ``t_vals [R, S]`` of :func:`error_bounded_sampling` (same arguments)."""
    return error_bounded_sampling(sdf_fn, origins, directions, near, far, beta, **kwargs).t_vals
