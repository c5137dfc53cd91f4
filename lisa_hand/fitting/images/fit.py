"""Fit LISA to one or more calibrated views (paper Section 4.3): :func:`fit_images` composes the
stages.

Unknowns: the 48-D pose (global rotation and 15 finger joints, axis-angle), the translation,
the mesh template's shape coefficients ``betas`` (LISA's skeleton is
``template.rest_joints(betas)``, as in training), the shape code ``beta+`` and the colour code
``gamma`` (both start at the mean of the training subjects' codes). Each stage takes and
returns a :class:`lisa_hand.skeleton.params.HandParams` and its
:class:`lisa_hand.fitting.stages.StageReport`:

1. global-pose search and keypoint stage (:mod:`lisa_hand.fitting.images.pose_search`,
   :func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`): pose, translation and betas from
   the 2D keypoints and the masks, on the mesh template;
2. colour stage (:func:`lisa_hand.fitting.images.color_stage.fit_color`): pose, betas, shape and
   colour codes by volume rendering LISA (L_col, Eq. 13; L_reg, Eq. 16; the joint loss).

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
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams
from ...utils.device import resolve_device
from ...utils.threads import cpu_threads
from ..sides import mirror_hand
from ..stages import HistoryRecord, StageReport, template_on
from .color_stage import fit_color, with_mean_codes
from .config import FitImagesConfig
from .keypoint_stage import fit_keypoints, keypoint_errors, mean_keypoint_error
from .views import ImageView, check_views, mirror_view

__all__ = ["FitImagesResult", "fit_images"]


@dataclass
class FitImagesResult:
    """Result of :func:`fit_images`.

    params: the fitted hand (pose, translation, rest joints, betas, codes, side); ``extra``
        holds the stage timings and errors.
    reports: the stages' :class:`lisa_hand.fitting.stages.StageReport` ({"keypoints"} and,
        when it ran, "color").
    history: the stages' per-iteration records in order (the keypoint stage's, then the colour
        stage's; each names its ``"stage"``; keys in
        :class:`lisa_hand.fitting.stages.StageReport`; columns:
        :func:`lisa_hand.fitting.stages.history_columns`).
    seconds: wall time of the whole fit; stage_seconds: {"keypoints", "color"}.
    keypoint_error_px: mean keypoint reprojection error after each stage ({"keypoints": over
        all visible keypoints, "color": the mean of the views' means}; NaN without keypoints).
    """

    params: HandParams
    reports: dict[str, StageReport]
    history: list[HistoryRecord]
    seconds: float
    stage_seconds: dict[str, float]
    keypoint_error_px: dict[str, float]


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
    start: HandParams | None = None,
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
        are used; the codes start from the model's mean.
    -> :class:`FitImagesResult`; ``params.model`` is ``model.source``, ``params.side`` is
    ``side``.
    """
    config = FitImagesConfig() if config is None else config
    if not isinstance(config, FitImagesConfig):
        raise TypeError(f"config must be a FitImagesConfig, got {type(config).__name__}")
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    views = check_views(views)
    if config.color_iters > 0 and not model.has_color:
        raise ValueError(f"model {model.source}: it has no colour (a geometry-only prior); "
                         "fitting to images needs a model trained on images (lisa train), or "
                         "color_iters=0")
    model, device = _model_on(model, config)
    views = [view.to(device) for view in views]
    if side == "left":
        views = [mirror_view(view) for view in views]
    template = template_on(template, device)
    start_time = time.perf_counter()
    with cpu_threads(config.num_threads):
        hand, report = _keypoint_hand(views, config, template, progress, start, side)
        stage1 = time.perf_counter() - start_time
        reports = {"keypoints": report}
        hand = with_mean_codes(hand, model)
        if config.color_iters > 0:
            hand, reports["color"] = fit_color(model, views, hand, config, template, progress)
    seconds = time.perf_counter() - start_time
    return _result(hand, reports, views, template, config, seconds, stage1, side)


def _result(hand: HandParams, reports: dict[str, StageReport], views: list[ImageView],
            template: Any, config: FitImagesConfig, seconds: float, stage1: float,
            side: str) -> FitImagesResult:
    """The result of :func:`fit_images`: errors, timings and the hand mirrored back."""
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
    }
    if side == "left":
        hand = mirror_hand(hand)
    return FitImagesResult(params=hand, reports=reports, history=history, seconds=seconds,
                           stage_seconds={"keypoints": stage1, "color": seconds - stage1},
                           keypoint_error_px=errors)
