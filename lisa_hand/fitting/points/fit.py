"""Fitting LISA to a point cloud (paper Section 4.3, "Reconstruction from point clouds").

The paper minimises ``sum_x |G(x, theta, beta+)| + ||beta+||`` over the pose ``theta`` and the
shape code ``beta+``. The hand in a scan can be anywhere, in any orientation and finger pose,
seen from one side, with noise and outliers, so :func:`fit_points` composes its stages, each
a function from hands (:class:`~lisa_hand.skeleton.params.HandParams`) to hands:

1. **Global-pose search** (:func:`.global_pose.search_global_pose`, 'align', no network): a
   surface proxy of the model (:mod:`lisa_hand.fitting.points.proxy`) in 24
   orientations per initial finger pose, rigidly aligned to the cloud; the ``num_restarts``
   best distinct candidates go on.
2. **Articulated proxy** (:func:`.proxy.fit_proxy_pose`, 'pose', no network): the candidates
   also fit the finger pose on the proxy.
   **Size** (:func:`.size_search.search_size`, 'size', no network): the best candidate tried
   at several hand sizes (proxy and skeleton scaled); every candidate goes on at the best one.
   **Per-finger restarts** (:func:`.finger_search.restart_fingers`, 'fingers', no network): the
   best candidate with each finger restarted from other poses; the best chain of each finger
   combined replaces the last candidate when it fits better.
3. **Surface** (:func:`.surface_stage.fit_surface`, 'field'): all unknowns on the LISA field
   (rotation, translation, finger pose, shape code, the template's betas), candidates pruned
   to one (8 -> 3 -> 1); the shape prior is weaker (``covered_shape_weight``) when the scan
   covers the hand all round (:func:`.proxy.covered_fraction`).
4. **The fingers' second chance** (:func:`second_finger_pass`, 'second'): the per-finger
   restarts again, on a proxy of the fitted hand's own shape and skeleton, then a short field
   stage of the changed hand beside the fitted one, the better one kept.

The residual's penalty is :func:`lisa_hand.fitting.robust.robust_loss` (Geman-McClure by
default; the paper's ``|r|`` with ``robust_loss="l1"``); the finger-pose prior and the joint
limits are the shared ones of :mod:`lisa_hand.fitting.priors`.

LISA is a right hand: a left hand's cloud (``side="left"``) is fitted as the right hand of the
mirrored cloud and the result mirrored back (``params.side == "left"``). With ``side="auto"``
both are fitted and the one whose surface lies nearer the scan is kept; with
``FitPointsConfig.tries`` above 1, so is the nearest of fits from as many seeds
(:func:`.hypotheses.best_of`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ...geometry.planes import Plane
from ...skeleton import NUM_JOINTS, POSE_DIM, check_side
from ...skeleton.params import HandParams
from ...skeleton.wrist import wrist_plane
from ...utils.threads import cpu_threads
from ..sides import mirror_cloud, mirror_hand
from ..stages import HistoryRecord, StageReport
from .candidates import CandidateBatch
from .cloud import TargetCloud, point_spacing, target_cloud
from .config import FitPointsConfig
from .finger_search import restart_fingers
from .free_space import DepthImage, free_points_near, free_space_points
from .global_pose import search_global_pose
from .hypotheses import best_of
from .monitor import FitMonitor, FitStep
from .others import Others, find_others
from .proxy import build_surface_proxy, covered_fraction, fit_proxy_pose, unseen_fingers
from .size_search import search_size
from .support import Support, find_support, support_points
from .surface_stage import fit_surface, frozen_field, surface_residuals
from .viewpoint import ViewpointEstimate, estimate_viewpoint

__all__ = ["FitPointsConfig", "FitStep", "FitResult", "fit_points", "start_hand"]

_MM = 1e-3


@dataclass
class FitResult:
    """Result of :func:`fit_points`.

    params: the fitted hand (pose, translation, skeleton, betas, shape and colour codes, side);
        ``params.extra["fit"]`` holds the numbers below as JSON.
    energy: the field energy of the result over the evaluation subset of the cloud (the last
        stage's ``loss``: 'second', or 'field' when the second pass is off).
    residual_median_mm, residual_mean_mm: median and mean ``|G(x)|`` over the whole cloud, mm.
    inlier_fraction: fraction of points with ``|G(x)| < 3 sigma`` (``sigma = robust_scale_mm``).
    seconds: wall time of the fit; stage_seconds: per stage ('proxy', 'align', 'pose',
        'fingers', 'field', 'second', 'finish').
    num_points: points fitted (after ``max_points``, without those beyond the wrist).
    beyond_wrist_points: points left out as lying beyond the wrist (``config.wrist_clip_m``).
    wrist_plane: the fitted hand's wrist cut (:func:`lisa_hand.skeleton.wrist.wrist_plane`
        ``config.wrist_clip_m`` beyond the wrist joint, or sooner where the scan stops; None
        without one), where the written mesh and the metrics end.
    candidate_energies: proxy energy of each candidate (24 orientations per initial finger
        pose) after the first part of the alignment (the 'align' report's
        ``screened_energies``).
    history: per iteration ``{"stage", "iteration", "energy" (best live candidate), "seconds"
        (since the fit started)}`` (:data:`lisa_hand.fitting.stages.HistoryRecord`), every
        stage in order.
    reports: each stage's :class:`lisa_hand.fitting.stages.StageReport` ({"align", "pose", "size",
        "fingers", "field", "second"}; no "second" with ``config.second_pass_iters`` 0), as the
        image fit's ``reports``.
    coverage: share of the hand's surface (its proxy, after the finger restarts) within
        ``config.covered_mm`` of the scan (:func:`.proxy.covered_fraction`): near 1 for a scan
        from all sides, about a half or less for one view.
    """

    params: HandParams
    energy: float
    residual_median_mm: float
    residual_mean_mm: float
    inlier_fraction: float
    seconds: float
    stage_seconds: dict[str, float]
    num_points: int
    candidate_energies: list[float]
    history: list[HistoryRecord]
    reports: dict[str, StageReport] = field(default_factory=dict)
    beyond_wrist_points: int = 0
    wrist_plane: Plane | None = None
    coverage: float = float("nan")
    side_distances_mm: dict[str, float] | None = None
    """``side="auto"``: each side's fitted surface's mean distance (mm) from the scan points
    that all fits keep (:func:`.hypotheses.best_of`); None when the side was given."""
    try_distances_mm: list[float] | None = None
    """Several fits (``side="auto"``, ``config.tries`` > 1): every fit's distance (mm), the
    sides side by side for each seed; None for one fit."""
    viewpoint: ViewpointEstimate | None = None
    """``viewpoint="auto"``: what :func:`.viewpoint.estimate_viewpoint` found (its position
    was used when ``one_view``); None when the viewpoint was given or left out.
    support: ``support="auto"``: the surface the hand rests on, found and left out
    (:class:`.support.Support`; its ``removed`` mask is over the points given), or None."""
    support: Support | None = None
    others: Others | None = None
    """``others="auto"``: the pieces of the scan apart from the hand, left out
    (:class:`.others.Others`; its ``removed`` mask is over the points left after the support's
    were), or None."""

    def summary(self) -> dict[str, Any]:
        """The scalar results as a JSON-able dict (what ``params.extra["fit"]`` holds)."""
        return {
            "energy": self.energy,
            "residual_median_mm": self.residual_median_mm,
            "residual_mean_mm": self.residual_mean_mm,
            "inlier_fraction": self.inlier_fraction,
            "seconds": self.seconds,
            "stage_seconds": dict(self.stage_seconds),
            "num_points": self.num_points,
            "beyond_wrist_points": self.beyond_wrist_points,
            "wrist_plane": None if self.wrist_plane is None else self.wrist_plane.to_dict(),
            "coverage": self.coverage,
            **({} if self.side_distances_mm is None
               else {"side_distances_mm": dict(self.side_distances_mm)}),
            **({} if self.try_distances_mm is None
               else {"try_distances_mm": list(self.try_distances_mm)}),
            **({} if self.viewpoint is None else {"viewpoint_estimate": {
                "position_m": [float(v) for v in self.viewpoint.position],
                "hidden_fraction": self.viewpoint.hidden_fraction,
                "one_view": self.viewpoint.one_view, "at_origin": self.viewpoint.at_origin,
                "num_points": self.viewpoint.num_points}}),
            **({} if self.support is None else {"support_plane": self.support.to_dict()}),
            **({} if self.others is None else {"others": self.others.to_dict()}),
        }


def _check_model(model) -> None:
    from ...model.trained import TrainedModel

    if not isinstance(model, TrainedModel):
        raise TypeError(f"model must be a lisa_hand.model.trained.TrainedModel, got "
                        f"{type(model).__name__}")


def _check_rest_joints(rest_joints) -> torch.Tensor | None:
    if rest_joints is None:
        return None
    rest_joints = torch.as_tensor(rest_joints)
    if rest_joints.shape != (NUM_JOINTS, 3) or not torch.isfinite(rest_joints).all():
        raise ValueError(f"rest_joints must be finite with shape [16, 3], got "
                         f"{list(rest_joints.shape)}")
    return rest_joints


def start_hand(model, cloud: TargetCloud, rest_joints: torch.Tensor | None):
    """(the template or None, the right hand at rest every candidate starts from: the fixed
    skeleton or the template's mean one, the mean shape and colour codes, on the cloud's
    device and dtype)."""
    like = dict(device=cloud.points.device, dtype=cloud.points.dtype)
    template = None
    betas = None
    if rest_joints is None:
        from ...handmodel.template import load_template

        template = load_template().to(**like)
        betas = torch.zeros(1, template.num_betas, **like)
        rest_joints = template.rest_joints(betas)[0]
        betas = betas[0]
    else:
        rest_joints = rest_joints.to(**like)
    shape_code = model.mean_shape_code().to(**like)
    color = model.mean_color_code()
    color = None if color is None else color.to(**like)
    hand = HandParams(pose=torch.zeros(POSE_DIM), translation=torch.zeros(3),
                      rest_joints=rest_joints.detach().cpu().float(),
                      shape_code=shape_code.cpu().float(),
                      color_code=None if color is None else color.cpu().float(),
                      betas=None if betas is None else betas.cpu().float(),
                      side="right", model=model.source)
    return template, hand, (rest_joints, shape_code, color)


def with_free_space(cloud: TargetCloud, viewpoint, side: str, config: FitPointsConfig
                    ) -> TargetCloud:
    """``cloud`` (of the right hand: a left one already mirrored) with the free space its
    sensor at ``viewpoint`` ([3] world metres, of the ``side`` hand's world) saw."""
    like = dict(device=cloud.points.device, dtype=cloud.points.dtype)
    view = torch.as_tensor(np.asarray(viewpoint, dtype=np.float64)).to(**like)
    if view.shape != (3,) or not bool(torch.isfinite(view).all()):
        raise ValueError(f"viewpoint must be 3 finite numbers (metres), got "
                         f"{list(view.shape)} values")
    if side == "left":
        view = mirror_cloud(view[None], side)[0]
    image = DepthImage(cloud.points, view)
    free = free_space_points(image, cloud.points, config.free_space_points, cloud.generator)
    return cloud.replace(free=free, depth=image)


def with_support(cloud: TargetCloud, plane, side: str, config: FitPointsConfig
                 ) -> TargetCloud:
    """``cloud`` (of the right hand: a left one already mirrored) resting on ``plane`` (a
    :class:`~lisa_hand.geometry.planes.Plane` of the ``side`` hand's world, its normal towards
    the hand): the plane for the proxy stages, and free points just beyond it under the hand
    (:func:`.support.support_points`) added to the cloud's own for the surface stage."""
    if side == "left":
        mirrored = mirror_cloud(torch.as_tensor(np.stack([plane.point, plane.normal])), side)
        plane = Plane(mirrored[0].numpy(), mirrored[1].numpy())
    beyond = support_points(plane, cloud.points, config.free_space_points, cloud.generator)
    free = beyond if cloud.free is None else torch.cat([cloud.free, beyond])
    bound = torch.as_tensor(np.stack([plane.point, plane.normal])).to(cloud.points)
    return cloud.replace(free=free, support=bound)


def _free_near(cloud: TargetCloud, proxy, config: FitPointsConfig
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


def _clip_cloud(cloud: TargetCloud, hand: HandParams, offset: float | None, min_points: int
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


def _with_coupling(cloud: TargetCloud, proxy, hand: HandParams, config: FitPointsConfig,
                   notes: list[str]) -> TargetCloud:
    """``cloud`` with the weights of the fingers its sensor could not see on ``hand``
    (:func:`.proxy.unseen_fingers`; none without a sensor position or with
    ``coupling_weight`` and ``unseen_thumb_weight`` 0), named in ``notes``."""
    from ..priors import UNSEEN_FINGERS

    if cloud.depth is None or (config.coupling_weight <= 0 and config.unseen_thumb_weight <= 0):
        return cloud
    coupling = unseen_fingers(proxy, cloud, hand, config.unseen_share)
    unseen = [f"{name} {float(w):.2f}" for name, w in zip(UNSEEN_FINGERS, coupling,
                                                           strict=True) if float(w) > 0]
    notes.append(f"unseen fingers: {', '.join(unseen) or 'none'}")
    return cloud.replace(coupling=coupling)


_SPARSE_COVER = 2.0
"""A sparse cloud counts a proxy point as covered within this many times its point spacing
(:func:`_covered_distance`)."""


def _covered_distance(cloud: TargetCloud, config: FitPointsConfig) -> float:
    """How near the scan a proxy point must be to count as covered, metres:
    ``config.covered_mm``, or twice the cloud's median point spacing ``s`` where that is larger
    (a sparse cloud, such as a mesh's vertices some millimetres apart, would otherwise cover a
    full hand no more than one view of it does). Points scattered at random with median
    nearest-neighbour distance ``s`` leave ``2^-(r/s)^2`` of the surface farther than ``r`` from
    all of them: 6% at ``r = 2 s``, 21% at 1.5 s."""
    return max(config.covered_mm * _MM, _SPARSE_COVER * point_spacing(cloud.points))


def _cut_offset(hand: HandParams, cloud: TargetCloud, clip: float | None) -> float | None:
    """Where the fitted hand ends, metres beyond its wrist joint: ``clip``, or sooner where the
    scan itself stops (the 99.9th percentile of its points' distance beyond the joint, towards
    the forearm); None without a cut."""
    if clip is None:
        return None
    beyond = -wrist_plane(hand, 0.0).signed_distance(cloud.points.detach().cpu().double().numpy())
    return float(min(clip, np.quantile(beyond, 0.999)))


def _run_stages(model, cloud: TargetCloud, config: FitPointsConfig, rest_joints, monitor
                ) -> tuple[HandParams, dict[str, StageReport], TargetCloud, float]:
    """The three stages on a right hand's cloud -> (hand, {stage: its report}, the cloud the
    last stage fitted: without what lies beyond the wrist, ``config.wrist_clip_m``; the scan's
    coverage of the hand, :attr:`FitResult.coverage`)."""
    since = monitor.start
    template, start, (rest, shape_code, color) = start_hand(model, cloud, rest_joints)
    proxy = build_surface_proxy(model, rest, shape_code, color, config.proxy_points,
                                cloud.generator)
    clip = config.wrist_clip_m
    if clip is not None:
        proxy = proxy.without_forearm(clip)
    since = monitor.lap("proxy", since)
    reports = {}
    candidates, reports["align"] = search_global_pose(proxy, cloud, config, start,
                                                      monitor=monitor)
    since = monitor.lap("align", since)
    loose = _clip_cloud(cloud, candidates[0], None if clip is None else
                        clip + config.wrist_margin_m, config.min_points)
    candidates, reports["pose"] = fit_proxy_pose(proxy, loose, candidates, config,
                                                 monitor=monitor)
    since = monitor.lap("pose", since)
    sized, candidates, reports["size"] = search_size(proxy, loose, candidates, template, config,
                                                     monitor=monitor)
    if sized is not proxy and clip is not None:  # a larger proxy's stub reaches past the cut
        sized = sized.without_forearm(clip)
    proxy = sized
    loose = _with_coupling(loose, proxy, candidates[0], config, reports["pose"].notes)
    since = monitor.lap("size", since)
    candidates, reports["fingers"] = restart_fingers(proxy, loose, candidates, config,
                                                     monitor=monitor)
    since = monitor.lap("fingers", since)
    near = _clip_cloud(loose, candidates[0], clip, config.min_points)
    cover = _covered_distance(near, config)
    covered = covered_fraction(proxy, near, candidates[0], cover)
    if covered >= config.covered_fraction:  # a scan from all sides: the data sets the shape
        config = dataclasses.replace(config, shape_weight=config.covered_shape_weight)
    hand, reports["field"] = fit_surface(model, loose, candidates, config, template=template,
                                         pivot=proxy.pivot, monitor=monitor,
                                         free_near=_free_near(loose, proxy, config))
    reports["field"].notes.append(f"scan covers {covered:.0%} of the hand within "
                                  f"{cover / _MM:.3g} mm: shape prior "
                                  f"{config.shape_weight:g}")
    since = monitor.lap("field", since)
    if config.second_pass_iters > 0:
        hand, reports["second"] = second_finger_pass(model, loose, hand, config,
                                                     reports["field"].loss, template=template,
                                                     monitor=monitor)
        monitor.lap("second", since)
    cloud = _clip_cloud(loose, hand, clip, config.min_points)
    return hand, reports, cloud, covered


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
    cloud = _with_coupling(cloud, proxy, hand, config, notes)  # unseen where this hand is
    moved, fingers = restart_fingers(proxy, _clip_cloud(cloud, hand, config.wrist_clip_m,
                                                        config.min_points),
                                     [hand], config, monitor=monitor,
                                     moved_base=cloud.depth is not None)
    notes = list(fingers.notes) + notes
    loss = energy
    if moved[0] is not hand:
        iters = dataclasses.replace(config, field_iters=config.second_pass_iters)
        hand, field = fit_surface(model, cloud, [moved[0], hand], iters, template=template,
                                  pivot=proxy.pivot, monitor=monitor,
                                  free_near=_free_near(cloud, proxy, config))
        loss = field.loss
    history = monitor.history[began:] if monitor is not None else []
    return hand, StageReport(stage="second", seconds=time.perf_counter() - start, loss=loss,
                             history=history, notes=notes)


def fit_points(
    model,
    points: np.ndarray | torch.Tensor,
    normals: np.ndarray | torch.Tensor | None = None,
    config: FitPointsConfig | None = None,
    *,
    rest_joints: torch.Tensor | None = None,
    side: str = "right",
    viewpoint: np.ndarray | torch.Tensor | str | None = None,
    support: str | None = None,
    others: str | None = None,
    progress: bool = False,
    callback: Callable[[FitStep], None] | None = None,
) -> FitResult:
    """Fit a trained LISA model to a point cloud of one hand (see the module docstring).

    model: a :class:`lisa_hand.model.trained.TrainedModel`.
    points: [N, 3] world metres, finite (:func:`lisa_hand.fitting.points.inputs.prepare_point_cloud`
        checks files and converts units). Any position and orientation; partial is fine.
    normals: [N, 3] outward normals or None; they add the offset-point term.
    config: :class:`FitPointsConfig` (defaults when None).
    rest_joints: [16, 3] metres, a fixed skeleton (of the ``side`` hand); None: the template's
        (:func:`lisa_hand.handmodel.template.load_template`), whose betas are fitted.
    side: 'right' or 'left': the hand the cloud shows (a left one is fitted mirrored); 'auto':
        both fitted, the nearer one kept (:func:`.hypotheses.best_of`; side by side in two
        threads). ``config.tries`` fits of each side from consecutive seeds, the same way.
    viewpoint: [3] world metres, the sensor position of a one-view scan (a depth camera's
        points in its own frame: the origin), or None; with it the proxy and surface stages keep
        the hand out of what the sensor saw to be empty (:mod:`.free_space`,
        ``config.free_space_weight``). Leave it None for a scan merged from several views.
        "auto": found from the points (:func:`.viewpoint.estimate_viewpoint`) and used when
        they look like one view (``FitResult.viewpoint`` says what was found).
    support: "auto": a surface the hand rests on (a desk in a depth camera's view) is looked
        for (:func:`.support.find_support`); when found its points are left out and the hand
        kept on its side (``config.support_weight``; ``FitResult.support``); "auto" viewpoints
        are looked for with its points (the whole view). None: every point is the hand's.
    others: "auto": pieces of the scan well apart from the hand (another object, the other
        hand; :func:`.others.find_others`) are left out (``FitResult.others``), after the
        support's points; when the scan is larger than a hand (a person) and the viewpoint is
        known, only the part nearest the sensor is kept (:func:`.others.nearest_part`);
        None: kept.
    progress: show a progress bar. callback: called with a :class:`FitStep` after every
        iteration (for benchmarks and logging; its hands are of ``side``).
    -> :class:`FitResult`. Runs on ``config.device`` (default: the model's), in the model's dtype.
    """
    config = FitPointsConfig() if config is None else config
    if not isinstance(config, FitPointsConfig):
        raise TypeError(f"config must be a FitPointsConfig, got {type(config).__name__}")
    _check_model(model)
    rest_joints = _check_rest_joints(rest_joints)
    device = torch.device(config.device) if config.device is not None else model.device
    if device != model.device:
        model = model.to(device)
    for name, value in (("support", support), ("others", others)):
        if value not in (None, "auto"):
            raise ValueError(f"{name} must be 'auto' or None, got {value!r}")
    if isinstance(viewpoint, str) and viewpoint != "auto":
        raise ValueError(f"viewpoint must be 3 numbers (metres), 'auto' or None, got "
                         f"{viewpoint!r}")
    found = None if support is None else find_support(points, seed=config.seed)
    estimate = None
    if isinstance(viewpoint, str):  # "auto", with the support's points: the whole view,
        # and on the hand's side of the support (the sensor saw its top)
        estimate = estimate_viewpoint(points, seed=config.seed,
                                      side=None if found is None else found.plane.normal)
        viewpoint = estimate.position if estimate.one_view else None
    if found is not None:
        points, normals = _kept(points, ~found.removed), _kept(normals, ~found.removed)
    apart = None if others is None else find_others(
        points, sensor=None if viewpoint is None else _as_numpy(viewpoint))
    if apart is not None and apart.removed.any():
        points, normals = _kept(points, ~apart.removed), _kept(normals, ~apart.removed)

    def fit_one(one_side: str, one_config: FitPointsConfig, bar) -> FitResult:
        return _fit_side(model, points, normals, one_config, rest_joints=rest_joints,
                         side=one_side, viewpoint=viewpoint, progress=progress,
                         callback=callback, bar=bar, support=found)

    sides = ("right", "left") if side == "auto" else (check_side(side),)
    result = best_of(fit_one, model, points, config, sides)
    result.viewpoint, result.support, result.others = estimate, found, apart
    result.params.extra["fit"] = result.summary()
    return result


def _as_numpy(values) -> np.ndarray:
    """numpy float64 of a tensor (any device) or a sequence."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu()
    return np.asarray(values, np.float64)


def _kept(values, keep: np.ndarray):
    """The rows ``keep`` ([N] bool) of points or normals (numpy, or torch on any device), or
    None."""
    if values is None or not isinstance(values, torch.Tensor):
        return None if values is None else np.asarray(values)[keep]
    return values[torch.as_tensor(keep, device=values.device)]


def _fit_side(model, points, normals, config: FitPointsConfig, *, rest_joints, side: str,
              viewpoint, progress: bool, callback, bar: tuple[str, int | None] = ("fit", None),
              support=None) -> FitResult:
    """:func:`fit_points` of one side, its arguments checked (the model on its device); bar:
    the progress bar's label and line (None: tqdm's choice)."""
    device = model.device
    cloud = target_cloud(points, normals, dtype=model.field.dtype, device=device,
                         min_points=config.min_points, max_points=config.max_points,
                         seed=config.seed)
    if side == "left":
        cloud = TargetCloud(mirror_cloud(cloud.points, side), None if cloud.normals is None
                            else mirror_cloud(cloud.normals, side), cloud.generator)
        rest_joints = None if rest_joints is None else mirror_cloud(rest_joints, side)
        callback = _left_callback(callback)
    if viewpoint is not None and config.free_space_weight > 0:
        cloud = with_free_space(cloud, viewpoint, side, config)
    if support is not None and config.support_weight > 0:
        cloud = with_support(cloud, support.plane, side, config)
    total = config.align_iters + config.pose_iters + config.finger_iters + config.field_iters
    if len(config.sizes) > 1 and rest_joints is None and config.fit_betas:
        total += len(config.sizes) * config.size_iters
    if config.second_pass_iters > 0:  # at most: its field steps run when a finger changed
        total += config.finger_iters + config.second_pass_iters
    monitor = FitMonitor(progress_total=total if progress else None, callback=callback,
                         bar=bar)
    threads = config.num_threads if device.type == "cpu" else None
    try:
        with cpu_threads(threads), frozen_field(model):
            total_points = cloud.num_points
            hand, reports, cloud, covered = _run_stages(model, cloud, config, rest_joints,
                                                        monitor)
            cut = _cut_offset(hand, cloud, config.wrist_clip_m)
            since = time.perf_counter()
            residual = surface_residuals(model, hand, cloud.points)
            monitor.lap("finish", since)
    finally:
        monitor.close()
    params = mirror_hand(hand) if side == "left" else hand
    result = FitResult(
        params=params,
        energy=list(reports.values())[-1].loss,
        residual_median_mm=float(residual.median()) / _MM,
        residual_mean_mm=float(residual.mean()) / _MM,
        inlier_fraction=float((residual < 3.0 * config.robust_scale_mm * _MM).float().mean()),
        seconds=time.perf_counter() - monitor.start,
        stage_seconds=monitor.stage_seconds,
        num_points=cloud.num_points,
        beyond_wrist_points=total_points - cloud.num_points,
        wrist_plane=None if cut is None else wrist_plane(params, cut),
        candidate_energies=reports["align"].screened_energies,
        history=monitor.history,
        reports=reports,
        coverage=covered,
    )
    params.extra["fit"] = result.summary()
    return result


def _left_callback(callback: Callable[[FitStep], None] | None
                   ) -> Callable[[FitStep], None] | None:
    """The callback of a left hand's fit: its steps' hands mirrored back to the left."""
    if callback is None:
        return None

    def forward(step: FitStep) -> None:
        right = step.params
        callback(dataclasses.replace(step, _make_params=lambda: mirror_hand(right())))

    return forward
