"""A scan of several hands that may touch (``lisa fit-points --hands N``): the points split
between the hands by the hands' own fits, not only by connected pieces (:func:`fit_scan_hands`).

Two clasped hands are one connected piece, so :func:`.others.split_hands` cannot tell them
apart. Here the hand points (the scan without a support plane) are first split into N parts
(:func:`choose_split`: parts apart from each other are the hands; touching hands are cut in
several ways, :func:`split_candidates`, each cut's parts fitted quickly as hands, and the cut
whose hands lie nearest the scan wins, its hands refitted quickly on the points they claim: the
hands' fits decide, not the cut's shape), each part
is fitted as a hand (:func:`.fit.fit_points`, side "auto"), and then every point goes to the
fitted hand whose surface is nearest (each hand's field's ``|SDF|`` at the point,
:meth:`lisa_hand.fitting.pair.contact.HandBody.sdf`; points farther than ``far_mm`` from every
hand are left out). The parts are fitted again from that split (``config.rounds`` times), and
finally all hands are refined together (:func:`lisa_hand.fitting.pair.joint.fit_hands_together`:
each hand's field at its own points, and at the other hands' surfaces: touching, not
overlapping); the split is made once more from the result.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams
from .config import ScanHandsConfig

__all__ = ["ScanHandsConfig", "ScanHands", "kmeans_split", "split_candidates", "initial_split",
           "choose_split", "surface_distances", "assign_points", "fit_scan_hands"]


@dataclass
class ScanHands:
    """What :func:`fit_scan_hands` found: each hand (world metres, its own side), which hand
    each input point belongs to (``labels`` [N]: -1 none), each hand's last
    :class:`.fit.FitResult` alone, and the joint fit's report (None when it did not run)."""

    hands: list[HandParams]
    labels: np.ndarray
    fits: list[Any]
    joint: Any
    seconds: float


