"""Combining per-bone predictions into one SDF and colour (paper Eq. 9 and the baselines).

All compositions are restricted to the bones whose region contains the point (``active``); a
point in no region takes its nearest bone (``fallback``) with weight one:

* LISA and NARF: a masked softmax over skinning logits, ``w_j = 0`` outside bone ``j``'s region.
* NASA: per-bone selection, one-hot on the active bone with the smallest SDF (the analogue of
  NASA's maximum occupancy) — no learned blend.

Then ``s = sum_j w_j s_j`` and ``c = sum_j w_j c_j`` (paper Eq. 9).
"""

from __future__ import annotations

import torch

__all__ = ["masked_softmax", "nasa_selection", "one_hot_weights", "blend"]


def _allowed(active: torch.Tensor, fallback: torch.Tensor) -> torch.Tensor:
    """Active bones, or only the fallback bone where no bone is active."""
    none_active = ~active.any(dim=-1, keepdim=True)
    fallback_mask = torch.nn.functional.one_hot(fallback, active.shape[-1]).bool()
    return active | (none_active & fallback_mask)


def masked_softmax(
    logits: torch.Tensor, active: torch.Tensor, fallback: torch.Tensor
) -> torch.Tensor:
    """Softmax over the active bones (others get weight 0); one-hot on ``fallback`` where none.

    logits: [..., J]; active: [..., J] bool; fallback: [...] long -> weights [..., J], >= 0,
    summing to 1. A point with exactly one active bone gets an exact one-hot (and zero gradient
    with respect to the logits), so evaluating the skinning MLP there is unnecessary.
    """
    masked = logits.masked_fill(~_allowed(active, fallback), float("-inf"))
    return torch.softmax(masked, dim=-1)


def one_hot_weights(choice: torch.Tensor, num_bones: int, dtype: torch.dtype) -> torch.Tensor:
    """choice: [...] long -> one-hot weights [..., num_bones] of ``dtype``."""
    return torch.nn.functional.one_hot(choice, num_bones).to(dtype)


def nasa_selection(
    bone_sdf: torch.Tensor, active: torch.Tensor, fallback: torch.Tensor
) -> torch.Tensor:
    """NASA-style choice: the active bone with the smallest SDF, else the fallback bone.

    bone_sdf: [..., J] metres; active: [..., J] bool; fallback: [...] long -> [...] long
    """
    masked = bone_sdf.detach().masked_fill(~active, float("inf"))
    best = masked.argmin(dim=-1)
    return torch.where(active.any(dim=-1), best, fallback)


def blend(weights: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """``sum_j w_j v_j`` (paper Eq. 9).

    weights: [..., J]; values: [..., J] or [..., J, C] -> [...] or [..., C]
    """
    if values.dim() == weights.dim():
        return (weights * values).sum(dim=-1)
    return (weights[..., None] * values).sum(dim=-2)
