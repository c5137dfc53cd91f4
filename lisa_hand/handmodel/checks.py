"""Checks of the inputs every posed hand takes (:class:`~.hand.PosedHand`,
:class:`~.mesh_hand.PosedMeshHand`)."""

from __future__ import annotations

import torch

__all__ = ["check_vector", "check_query_points"]


def check_vector(value, size: int, name: str) -> torch.Tensor:
    """A pose or translation: a tensor [size] or [1, size] of finite values -> [size] float64
    (CPU); TypeError / ValueError naming ``name`` otherwise."""
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if value.shape not in ((size,), (1, size)):
        raise ValueError(f"{name} must have shape [{size}] or [1, {size}], got "
                         f"{tuple(value.shape)}")
    value = value.reshape(size).detach().to(torch.float64).cpu()
    if not torch.isfinite(value).all():
        raise ValueError(f"{name} contains NaN or inf values")
    return value


def check_query_points(points, name: str = "points") -> torch.Tensor:
    """Query points: a floating-point tensor [N, 3] (metres), returned as it is."""
    if not isinstance(points, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(points).__name__}")
    if points.dim() != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape [N, 3] (metres), got {tuple(points.shape)}")
    if not points.is_floating_point():
        raise TypeError(f"{name} must be a floating point tensor, got {points.dtype}")
    return points
