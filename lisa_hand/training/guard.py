"""The checks around one training step: what a step function returned (:func:`check_step_output`)
and the NaN/inf guard on the losses and the gradient (:func:`check_finite_step`), which stops
the run before the optimizer updates the weights, with a message that names the bad term."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .checkpoint import NonFiniteError

__all__ = ["check_step_output", "check_finite_step"]


def check_step_output(
    out: Any, step: int
) -> tuple[list[str], list[torch.Tensor], torch.Tensor]:
    """Check a step function's ``{"total": scalar tensor, name: scalar tensor or number}``.

    -> (the names, their values as detached 0-d tensors, the total as a 0-d tensor with its
    graph). Raises ``ValueError`` naming the step and the bad entry.
    """
    if not isinstance(out, Mapping) or "total" not in out:
        raise ValueError(f"step {step}: step_fn must return a dict with a 'total' loss "
                         f"tensor, got {type(out).__name__}"
                         + (f" with keys {list(out)}" if isinstance(out, Mapping) else ""))
    total = out["total"]
    if not torch.is_tensor(total) or total.numel() != 1:
        raise ValueError(f"step {step}: step_fn's 'total' must be a scalar tensor, got "
                         f"{type(total).__name__}"
                         + (f" of shape {list(total.shape)}" if torch.is_tensor(total)
                            else ""))
    if not total.requires_grad:
        raise ValueError(f"step {step}: step_fn's 'total' does not require grad (computed "
                         "under no_grad, or from no trainable parameter)")
    names, values = [], []
    for name, value in out.items():
        if torch.is_tensor(value):
            if value.numel() != 1:
                raise ValueError(f"step {step}: loss {name!r} must be a scalar, got shape "
                                 f"{list(value.shape)}")
            values.append(value.detach().reshape(()))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            values.append(torch.tensor(float(value), dtype=torch.float64))
        else:
            raise ValueError(f"step {step}: loss {name!r} must be a scalar tensor or a "
                             f"number, got {type(value).__name__}")
        names.append(str(name))
    return names, values, total.reshape(())


def check_finite_step(
    step: int,
    losses: Mapping[str, float],
    grad_norm: float,
    model: nn.Module,
    params: Sequence[nn.Parameter],
    last_good: Path | None,
) -> None:
    """Raise ``NonFiniteError`` when a loss or the gradient norm is NaN/inf (before the update).

    losses: the step's terms (averaged over ranks); grad_norm: the global gradient norm.
    model, params: where to look for the parameter with a non-finite gradient (named in the
    message). last_good: the last checkpoint written or resumed from (None: none yet).
    """
    if all(math.isfinite(v) for v in losses.values()) and math.isfinite(grad_norm):
        return
    if last_good is not None:
        where = f"the last good checkpoint is {last_good}"
    else:
        where = "no checkpoint was written yet"
    # Name a specific term before 'total' (which is non-finite whenever a term is).
    bad = sorted((k for k, v in losses.items() if not math.isfinite(v)),
                 key=lambda k: k == "total")
    if bad:
        what = f"loss {bad[0]!r} is {losses[bad[0]]}"
        if len(bad) > 1:
            what += f" (also non-finite: {', '.join(f'{k}={losses[k]}' for k in bad[1:])})"
    else:
        names = {id(p): n for n, p in model.named_parameters()}
        bad_params = [names.get(id(p), "?") for p in params
                      if p.grad is not None and not bool(torch.isfinite(p.grad).all())]
        what = (f"the gradient is non-finite (norm {grad_norm}) in "
                f"{', '.join(repr(n) for n in bad_params[:5]) or 'another rank'}, "
                f"while the losses are finite")
    raise NonFiniteError(
        f"training diverged at step {step}: {what}. Stopped without updating the weights; "
        f"{where}. Lower the learning rate (lr), set grad_clip, or check the data and the "
        "loss weights.")
