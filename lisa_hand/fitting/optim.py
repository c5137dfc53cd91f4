"""The one optimiser and the one learning-rate schedule of every fitter's stages.

Every stage of the point, image and photo fitters (and the template baseline) steps
``torch.optim.Adam`` on a few tensors, each with its own learning rate, under
:func:`lr_schedule`: a cosine from each rate down to ``final_fraction`` of it over the stage.
The point fit's candidates are pruned while they are optimised; :func:`keep_rows` keeps the
optimiser's moments of the rows that go on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

__all__ = ["adam", "cosine_factor", "lr_schedule", "keep_rows"]


def adam(groups: Sequence[tuple[torch.Tensor, float]]) -> torch.optim.Adam:
    """``torch.optim.Adam`` (default betas and eps) on ``groups``: (tensor, learning rate)
    pairs, one parameter group each, in order."""
    return torch.optim.Adam([{"params": [tensor], "lr": float(lr)} for tensor, lr in groups])


def cosine_factor(step: int, total: int, final_fraction: float) -> float:
    """The learning-rate factor at ``step`` (0-based) of ``total`` steps: a cosine from 1 at the
    first step to ``final_fraction`` at the last."""
    if total <= 1:
        return 1.0
    step = min(max(step, 0), total - 1)
    return final_fraction + (1.0 - final_fraction) * 0.5 * (
        1.0 + math.cos(math.pi * step / (total - 1)))


def lr_schedule(optimizer: torch.optim.Optimizer, total: int, final_fraction: float,
                start: int = 0) -> torch.optim.lr_scheduler.LambdaLR:
    """The schedule of a stage of ``total`` steps that starts at step ``start`` (a stage run
    in parts): every rate times :func:`cosine_factor`; call ``.step()`` after each optimiser
    step."""
    return torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: cosine_factor(start + step, total, final_fraction))


@torch.no_grad()
def keep_rows(optimizer: torch.optim.Adam, index: torch.Tensor,
              tensors: Sequence[torch.Tensor]) -> None:
    """Go on with ``tensors`` (the rows ``index`` of the optimised tensors, one per parameter
    group, in order) in place of the optimised ones, with the same rows of Adam's moments, so
    that pruning candidates does not restart the survivors' steps."""
    groups = optimizer.param_groups
    if len(tensors) != len(groups):
        raise ValueError(f"keep_rows needs one tensor per parameter group ({len(groups)}), got "
                         f"{len(tensors)}")
    for group, new in zip(groups, tensors, strict=True):
        old = group["params"][0]
        state = optimizer.state.pop(old, None)
        group["params"][0] = new
        if state:
            optimizer.state[new] = {key: value[index] if isinstance(value, torch.Tensor)
                                    and value.dim() > 0 else value
                                    for key, value in state.items()}
