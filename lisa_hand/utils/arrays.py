"""Array inputs: torch tensors (any device, with grad or not) or array-likes in, numpy out, with
the argument named in the error (the data layer, the renderer, the metrics)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["as_numpy"]


def as_numpy(value: Any, name: str) -> np.ndarray:
    """``value`` as a numpy array (a tensor is detached and copied to the CPU).

    Raises TypeError naming ``name`` when it is not array-like.
    """
    if hasattr(value, "detach") and hasattr(value, "cpu"):
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array, got {type(value).__name__} ({exc})") from None
