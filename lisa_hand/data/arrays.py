"""Input arrays of the data layer: numpy or torch in, numpy out, with the argument named."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["to_numpy"]


def to_numpy(value, name: str) -> np.ndarray:
    """A torch tensor (any device; detached) or array-like as a numpy array. Raises TypeError
    naming ``name`` when ``value`` is not array-like."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    try:
        return np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array, got {type(value).__name__} ({exc})") from None
