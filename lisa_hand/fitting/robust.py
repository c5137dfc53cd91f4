"""Robust penalties of residuals, shared by every fitter (the point fit and the MANO-like
template fit).

* ``l1``: ``|r|``, the paper's point-cloud energy ``sum_x |G(x)|`` (Section 4.3); not robust.
* ``huber``: ``r^2 / (2 sigma)`` for ``|r| <= sigma``, else ``|r| - sigma / 2``.
* ``geman_mcclure``: ``sigma r^2 / (r^2 + sigma^2)``, bounded by ``sigma``: an outlier costs at
  most ``sigma`` and pulls with a force that falls as ``1 / r^3``.
"""

from __future__ import annotations

import torch

__all__ = ["ROBUST_LOSSES", "robust_loss", "annealed_scale"]

ROBUST_LOSSES = ("geman_mcclure", "huber", "l1")
"""Names :func:`robust_loss` accepts."""


def robust_loss(residual: torch.Tensor, kind: str, scale: float) -> torch.Tensor:
    """Penalty of residuals, elementwise (see the module docstring).

    residual: [...] metres. kind: one of :data:`ROBUST_LOSSES`. scale: ``sigma``, metres
    (positive; unused by 'l1'). -> [...] metres.
    """
    if kind == "l1":
        return residual.abs()
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    if kind == "huber":
        magnitude = residual.abs()
        return torch.where(magnitude <= scale, 0.5 * residual * residual / scale,
                           magnitude - 0.5 * scale)
    if kind == "geman_mcclure":
        squared = residual * residual
        return scale * squared / (squared + scale * scale)
    raise ValueError(f"kind must be one of {ROBUST_LOSSES}, got {kind!r}")


def annealed_scale(start: float, end: float, step: int, total: int) -> float:
    """Robust scale at ``step`` of a stage of ``total`` steps: geometric from ``start`` to
    ``end`` (metres) over the first 60% of the stage, then ``end`` (coarse to fine)."""
    if total <= 1 or start <= end:
        return end
    progress = min(1.0, step / (0.6 * (total - 1)))
    return start * (end / start) ** progress
