"""The colour stage of the image fit (:func:`fit_color`; paper Section 4.3: 5k iterations):
pose, translation, LISA's shape code ``beta+`` and colour code ``gamma`` (and the template betas
when ``color_betas_lr > 0``; by default the skeleton stays the keypoint stage's) by volume
rendering.

Each iteration draws ``num_rays`` camera rays (:class:`RayPool`), ``mask_fraction`` of them
through the mask and a band of ``band_px`` pixels around it (a view without a mask: the box
around the projected template), renders them with VolSDF
(:func:`lisa_hand.render.render_rays`, the model's ``field_fn`` with bone culling and
``LaplaceDensity(model.beta)``), applies the colour calibration of each ray's view
(:func:`lisa_hand.render.renderer.calibrate`: the model's mean gain and bias, times the view's
fitted response, :class:`lisa_hand.fitting.images.calibration.ViewCalibration`, with
``view_calibration``) and minimises

    L = rgb_weight L_col + code_weight L_reg + joints_weight L_joints' + mask_weight L_mask
        + shape_weight L_shape + view_calibration_weight L_calibration

* ``L_col``: L1 colour loss of the rays (Eq. 13) against
  :func:`lisa_hand.fitting.images.views.fit_target` (black outside a mask).
* ``L_reg = |beta+|_2 + |gamma|_2`` (Eq. 16).
* ``L_joints'``: the keypoint stage's keypoint L1 (pixels) with its pose and shape priors (no
  silhouette terms: the geometry is now LISA's).
* ``L_mask`` (NOT in the paper; ``mask_weight = 0`` turns it off): binary cross-entropy between
  the rays' opacity and the mask.
* ``L_shape = 0.5 |c|^2`` (NOT in the paper): the shape code's coefficients ``c`` in the
  principal subspace of the training subjects' codes (:class:`ShapeCode`,
  ``shape_fit="space"``, the default), in standard deviations, clamped to the training codes'
  range along each direction. The paper's free code (``shape_fit="free"``) can leave the
  training codes' span on real photos and break the surface; ``shape_fit="fixed"`` keeps the
  start's code.
* ``L_calibration`` (NOT in the paper): the Gaussian prior of the views' responses, in standard
  deviations of the cameras' spread (:meth:`ViewCalibration.prior`; 0 without
  ``view_calibration``).

The network's weights stay fixed; the codes start from the ``start`` hand's (usually the mean
of the training subjects' codes, :func:`with_mean_codes`).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ...geometry.rays import ray_box_bounds
from ...model.lisa import region_bounds
from ...model.losses import color_loss, latent_loss
from ...render import LaplaceDensity, render_rays
from ...render.renderer import calibrate
from ...render.shading import surface_normals
from ...skeleton.params import HandParams
from ..optim import lr_schedule
from ..priors import prior_mean_fingers
from ..stages import HistoryRecord, StageReport, progress_bar, template_on
from ..terms import HandTerms, hand_prior
from .calibration import ViewCalibration
from .config import FitImagesConfig
from .shape_prior import HandSizePrior, ShapeSpace
from .terms import ViewData, keypoint_l1, keypoint_px
from .views import ImageView, background_colour, check_moments, check_views, fit_target

__all__ = ["RayPool", "ShapeCode", "template_boxes", "with_mean_codes", "fit_color"]

Box = tuple[float, float, float, float]


class RayPool:
    """Candidate rays of all views: the mask plus a band (or, without a mask, a box around the
    projected template), and the background pixels; drawn uniformly within each pool.

    views: the views (one device). band_px: width of the band around each mask, pixels.
    boxes: per view, None (it has a mask) or the box (u0, v0, u1, v1) pixels to draw from.
    """

    def __init__(self, views: Sequence[ImageView], band_px: int,
                 boxes: Sequence[Box | None]) -> None:
        device = views[0].rgb.device
        world_from_pixel, centres, rotations, backgrounds = [], [], [], []
        near_parts, far_parts = [], []
        for index, (view, box) in enumerate(zip(views, boxes, strict=True)):
            camera = view.camera
            world_from_pixel.append((camera.R.double().T @ torch.linalg.inv(camera.K.double()))
                                    .float())
            centres.append(camera.center.float())
            rotations.append(camera.R.float())
            backgrounds.append(background_colour(view))
            near, in_mask, target = _view_pixels(view, band_px, box)
            has_mask = view.mask is not None
            for part, chosen in ((near_parts, near), (far_parts, ~near)):
                pixel = torch.from_numpy(np.flatnonzero(chosen)).to(device)
                part.append((torch.full_like(pixel, index), pixel, target[pixel],
                             torch.from_numpy(in_mask[chosen]).to(device),
                             torch.full(pixel.shape, has_mask, dtype=torch.bool, device=device)))
        self.world_from_pixel = torch.stack(world_from_pixel)  # [C, 3, 3]
        self.centre = torch.stack(centres)  # [C, 3]
        self.rotation = torch.stack(rotations)  # [C, 3, 3] world-to-camera
        self.background = torch.stack(backgrounds)  # [C, 3]
        self.width = torch.tensor([v.width for v in views], device=device)
        self.near = [torch.cat(values) for values in zip(*near_parts, strict=True)]
        self.far = [torch.cat(values) for values in zip(*far_parts, strict=True)]

    def sample(self, num_rays: int, mask_fraction: float, generator: torch.Generator
               ) -> dict[str, torch.Tensor]:
        """-> origins, directions [R, 3] (world, metres / unit); target, background [R, 3];
        in_mask, has_mask [R] bool; view [R] the index of each ray's view; rotations [R, 3, 3]
        its view's world-to-camera rotation."""
        num_near_pool, num_far_pool = self.near[0].numel(), self.far[0].numel()
        num_near = int(round(mask_fraction * num_rays)) if num_far_pool else num_rays
        if num_near_pool == 0:
            num_near = 0
        picks = []
        for pool, count, size in ((self.near, num_near, num_near_pool),
                                  (self.far, num_rays - num_near, num_far_pool)):
            if count:
                index = torch.randint(0, size, (count,), generator=generator)
                picks.append([value[index.to(value.device)] for value in pool])
        view, pixel, target, in_mask, has_mask = (torch.cat(v) for v in zip(*picks, strict=True))
        width = self.width[view]
        uv = torch.stack([(pixel % width).float() + 0.5,
                          torch.div(pixel, width, rounding_mode="floor").float() + 0.5], dim=-1)
        homogeneous = torch.cat([uv, torch.ones_like(uv[:, :1])], dim=-1)
        directions = (self.world_from_pixel[view] @ homogeneous[..., None])[..., 0]
        directions = directions / directions.norm(dim=-1, keepdim=True)
        return {"origins": self.centre[view], "directions": directions, "target": target,
                "background": self.background[view], "in_mask": in_mask,
                "has_mask": has_mask, "view": view, "rotations": self.rotation[view]}


