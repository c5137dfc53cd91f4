"""Fitting LISA to a point cloud (paper Section 4.3, "Reconstruction from point clouds").

The paper minimises ``sum_x |G(x, theta, beta+)| + ||beta+||`` over the pose ``theta`` and the
shape code ``beta+``. The hand in a scan can be anywhere, in any orientation and finger pose,
seen from one side, with noise and outliers, on a desk, beside other things. So
:func:`fit_points` first analyses the scan once (:func:`.analysis.analyse_scan`: the support
plane, the sensor position, the other pieces), then runs the stages ``FitPointsConfig.stages``
names (:mod:`.stages`: each ``stage(state, fit) -> (state, report)``): a global-pose search and
an articulated fit on a surface proxy of the model (no network), a size search and per-finger
restarts, then every unknown on the LISA field, and the fingers' second chance.

Each stage's energy is a robust data term (:func:`lisa_hand.fitting.robust.robust_loss`,
Geman-McClure by default; the paper's ``|r|`` with ``robust_loss="l1"``) plus the prior terms
every fitter shares (:func:`lisa_hand.fitting.terms.hand_prior`: finger pose, joint limits,
shape code, betas, and for one view the unseen fingers' coupling).

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
from ...utils.config import config_to_dict
from ...utils.threads import cpu_threads
from ..sides import mirror_cloud, mirror_hand
from ..stages import HistoryRecord, StageReport
from .analysis import ScanAnalysis, analyse_scan
from .cloud import TargetCloud, check_points, target_cloud
from .config import FitPointsConfig
from .free_space import DepthImage, free_space_points
from .hypotheses import best_of
from .monitor import FitMonitor, FitStep
from .others import Others
from .proxy import build_surface_proxy
from .stages import PointFit, PointState, clip_cloud, run_point_stages
from .support import Support, support_points
from .surface_stage import frozen_field, surface_residuals
from .viewpoint import ViewpointEstimate

__all__ = ["FitPointsConfig", "FitStep", "FitResult", "fit_points", "start_hand"]

_MM = 1e-3


@dataclass
class FitResult:
    """Result of :func:`fit_points`.

    params: the fitted hand (pose, translation, skeleton, betas, shape and colour codes, side);
        ``params.extra["fit"]`` holds the numbers below as JSON.
    energy: the field energy of the result over the evaluation subset of the cloud (after
        'field' and 'second').
    residual_median_mm, residual_mean_mm: median and mean ``|G(x)|`` over the whole cloud, mm.
    inlier_fraction: fraction of points with ``|G(x)| < 3 sigma`` (``sigma = robust_scale_mm``).
    seconds: wall time of the fit; stage_seconds: 'proxy' (building it), each stage that ran
        (:data:`.config.POINT_STAGES`), 'finish'.
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
    reports: the :class:`lisa_hand.fitting.stages.StageReport` of each stage that ran, by
        name (``config.stages``), as the image fit's ``reports``.
    coverage: share of the hand's surface (its proxy, after the finger restarts) within
        ``config.covered_mm`` of the scan (the 'coverage' stage): near 1 for a scan from all
        sides, about a half or less for one view; NaN when the stage did not run.
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
    analysis: ScanAnalysis | None = None
    """The scan's analysis (:mod:`.analysis`), with the coverage the 'coverage' stage found."""

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
            **({} if self.analysis is None else {"analysis": self.analysis.to_dict()}),
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


