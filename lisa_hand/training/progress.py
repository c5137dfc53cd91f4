"""What a run tells while it trains: the JSON-lines log (``log.jsonl``) and the progress bar or
printed lines of losses (rank 0 only; the other ranks get objects that do nothing)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..utils.io import atomic_path, is_no_space, no_space_error
from .config import TrainerConfig

__all__ = ["LOG_FILE", "RunLog", "Progress", "format_losses"]

LOG_FILE = "log.jsonl"
"""One JSON object per logged step: step, lr, grad_norm, seconds, losses."""


def format_losses(losses: Mapping[str, float], lr: float) -> str:
    """``"total=0.1234 data=0.01 lr=0.0005"``: the losses and the learning rate, for one line."""
    parts = [f"{k}={v:.4g}" for k, v in losses.items()]
    parts.append(f"lr={lr:.3g}")
    return " ".join(parts)


class RunLog:
    """``out_dir/log.jsonl``, open for appending (rank 0; elsewhere every call does nothing).

    A fresh run (``start_step`` 0) truncates the file. A resumed run keeps the lines of the steps
    before ``start_step`` and drops the later ones (written after the checkpoint and before the
    kill), so that the log reads like one uninterrupted run.
    """

    def __init__(self, out_dir: Path, start_step: int, is_main: bool) -> None:
        self._file: Any = None
        if not is_main:
            return
        path = out_dir / LOG_FILE
        if start_step == 0:
            self._file = open(path, "w")
            return
        kept = []
        if path.is_file():
            for line in path.read_text().splitlines():
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut by the kill
                if isinstance(entry, dict) and entry.get("step", math.inf) < start_step:
                    kept.append(line)
        with atomic_path(path) as tmp:
            tmp.write_text("".join(line + "\n" for line in kept))
        self._file = open(path, "a")

    def write(self, entry: Mapping[str, Any]) -> None:
        """Append one JSON line and flush it."""
        if self._file is not None:
            try:
                self._file.write(json.dumps(entry) + "\n")
                self._file.flush()
            except OSError as exc:
                if is_no_space(exc):
                    raise no_space_error(self._file.name) from None
                raise

    def close(self) -> None:
        if self._file is not None:
            handle, self._file = self._file, None
            try:
                handle.close()
            except OSError as exc:  # the flush of a line a full disk refused
                if is_no_space(exc):
                    raise no_space_error(handle.name) from None
                raise


class Progress:
    """A tqdm bar with the losses (rank 0, stderr a terminal, ``config.progress``), or a printed
    line every ``config.print_every`` steps when stderr is not a terminal, or nothing."""

    def __init__(self, config: TrainerConfig, start_step: int, is_main: bool) -> None:
        self.config = config
        show_bar = config.progress and is_main and sys.stderr.isatty()
        self._print_lines = config.progress and is_main and not show_bar
        self._bar = None
        if show_bar:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=config.steps, initial=start_step, desc="train",
                             dynamic_ncols=True, file=sys.stderr)

    def update(self, done: int, losses: Mapping[str, float], lr: float) -> None:
        """After a step: ``done`` steps completed, the step's ``losses`` and ``lr``."""
        config = self.config
        if self._bar is not None:
            self._bar.set_postfix_str(format_losses(losses, lr), refresh=False)
            self._bar.update(1)
        elif self._print_lines and config.print_every and (
                done % config.print_every == 0 or done == config.steps):
            print(f"step {done}/{config.steps} {format_losses(losses, lr)}",
                  file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
