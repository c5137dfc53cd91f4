"""The point fit's stages, each one function of one signature: ``stage(state, fit) -> (state,
report)``.

:class:`PointState` is what the stages pass on (the cloud they fit, the surface proxy, the
candidate hands, the scan's :class:`~.analysis.ScanAnalysis`, the field energy); :class:`PointFit`
is what stays fixed through one fit (the model, the settings, the template, the monitor).
:func:`run_point_stages` runs the stages ``FitPointsConfig.stages`` names, in that order
(:data:`STAGES`):

- 'align' (:func:`.global_pose.search_global_pose`, no network): the proxy in 24 orientations
  per initial finger pose, rigidly aligned; the ``restarts`` best distinct candidates go on,
  and the cloud loses what lies well beyond their wrist.
- 'pose' (:func:`.proxy.fit_proxy_pose`): the candidates' finger poses on the proxy.
- 'size' (:func:`.size_search.search_size`): the best candidate at several hand sizes.
- 'unseen' (:func:`.proxy.unseen_fingers`): for a one-view scan, the fingers its sensor could
  not see, which the finger-pose prior then couples to their neighbours.
- 'fingers' (:func:`.finger_search.restart_fingers`): each finger of the best candidate
  restarted from other poses.
- 'coverage' (:func:`.proxy.covered_fraction`): how much of the hand the scan covers
  (:meth:`.analysis.ScanAnalysis.with_coverage`); a scan all round sets the shape with a
  weaker prior (``covered_shape_weight``) in the field stages.
- 'field' (:func:`.surface_stage.fit_surface`): every unknown on the LISA field, the
  candidates pruned to one.
- 'second' (:func:`second_finger_pass`): the fingers' second chance on a proxy of the fitted
  hand's own shape.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from ...skeleton.params import HandParams
from ...skeleton.wrist import wrist_plane
from ..stages import Stage, StageReport, run_stages
from .analysis import ScanAnalysis
from .candidates import CandidateBatch
from .cloud import TargetCloud, point_spacing
from .config import POINT_STAGES, FitPointsConfig
from .finger_search import restart_fingers
from .free_space import free_points_near
from .global_pose import search_global_pose
from .monitor import FitMonitor
from .proxy import (
    SurfaceProxy,
    build_surface_proxy,
    covered_fraction,
    fit_proxy_pose,
    unseen_fingers,
)
from .size_search import search_size
from .surface_stage import fit_surface

__all__ = ["PointState", "PointFit", "STAGES", "run_point_stages", "clip_cloud",
           "second_finger_pass"]

_MM = 1e-3
_SPARSE_COVER = 2.0
"""A sparse cloud counts a proxy point as covered within this many times its point spacing
(:func:`_covered_distance`)."""


@dataclass(frozen=True)
class PointFit:
    """What stays fixed through one point fit (of one side).

    model: the :class:`lisa_hand.model.trained.TrainedModel`, on the cloud's device and dtype.
    config: the :class:`~.config.FitPointsConfig`. template: the mesh template whose betas
    give the skeleton, or None (a fixed skeleton). start: the right hand at rest every
    candidate starts from. monitor: the fit's :class:`~.monitor.FitMonitor`.
    """

    model: Any
    config: FitPointsConfig
    template: Any
    start: HandParams
    monitor: FitMonitor


@dataclass(frozen=True)
class PointState:
    """What one stage passes to the next.

    cloud: the right hand's cloud the stages fit (after 'align', without what lies beyond its
    wrist and margin). proxy: the surface proxy of the proxy stages. candidates: right hands,
    best first (one after 'field'). analysis: the scan's analysis (its ``coverage`` set by the
    'coverage' stage). unseen: [5] weights of the fingers a one-view sensor could not see on the
    best candidate (the 'unseen' stage; :func:`.proxy.unseen_fingers`), which the prior couples
    to their neighbours; None: none. energy: the field energy of ``candidates[0]`` (NaN before
    'field').
    """

    cloud: TargetCloud
    proxy: SurfaceProxy
    candidates: tuple[HandParams, ...] = ()
    analysis: ScanAnalysis | None = None
    unseen: torch.Tensor | None = None
    energy: float = math.nan

    def replace(self, **changes) -> PointState:
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)


def clip_cloud(cloud: TargetCloud, hand: HandParams, offset: float | None, min_points: int
               ) -> TargetCloud:
    """``cloud`` without its points beyond ``hand``'s wrist cut at ``offset`` metres
    (:func:`lisa_hand.skeleton.wrist.wrist_plane`); unchanged when ``offset`` is None, and
    its points all kept when fewer than ``min_points`` would be left. (Its free-space points
    stay: the surface stage cuts them, and the points, at each candidate's own wrist.)"""
    if offset is None:
        return cloud
    keep = torch.from_numpy(wrist_plane(hand, offset).keeps(
        cloud.points.detach().cpu().double().numpy()))
    if int(keep.sum()) < min_points or bool(keep.all()):
        return cloud
    keep = keep.to(cloud.points.device)
    return cloud.replace(points=cloud.points[keep],
                         normals=None if cloud.normals is None else cloud.normals[keep])


def _free_near(cloud: TargetCloud, proxy: SurfaceProxy, config: FitPointsConfig
               ) -> Callable[[CandidateBatch], torch.Tensor] | None:
    """The surface stage's source of free-space points near its candidates' surfaces: batch
    -> [M, 3] world metres (the proxy posed by each candidate,
    :func:`.free_space.free_points_near`), refreshed as the candidates move; None when the
    cloud has no depth image."""
    if cloud.depth is None or config.free_space_weight <= 0:
        return None

    def near(batch: CandidateBatch) -> torch.Tensor:
        with torch.no_grad():
            surface = proxy.world(batch).reshape(-1, 3)
        return free_points_near(cloud.depth, surface, config.free_space_points,
                                cloud.generator)

    return near


def _unseen_weights(cloud: TargetCloud, proxy: SurfaceProxy, hand: HandParams,
                    config: FitPointsConfig, notes: list[str]) -> torch.Tensor | None:
    """[5] the weights of the fingers the cloud's sensor could not see on ``hand``
    (:func:`.proxy.unseen_fingers`), named in ``notes``; None without a sensor position or with
    ``coupling_weight`` and ``unseen_thumb_weight`` 0."""
    from ..priors import UNSEEN_FINGERS

    if cloud.depth is None or (config.coupling_weight <= 0 and config.unseen_thumb_weight <= 0):
        return None
    weights = unseen_fingers(proxy, cloud, hand, config.unseen_share)
    unseen = [f"{name} {float(w):.2f}" for name, w in zip(UNSEEN_FINGERS, weights,
                                                           strict=True) if float(w) > 0]
    notes.append(f"unseen fingers: {', '.join(unseen) or 'none'}")
    return weights


def _covered_distance(cloud: TargetCloud, config: FitPointsConfig) -> float:
    """How near the scan a proxy point must be to count as covered, metres:
    ``config.covered_mm``, or twice the cloud's median point spacing ``s`` where that is larger
    (a sparse cloud, such as a mesh's vertices some millimetres apart, would otherwise cover a
    full hand no more than one view of it does). Points scattered at random with median
    nearest-neighbour distance ``s`` leave ``2^-(r/s)^2`` of the surface farther than ``r`` from
    all of them: 6% at ``r = 2 s``, 21% at 1.5 s."""
    return max(config.covered_mm * _MM, _SPARSE_COVER * point_spacing(cloud.points))


def _field_config(state: PointState, config: FitPointsConfig) -> FitPointsConfig:
    """``config`` with the shape prior the scan's coverage calls for: ``covered_shape_weight``
    when the 'coverage' stage found the scan covering the hand all round."""
    coverage = None if state.analysis is None else state.analysis.coverage
    if coverage is not None and coverage >= config.covered_fraction:
        return dataclasses.replace(config, shape_weight=config.covered_shape_weight)
    return config


def align(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'align': the global-pose search; the cloud then loses what lies beyond the best
    candidate's wrist cut and margin (``wrist_clip_m + wrist_margin_m``)."""
    config = fit.config
    candidates, report = search_global_pose(state.proxy, state.cloud, config, fit.start,
                                            monitor=fit.monitor)
    clip = config.wrist_clip_m
    cloud = clip_cloud(state.cloud, candidates[0], None if clip is None else
                       clip + config.wrist_margin_m, config.min_points)
    return state.replace(cloud=cloud, candidates=tuple(candidates)), report


def pose(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'pose': the candidates' rotation, position and finger pose on the proxy."""
    candidates, report = fit_proxy_pose(state.proxy, state.cloud, state.candidates, fit.config,
                                        monitor=fit.monitor, unseen=state.unseen)
    return state.replace(candidates=tuple(candidates)), report


def size(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'size': the best candidate tried at several hand sizes; every candidate and the proxy
    go on at the best one."""
    config = fit.config
    sized, candidates, report = search_size(state.proxy, state.cloud, state.candidates,
                                            fit.template, config, monitor=fit.monitor)
    if sized is not state.proxy and config.wrist_clip_m is not None:
        sized = sized.without_forearm(config.wrist_clip_m)  # a larger stub reaches past the cut
    return state.replace(proxy=sized, candidates=tuple(candidates)), report


def unseen(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'unseen': the fingers of the best candidate a one-view scan's sensor could not see
    (their weights into the state, named in the report's notes)."""
    began = time.perf_counter()
    notes: list[str] = []
    weights = _unseen_weights(state.cloud, state.proxy, state.candidates[0], fit.config, notes)
    return state.replace(unseen=weights), StageReport(
        stage="unseen", seconds=time.perf_counter() - began, notes=notes)


def fingers(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'fingers': the per-finger restarts of the best candidate."""
    candidates, report = restart_fingers(state.proxy, state.cloud, state.candidates,
                                         fit.config, monitor=fit.monitor, unseen=state.unseen)
    return state.replace(candidates=tuple(candidates)), report


def coverage(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'coverage': the share of the best candidate's proxy within reach of the scan (cut at
    its wrist), into the analysis."""
    began = time.perf_counter()
    config = fit.config
    near = clip_cloud(state.cloud, state.candidates[0], config.wrist_clip_m, config.min_points)
    reach = _covered_distance(near, config)
    covered = covered_fraction(state.proxy, near, state.candidates[0], reach)
    state = state.replace(analysis=state.analysis.with_coverage(covered))
    weight = _field_config(state, config).shape_weight
    return state, StageReport(stage="coverage", seconds=time.perf_counter() - began,
                              loss=covered, notes=[f"scan covers {covered:.0%} of the hand "
                                                   f"within {reach / _MM:.3g} mm: shape prior "
                                                   f"{weight:g}"])


def field(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'field': every unknown on the LISA field, the candidates pruned to one."""
    hand, report = fit_surface(fit.model, state.cloud, state.candidates,
                               _field_config(state, fit.config), template=fit.template,
                               pivot=state.proxy.pivot, monitor=fit.monitor,
                               free_near=_free_near(state.cloud, state.proxy, fit.config),
                               unseen=state.unseen)
    return state.replace(candidates=(hand,), energy=report.loss), report


def second(state: PointState, fit: PointFit) -> tuple[PointState, StageReport]:
    """'second': the fingers' second chance (:func:`second_finger_pass`); nothing with
    ``second_pass_iters`` 0."""
    config = _field_config(state, fit.config)
    if config.second_pass_iters <= 0:
        return state, StageReport(stage="second", loss=state.energy)
    hand, report = second_finger_pass(fit.model, state.cloud, state.candidates[0], config,
                                      state.energy, template=fit.template,
                                      monitor=fit.monitor)
    return state.replace(candidates=(hand,), energy=report.loss), report


STAGES: dict[str, Stage] = {"align": align, "pose": pose, "size": size, "unseen": unseen,
                            "fingers": fingers, "coverage": coverage, "field": field,
                            "second": second}
"""Every stage by name, in the one order they may run (``FitPointsConfig.stages`` names a
subsequence of it)."""
assert tuple(STAGES) == POINT_STAGES


def run_point_stages(state: PointState, fit: PointFit
                     ) -> tuple[PointState, dict[str, StageReport]]:
    """The stages ``fit.config.stages`` names, in order (:func:`lisa_hand.fitting.stages.
    run_stages`), each timed on the monitor -> (the last state, {stage: its report})."""
    return run_stages(STAGES, fit.config.stages, state, fit, fit.monitor.lap)


def second_finger_pass(model, cloud: TargetCloud, hand: HandParams, config, energy: float, *,
                       template=None, monitor: FitMonitor | None = None
                       ) -> tuple[HandParams, StageReport]:
    """The fingers' second chance ('second'), after the field stage.

    The first proxy has the model's mean shape on the template's mean skeleton: on a hand the
    generator did not make it is millimetres from the scan everywhere, and a finger curled the
    wrong way can cost it no more than the right one. Here the per-finger restarts
    (:func:`.finger_search.restart_fingers`) run again on a proxy of the fitted hand itself
    (its shape code and skeleton), which lies near the scan where the first did not; when a
    finger changes, the changed hand and the fitted one both take ``config.second_pass_iters``
    field steps and the one of lower field energy is kept.

    hand: the field stage's right hand; cloud: the cloud it was fitted to (the restarts see it
    cut at ``hand``'s wrist, the field steps each candidate at its own); energy: the field
    stage's energy of ``hand`` (:func:`.surface_stage.fit_surface`'s ``loss``). -> (the hand,
    the :class:`StageReport` ('second'): ``loss`` the hand's field energy, ``notes`` which
    fingers the restarts changed).
    """
    start = time.perf_counter()
    began = len(monitor.history) if monitor is not None else 0
    color = hand.color_code
    like = dict(device=cloud.points.device, dtype=cloud.points.dtype)
    proxy = build_surface_proxy(model, hand.rest_joints.to(**like), hand.shape_code.to(**like),
                                None if color is None or color.numel() == 0 else
                                color.to(**like), config.proxy_points, cloud.generator)
    if config.wrist_clip_m is not None:
        proxy = proxy.without_forearm(config.wrist_clip_m)
    notes: list[str] = []
    unseen = _unseen_weights(cloud, proxy, hand, config, notes)  # unseen where this hand is
    moved, changed = restart_fingers(proxy, clip_cloud(cloud, hand, config.wrist_clip_m,
                                                       config.min_points),
                                     [hand], config, monitor=monitor,
                                     moved_base=cloud.depth is not None, unseen=unseen)
    notes = list(changed.notes) + notes
    loss = energy
    if moved[0] is not hand:
        iters = dataclasses.replace(config, field_iters=config.second_pass_iters)
        hand, report = fit_surface(model, cloud, [moved[0], hand], iters, template=template,
                                   pivot=proxy.pivot, monitor=monitor,
                                   free_near=_free_near(cloud, proxy, config), unseen=unseen)
        loss = report.loss
    history = monitor.history[began:] if monitor is not None else []
    return hand, StageReport(stage="second", seconds=time.perf_counter() - start, loss=loss,
                             history=history, notes=notes)