def _view_pixels(view: ImageView, band_px: int, box: Box | None
                 ) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
    """A view's flat pixels: near [H W] bool (the mask and its band, or the box), in_mask
    [H W] bool, target [H W, 3] colours."""
    from scipy.ndimage import distance_transform_edt

    height, width = view.height, view.width
    if view.mask is not None:
        mask = view.mask.cpu().numpy()
        distance = distance_transform_edt(~mask).reshape(-1)
        return distance <= band_px, mask.reshape(-1), fit_target(view).reshape(-1, 3)
    columns = np.arange(width) + 0.5
    rows = np.arange(height) + 0.5
    inside_u = (columns >= box[0]) & (columns <= box[2])
    inside_v = (rows >= box[1]) & (rows <= box[3])
    near = (inside_v[:, None] & inside_u[None, :]).reshape(-1)
    return near, np.zeros(height * width, dtype=bool), view.rgb.reshape(-1, 3)


@contextlib.contextmanager
def _frozen(module: torch.nn.Module) -> Iterator[None]:
    """Freeze a module's parameters (no weight gradients are computed) and restore them."""
    flags = [(p, p.requires_grad) for p in module.parameters()]
    for parameter, _ in flags:
        parameter.requires_grad_(False)
    try:
        yield
    finally:
        for parameter, flag in flags:
            parameter.requires_grad_(flag)


