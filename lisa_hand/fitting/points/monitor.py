"""What the point fit reports while it runs: :class:`FitStep` (to a callback, after every
iteration), and the per-iteration history and per-stage timings (:class:`FitMonitor`). Each
stage's own diagnostics are a :class:`lisa_hand.fitting.stages.StageReport`."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ...skeleton.params import HandParams
from ..stages import HistoryRecord

__all__ = ["FitStep", "FitMonitor"]


@dataclass
class FitStep:
    """What a fit tells its ``callback`` after every iteration.

    stage: 'align', 'pose', 'size', 'fingers' or 'field'. iteration: within the stage (from
    0); num_iterations: of the stage. energy: [K] the energy of each live candidate on this
    iteration's points (the stage's own energy: proxy distances for all but 'field').
    seconds: since the fit started.
    """

    stage: str
    iteration: int
    num_iterations: int
    energy: list[float]
    seconds: float
    _make_params: Callable[[], HandParams] = field(repr=False)

    def params(self) -> HandParams:
        """The current best candidate as :class:`HandParams` (a copy, detached)."""
        return self._make_params()


class FitMonitor:
    """Bookkeeping of one fit, shared by its stages: the history of every iteration
    (:data:`~lisa_hand.fitting.stages.HistoryRecord` ``{"stage", "iteration", "energy" (best
    live candidate), "seconds" (since the monitor started)}``), the stages' timings
    (``stage_seconds``, seconds), an optional progress bar (``progress_total`` iterations) and
    callback; ``bar``: the progress bar's label and line (None: tqdm's choice; two fits side by
    side take lines 0 and 1)."""

    def __init__(self, *, progress_total: int | None = None,
                 callback: Callable[[FitStep], None] | None = None,
                 bar: tuple[str, int | None] = ("fit", None)) -> None:
        self.start = time.perf_counter()
        self.history: list[HistoryRecord] = []
        self.stage_seconds: dict[str, float] = {}
        self.callback = callback
        self.bar = None
        if progress_total is not None:
            from tqdm import tqdm

            self.bar = tqdm(total=progress_total, desc=bar[0], position=bar[1], unit="it",
                            leave=False)

    def record(self, stage: str, iteration: int, total: int, energies: torch.Tensor,
               make_params: Callable[[int], HandParams]) -> None:
        """Log one iteration; energies: [K] per live candidate; ``make_params(k)`` the k-th
        candidate's hand (called lazily, by the callback's :meth:`FitStep.params`)."""
        values = [float(v) for v in energies.detach().cpu()]
        seconds = time.perf_counter() - self.start
        self.history.append({"stage": stage, "iteration": iteration, "energy": min(values),
                             "seconds": seconds})
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(stage=stage, energy_mm=f"{1e3 * min(values):.3f}")
        if self.callback is not None:
            best = int(np.argmin(values))
            self.callback(FitStep(stage, iteration, total, values, seconds,
                                  lambda: make_params(best)))

    def lap(self, name: str, since: float) -> float:
        """Store the seconds from ``since`` to now as stage ``name``'s; -> now."""
        now = time.perf_counter()
        self.stage_seconds[name] = now - since
        return now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
