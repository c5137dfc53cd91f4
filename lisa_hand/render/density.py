"""VolSDF's density: a scaled Laplace CDF of the negated signed distance.

VolSDF (Yariv et al. 2021, Eq. 2-3) and LISA (Section 4.1, "Model rendering") turn a signed
distance ``s`` (negative inside the surface, metres) into a volume density

    sigma(x) = alpha * Psi_beta(-s(x)),

    Psi_beta(y) = 0.5 * exp(y / beta)          if y <= 0
                = 1 - 0.5 * exp(-y / beta)     if y > 0,

the CDF of a zero-mean Laplace distribution with scale ``beta`` (metres). As in VolSDF,
``alpha = 1 / beta`` unless given, so that the density is ``1/beta`` deep inside and decays like
``exp(-s / beta) / (2 beta)`` outside. Only exponentials of non-positive arguments are evaluated,
so large ``|s| / beta`` gives exact 0 / 1 limits instead of inf or NaN (values and gradients).
"""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["laplace_cdf", "volsdf_density", "laplace_beta", "LaplaceDensity"]


def _check_beta(beta: float | torch.Tensor) -> None:
    # A tensor beta is not checked: that would force a device sync in the hot path.
    if isinstance(beta, torch.Tensor):
        return
    if not isinstance(beta, (int, float)) or isinstance(beta, bool):
        raise TypeError(f"beta must be a float or a torch.Tensor, got {type(beta).__name__}")
    elif not beta > 0:
        raise ValueError(f"beta must be > 0 (Laplace scale, metres), got {beta}")


def laplace_cdf(x: torch.Tensor, beta: float | torch.Tensor) -> torch.Tensor:
    """CDF of the zero-mean Laplace distribution with scale ``beta``, ``Psi_beta(x)``.

    x: [...] values (metres). beta: float or tensor broadcastable to ``x`` (metres, > 0).
    Returns [...] in [0, 1]. Stable for any ``|x| / beta``; the gradient at ``x = 0`` is the
    density ``1 / (2 beta)``.
    """
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"x must be a torch.Tensor, got {type(x).__name__}")
    _check_beta(beta)
    # Each branch clamps its argument to be <= 0, so torch.where never sees inf in either branch
    # (no inf * 0 = NaN in the backward pass).
    neg = 0.5 * torch.exp(torch.clamp(x, max=0.0) / beta)
    pos = 0.5 - 0.5 * torch.expm1(-torch.clamp(x, min=0.0) / beta)
    return torch.where(x <= 0, neg, pos)


def volsdf_density(
    sdf: torch.Tensor,
    beta: float | torch.Tensor,
    alpha: float | torch.Tensor | None = None,
) -> torch.Tensor:
    """VolSDF density ``alpha * Psi_beta(-sdf)`` (VolSDF Eq. 2; LISA Section 4.1).

    sdf: [...] signed distance, metres, negative inside.
    beta: float or tensor broadcastable to ``sdf`` (metres, > 0).
    alpha: scale (1/metres); None gives VolSDF's ``1 / beta``.
    Returns [...] density (1/metres), differentiable w.r.t. ``sdf``, ``beta`` and ``alpha``.
    """
    if not isinstance(sdf, torch.Tensor):
        raise TypeError(f"sdf must be a torch.Tensor, got {type(sdf).__name__}")
    if alpha is None:
        alpha = 1.0 / beta
    return alpha * laplace_cdf(-sdf, beta)


def _inverse_softplus(value: float) -> float:
    # log(exp(v) - 1), written to stay finite for large v.
    return value + math.log(-math.expm1(-value))


def laplace_beta(beta_raw: torch.Tensor, beta_min: float) -> torch.Tensor:
    """VolSDF's Laplace scale from its raw parameter: ``beta_min + softplus(beta_raw)``.

    beta_raw: [] unconstrained; beta_min: metres (>= 0) -> [] metres, > ``beta_min``
    (differentiable in ``beta_raw``).
    """
    return beta_min + nn.functional.softplus(beta_raw)


class LaplaceDensity(nn.Module):
    """VolSDF density with a learnable Laplace scale ``beta`` and ``alpha = 1 / beta``.

    ``beta = beta_min + softplus(beta_raw)``: always > ``beta_min`` and smooth in the raw
    parameter (VolSDF uses ``beta_min + |raw|``; softplus avoids the kink at 0).

    Args:
        beta_init: initial ``beta`` in metres (> beta_min). VolSDF starts at 0.1 for a scene
            scaled into the unit sphere; for a hand in metres a few millimetres is reasonable.
        beta_min: lower bound of ``beta`` in metres (>= 0).
    """

    def __init__(self, beta_init: float = 0.01, beta_min: float = 1e-4) -> None:
        super().__init__()
        if not beta_min >= 0:
            raise ValueError(f"beta_min must be >= 0 (metres), got {beta_min}")
        if not beta_init > beta_min:
            raise ValueError(f"beta_init must be > beta_min={beta_min} (metres), got {beta_init}")
        self.beta_min = float(beta_min)
        self.beta_raw = nn.Parameter(torch.tensor(_inverse_softplus(beta_init - beta_min)))

    @property
    def beta(self) -> torch.Tensor:
        """[] current Laplace scale, metres (differentiable)."""
        return laplace_beta(self.beta_raw, self.beta_min)

    @property
    def alpha(self) -> torch.Tensor:
        """[] current density scale ``1 / beta``, 1/metres (differentiable)."""
        return 1.0 / self.beta

    def forward(self, sdf: torch.Tensor) -> torch.Tensor:
        """sdf: [...] metres, negative inside -> density [...] in 1/metres (dtype of ``sdf``)."""
        beta = self.beta.to(sdf.dtype)
        return volsdf_density(sdf, beta)

    def extra_repr(self) -> str:
        return f"beta={float(self.beta.detach()):.3g}, beta_min={self.beta_min:.3g}"