def template_boxes(template: Any, views: Sequence[ImageView],
                   hand: HandParams | Sequence[HandParams], margin: float) -> list[Box | None]:
    """For each view without a mask: the box (u0, v0, u1, v1) pixels around the projected
    template of ``hand`` (pose, translation, betas; a sequence: each view's hand), grown by
    ``margin`` of its size on each side; None for the views with a mask."""
    device = views[0].rgb.device
    hands = [hand] * len(views) if isinstance(hand, HandParams) else list(hand)
    posed: dict[int, torch.Tensor] = {}  # the template's vertices of each distinct hand
    boxes: list[Box | None] = []
    for view, one in zip(views, hands, strict=True):
        if view.mask is not None:
            boxes.append(None)
            continue
        if id(one) not in posed:
            with torch.no_grad():
                posed[id(one)] = template.forward(
                    one.pose[None].to(device), one.betas[None].to(device),
                    one.translation[None].to(device)).vertices[0]
        pixels, _ = view.camera.project(posed[id(one)])
        low, high = pixels.amin(0), pixels.amax(0)
        grow = margin * (high - low)
        low, high = (low - grow).tolist(), (high + grow).tolist()
        boxes.append((low[0], low[1], high[0], high[1]))
    return boxes


def with_mean_codes(hand: HandParams, model: Any) -> HandParams:
    """``hand`` with the model's mean shape and colour codes (the training subjects' mean, where
    the colour stage starts) and ``model=str(model.source)``."""
    return HandParams(pose=hand.pose, translation=hand.translation,
                      rest_joints=hand.rest_joints, shape_code=model.mean_shape_code(),
                      color_code=model.mean_color_code(), betas=hand.betas, side=hand.side,
                      model=str(model.source), extra=dict(hand.extra))


def _check_start(model: Any, start: HandParams) -> None:
    if not isinstance(start, HandParams):
        raise TypeError(f"start must be a HandParams, got {type(start).__name__}")
    if start.betas is None:
        raise ValueError("start.betas is None: the colour stage fits the template's betas "
                         "(start from the keypoint stage's hand)")
    sizes = {"shape_code": (start.shape_code, model.mean_shape_code()),
             "color_code": (start.color_code, model.mean_color_code())}
    for name, (code, mean) in sizes.items():
        if code is None or code.numel() != mean.numel():
            got = "none" if code is None else f"{code.numel()} values"
            raise ValueError(f"start.{name} has {got}, but model {model.source}'s codes have "
                             f"{mean.numel()}: start from with_mean_codes(hand, model)")


class ShapeCode:
    """The shape code ``beta+`` as the colour stage fits it (``config.shape_fit``).

    "space": ``space.code(coefficients, offset)`` (:class:`ShapeSpace` of the model's training
    codes, at most ``config.shape_dims`` directions); the coefficients (standard deviations)
    start at the start code's and are clamped to the training codes' range, widened by
    ``config.shape_range_margin``, after every step; the offset (the start code's part outside
    the subspace, 0 for the mean code) is fixed.
    "free": every dimension (the paper). "fixed": the start code.
    """

    def __init__(self, model: Any, start_code: torch.Tensor, config: FitImagesConfig,
                 device: torch.device) -> None:
        self.mode, self.margin = config.shape_fit, config.shape_range_margin
        start_code = start_code.to(device).float()
        self.space: ShapeSpace | None = None
        if self.mode == "space":
            self.space = ShapeSpace.from_codes(model.shape_codes, config.shape_dims).to(device)
            coefficients, self.offset = self.space.split(start_code)
            self.value = self.space.clamp(coefficients, self.margin).requires_grad_(True)
        else:
            self.value = start_code.clone().requires_grad_(self.mode == "free")

    def parameters(self) -> list[torch.Tensor]:
        return [self.value] if self.mode != "fixed" else []

    def code(self) -> torch.Tensor:
        """[D] the current shape code (differentiable)."""
        if self.space is None:
            return self.value
        return self.space.code(self.value, self.offset)

    def prior(self) -> torch.Tensor:
        """``0.5 |c|^2`` of the coefficients ("space"; 0 otherwise)."""
        if self.space is None:
            return self.value.new_zeros(())
        return 0.5 * (self.value**2).sum()

    @torch.no_grad()
    def project_(self) -> None:
        """Clamp the coefficients to the training codes' range ("space")."""
        if self.space is not None:
            self.value.copy_(self.space.clamp(self.value, self.margin))


