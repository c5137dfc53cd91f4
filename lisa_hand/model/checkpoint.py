"""The training checkpoint file: its format, its kinds of run, and reading it.

A checkpoint (written by :mod:`lisa_hand.training.checkpoint`) holds the model, optimizer and
LR-scheduler states, the number of completed steps, the run's resolved config and the random
state of every rank. Reading it lives here, below training, because inference and fitting load
a model straight from a training run (:func:`lisa_hand.model.trained.load_trained`) and must not
import the training code.

Files are read with ``torch.load(weights_only=True)``: a checkpoint cannot run code on load.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "LAST_CHECKPOINT",
    "PRIOR_KIND",
    "IMAGE_KIND",
    "Checkpoint",
    "load_checkpoint",
    "load_run_checkpoint",
    "read_torch_file",
]

CHECKPOINT_FORMAT = "lisa_hand.checkpoint"
CHECKPOINT_VERSION = 1
LAST_CHECKPOINT = "last.pt"
"""File name of the most recent checkpoint inside a run folder."""
PRIOR_KIND = "lisa-prior"
"""``Checkpoint.extra["kind"]`` of a prior run (``lisa train-prior``)."""
IMAGE_KIND = "lisa-images"
"""``Checkpoint.extra["kind"]`` of an image run (``lisa train``)."""


@dataclass
class Checkpoint:
    """Everything needed to resume a run (or to rebuild its model)."""

    step: int
    """Number of completed optimizer steps (= the 0-based index of the next step)."""
    model: dict[str, torch.Tensor]
    """``state_dict()`` of the (unwrapped) model."""
    optimizer: dict[str, Any] | None = None
    """``state_dict()`` of the optimizer."""
    scheduler: dict[str, Any] | None = None
    """``state_dict()`` of the LR scheduler."""
    rng: list[dict[str, Any]] = field(default_factory=list)
    """Random state of every rank, in rank order (``capture_rng_state``)."""
    config: dict[str, Any] | None = None
    """The run's resolved config (``config_to_dict``): rebuild the model from it."""
    trainer: dict[str, Any] | None = None
    """The training engine's config (``config_to_dict(TrainerConfig)``)."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Anything else the caller wants kept (plain data and tensors only)."""
    path: Path | None = None
    """File it was loaded from (None for one built in memory)."""


def read_torch_file(path: str | os.PathLike, what: str = "LISA model file",
                    map_location: Any = "cpu") -> Any:
    """What a torch file holds, read with ``torch.load(weights_only=True)``.

    Raises ValueError naming the file and saying it is not a ``what`` for anything torch cannot
    read that way: text or another format, a truncated or corrupted file, or a pickle of Python
    objects (never loaded; torch's advice to turn ``weights_only`` off is not passed on).
    """
    import pickle

    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        if "global" in str(exc):  # a class or function named in the file: refused
            reason = "it holds Python objects besides tensors, which are never loaded"
        else:
            reason = "not a torch file, or a truncated or corrupted one"
    except RuntimeError as exc:
        reason = ("truncated or corrupted" if "zip archive" in str(exc)
                  else "not a torch file, or a truncated or corrupted one")
    except Exception:  # text and other formats: KeyError, IndexError, EOFError, ...
        reason = "not a torch file, or a truncated or corrupted one"
    raise ValueError(f"{path}: not a {what} ({reason})")


def load_checkpoint(path: str | os.PathLike, map_location: Any = "cpu") -> Checkpoint:
    """Read a checkpoint written by ``save_checkpoint``.

    A missing file raises ``FileNotFoundError``; a truncated, corrupt or foreign file (not
    written by this module) raises ``ValueError``; both name the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    payload = read_torch_file(path, "readable checkpoint", map_location)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a lisa_hand training checkpoint (no "
                         f"format={CHECKPOINT_FORMAT!r} marker)")
    version = payload.get("version")
    if not isinstance(version, int) or version > CHECKPOINT_VERSION:
        raise ValueError(f"{path}: checkpoint version {version!r} is newer than this code "
                         f"understands ({CHECKPOINT_VERSION}); update lisa_hand")
    for key, kind in (("step", int), ("model", dict)):
        if not isinstance(payload.get(key), kind):
            raise ValueError(f"{path}: checkpoint is missing or has a bad {key!r} entry")
    return Checkpoint(
        step=payload["step"],
        model=payload["model"],
        optimizer=payload.get("optimizer"),
        scheduler=payload.get("scheduler"),
        rng=list(payload.get("rng") or []),
        config=payload.get("config"),
        trainer=payload.get("trainer"),
        extra=dict(payload.get("extra") or {}),
        path=path,
    )


def load_run_checkpoint(run: str | os.PathLike, kind: str) -> Checkpoint:
    """The checkpoint of a run folder (``RUN/last.pt``) or a checkpoint file, checked to be of
    ``kind`` (``Checkpoint.extra["kind"]``: :data:`PRIOR_KIND` or :data:`IMAGE_KIND`) and to
    hold its run config."""
    path = Path(run)
    if path.is_dir():
        path = path / LAST_CHECKPOINT
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no checkpoint in this run folder (has the run "
                                    "written one yet?)")
    ckpt = load_checkpoint(path)
    found = ckpt.extra.get("kind")
    if found != kind:
        raise ValueError(f"{path}: expected a {kind!r} checkpoint, got {found!r}")
    if ckpt.config is None:
        raise ValueError(f"{path}: the checkpoint holds no run config")
    return ckpt
