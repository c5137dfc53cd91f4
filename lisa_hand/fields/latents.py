"""Auto-decoder latent tables for the shape (beta+) and colour (gamma) codes (DeepSDF style).

LISA assigns one shape code and one colour code per person, 128-D each, initialised from a
zero-mean Gaussian with spherical covariance and optimised jointly with the networks (Park et al.,
DeepSDF, CVPR 2019), under the norm prior ``L_reg = ||beta+||_2 + ||gamma||_2`` (paper Eq. 16).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["LatentTable"]


class LatentTable(nn.Module):
    """A table of learnable codes, one row per identity (an ``nn.Embedding`` with a norm prior)."""

    def __init__(self, num_codes: int, dim: int = 128, init_std: float = 0.01) -> None:
        """
        num_codes: number of identities (rows); dim: code size (paper: 128).
        init_std: standard deviation of the zero-mean spherical Gaussian the codes start from.
        """
        super().__init__()
        if num_codes < 1 or dim < 1:
            raise ValueError(f"num_codes and dim must be >= 1, got {num_codes} and {dim}")
        if not init_std >= 0.0:
            raise ValueError(f"init_std must be >= 0, got {init_std}")
        self.num_codes = int(num_codes)
        self.dim = int(dim)
        self.init_std = float(init_std)
        self.weight = nn.Parameter(torch.empty(self.num_codes, self.dim))
        self.reset_parameters()

    @torch.no_grad()
    def reset_parameters(self) -> None:
        self.weight.normal_(0.0, self.init_std)

    def extra_repr(self) -> str:
        return f"num_codes={self.num_codes}, dim={self.dim}, init_std={self.init_std:g}"

    def _check(self, indices: torch.Tensor) -> torch.Tensor:
        if not isinstance(indices, torch.Tensor):
            raise TypeError(f"indices must be a torch.Tensor, got {type(indices).__name__}")
        if indices.dtype not in (torch.int64, torch.int32):
            raise TypeError(f"indices must be an integer tensor, got {indices.dtype}")
        if indices.numel() and (indices.min() < 0 or indices.max() >= self.num_codes):
            raise ValueError(
                f"indices must lie in [0, {self.num_codes}), got range "
                f"[{int(indices.min())}, {int(indices.max())}]"
            )
        return indices.to(device=self.weight.device, dtype=torch.long)

    def forward(self, indices: torch.Tensor) -> torch.Tensor:
        """indices: [...] long in [0, num_codes) -> codes [..., dim]"""
        return self.weight[self._check(indices)]

    def prior_loss(self, indices: torch.Tensor | None = None) -> torch.Tensor:
        """Mean L2 norm ``||z||_2`` of the selected codes (all codes when None); paper Eq. 16.

        indices: [...] long, or None -> scalar
        """
        codes = self.weight if indices is None else self(indices)
        return codes.norm(dim=-1).mean()

    def mean_code(self) -> torch.Tensor:
        """The mean code [dim], a neutral starting point for fitting an unseen identity."""
        return self.weight.mean(dim=0)