def _unknowns(starts: Sequence[HandParams], device: torch.device, config: FitImagesConfig
              ) -> dict[str, torch.Tensor]:
    """The stage's unknowns on ``device`` but the shape code, with gradients (the betas only
    with a rate): pose [M, 48] and translation [M, 3] of each moment's hand, the first's betas
    and colour code."""
    def free(value: torch.Tensor, flag: bool = True) -> torch.Tensor:
        return value.to(device).float().clone().requires_grad_(flag)

    return {"pose": free(torch.stack([hand.pose.to(device) for hand in starts])),
            "translation": free(torch.stack([hand.translation.to(device) for hand in starts])),
            "betas": free(starts[0].betas, config.color_betas_lr > 0),
            "color_code": free(starts[0].color_code)}


def _optimizer(unknowns: dict[str, torch.Tensor], shape: ShapeCode,
               calibration: ViewCalibration, config: FitImagesConfig) -> torch.optim.Optimizer:
    groups = [{"params": [unknowns["pose"]], "lr": config.color_pose_lr},
              {"params": [unknowns["translation"]], "lr": config.color_translation_lr},
              {"params": [unknowns["color_code"]], "lr": config.code_lr}]
    if shape.parameters():
        rate = config.shape_lr if shape.mode == "space" else config.code_lr
        groups.append({"params": shape.parameters(), "lr": rate})
    if config.color_betas_lr > 0:
        groups.append({"params": [unknowns["betas"]], "lr": config.color_betas_lr})
    if calibration.parameters():
        groups.append({"params": calibration.parameters(), "lr": config.view_calibration_lr})
    return torch.optim.Adam(groups)


