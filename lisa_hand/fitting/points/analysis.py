"""What a scan shows, found once before any stage of the point fit runs.

A scan is more than a hand: a desk it rests on (:mod:`.support`), other objects or other hands
(:mod:`.others`), a sensor seen from one side or views merged all round (:mod:`.viewpoint`).
:func:`analyse_scan` looks for all of them once and returns one immutable
:class:`ScanAnalysis`: the command's model choice, :func:`.fit.fit_points` and each of its
stages read it, and ``params.json`` records it (``fit.analysis``). The stages never look again;
the one thing they add is how much of the aligned hand the scan covers (the 'coverage' stage,
:meth:`ScanAnalysis.with_coverage`), which needs a hand to measure.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from .others import Others, OthersConfig, find_others, split_hands
from .support import Support, SupportConfig, find_support
from .viewpoint import ViewpointConfig, ViewpointEstimate, estimate_viewpoint

__all__ = ["AnalysisConfig", "ScanAnalysis", "analyse_scan"]

_MIN_VIEW_POINTS = 20
"""Fewer points than this cannot tell one view from all round (taken for one view)."""


@dataclass(frozen=True)
class AnalysisConfig:
    """How :func:`analyse_scan` looks (``FitPointsConfig.analysis``; ``--set
    analysis.support.threshold_m=0.004``)."""

    support: SupportConfig = field(default_factory=SupportConfig)
    """The support plane's search (:func:`.support.find_support`)."""
    viewpoint: ViewpointConfig = field(default_factory=ViewpointConfig)
    """The sensor position's search (:func:`.viewpoint.estimate_viewpoint`)."""
    others: OthersConfig = field(default_factory=OthersConfig)
    """The search for pieces apart from the hand (:func:`.others.find_others`)."""


@dataclass(frozen=True)
class ScanAnalysis:
    """What a scan shows (see the module docstring); every array is float64 numpy, metres.

    num_points: points given. keep: [num_points] bool, the hand's points: not the support's, not
    the other pieces'. sensor: [3] the sensor position the fit uses (given, or found for a scan
    that looks like one view with ``viewpoint="auto"``); None: views all round, or unknown.
    one_view: the scan looks like one view (its sensor given, too few points to tell, or
    :func:`.viewpoint.estimate_viewpoint` says so; False when nobody asked: ``viewpoint=None``).
    viewpoint: what that search found (None when the sensor was given or the points were too
    few). support: the plane the hand rests on (``support="auto"`` and found), its ``removed``
    over the points given. others: the pieces left out (``others="auto"``), its ``removed``
    over the points the support left.
    hands: how many hands the scan holds apart from each other (:func:`.others.split_hands`,
    its support left out; a scan of several is fitted a hand at a time, ``lisa fit-points
    --hand N``).
    coverage: share of the aligned hand's surface within reach of the scan (the 'coverage'
    stage); None before it ran.
    """

    num_points: int
    keep: np.ndarray
    sensor: np.ndarray | None = None
    one_view: bool = False
    viewpoint: ViewpointEstimate | None = None
    support: Support | None = None
    others: Others | None = None
    hands: int = 1
    coverage: float | None = None

    @property
    def hand_points(self) -> int:
        """How many points are the hand's."""
        return int(self.keep.sum())

    def hand(self, values):
        """The rows of ``values`` ([num_points, ...] numpy or torch on any device, or None)
        that are the hand's."""
        if values is None:
            return None
        if isinstance(values, torch.Tensor):
            return values[torch.as_tensor(self.keep, device=values.device)]
        return np.asarray(values)[self.keep]

    def with_coverage(self, coverage: float) -> ScanAnalysis:
        """This analysis with the aligned hand's coverage (a new object)."""
        return dataclasses.replace(self, coverage=float(coverage))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``params.json``'s ``fit.analysis``)."""
        estimate = self.viewpoint
        return {
            "num_points": self.num_points,
            "hand_points": self.hand_points,
            "one_view": self.one_view,
            "sensor_m": None if self.sensor is None else [float(v) for v in self.sensor],
            "viewpoint_estimate": None if estimate is None else {
                "position_m": [float(v) for v in estimate.position],
                "hidden_fraction": estimate.hidden_fraction,
                "one_view": estimate.one_view, "at_origin": estimate.at_origin,
                "num_points": estimate.num_points},
            "support_plane": None if self.support is None else self.support.to_dict(),
            "others": None if self.others is None else self.others.to_dict(),
            "hands": self.hands,
            "coverage": self.coverage,
        }


def _as_numpy(values) -> np.ndarray:
    """float64 numpy of a tensor (any device) or a sequence."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu()
    return np.asarray(values, np.float64)


def analyse_scan(points, *, viewpoint=None, support: str | None = None,
                 others: str | None = None, config: AnalysisConfig | None = None,
                 seed: int = 0) -> ScanAnalysis:
    """Analyse a scan once (see the module docstring).

    points: [N, 3] world metres (numpy or torch), finite.
    viewpoint: [3] metres, the sensor position of a one-view scan; "auto": found from the
        points and used when they look like one view; None: no sensor (a scan merged from
        several views).
    support: "auto": a surface the hand rests on is looked for and its points left out; None.
    others: "auto": pieces well apart from the hand are left out (after the support's points);
        when the scan is larger than a hand and the sensor is known, only the part nearest the
        sensor is kept; None.
    seed: of the random searches.
    -> :class:`ScanAnalysis`.
    """
    config = AnalysisConfig() if config is None else config
    for name, value in (("support", support), ("others", others)):
        if value not in (None, "auto"):
            raise ValueError(f"{name} must be 'auto' or None, got {value!r}")
    if isinstance(viewpoint, str) and viewpoint != "auto":
        raise ValueError(f"viewpoint must be 3 numbers (metres), 'auto' or None, got "
                         f"{viewpoint!r}")
    array = _as_numpy(points)
    count = len(array)
    keep = np.ones(count, bool)
    found = None if support is None else find_support(array, config.support, seed=seed)
    sensor, estimate = None, None
    if viewpoint is not None and not isinstance(viewpoint, str):
        sensor = _as_numpy(viewpoint)
        if sensor.shape != (3,) or not np.isfinite(sensor).all():
            raise ValueError(f"viewpoint must be 3 finite numbers (metres), got "
                             f"{list(sensor.shape)} values")
        one_view = True
    elif viewpoint is None:
        one_view = False
    elif count < _MIN_VIEW_POINTS:
        one_view = True
    else:  # with the support's points: the whole view, and on the hand's side of the support
        estimate = estimate_viewpoint(array, config.viewpoint, seed=seed,
                                      side=None if found is None else found.plane.normal)
        one_view = estimate.one_view
        if isinstance(viewpoint, str) and one_view:
            sensor = estimate.position
    split = split_hands(array, seed=seed, support=False, found=found) if count > 1 else None
    if found is not None:
        keep &= ~found.removed
    apart = None
    if others is not None:
        apart = find_others(array[keep], config.others, sensor=sensor)
        if apart is not None and apart.removed.any():
            keep[np.flatnonzero(keep)[apart.removed]] = False
    return ScanAnalysis(num_points=count, keep=keep, sensor=sensor, one_view=one_view,
                        viewpoint=estimate if isinstance(viewpoint, str) else None,
                        support=found, others=apart, hands=1 if split is None else len(split))
