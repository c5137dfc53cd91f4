"""Discrete volume-rendering quadrature: per-sample weights and alpha compositing."""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["RenderOutput", "sample_deltas", "composite"]


@dataclass
class RenderOutput:
    """Per-ray result of volume rendering.

    rgb: [R, C] colour composited over the background.
    opacity: [R] accumulated opacity ``sum_i w_i = 1 - T(far)`` in [0, 1].
    depth: [R] expected termination distance given that the ray terminates,
        ``sum_i w_i t_i / max(sum_i w_i, 1e-10)`` (units of ``t``, metres for unit directions);
        0 where the opacity is 0.
    weights: [R, S] quadrature weights ``w_i``.
    t_vals: [R, S] sample distances along the ray, or None when not recorded.
    """

    rgb: torch.Tensor
    opacity: torch.Tensor
    depth: torch.Tensor
    weights: torch.Tensor
    t_vals: torch.Tensor | None = None


def sample_deltas(t_vals: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """Interval lengths ``delta_i = t_{i+1} - t_i``, the last one up to ``far``.

    t_vals: [R, S] sorted sample distances. far: [R] end of each ray's interval.
    Returns [R, S] (non-negative where ``t_vals`` is sorted and ``t_vals <= far``).
    """
    if t_vals.dim() != 2:
        raise ValueError(f"t_vals must have shape [R, S], got {tuple(t_vals.shape)}")
    if far.shape != t_vals.shape[:1]:
        raise ValueError(
            f"far must have shape [R]={tuple(t_vals.shape[:1])}, got {tuple(far.shape)}"
        )
    return torch.diff(t_vals, dim=-1, append=far[:, None].to(t_vals.dtype))


def composite(
    densities: torch.Tensor,
    colors: torch.Tensor,
    t_vals: torch.Tensor,
    far: torch.Tensor,
    background: torch.Tensor | None = None,
) -> RenderOutput:
    """Alpha-composite samples along rays (LISA Eq. for ``c_k`` and ``T(t)``; NeRF's quadrature).

    With ``delta_i`` from :func:`sample_deltas` and ``tau_i = sigma_i delta_i``:

        alpha_i = 1 - exp(-tau_i),   T_i = exp(-sum_{k<i} tau_k),   w_i = T_i alpha_i,
        rgb = sum_i w_i c_i + (1 - sum_i w_i) * background.

    This is the exact integral for a density and colour that are piecewise constant on
    ``[t_i, t_i + delta_i)``. Differentiable w.r.t. ``densities``, ``colors`` and ``background``
    (and ``t_vals``, though the renderer does not use that).

    densities: [R, S] volume density sigma_i >= 0, 1/metres.
    colors: [R, S, C] sample colours.
    t_vals: [R, S] sorted sample distances (metres for unit directions).
    far: [R] end of each ray's interval (the last interval ends there).
    background: [C] or [R, C] colour behind the volume; None for black.
    """
    if densities.dim() != 2:
        raise ValueError(f"densities must have shape [R, S], got {tuple(densities.shape)}")
    if t_vals.shape != densities.shape:
        raise ValueError(
            f"t_vals must have the shape of densities {tuple(densities.shape)}, "
            f"got {tuple(t_vals.shape)}"
        )
    if colors.dim() != 3 or colors.shape[:2] != densities.shape:
        raise ValueError(
            f"colors must have shape [R, S, C] with [R, S]={tuple(densities.shape)}, "
            f"got {tuple(colors.shape)}"
        )
    num_rays, num_channels = densities.shape[0], colors.shape[-1]
    if background is not None and background.shape not in (
        (num_channels,),
        (num_rays, num_channels),
    ):
        raise ValueError(
            f"background must have shape [C]=({num_channels},) or [R, C]="
            f"({num_rays}, {num_channels}), got {tuple(background.shape)}"
        )

    deltas = sample_deltas(t_vals, far)
    optical_depth = densities * deltas
    # alpha_i = 1 - exp(-tau_i) via expm1: exact for small tau.
    alphas = -torch.expm1(-optical_depth)
    # Exclusive cumulative sum: the optical depth in front of sample i.
    depth_before = torch.cumsum(optical_depth[:, :-1], dim=-1)
    depth_before = torch.cat([torch.zeros_like(optical_depth[:, :1]), depth_before], dim=-1)
    transmittance = torch.exp(-depth_before)
    weights = transmittance * alphas

    opacity = weights.sum(-1)
    rgb = torch.einsum("rs,rsc->rc", weights, colors)
    if background is not None:
        rgb = rgb + (1.0 - opacity)[:, None] * background.to(rgb.dtype)
    weighted_t = (weights * t_vals).sum(-1)
    # Rays with (almost) no opacity have all weights (almost) 0, hence depth (almost) 0.
    depth = weighted_t / torch.clamp(opacity, min=1e-10)
    return RenderOutput(rgb=rgb, opacity=opacity, depth=depth, weights=weights, t_vals=t_vals)