def _spread(points: np.ndarray) -> float:
    """The area of ``points`` [N, 3] across its two longest principal axes, m^2 (the extents
    between the 2nd and 98th percentiles: a few stray points do not count). A whole hand is
    long and wide; half of two hands (their fingers, or their thumb sides) is not."""
    centred = points - points.mean(0)
    _, _, axes = np.linalg.svd(centred[:: max(1, len(points) // 4000)], full_matrices=False)
    along = centred @ axes[:2].T
    extent = np.percentile(along, 98, axis=0) - np.percentile(along, 2, axis=0)
    return float(extent[0] * extent[1])


def _gap(points: np.ndarray, labels: np.ndarray) -> float:
    """The distance between the two parts of a split, metres (their nearest points)."""
    from scipy.spatial import cKDTree

    first, second = points[labels == 0], points[labels == 1]
    if not len(first) or not len(second):
        return 0.0
    return float(cKDTree(first).query(second)[0].min())


def _spacing(points: np.ndarray) -> float:
    """The points' typical spacing, metres (median nearest-neighbour distance, of a sample
    corrected to all points)."""
    from scipy.spatial import cKDTree

    sample = points[:: max(1, len(points) // 2000)]
    return float(np.median(cKDTree(sample).query(sample, k=2)[0][:, 1])) * max(
        1.0, np.sqrt(len(sample) / len(points)))


def split_candidates(points: np.ndarray, count: int, seed: int = 0) -> list[np.ndarray]:
    """Ways to cut ``points`` [N, 3] into ``count`` parts, each [N] labels 0..count-1: k-means
    on the positions, and (two hands) the points cut in half by the median plane across each
    principal axis."""
    points = np.asarray(points, np.float64)
    if count < 1 or len(points) < count:
        raise ValueError(f"cannot split {len(points)} points into {count} hands")
    candidates = [kmeans_split(points, count, seed)]
    if count != 2:
        return candidates
    centred = points - points.mean(0)
    _, _, axes = np.linalg.svd(centred[:: max(1, len(points) // 4000)], full_matrices=False)
    for axis in axes:
        along = centred @ axis
        candidates.append((along > np.median(along)).astype(np.int64))
    return candidates


def _apart(points: np.ndarray, candidates: list[np.ndarray]) -> np.ndarray | None:
    """Of two-part ``candidates``, the one whose parts lie apart (the widest gap, more than three
    times the points' spacing), or None (the hands touch)."""
    if len(candidates) < 2:
        return None
    gaps = [_gap(points, labels) for labels in candidates]
    return candidates[int(np.argmax(gaps))] if max(gaps) > 3.0 * _spacing(points) else None


def initial_split(points: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """[N] labels 0..count-1: a guess, from the points alone, of which hand each point belongs
    to (:func:`split_candidates`). Parts apart from each other are two hands apart: the
    candidate with the widest gap wins. Otherwise (touching hands) the one whose smallest part
    spreads widest (:func:`_spread`: each part should be a whole hand, not two hands' fingers
    and two hands' palms, which is how k-means cuts two flat hands lying palm to palm)."""
    points = np.asarray(points, np.float64)
    candidates = split_candidates(points, count, seed)
    return _guess(points, candidates, count, _apart(points, candidates))


def _guess(points: np.ndarray, candidates: list[np.ndarray], count: int,
           apart: np.ndarray | None) -> np.ndarray:
    """:func:`initial_split`'s choice among ``candidates`` (``apart``: the one whose parts lie
    apart, or None)."""
    if apart is not None or len(candidates) == 1:
        return candidates[0] if apart is None else apart
    return max(candidates, key=lambda labels: min(_spread(points[labels == k])
                                                  for k in range(count)))


def choose_split(model: Any, points: np.ndarray, count: int, config: Any,
                 hands_config: ScanHandsConfig, sensor: np.ndarray | None = None,
                 side: str = "auto", log: Callable[[str], None] | None = None) -> np.ndarray:
    """[N] labels (-1: near no hand): the first split of a scan of ``count`` hands. Parts apart
    from each other are the hands. Touching hands: each of :func:`split_candidates` is tried
    (three hands or more: k-means alone), its parts fitted quickly as hands
    (:func:`.fit.fit_points` with only its align, pose, unseen and field stages,
    ``hands_config.candidate_iters`` field iterations: no size search, no finger restarts), and
    the candidate whose hands lie nearest the scan (the mean distance of every point to its
    nearest hand's surface, capped at ``far_mm``) wins, its points given to their nearest
    hand. A cut through two interlaced hands' fingers gives two misshapen
    hands far from half the points; the cut between the hands, two hands on the scan. The
    winner's hands are then fitted quickly again on the points they were given, up to
    ``candidate_rounds`` times while they come nearer the scan (two clasped hands: no cut
    separates the fingers wrapped round the other hand, but the hands fitted to most of their
    own points claim them)."""
    log = log or (lambda line: None)
    points = np.asarray(points, np.float64)
    candidates = split_candidates(points, count, config.seed)
    apart = _apart(points, candidates)
    if apart is not None or hands_config.candidate_iters == 0:
        return _guess(points, candidates, count, apart)
    best_score, best = math.inf, candidates[0]
    for number, labels in enumerate(candidates):
        score, given = _quick_split(model, points, labels, count, config, hands_config, sensor,
                                    side)
        log(f"cut {number + 1} of {len(candidates)}: " + (
            f"the hands {1000 * score:.2f} mm from the scan (mean)" if math.isfinite(score)
            else "a part too small to fit"))
        if score < best_score:
            best_score, best = score, given
    for number in range(hands_config.candidate_rounds if math.isfinite(best_score) else 0):
        score, given = _quick_split(model, points, best, count, config, hands_config, sensor,
                                    side)
        log(f"refit {number + 1}: the hands {1000 * score:.2f} mm from the scan (mean)")
        if not score < best_score:
            break
        best_score, best = score, given
    return best


def _quick_split(model: Any, points: np.ndarray, labels: np.ndarray, count: int, config: Any,
                 hands_config: ScanHandsConfig, sensor: np.ndarray | None, side: str
                 ) -> tuple[float, np.ndarray]:
    """Each part of ``labels`` [N] fitted quickly as a hand (:func:`choose_split`) -> (the mean
    distance of the points to their nearest hand, capped at ``far_mm``, metres; inf when a part
    is too small to fit; [N] each point's nearest hand, -1 beyond ``far_mm``)."""
    from .fit import fit_points

    if min(int((labels == k).sum()) for k in range(count)) < config.min_points:
        return math.inf, labels
    quick = dataclasses.replace(
        config, stages=tuple(stage for stage in config.stages
                             if stage in ("align", "pose", "unseen", "field")),
        field_iters=hands_config.candidate_iters, second_pass_iters=0, tries=1)
    hands = [fit_points(model, points[labels == k], None, quick, side=side,
                        viewpoint=sensor).params for k in range(count)]
    distances = surface_distances(model, hands, points, hands_config.far_mm)
    far = hands_config.far_mm / 1000.0
    given = distances.argmin(0)
    given[distances.min(0) > far] = -1
    return float(np.minimum(distances.min(0), far).mean()), given


def kmeans_split(points: np.ndarray, count: int, seed: int = 0, tries: int = 8,
                 iterations: int = 30) -> np.ndarray:
    """[N] labels 0..count-1: k-means of ``points`` [N, 3], the lowest-inertia of ``tries``
    starts (k-means++ seeding from ``seed``)."""
    points = np.asarray(points, np.float64)
    if count < 1 or len(points) < count:
        raise ValueError(f"cannot split {len(points)} points into {count} hands")
    rng = np.random.default_rng(seed)
    best, best_inertia = None, np.inf
    for _ in range(tries):
        centres = [points[rng.integers(len(points))]]
        for _ in range(count - 1):
            distance = np.min([((points - c) ** 2).sum(1) for c in centres], axis=0)
            centres.append(points[rng.choice(len(points), p=distance / distance.sum())])
        centres = np.stack(centres)
        for _ in range(iterations):
            labels = ((points[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
            moved = np.stack([points[labels == k].mean(0) if (labels == k).any() else centres[k]
                              for k in range(count)])
            if np.allclose(moved, centres):
                break
            centres = moved
        inertia = ((points - centres[labels]) ** 2).sum()
        if inertia < best_inertia:
            best, best_inertia = labels, inertia
    return best


@torch.no_grad()
def surface_distances(model: Any, hands: list[HandParams], points: np.ndarray, far_mm: float
                      ) -> np.ndarray:
    """[K, N] metres: each hand's distance to each point (its field's ``|SDF|``; beyond its
    bone regions, at least ``far_mm``). hands: either side, world metres."""
    from ..pair.contact import HandBody

    cloud = torch.as_tensor(np.asarray(points), dtype=torch.float64)
    distances = []
    for hand in hands:
        body = HandBody(right=_right(hand), flip=hand.side == "left", surface=None,
                        rows=torch.zeros(0, dtype=torch.long))
        sdf = body.sdf(model, body.right.pose, body.right.translation, body.right.shape_code,
                       cloud, margin_m=far_mm / 1000.0)
        distances.append(sdf.abs().double().numpy())
    return np.stack(distances)


def assign_points(model: Any, hands: list[HandParams], points: np.ndarray, far_mm: float
                  ) -> np.ndarray:
    """[N] the hand whose surface is nearest each point (:func:`surface_distances`), -1 where
    every hand's is farther than ``far_mm``. hands: either side, world metres."""
    distances = surface_distances(model, hands, points, far_mm)  # [K, N] metres
    labels = distances.argmin(0)
    labels[distances.min(0) > far_mm / 1000.0] = -1
    return labels


def _right(hand: HandParams) -> HandParams:
    from ..sides import mirror_hand

    return mirror_hand(hand) if hand.side == "left" else hand


def _fit_parts(model: Any, points: np.ndarray, labels: np.ndarray, count: int, config: Any,
               sensor: np.ndarray | None, side: str, progress: bool,
               log: Callable[[str], None]) -> list[Any]:
    from .fit import fit_points

    fits = []
    for index in range(count):
        part = points[labels == index]
        if len(part) < config.min_points:
            raise ValueError(f"hand {index} of {count} has {len(part)} points after the split "
                             f"(at least {config.min_points} needed): does the scan hold "
                             f"{count} hands?")
        fits.append(fit_points(model, part, None, config, side=side,
                               viewpoint=None if sensor is None else sensor,
                               progress=progress))
        log(f"hand {index}: {len(part)} points, a {fits[-1].params.side} hand, residual "
            f"{fits[-1].residual_median_mm:.1f} mm (median)")
    return fits


def fit_scan_hands(model: Any, points: np.ndarray, count: int, config: Any = None, *,
                   side: str = "auto",
                   sensor: np.ndarray | None = None, progress: bool = False,
                   log: Callable[[str], None] | None = None) -> ScanHands:
    """Fit ``count`` >= 2 hands to the hand points of one scan (module docstring).

    points: [N, 3] world metres (a support plane and other objects already left out).
    config: the point fit's :class:`.fit.FitPointsConfig` for each hand; its ``hands``
    (:class:`.config.ScanHandsConfig`): how the scan is split and the hands fitted together.
    side: each hand's side ("auto": both tried per hand). sensor: [3] metres, a one-view scan's
    sensor position.
    """
    import time

    from ...inference import mesh_hand
    from ..pair.joint import JointHand, fit_hands_together
    from ..stages import template_on
    from .fit import FitPointsConfig

    began = time.perf_counter()
    log = log or (lambda line: None)
    config = FitPointsConfig() if config is None else config
    hands_config = config.hands
    points = np.asarray(points, np.float64)
    labels = choose_split(model, points, count, config, hands_config, sensor, side, log)
    fits = _fit_parts(model, points, labels, count, config, sensor, side, progress, log)
    for _ in range(hands_config.rounds):
        labels = assign_points(model, [fit.params for fit in fits], points, hands_config.far_mm)
        fits = _fit_parts(model, points, labels, count, config, sensor, side, progress, log)
    hands = [fit.params for fit in fits]
    labels = assign_points(model, hands, points, hands_config.far_mm)
    report = None
    if hands_config.joint.iters > 0:
        joint = [JointHand(params=hand, mesh=mesh_hand(model, hand, hands_config.mesh_resolution),
                           points=points[labels == index])
                 for index, hand in enumerate(hands)]
        hands, report = fit_hands_together(model, joint, template_on(None, torch.device("cpu")),
                                           hands_config.joint, progress)
        labels = assign_points(model, hands, points, hands_config.far_mm)
    return ScanHands(hands=hands, labels=labels, fits=fits, joint=report,
                     seconds=time.perf_counter() - began)
