"""Several fits of one cloud, the nearest kept: ``side="auto"`` and ``FitPointsConfig.tries``.

A cloud can be fitted as a right hand and as a left one (``side="auto"``), and from several
seeds (``tries``: seeds ``seed``, ``seed + 1``, ...; the seed draws the point subsets, the proxy
and the free-space points, and on a one-view scan it can decide whether a hidden finger is
found). :func:`best_of` runs every (side, seed) fit and keeps the one whose surface lies nearest
the scan: the mean ``min(|G(x)|, 10 mm)`` over the scan points that all fits keep within their
wrist cuts (the same points for all, so that none wins by cutting more of the scan away).

Fits run two at a time in threads on a CUDA device, or on a CPU with two cores or more when a
fit runs on one thread (``config.num_threads`` 1, the default); each fit has its own seeded
generator, so the results are those of one after the other, in about half the time. The
callback then gets the fits' steps interleaved (``step.params().side`` tells the sides apart).

Which side: from a scan all round the mirror image fits clearly worse, so the true side is kept;
from one view the mirror image can fit the seen side as well (``lisa fit-points`` then asks for
``--side``), and a viewpoint found from the scan (``viewpoint="auto"``) tells them apart more
often. Which seed: on a hand the generator did not make, the scan distance ranks the fits of
a one-view scan little better than chance, so a second try (twice the work) is left to
``tries`` rather than made by default.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import torch

from ...utils.threads import cpu_threads
from ..sides import mirror_cloud, mirror_hand
from .cloud import target_cloud
from .config import FitPointsConfig
from .surface_stage import frozen_field, surface_residuals

__all__ = ["DISTANCE_CAP_MM", "best_of", "scan_distances"]

_MM = 1e-3

DISTANCE_CAP_MM = 10.0
"""Distances beyond this count as this much when fits are compared (an outlier in the scan is
far from every hand and must not decide)."""

FitOne = Callable[[str, FitPointsConfig, tuple[str, int | None]], Any]
"""``fit_one(side, config, bar) -> FitResult``: one fit of the cloud (the config's seed and
threads set by :func:`best_of`; bar: the progress bar's label and line)."""


def best_of(fit_one: FitOne, model, points, config: FitPointsConfig, sides: tuple[str, ...]):
    """Fit ``points`` [N, 3] metres as each of ``sides`` from ``config.tries`` seeds each and
    keep the nearest (see the module docstring) -> its ``FitResult``, with
    ``side_distances_mm`` (each side's nearest fit's distance, mm; None for one side),
    ``try_distances_mm`` (every fit's, side by side for each seed; None for one fit) and
    ``seconds`` (the wall time of all)."""
    start = time.perf_counter()
    plan = [(side, config.seed + k) for k in range(config.tries) for side in sides]
    if len(plan) == 1:
        return fit_one(sides[0], config, ("fit", None))
    parallel = model.device.type == "cuda" or (config.num_threads == 1
                                               and (os.cpu_count() or 1) >= 2)
    inner = dataclasses.replace(config, num_threads=None)  # the threads are set here, once
    threads = config.num_threads if model.device.type == "cpu" else None

    def one(index: int):
        side, seed = plan[index]
        label = side if config.tries == 1 else f"{side} {seed - config.seed + 1}"
        return fit_one(side, dataclasses.replace(inner, seed=seed),
                       (label, index % 2 if parallel else None))

    with cpu_threads(threads), frozen_field(model):
        if parallel:
            with ThreadPoolExecutor(max_workers=2, thread_name_prefix="fit-try") as pool:
                fits = list(pool.map(one, range(len(plan))))
        else:
            fits = [one(index) for index in range(len(plan))]
        distances = scan_distances(model, points, fits, config)
    best = fits[int(np.argmin(distances))]
    if len(sides) > 1:
        best.side_distances_mm = {side: min(d for (s, _), d in zip(plan, distances, strict=True)
                                            if s == side) for side in sides}
    best.try_distances_mm = distances
    best.seconds = time.perf_counter() - start
    return best


def scan_distances(model, points, fits: list, config: FitPointsConfig) -> list[float]:
    """Each fit's mean capped distance (mm) from the points all of ``fits`` keep (the module
    docstring). points: [N, 3] metres."""
    cloud = target_cloud(points, None, dtype=model.field.dtype, device=model.device,
                         min_points=config.min_points, max_points=config.max_points,
                         seed=config.seed).points
    numpy_cloud = cloud.detach().cpu().double().numpy()
    keep = np.ones(cloud.shape[0], dtype=bool)
    for fit in fits:
        if fit.wrist_plane is not None:
            keep &= fit.wrist_plane.keeps(numpy_cloud)
    common = cloud[torch.from_numpy(keep).to(cloud.device)] if keep.any() else cloud
    distances = []
    with torch.no_grad():
        for fit in fits:
            side = fit.params.side
            hand = mirror_hand(fit.params) if side == "left" else fit.params
            residual = surface_residuals(model, hand, mirror_cloud(common, side))
            distances.append(float(residual.clamp_max(DISTANCE_CAP_MM * _MM).mean()) / _MM)
    return distances