class _Renderer:
    """One iteration's loss terms: rays rendered with the current unknowns, and the joint
    loss."""

    def __init__(self, model: Any, views: Sequence[ImageView], template: Any,
                 config: FitImagesConfig, starts: Sequence[HandParams],
                 moments: Sequence[int]) -> None:
        device = views[0].rgb.device
        self.model, self.template, self.config = model, template, config
        self.moment = torch.tensor(list(moments), device=device)  # [C] each view's moment
        self.num_moments = len(starts)
        self.generator = torch.Generator().manual_seed(config.seed + 1)
        self.render_generator = torch.Generator(device=device).manual_seed(config.seed + 2)
        self.data = ViewData(views, config.coverage_pixels, self.generator)
        self.mean_fingers = prior_mean_fingers(config.prior_pose, device)
        self.size_prior = HandSizePrior.from_template(template).for_keypoints(
            self.data.num_visible)
        self.pool = RayPool(views, config.band_px, template_boxes(
            template, views, [starts[m] for m in moments], config.no_mask_margin))
        self.density = LaplaceDensity(beta_init=float(model.beta), beta_min=0.0).to(device)
        self.density.requires_grad_(False)
        self.gain = model.gain.to(device).float()
        self.bias = model.bias.to(device).float()
        calibrate_views = (config.view_calibration
                           and len(views) >= config.view_calibration_min_views)
        self.calibration = ViewCalibration(len(views), config.view_gain_std,
                                           config.view_bias_std, calibrate_views, device)

    def _moment_rays(self, rays: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor],
                                                                   list[int]]:
        """The rays grouped by their view's moment -> (the rays reordered, the count of each
        moment's)."""
        if self.num_moments == 1:
            return rays, [rays["view"].numel()]
        moment = self.moment[rays["view"]]
        order = torch.argsort(moment, stable=True)
        counts = torch.bincount(moment, minlength=self.num_moments).tolist()
        return {name: value[order] for name, value in rays.items()}, counts

    def _render(self, state: Any, rays: dict[str, torch.Tensor]
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """rays (one moment's) rendered through the hand ``state`` -> rgb [R, 3] (shaded
        when the model is), opacity [R]."""
        field_model = self.model.field
        low, high = region_bounds(state, field_model)
        near, far, hit = ray_box_bounds(rays["origins"], rays["directions"], low[0], high[0])
        hit = hit & (far > near)
        sdf_fn = field_model.sdf_fn(state)
        out = render_rays(field_model.field_fn(state), sdf_fn, rays["origins"],
                          rays["directions"], near, far, self.config.render, self.density,
                          hit=hit, background=self.gain.new_zeros(3),
                          generator=self.render_generator)
        rgb = out.rgb
        if self.model.shading is not None:  # a model trained with headlight shading
            normals = surface_normals(sdf_fn, rays["origins"], rays["directions"], out.depth,
                                      out.opacity)
            rgb = self.model.shading(rgb, normals, rays["directions"], rays["rotations"])
        return rgb, out.opacity

    def keypoint_pixels(self, pose: torch.Tensor, translation: torch.Tensor,
                        betas: torch.Tensor) -> tuple[torch.Tensor, Any]:
        """Each moment's pose [M, 48] and translation [M, 3], the betas [10] -> (the template's
        keypoints in each view at its moment's pose [1, C, 21, 2] pixels, the posed
        template [M])."""
        posed = self.template.forward(pose, betas[None].expand(pose.shape[0], -1), translation)
        pixels, _ = self.data.project(posed.keypoints)  # [M, C, 21, 2]
        views = torch.arange(self.moment.numel(), device=pixels.device)
        return pixels[self.moment, views][None], posed

    def terms(self, unknowns: dict[str, torch.Tensor]
              ) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """unknowns: pose [M, 48], translation [M, 3] (a moment's each), betas, shape_code,
        color_code -> ({"col", "reg", "joints", "mask", "calibration"} scalars, keypoint pixels
        [1, C, 21, 2]); each ray goes through its view's moment's hand, calibrated with its
        view's response (``self.calibration``)."""
        config, field_model = self.config, self.model.field
        pose, translation, betas = (unknowns[k] for k in ("pose", "translation", "betas"))
        shape_code, color_code = unknowns["shape_code"], unknowns["color_code"]
        rest_joints = self.template.rest_joints(betas[None])
        rays, counts = self._moment_rays(self.pool.sample(config.num_rays, config.mask_fraction,
                                                          self.generator))
        parts, begin = [], 0
        for moment, count in enumerate(counts):
            if count == 0:
                continue
            state = field_model.prepare(pose[moment:moment + 1],
                                        translation[moment:moment + 1], rest_joints,
                                        shape_code[None], color_code[None])
            parts.append(self._render(state, {name: value[begin:begin + count]
                                              for name, value in rays.items()}))
            begin += count
        rgb, opacity = (torch.cat(values) for values in zip(*parts, strict=True))
        gain, bias = self.calibration.for_rays(self.gain, self.bias, rays["view"])
        prediction = calibrate(rgb, opacity, gain, bias, rays["background"])
        terms = {"col": color_loss(prediction, rays["target"]),
                 "reg": latent_loss(shape_code[None], color_code[None])}
        pixels, posed = self.keypoint_pixels(pose, translation, betas)
        prior = hand_prior(config, self.mean_fingers, size_prior=self.size_prior)
        terms["joints"] = keypoint_l1(pixels, self.data)[0] + prior(HandTerms(
            pose=pose, betas=betas[None].expand(pose.shape[0], -1), joints=posed.joints)).mean()
        has_mask = rays["has_mask"]
        if config.mask_weight > 0 and bool(has_mask.any()):
            opacity = opacity[has_mask].clamp(1e-5, 1.0 - 1e-5)
            terms["mask"] = F.binary_cross_entropy(opacity, rays["in_mask"][has_mask].float())
        else:
            terms["mask"] = prediction.new_zeros(())
        terms["calibration"] = self.calibration.prior()
        return terms, pixels


def fit_color(
    model: Any,
    views: Sequence[ImageView],
    start: HandParams | Sequence[HandParams],
    config: FitImagesConfig | None = None,
    template: Any = None,
    progress: bool = False,
    *,
    moments: Sequence[int] | None = None,
) -> tuple[HandParams, StageReport]:
    """The colour stage: pose, translation, betas, shape and colour codes from the colour loss
    (see the module docstring).

    model: a :class:`lisa_hand.model.trained.TrainedModel` with colour, on the views' device.
    views: as for :func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`.
    start: the hand to start from (a right hand: pose, translation, betas, and codes of this
        model, e.g. ``with_mean_codes(keypoint_hand, model)``); with ``moments``, one hand a
        moment (their poses and translations; the first's betas and codes).
    moments: the moment each view shows (:func:`~lisa_hand.fitting.images.views.check_moments`;
        None: one). Each moment has its own pose and translation; the shape and colour codes
        (and the betas) are one, fitted to every view: a video's keyframes. The returned hand
        is the first moment's; ``hand.extra["moments"]`` holds the others' fitted ``pose`` and
        ``translation`` (lists).
    -> (hand, report): the fitted right hand (rest_joints ``template.rest_joints(betas)``,
    ``model=str(model.source)``) and the :class:`StageReport` ("color"): history records with
    "energy" (the weighted total ``L``), its unweighted terms "col", "reg", "joints", "mask",
    "shape_prior", "calibration" and "kp_px" (mean keypoint error, pixels) per iteration, the
    final keypoint error and the last iteration's total loss (``loss``, ``energies == [loss]``;
    NaN without iterations). With ``view_calibration``, ``hand.extra["view_calibration"]`` holds
    each view's fitted response ({name: {"gain": [3], "bias": [3]}}); the hand itself is
    rendered with the model's mean calibration, as LISA at inference.
    """
    began = time.perf_counter()
    config = FitImagesConfig() if config is None else config
    views = check_views(views)
    if not model.has_color:
        raise ValueError(f"model {model.source}: it has no colour (a geometry-only prior); "
                         "fitting to images needs a model trained on images (lisa train)")
    moments = check_moments(moments, len(views))
    starts = [start] if isinstance(start, HandParams) else list(start)
    if len(starts) != max(moments) + 1:
        raise ValueError(f"{len(starts)} start hand(s) for {max(moments) + 1} moment(s)")
    for hand in starts:
        _check_start(model, hand)
    device = views[0].rgb.device
    template = template_on(template, device)
    renderer = _Renderer(model, views, template, config, starts, moments)
    unknowns = _unknowns(starts, device, config)
    shape = ShapeCode(model, starts[0].shape_code, config, device)
    optimizer = _optimizer(unknowns, shape, renderer.calibration, config)
    schedule = lr_schedule(optimizer, config.color_iters, config.final_lr_fraction)
    history: list[HistoryRecord] = []
    weights = {"col": config.rgb_weight, "reg": config.code_weight,
               "joints": config.joints_weight, "mask": config.mask_weight,
               "shape_prior": config.shape_weight,
               "calibration": config.view_calibration_weight}
    bar = progress_bar(progress, config.color_iters, "colour")
    with _frozen(model.field):
        for iteration in range(config.color_iters):
            optimizer.zero_grad(set_to_none=True)
            unknowns["shape_code"] = shape.code()
            terms, pixels = renderer.terms(unknowns)
            terms["shape_prior"] = shape.prior()
            total = sum(weights[name] * terms[name] for name in weights)
            total.backward()
            optimizer.step()
            shape.project_()
            schedule.step()
            record: HistoryRecord = {"stage": "color", "iteration": iteration,
                                     "energy": float(total.detach())}
            for name, value in terms.items():
                record[name] = float(value.detach())
            record["kp_px"] = float(keypoint_px(pixels.detach(), renderer.data)[0])
            history.append(record)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(col=f"{record['col']:.4f}")
    if bar is not None:
        bar.close()
    unknowns["shape_code"] = shape.code()
    hand, report = _finish(model, renderer, unknowns, history, began)
    if renderer.calibration.enabled:
        hand.extra["view_calibration"] = renderer.calibration.to_dict(
            [view.name for view in views], renderer.gain, renderer.bias)
    return hand, report


def _finish(model: Any, renderer: _Renderer, unknowns: dict[str, torch.Tensor],
            history: list[HistoryRecord], began: float) -> tuple[HandParams, StageReport]:
    """The fitted hand (the first moment's) and the stage's report."""
    fitted = {name: value.detach() for name, value in unknowns.items()}
    with torch.no_grad():
        rest_joints = renderer.template.rest_joints(fitted["betas"][None])[0]
        pixels, _ = renderer.keypoint_pixels(fitted["pose"], fitted["translation"],
                                             fitted["betas"])
        error = float(keypoint_px(pixels, renderer.data)[0])
    hand = HandParams(pose=fitted["pose"][0], translation=fitted["translation"][0],
                      rest_joints=rest_joints, shape_code=fitted["shape_code"],
                      color_code=fitted["color_code"], betas=fitted["betas"],
                      model=str(model.source))
    if renderer.num_moments > 1:
        hand.extra["moments"] = [
            {"pose": fitted["pose"][m].tolist(), "translation": fitted["translation"][m].tolist()}
            for m in range(1, renderer.num_moments)]
    loss = float(history[-1]["energy"]) if history else float("nan")
    return hand, StageReport(stage="color", seconds=time.perf_counter() - began, loss=loss,
                             energies=[loss], history=history, keypoint_error_px=error)
