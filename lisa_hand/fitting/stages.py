"""What every fitter's stages share: one signature, :data:`Stage` (``stage(state, fit) ->
(state, report)``), run in the order a fitter's config declares (:func:`run_stages`); the
diagnostics each stage returns (:class:`StageReport`, with its per-iteration ``history``); the
progress bar and the mesh template on the fit's device.

A fitter's state is an immutable dataclass of what one stage hands the next (its hands are
:class:`lisa_hand.skeleton.params.HandParams`: right hands, float32 CPU tensors; the optimised
unknowns live inside the stage); ``fit`` holds what stays fixed through a fit (the model, the
settings). The point fit's stages: :mod:`lisa_hand.fitting.points.stages`; the image fit's:
:mod:`lisa_hand.fitting.images.fit`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import torch

__all__ = ["HistoryRecord", "StageReport", "Stage", "run_stages", "history_columns",
           "progress_bar", "template_on"]

HistoryRecord = dict[str, float | str]
"""One iteration of a stage: ``"stage"`` (str, the stage's name), ``"iteration"`` (int, within
the stage, from 0), ``"energy"`` (the stage's objective of the best live candidate, evaluated in
that iteration before its optimiser step), plus what the stage also logs (the keys are listed
under :class:`StageReport`'s ``history``)."""


@dataclass
class StageReport:
    """Diagnostics of one fitting stage (every stage of every fitter returns one).

    stage: its name: 'align', 'pose', 'size', 'fingers', 'field', 'second' (point fit),
        'keypoints', 'color' (image fit).
    seconds: its wall time, seconds.
    loss: the final objective of the best hand it returns (NaN when the stage did not run,
        e.g. a reused keypoint-stage hand): the point stages' energy (robust distances,
        metres; 'field' with its prior, over the fixed evaluation subset of the cloud), the
        keypoint stage's weighted loss (keypoint pixels, masks and priors), the colour stage's
        total loss of its last iteration.
    energies: [number of hands returned] the final objective of each returned hand, in the
        order they are returned (one value for single-hand stages; empty when it did not run).
    history: one :data:`HistoryRecord` per iteration, in order: ``"stage"``, ``"iteration"``,
        ``"energy"`` (the best live candidate's objective at that iteration); the point fit's
        also ``"seconds"`` (since the fit started,
        :class:`lisa_hand.fitting.points.monitor.FitMonitor`);
        the keypoint stage's also ``"kp_px"`` (the best candidate's mean keypoint error,
        pixels); the colour stage's also its terms ``"col"``, ``"reg"``, ``"joints"``,
        ``"mask"`` (unweighted) and ``"kp_px"``. :func:`history_columns` turns it into columns.
    keypoint_error_px: the image fit: mean distance (pixels) between the projected and the
        given visible keypoints over all views after the stage (NaN without keypoints, and for
        the point fit).
    candidate: the keypoint stage: which restart won; else None.
    screened_energies: the point fit's global-pose search: the proxy energy (metres) of every
        initial candidate (24 orientations per initial finger pose) after the first part of
        the alignment; the size search ('size'): the best candidate's proxy energy at each
        size of ``FitPointsConfig.sizes``, in that order; else empty.
    notes: what the stage did, in words (the point fit's 'fingers': which fingers it moved).
    """

    stage: str
    seconds: float = 0.0
    loss: float = math.nan
    energies: list[float] = field(default_factory=list)
    history: list[HistoryRecord] = field(default_factory=list)
    keypoint_error_px: float = math.nan
    candidate: int | None = None
    screened_energies: list[float] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


State = TypeVar("State")
Fit = TypeVar("Fit")

Stage = Callable[[State, Fit], "tuple[State, StageReport]"]
"""A stage: (the state it starts from, what stays fixed through the fit) -> (the state it
leaves, its :class:`StageReport`)."""


def run_stages(stages: Mapping[str, Stage], order: tuple[str, ...], state: State, fit: Fit,
               lap: Callable[[str, float], Any] | None = None
               ) -> tuple[State, dict[str, StageReport]]:
    """The stages ``order`` names (keys of ``stages``), in that order, each given the state
    the one before left -> (the last state, {name: its report}). lap: called with each
    stage's name and its start (``time.perf_counter()``) when it ends (a fit's timing)."""
    reports: dict[str, StageReport] = {}
    for name in order:
        since = time.perf_counter()
        state, reports[name] = stages[name](state, fit)
        if lap is not None:
            lap(name, since)
    return state, reports


def history_columns(history: list[HistoryRecord], stage: str | None = None
                    ) -> dict[str, list[float]]:
    """The numeric values of ``history`` (of the records of ``stage`` only, when given) as
    columns: {key: [value per record that has it]}, keys in first-seen order, without
    ``"stage"``."""
    columns: dict[str, list[float]] = {}
    for record in history:
        if stage is not None and record.get("stage") != stage:
            continue
        for key, value in record.items():
            if key != "stage":
                columns.setdefault(key, []).append(float(value))
    return columns


def progress_bar(enabled: bool, total: int, desc: str) -> Any:
    """A tqdm bar of ``total`` iterations, or None (disabled, or nothing to do)."""
    if not enabled or total == 0:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="it", leave=False)


def template_on(template: Any, device: torch.device) -> Any:
    """The mesh template on ``device`` in float32 (the shipped one is float64: twice the work);
    None: :func:`lisa_hand.handmodel.template.load_template`."""
    if template is None:
        from ..handmodel.template import load_template

        template = load_template()
    if getattr(template, "device", device) != device or getattr(template, "dtype",
                                                                 None) == torch.float64:
        template = template.to(device=device, dtype=torch.float32)
    return template
