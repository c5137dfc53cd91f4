"""Positional encoding of points (NeRF-style sinusoids, the raw coordinates kept first)."""

from __future__ import annotations

import torch

__all__ = ["encoding_dim", "positional_encoding"]


def encoding_dim(num_frequencies: int, in_dim: int = 3) -> int:
    """Width of :func:`positional_encoding`'s output: ``in_dim * (1 + 2 F)``."""
    return in_dim * (1 + 2 * num_frequencies)


def positional_encoding(points: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """``[x, sin(2^0 x), cos(2^0 x), ..., sin(2^(F-1) x), cos(2^(F-1) x)]``.

    The raw coordinates come first, so a layer reading only the first ``in_dim`` inputs sees the
    plain point (the geometric initialisation relies on this).

    points: [..., C] in network units (O(1)) -> [..., C * (1 + 2 F)]
    """
    if num_frequencies == 0:
        return points
    freqs = 2.0 ** torch.arange(num_frequencies, dtype=points.dtype, device=points.device)
    angles = points[..., None, :] * freqs[:, None]  # [..., F, C]
    waves = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)  # [..., F, 2C]
    return torch.cat([points, waves.flatten(-2)], dim=-1)