def _cut_offset(hand: HandParams, cloud: TargetCloud, clip: float | None) -> float | None:
    """Where the fitted hand ends, metres beyond its wrist joint: ``clip``, or sooner where the
    scan itself stops (the 99.9th percentile of its points' distance beyond the joint, towards
    the forearm); None without a cut."""
    if clip is None:
        return None
    beyond = -wrist_plane(hand, 0.0).signed_distance(cloud.points.detach().cpu().double().numpy())
    return float(min(clip, np.quantile(beyond, 0.999)))


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
    analysis: ScanAnalysis | None = None,
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
    viewpoint, support, others: what :func:`.analysis.analyse_scan` looks for, once, before the
        stages (with ``config.analysis`` and ``config.seed``). viewpoint: [3] world metres, the
        sensor position of a one-view scan (a depth camera's points in its own frame: the
        origin), or None (a scan merged from several views); with it the stages keep the hand
        out of what the sensor saw to be empty (:mod:`.free_space`, ``config.free_space_weight``);
        "auto": found from the points and used when they look like one view. support: "auto":
        a surface the hand rests on (a desk) is looked for, its points left out and the hand
        kept on its side (``config.support_weight``). others: "auto": pieces of the scan well
        apart from the hand (another object, the other hand) are left out; when the scan is
        larger than a hand and the sensor is known, only the part nearest it is kept.
    analysis: the scan's :class:`.analysis.ScanAnalysis` when already made (a command that
        chose its model from it); then ``viewpoint``, ``support`` and ``others`` must be left
        out.
    progress: show a progress bar. callback: called with a :class:`FitStep` after every
        iteration (for benchmarks and logging; its hands are of ``side``).
    -> :class:`FitResult` (its ``analysis``, with the coverage the stages found, is recorded in
    ``params.extra["fit"]["analysis"]``, the settings in ``params.extra["config"]``). Runs on
    ``config.device`` (default: the model's), in the model's dtype.
    """
    config = FitPointsConfig() if config is None else config
    if not isinstance(config, FitPointsConfig):
        raise TypeError(f"config must be a FitPointsConfig, got {type(config).__name__}")
    _check_model(model)
    rest_joints = _check_rest_joints(rest_joints)
    device = torch.device(config.device) if config.device is not None else model.device
    if device != model.device:
        model = model.to(device)
    check_points(points, config.min_points)  # one clear line for a bad cloud, first
    if analysis is None:
        analysis = analyse_scan(points, viewpoint=viewpoint, support=support, others=others,
                                config=config.analysis, seed=config.seed)
    elif not (viewpoint is None and support is None and others is None):
        raise ValueError("give either an analysis or viewpoint/support/others, not both")
    elif analysis.num_points != len(points):
        raise ValueError(f"the analysis is of {analysis.num_points} points, the cloud has "
                         f"{len(points)}")
    hand_points, hand_normals = analysis.hand(points), analysis.hand(normals)

    def fit_one(one_side: str, one_config: FitPointsConfig, bar) -> FitResult:
        return _fit_side(model, hand_points, hand_normals, one_config, rest_joints=rest_joints,
                         side=one_side, analysis=analysis, progress=progress,
                         callback=callback, bar=bar)

    sides = ("right", "left") if side == "auto" else (check_side(side),)
    result = best_of(fit_one, model, hand_points, config, sides)
    result.viewpoint, result.support, result.others = (analysis.viewpoint, analysis.support,
                                                       analysis.others)
    result.params.extra["fit"] = result.summary()
    result.params.extra["config"] = config_to_dict(config)
    return result


def _fit_side(model, points, normals, config: FitPointsConfig, *, rest_joints, side: str,
              analysis: ScanAnalysis, progress: bool, callback,
              bar: tuple[str, int | None] = ("fit", None)) -> FitResult:
    """:func:`fit_points` of one side on the hand's points of the ``analysis``, its arguments
    checked (the model on its device); bar: the progress bar's label and line (None: tqdm's
    choice)."""
    device = model.device
    cloud = target_cloud(points, normals, dtype=model.field.dtype, device=device,
                         min_points=config.min_points, max_points=config.max_points,
                         seed=config.seed)
    if side == "left":
        cloud = TargetCloud(mirror_cloud(cloud.points, side), None if cloud.normals is None
                            else mirror_cloud(cloud.normals, side), cloud.generator)
        rest_joints = None if rest_joints is None else mirror_cloud(rest_joints, side)
        callback = _left_callback(callback)
    if analysis.sensor is not None and config.free_space_weight > 0:
        cloud = with_free_space(cloud, analysis.sensor, side, config)
    if analysis.support is not None and config.support_weight > 0:
        cloud = with_support(cloud, analysis.support.plane, side, config)
    total = 0
    if "align" in config.stages:
        total += config.align_iters
    if "pose" in config.stages:
        total += config.pose_iters
    if "fingers" in config.stages:
        total += config.finger_iters
    total += config.field_iters
    if "size" in config.stages and len(config.sizes) > 1 and rest_joints is None \
            and config.fit_betas:
        total += len(config.sizes) * config.size_iters
    if "second" in config.stages and config.second_pass_iters > 0:  # at most: its field
        total += config.finger_iters + config.second_pass_iters  # steps run when a finger moved
    monitor = FitMonitor(progress_total=total if progress else None, callback=callback,
                         bar=bar)
    threads = config.num_threads if device.type == "cpu" else None
    try:
        with cpu_threads(threads), frozen_field(model):
            total_points = cloud.num_points
            since = monitor.start
            template, start, (rest, shape_code, color) = start_hand(model, cloud, rest_joints)
            proxy = build_surface_proxy(model, rest, shape_code, color, config.proxy_points,
                                        cloud.generator)
            if config.wrist_clip_m is not None:
                proxy = proxy.without_forearm(config.wrist_clip_m)
            monitor.lap("proxy", since)
            fit = PointFit(model=model, config=config, template=template, start=start,
                           monitor=monitor)
            state, reports = run_point_stages(PointState(cloud=cloud, proxy=proxy,
                                                   analysis=analysis), fit)
            hand = state.candidates[0]
            cloud = clip_cloud(state.cloud, hand, config.wrist_clip_m, config.min_points)
            cut = _cut_offset(hand, cloud, config.wrist_clip_m)
            since = time.perf_counter()
            residual = surface_residuals(model, hand, cloud.points)
            monitor.lap("finish", since)
    finally:
        monitor.close()
    params = mirror_hand(hand) if side == "left" else hand
    coverage = state.analysis.coverage
    result = FitResult(
        params=params,
        energy=state.energy,
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
        coverage=float("nan") if coverage is None else coverage,
        analysis=state.analysis,
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
