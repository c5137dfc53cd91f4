"""What LISA's two training runs (``lisa train-prior``, ``lisa train``) share around the engine:
the seeded model construction, the weighted total loss over the global batch, and the check that
a resumed run trains on the same subjects, cameras and frames as its checkpoint."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import torch

from .distributed import DistContext, global_mean
from .engine import Trainer

__all__ = ["seeded", "batch_mean", "weighted_total", "check_resumed_extra"]

T = TypeVar("T")


def seeded(seed: int, build: Callable[[], T]) -> T:
    """``build()`` with the global torch RNG seeded (the initial weights depend on the seed
    only), leaving the caller's RNG state untouched."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return build()


def batch_mean(local_mean: torch.Tensor, num_local: int, num_global: int,
               dist: DistContext) -> torch.Tensor:
    """This rank's share of a mean over the global batch, from the mean over its own frames.

    Every frame of a step has the same number of points, so the global mean is the mean of the
    per-rank means weighted by their frame counts; see :func:`distributed.global_mean`.
    """
    return global_mean(local_mean.reshape(1) * num_local, num_global, dist)


def weighted_total(terms: Mapping[str, torch.Tensor], weights: Mapping[str, float],
                   num_local: int, num_global: int,
                   dist: DistContext) -> dict[str, torch.Tensor]:
    """``{"total": sum of weight * term, name: term}`` over the global batch.

    terms: this rank's loss terms, each a mean over its ``num_local`` frames; weights: the
    weighted terms (by name, in the order they are summed); ``num_global``: frames of the step.
    """
    out: dict[str, torch.Tensor] = {}
    total = None
    for name, weight in weights.items():
        value = batch_mean(terms[name], num_local, num_global, dist)
        out[name] = value
        total = weight * value if total is None else total + weight * value
    return {"total": total, **out}


def check_resumed_extra(trainer: Trainer, expected: Mapping[str, Any]) -> None:
    """A resumed run must have the same subjects (cameras, frames) as its checkpoint: raise
    ``ValueError`` naming the first entry of ``expected`` (``Checkpoint.extra``) that differs
    (the data folder and the prior may move)."""
    if trainer.resumed_from is None:
        return
    for key, value in expected.items():
        if key in ("data_dir", "prior", "init"):
            continue
        saved = trainer.resumed_extra.get(key)
        if saved is not None and saved != value:
            raise ValueError(f"{trainer.resumed_from}: the checkpoint was trained with another "
                             f"{key} ({saved!r}, now {value!r}); use --no-resume or another "
                             "output folder")
