"""Writing training checkpoints: atomic, finite-checked, and complete enough to resume exactly.

A checkpoint holds the model, optimizer and LR-scheduler states, the number of completed steps,
the run's resolved config, and the random state of every rank (torch CPU, CUDA, numpy, python
``random`` and the named ``torch.Generator`` objects the training draws its data from), so that
a resumed run continues bit for bit where the interrupted one stopped (on CPU; CUDA kernels may
be non-deterministic, so there "within tolerance").

Files are written through a temporary file, flushed to disk and renamed (``atomic_path``): a
crash or ``kill -9`` at any moment leaves the previous checkpoint or the new one, never half of
one. A model state with a NaN or inf is refused before anything is written.

The file format (:class:`~lisa_hand.model.checkpoint.Checkpoint`) and its reading
(:func:`~lisa_hand.model.checkpoint.load_checkpoint`) live in :mod:`lisa_hand.model.checkpoint`,
below training, since inference loads models from training runs. Files are read with
``torch.load(weights_only=True)``: a checkpoint cannot run code on load. Anything put in
``extra`` must therefore be tensors, numbers, strings, lists, tuples or dicts.
"""

from __future__ import annotations

import os
import random
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..model.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, Checkpoint
from ..utils.io import NoSpaceError, atomic_path, no_space_error

__all__ = [
    "NonFiniteError",
    "capture_rng_state",
    "restore_rng_state",
    "check_finite_state",
    "save_checkpoint",
    "copy_checkpoint",
    "remove_stale_temporaries",
]


class NonFiniteError(ValueError):
    """A loss, a gradient or a parameter became NaN or inf (training diverged).

    A ``ValueError`` so that the command line prints it as one line: it is most often caused by
    the configuration (learning rate too high, a loss weight, bad data).
    """


# ------------------------------------------------------------------------------------------------
# random state


def capture_rng_state(generators: Mapping[str, torch.Generator] | None = None) -> dict[str, Any]:
    """Snapshot of this process's random state, as plain data ``torch.load`` reads safely.

    Covers torch's CPU generator, every CUDA device's generator (when CUDA is available), numpy's
    legacy global generator, python's ``random`` and the named ``generators``.
    """
    np_state = np.random.get_state(legacy=True)
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
        "numpy": {
            "keys": torch.from_numpy(np_state[1].astype(np.int64)),
            "pos": int(np_state[2]),
            "has_gauss": int(np_state[3]),
            "cached_gaussian": float(np_state[4]),
        },
        "python": random.getstate(),
        "generators": {name: gen.get_state() for name, gen in (generators or {}).items()},
    }
    return state


def restore_rng_state(
    state: Mapping[str, Any], generators: Mapping[str, torch.Generator] | None = None
) -> None:
    """Restore a snapshot from ``capture_rng_state`` (and the named ``generators`` in place).

    A named generator missing from the snapshot raises ``ValueError``. CUDA states are restored
    when this process sees the same number of CUDA devices; otherwise they are skipped.
    """
    torch.set_rng_state(state["torch"])
    cuda_states = state.get("cuda")
    if cuda_states and torch.cuda.is_available() and len(cuda_states) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda_states)
    np_state = state["numpy"]
    np.random.set_state((
        "MT19937", np_state["keys"].numpy().astype(np.uint32), np_state["pos"],
        np_state["has_gauss"], np_state["cached_gaussian"],
    ))
    random.setstate(_as_python_random_state(state["python"]))
    saved = state.get("generators", {})
    for name, gen in (generators or {}).items():
        if name not in saved:
            raise ValueError(f"the checkpoint has no state for generator {name!r} "
                             f"(it has: {sorted(saved)})")
        gen.set_state(saved[name])


def _as_python_random_state(value: Any) -> tuple:
    # random.setstate wants (version, tuple_of_625_ints, gauss_next) with an inner tuple.
    version, internal, gauss_next = value
    return (version, tuple(internal), gauss_next)


# ------------------------------------------------------------------------------------------------
# save / load


def check_finite_state(state: Mapping[str, Any], what: str) -> None:
    """Raise ``NonFiniteError`` naming the first floating tensor of ``state`` with a NaN/inf.

    state: a ``state_dict`` (name -> tensor). One device sync in total, not one per tensor.
    """
    names = [k for k, v in state.items() if torch.is_tensor(v) and v.is_floating_point()]
    if not names:
        return
    flags_on_device = [torch.isfinite(state[k]).all() for k in names]
    if len({flag.device for flag in flags_on_device}) == 1:
        flags = torch.stack(flags_on_device).cpu()
    else:  # a state spread over several devices: one copy per tensor
        flags = torch.stack([flag.cpu() for flag in flags_on_device])
    if bool(flags.all()):
        return
    bad = names[int((~flags).nonzero()[0, 0])]
    tensor = state[bad]
    num_bad = int((~torch.isfinite(tensor)).sum())
    raise NonFiniteError(f"{what}: parameter {bad!r} has {num_bad} non-finite value(s) "
                         f"(nan/inf) out of {tensor.numel()}")


def save_checkpoint(path: str | os.PathLike, checkpoint: Checkpoint) -> Path:
    """Write ``checkpoint`` to ``path`` atomically (temp file, fsync, rename); return the path.

    Raises ``NonFiniteError`` (writing nothing, the previous file intact) when a model tensor is
    NaN or inf, and ``NoSpaceError`` (an OSError; the previous file intact) naming ``path``, the
    free space and about the size needed when the disk is full.
    """
    path = Path(path)
    if not isinstance(checkpoint.step, int) or checkpoint.step < 0:
        raise ValueError(f"checkpoint step must be a non-negative int, got {checkpoint.step!r}")
    check_finite_state(checkpoint.model,
                       f"refusing to write checkpoint {path} (the previous one is left intact)")
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "step": checkpoint.step,
        "model": checkpoint.model,
        "optimizer": checkpoint.optimizer,
        "scheduler": checkpoint.scheduler,
        "rng": checkpoint.rng,
        "config": checkpoint.config,
        "trainer": checkpoint.trainer,
        "extra": checkpoint.extra,
    }
    try:
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                torch.save(payload, handle)
                handle.flush()
                os.fsync(handle.fileno())
    except NoSpaceError:
        raise no_space_error(path, _tensor_bytes(payload),
                             "the previous checkpoint is left intact") from None
    return path


def _tensor_bytes(value: Any) -> int:
    """Bytes of the tensors in a nested structure (about a checkpoint's size on disk)."""
    if torch.is_tensor(value):
        return value.numel() * value.element_size()
    if isinstance(value, Mapping):
        return sum(_tensor_bytes(item) for item in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_tensor_bytes(item) for item in value)
    return 0


def copy_checkpoint(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Copy a checkpoint file atomically (used to keep every N-th checkpoint)."""
    dst = Path(dst)
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)
    return dst


def remove_stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Delete temporary files a killed writer of ``path`` left behind; return them.

    ``atomic_path`` writes ``.<name>.<random><suffix>`` beside ``path``; a ``kill -9`` during the
    write leaves it there (the real file is intact). Call only when no writer is running.
    """
    path = Path(path)
    removed = []
    if path.parent.is_dir():
        for stale in path.parent.glob(f".{path.name}.*"):
            if stale.is_file():
                stale.unlink(missing_ok=True)
                removed.append(stale)
    return removed
