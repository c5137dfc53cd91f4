"""Fit LISA to one or more calibrated views (paper Section 4.3): :func:`fit_images` runs the
stages ``FitImagesConfig.stages`` names (:data:`STAGES`, each ``stage(state, fit) -> (state,
report)`` as every fitter's: :mod:`lisa_hand.fitting.stages`).

Unknowns: the 48-D pose (global rotation and 15 finger joints, axis-angle), the translation,
the mesh template's shape coefficients ``betas`` (LISA's skeleton is
``template.rest_joints(betas)``, as in training), the shape code ``beta+`` and the colour code
``gamma`` (both start at the mean of the training subjects' codes). The stages:

1. global-pose search and keypoint stage (:mod:`lisa_hand.fitting.images.pose_search`,
   :func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`): pose, translation and betas from
   the 2D keypoints and the masks, on the mesh template;
2. colour stage (:func:`lisa_hand.fitting.images.color_stage.fit_color`): pose, betas, shape and
   colour codes by volume rendering LISA (L_col, Eq. 13; L_reg, Eq. 16; the joint loss), the
   shape code kept in the training subjects' shape space
   (:class:`lisa_hand.fitting.images.shape_prior.ShapeSpace`);
3. the surface guard ('guard', :mod:`lisa_hand.fitting.images.guard`, ``config.guard``): the colour
   stage's hand and its start (the keypoint stage's pose and skeleton, the mean shape code) are
   meshed at ``guard_resolution``; a result with floating pieces the start does not have, or an
   area more than ``max_area_change`` away, is replaced by the first that passes of: the result
   with its change of pose and shape shrunk to ``guard_shrink`` (50 %, 25 %; meshing only),
   a second colour fit with the shape code and the skeleton fixed (pose and colour
   only), the start's geometry with that fit's colour. The verdict is
   :attr:`FitImagesResult.guard` and ``params.extra["guard"]``; a fallback is said in
   :attr:`FitImagesResult.notes`.

The input views and their fallbacks (no keypoints, no mask, keypoints outside the image) are
described in :mod:`lisa_hand.fitting.images.views`; settings in
:class:`lisa_hand.fitting.images.config.FitImagesConfig`. LISA and the template are right
hands: a left hand (``side='left'``) is fitted as the right hand of the mirrored views
(:func:`lisa_hand.fitting.images.views.mirror_view`) and mirrored back. From a frame folder to files
on disk: :func:`lisa_hand.fitting.images.folder.fit_image_folder` (``lisa fit-images``).

Self-consistency (views rendered from a small random LISA model at a known pose and codes,
4 views of 96 x 72, noiseless keypoints; defaults, 1 CPU thread): the keypoint stage reaches
0.02 px keypoint error (rotation 0.03 deg, translation 0.06 mm) in ~6 s; the colour stage keeps
it below 0.05 px, lowers the colour loss to near its floor and gives 45 dB PSNR inside the
masks. One view: the rotation within ~4 deg, the depth within ~1 cm (a single view barely
constrains it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from ...inference.mesh import mirror_mesh
from ...skeleton.params import HandParams
from ...utils.device import resolve_device
from ...utils.threads import cpu_threads
from ..sides import mirror_hand
from ..stages import HistoryRecord, StageReport, run_stages, template_on
from .color_stage import fit_color, with_mean_codes
from .config import FitImagesConfig
from .guard import GuardReport, guard_mesh, surface_guard
from .keypoint_stage import fit_keypoints, keypoint_errors, mean_keypoint_error
from .views import ImageView, check_moments, check_views, mirror_view

__all__ = ["FitImagesResult", "fit_images"]


@dataclass
class FitImagesResult:
    """Result of :func:`fit_images`.

    params: the fitted hand (pose, translation, rest joints, betas, codes, side); ``extra``
        holds the stage timings and errors.
    reports: the :class:`lisa_hand.fitting.stages.StageReport` of each stage that ran, by
        name ("keypoints", "color", "guard"; "color_fixed_shape" when the guard refitted).
    history: the stages' per-iteration records in order (the keypoint stage's, then the colour
        stage's; each names its ``"stage"``; keys in
        :class:`lisa_hand.fitting.stages.StageReport`; columns:
        :func:`lisa_hand.fitting.stages.history_columns`).
    seconds: wall time of the whole fit; stage_seconds: {"keypoints", "color"} (the colour
        stage's includes the guard and any fallback).
    keypoint_error_px: mean keypoint reprojection error after each stage ({"keypoints": over
        all visible keypoints, "color": the mean of the views' means}; NaN without keypoints).
    guard: the surface guard's report on the returned hand
        (:class:`lisa_hand.fitting.images.guard.GuardReport`), None when it did not run
        (``color_iters == 0``: the geometry is the keypoint stage's; ``config.guard`` off).
    guard_attempts: the guard's report on each hand it judged, in order ("color"; after a
        failure "shrink_0.5", "shrink_0.25": the change of pose and shape shrunk; "fixed_shape": the
        refit with the shape code and skeleton fixed).
    notes: sentences for the user: a failed guard and the fallback used, the guard turned off.
    start: the hand the colour stage started from, the guard's reference (the keypoint stage's
        pose, translation and betas with the model's mean codes; ``side`` as ``params``).
    surface_meshes: the guard's meshes, geometry only (:func:`guard_mesh` at
        ``surface_resolution`` samples a side, world frame, ``side`` as ``params``): "start"
        (of ``start``) and "returned" (of ``params``), for writers that mesh the same hands at
        the same resolution (:func:`lisa_hand.fitting.images.folder.fitted_mesh`); empty when
        the guard did not run.
    surface_resolution: the resolution of ``surface_meshes`` (None: empty).
    """

    params: HandParams
    reports: dict[str, StageReport]
    history: list[HistoryRecord]
    seconds: float
    stage_seconds: dict[str, float]
    keypoint_error_px: dict[str, float]
    guard: GuardReport | None = None
    guard_attempts: dict[str, GuardReport] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    start: HandParams | None = None
    surface_meshes: dict[str, Any] = field(default_factory=dict)
    surface_resolution: int | None = None


def _moment_hands(fit: ImageFit) -> tuple[list[HandParams], StageReport]:
    """The keypoint stage of each moment (:func:`_keypoint_hand` on its views) -> (the right
    hands, with one skeleton: the moments' mean betas; the first moment's report, its
    keypoint error over every view)."""
    starts = fit.start if isinstance(fit.start, list) else [fit.start]
    hands, reports = [], []
    for moment, start in enumerate(starts):
        hand, report = _keypoint_hand(_moment_views(fit, moment), fit.config, fit.template,
                                      fit.progress, start, fit.side)
        hands.append(hand)
        reports.append(report)
    if len(hands) == 1:
        return hands, reports[0]
    betas = torch.stack([hand.betas for hand in hands]).mean(0)
    with torch.no_grad():
        rest_joints = fit.template.rest_joints(betas[None])[0]
    hands = [replace(hand, betas=betas, rest_joints=rest_joints) for hand in hands]
    errors = [error for moment, hand in enumerate(hands)
              for error in keypoint_errors(fit.template, _moment_views(fit, moment),
                                           hand).values()]
    report = replace(reports[0], keypoint_error_px=float(np.mean(errors)) if errors
                     else math.nan)
    return hands, report


def _moment_views(fit: ImageFit, moment: int) -> list[ImageView]:
    """The views of ``moment`` (:attr:`ImageFit.moments`)."""
    return [view for view, m in zip(fit.views, fit.moments, strict=True) if m == moment]


def _keypoint_hand(views: list[ImageView], config: FitImagesConfig, template: Any,
                   progress: bool, start: HandParams | None, side: str
                   ) -> tuple[HandParams, StageReport]:
    """The keypoint stage's right hand: fitted, or ``start`` (in the views' world) reused."""
    if start is None:
        return fit_keypoints(views, config, template, progress)
    if not isinstance(start, HandParams):
        raise TypeError(f"start must be a HandParams, got {type(start).__name__}")
    if start.side != side:
        raise ValueError(f"start is a {start.side} hand but side is {side!r}")
    if start.betas is None:
        raise ValueError("start.betas is None: start from a keypoint-stage hand "
                         "(lisa_hand.fitting.images.keypoint_stage.fit_keypoints)")
    hand = mirror_hand(start) if side == "left" else start
    return hand, StageReport(stage="keypoints",
                             keypoint_error_px=mean_keypoint_error(template, views, hand))


def _model_on(model: Any, config: FitImagesConfig) -> tuple[Any, torch.device]:
    """The model on ``config.device`` (default: its own device)."""
    device = model.device if config.device is None else resolve_device(config.device)
    return (model if device == model.device else model.to(device)), device


def fit_images(
    model: Any,
    views: Sequence[ImageView],
    config: FitImagesConfig | None = None,
    progress: bool = False,
    *,
    side: str = "right",
    template: Any = None,
    start: HandParams | Sequence[HandParams] | None = None,
    moments: Sequence[int] | None = None,
) -> FitImagesResult:
    """Fit LISA to calibrated views: the keypoint stage then the colour stage (see the module
    docstring).

    model: a :class:`lisa_hand.model.trained.TrainedModel` with colour (a geometry-only model
        needs ``color_iters=0``); moved to ``config.device`` when that is set (its field module
        in place), else the fit runs on its device. The views are moved there.
    views: from :func:`lisa_hand.fitting.images.views.read_views`.
    config: :class:`FitImagesConfig` (default: the CPU-friendly defaults).
    progress: show a progress bar per stage.
    side: "right" or "left": the hand the views show.
    template: the mesh template (default: :func:`lisa_hand.handmodel.template.load_template`).
    start: a keypoint-stage hand of these views (:func:`fit_keypoints`, which depends on the
        views and the template only; a left hand's mirrored back, ``start.side == side``) to
        skip that stage and reuse it, e.g. for several models. Its pose, translation and betas
        are used; the codes start from the model's mean. With ``moments``: one a moment, or
        None.
    moments: the moment each view shows (:func:`~lisa_hand.fitting.images.views.check_moments`;
        None: one, every view at one pose). Views of several moments (a video's keyframes)
        share the shape code, skeleton and colour code and have a pose and translation a
        moment: the keypoint stage runs on each moment's views (the skeleton is the mean of
        their betas), the colour stage on all views at once; the returned hand, the guard and
        the per-view keypoint errors are the first moment's.
    -> :class:`FitImagesResult`; ``params.model`` is ``model.source``, ``params.side`` is
    ``side``.
    """
    config = FitImagesConfig() if config is None else config
    if not isinstance(config, FitImagesConfig):
        raise TypeError(f"config must be a FitImagesConfig, got {type(config).__name__}")
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    views = check_views(views)
    moments = check_moments(moments, len(views))
    start = _starts(start, max(moments) + 1)
    if config.color_iters > 0 and not model.has_color:
        raise ValueError(f"model {model.source}: it has no colour (a geometry-only prior); "
                         "fitting to images needs a model trained on images (lisa train), or "
                         "color_iters=0")
    model, device = _model_on(model, config)
    views = [view.to(device) for view in views]
    if side == "left":
        views = [mirror_view(view) for view in views]
    fit = ImageFit(model=model, views=views, config=config,
                   template=template_on(template, device), progress=progress, side=side,
                   start=start, moments=moments)
    start_time = time.perf_counter()
    laps: dict[str, float] = {}
    with cpu_threads(config.num_threads):
        state, reports = run_stages(STAGES, _order(config), ImageState(), fit,
                                    lambda name, since: laps.setdefault(
                                        name, time.perf_counter() - since))
    seconds = time.perf_counter() - start_time
    guarded = state.guarded
    if guarded.fixed_shape is not None:
        reports["color_fixed_shape"] = guarded.fixed_shape
    return _result(guarded, reports, _moment_views(fit, 0), fit.template, config, seconds,
                   laps.get("keypoints", 0.0), side)


def _starts(start: Any, num_moments: int) -> HandParams | list[HandParams | None] | None:
    """``start`` of :func:`fit_images` checked against the number of moments: as given for
    one, a list of one (or None) a moment for several."""
    if num_moments == 1:
        if isinstance(start, list | tuple):
            raise ValueError(f"start holds {len(start)} hands, but the views show one moment")
        return start
    if start is None:
        return [None] * num_moments
    if not isinstance(start, list | tuple) or len(start) != num_moments:
        raise ValueError(f"start must hold one hand a moment ({num_moments})")
    return list(start)


@dataclass
class _Guarded:
    """The hand the fit returns and what the guard said about it."""

    hand: HandParams
    start: HandParams | None = None
    guard: GuardReport | None = None
    attempts: dict[str, GuardReport] = field(default_factory=dict)
    fallback: str = "none"
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    meshes: dict[str, Any] = field(default_factory=dict)
    """{"start", "returned"}: the guard's meshes of ``start`` and ``hand`` (the fit's frame)."""
    fixed_shape: StageReport | None = None
    """The report of the refit with the shape code and skeleton fixed, when the guard ran it."""


@dataclass(frozen=True)
class ImageFit:
    """What stays fixed through one image fit: the model, the (right hand's) views, the
    settings, the template, whether to show progress, the side, a keypoint-stage hand to
    reuse (``start`` of :func:`fit_images`) or None."""

    model: Any
    views: list[ImageView]
    config: FitImagesConfig
    template: Any
    progress: bool
    side: str
    start: HandParams | list[HandParams | None] | None = None
    moments: tuple[int, ...] = ()
    """Each view's moment (:func:`fit_images`); ``start`` a list then, one a moment."""


@dataclass(frozen=True)
class ImageState:
    """What one image-fit stage hands the next: ``guarded``, the hand so far with what the
    guard said of it (None before 'keypoints'); ``fitted``, the colour stage's hand
    before the guard judged it (None before 'color'); ``others``: the keypoint stage's hands of
    the further moments (:attr:`ImageFit.moments`; empty for one)."""

    guarded: _Guarded | None = None
    fitted: HandParams | None = None
    others: tuple[HandParams, ...] = ()


def keypoints(state: ImageState, fit: ImageFit) -> tuple[ImageState, StageReport]:
    """'keypoints': the template's pose, translation and betas from the 2D keypoints and the
    masks (or ``fit.start`` reused), with the model's mean codes."""
    hands, report = _moment_hands(fit)
    hand, *others = (with_mean_codes(one, fit.model) for one in hands)
    return replace(state, guarded=_Guarded(hand, start=hand), others=tuple(others)), report


def color(state: ImageState, fit: ImageFit) -> tuple[ImageState, StageReport]:
    """'color': pose, shape and colour codes on the LISA field by volume rendering."""
    fitted, report = fit_color(fit.model, fit.views, [state.guarded.hand, *state.others],
                               fit.config, fit.template, fit.progress, moments=fit.moments)
    return replace(state, guarded=_Guarded(fitted, start=state.guarded.start),
                   fitted=fitted), report


def guard(state: ImageState, fit: ImageFit) -> tuple[ImageState, StageReport]:
    """'guard': the colour stage's surface judged against its start, and replaced when it
    fails (:func:`_guard`)."""
    guarded = _guard(fit, state.guarded.start, state.fitted, state.others)
    return replace(state, guarded=guarded), StageReport(
        stage="guard", seconds=guarded.seconds, notes=list(guarded.notes),
        loss=math.nan if guarded.guard is None else guarded.guard.area_ratio)


STAGES = {"keypoints": keypoints, "color": color, "guard": guard}
"""The image fit's stages by name (``FitImagesConfig.stages``)."""


def _order(config: FitImagesConfig) -> tuple[str, ...]:
    """The stages that run: ``config.stages``; without 'color' and 'guard' when
    ``color_iters`` is 0 (the keypoint stage's geometry is the result)."""
    if config.color_iters > 0:
        return config.stages
    return tuple(name for name in config.stages if name == "keypoints")


def _guard(fit: ImageFit, start: HandParams, fitted: HandParams,
           others: Sequence[HandParams] = ()) -> _Guarded:
    """The surface guard after the colour stage (:attr:`FitImagesConfig.guard`), in order: the
    fitted hand; the fitted hand with its change of pose and shape shrunk to each fraction of
    ``config.guard_shrink`` (:func:`_shrunk`, colour kept); the colour stage again with the
    shape code and the skeleton fixed at the start (pose and colour only,
    :attr:`_Guarded.fixed_shape`); the start's geometry with that fit's colour code. The
    first that passes is returned. ``others``: the further moments' start hands (the
    refit's)."""
    model, config, template = fit.model, fit.config, fit.template
    if not config.guard:
        return _Guarded(fitted, start=start, notes=["the surface guard is off (guard=False): "
                                                    "the colour stage's surface was not "
                                                    "checked"])
    began = time.perf_counter()
    resolution, change = config.guard_resolution, config.max_area_change

    meshes: dict[str, Any] = {}

    def judge(name: str, hand: HandParams) -> GuardReport:
        meshes[name] = guard_mesh(model, hand, resolution)
        return surface_guard(reference, meshes[name], change)

    reference = guard_mesh(model, start, resolution)
    first = judge("color", fitted)
    result = _Guarded(fitted, start=start, guard=first, attempts={"color": first})
    why = "; ".join(note for note in first.notes[1:] if " speck(s) below " not in note)
    failed = f"the colour stage failed the surface guard ({why})"
    for fraction in () if first.passed else config.guard_shrink:
        shrunk = _shrunk(template, start, fitted, fraction)
        name = f"shrink_{fraction:g}"
        report = result.attempts[name] = judge(name, shrunk)
        if report.passed:
            result.hand, result.guard, result.fallback = shrunk, report, f"shrink_{fraction:g}"
            result.notes.append(f"{failed}: its change of pose and shape was shrunk to "
                                f"{100 * fraction:g} %, which passed")
            break
    if not result.guard.passed:
        fallback, result.fixed_shape = _fixed_shape_fit(fit, [start, *others])
        second = result.attempts["fixed_shape"] = judge("fixed_shape", fallback)
        if second.passed:
            result.hand, result.guard, result.fallback = fallback, second, "fixed_shape"
            result.notes.append(f"{failed}: fitted again with the shape code and skeleton "
                                "fixed (pose and colour only), which passed")
        else:
            result.hand = replace(start, color_code=fallback.color_code,
                                  extra=_calibration_extra(fallback))
            result.guard = surface_guard(reference, reference, change)
            result.fallback = "start_geometry"
            meshes["start_geometry"] = reference
            result.notes.append(f"{failed}, and so did a fit of pose and colour only: the "
                                "keypoint stage's geometry is kept, with that fit's colour")
            if not result.guard.passed:
                result.notes.append("the returned hand fails the surface guard too ("
                                    + "; ".join(result.guard.notes) + ")")
    chosen = "color" if result.fallback == "none" else result.fallback
    result.meshes = {"start": reference, "returned": meshes[chosen]}
    result.seconds = time.perf_counter() - began
    return result


def _shrunk(template: Any, start: HandParams, fitted: HandParams, fraction: float
            ) -> HandParams:
    """``fitted`` with its geometry moved back to ``fraction`` of its change from ``start``:
    pose (axis-angle, linearly: the colour stage moves it little), translation, shape code and
    betas (the skeleton follows them); the colour code kept. The floaters of a fit come from
    pose and shape together: on a real photo, shrinking either alone kept one, both to 50 %
    did not."""
    def between(begin: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
        begin = begin.to(end)
        return begin + fraction * (end - begin)

    betas = between(start.betas, fitted.betas)
    with torch.no_grad():
        rest_joints = template.rest_joints(betas[None].to(template.device,
                                                         template.dtype))[0].to(betas)
    return replace(fitted, pose=between(start.pose, fitted.pose),
                   translation=between(start.translation, fitted.translation),
                   shape_code=between(start.shape_code, fitted.shape_code), betas=betas,
                   rest_joints=rest_joints, extra=_calibration_extra(fitted))


def _calibration_extra(hand: HandParams) -> dict[str, Any]:
    """The part of a colour-stage hand's ``extra`` its colour code goes with: the input views'
    fitted responses (``"view_calibration"``, when the stage fitted them)."""
    if "view_calibration" not in hand.extra:
        return {}
    return {"view_calibration": hand.extra["view_calibration"]}


def _fixed_shape_fit(fit: ImageFit, starts: list[HandParams]
                     ) -> tuple[HandParams, StageReport]:
    """The colour stage with the shape code and skeleton fixed at the start's (``starts``: a
    hand a moment) -> (its hand, its report, named "color_fixed_shape", as are its history
    records)."""
    fixed = replace(fit.config, shape_fit="fixed", color_betas_lr=0.0)
    hand, report = fit_color(fit.model, fit.views, starts, fixed, fit.template, fit.progress,
                             moments=fit.moments)
    report.stage = "color_fixed_shape"
    for record in report.history:
        record["stage"] = "color_fixed_shape"
    return hand, report


def _result(guarded: _Guarded, reports: dict[str, StageReport], views: list[ImageView],
            template: Any, config: FitImagesConfig, seconds: float, stage1: float,
            side: str) -> FitImagesResult:
    """The result of :func:`fit_images`: errors, timings, the guard and the hand mirrored
    back."""
    hand = guarded.hand
    calibration = _calibration_extra(hand)
    history = [record for report in reports.values() for record in report.history]
    per_view = keypoint_errors(template, views, hand)
    errors = {"keypoints": reports["keypoints"].keypoint_error_px,
              "color": float(np.mean(list(per_view.values()))) if per_view else math.nan}
    hand.extra = {
        "fit": "images",
        "views": [view.name for view in views],
        "seconds": seconds,
        "seconds_keypoints": stage1,
        "seconds_color": seconds - stage1,
        "keypoint_iters": config.keypoint_iters,
        "color_iters": config.color_iters,
        "keypoint_error_px_stage1": errors["keypoints"],
        "keypoint_error_px": errors["color"],
        "keypoint_error_px_per_view": per_view,
        "restart": reports["keypoints"].candidate,
        "notes": list(guarded.notes),
        **calibration,
    }
    if guarded.guard is not None:
        hand.extra["guard"] = {**guarded.guard.to_dict(), "fallback": guarded.fallback,
                               "seconds": guarded.seconds,
                               "attempts": {name: report.to_dict() for name, report in
                                            guarded.attempts.items()}}
    start = replace(guarded.start, extra={})
    meshes = dict(guarded.meshes)
    if side == "left":
        hand, start = mirror_hand(hand), mirror_hand(start)
        meshes = {name: mirror_mesh(mesh) for name, mesh in meshes.items()}
    return FitImagesResult(params=hand, reports=reports, history=history, seconds=seconds,
                           stage_seconds={"keypoints": stage1, "color": seconds - stage1},
                           keypoint_error_px=errors, guard=guarded.guard,
                           guard_attempts=dict(guarded.attempts), notes=list(guarded.notes),
                           start=start, surface_meshes=meshes,
                           surface_resolution=config.guard_resolution if meshes else None)
