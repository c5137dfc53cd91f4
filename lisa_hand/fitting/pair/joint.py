"""Several hands refined together after each was fitted alone (:func:`fit_hands_together`):
the hands of a photo, of calibrated views, or of a scan.

Per hand the unknowns are its pose [48], translation [3] and shape code; its skeleton, colour
and the mesh whose vertices are its surface samples stay its own fit's. What each hand was
fitted to stays its evidence (:class:`JointHand`): its 2D keypoints in each view
(:class:`HandView`) and its points of a scan. The energy:

* each hand's 2D keypoints in every view (projected and compared with the detector's,
  pseudo-Huber in percent of the hand's size, as the video fit's; averaged over the views),
  its scan points (its field's SDF there, pseudo-Huber in mm) and the prior of every fitter
  (:func:`lisa_hand.fitting.terms.hand_prior`);
* staying near its own fit: the finger pose, the shape code and (weakly) the translation (the
  joint stage moves them only as far as the contact needs; the root rotation is free);
* **interpenetration**: each hand's field evaluated at every other hand's surface samples, the
  depth inside beyond ``contact_mm`` squared (mm^2) and averaged: contact is allowed, overlap
  is not (:mod:`lisa_hand.fitting.pair.contact`);
* **depth order from the masks** (views with both hands' masks): where a hand's surface samples
  project into another hand's mask (and not into its own), that hand is in front there: the
  samples must lie behind the other hand's nearest surface at that pixel (its samples within
  ``order_radius_px``), along that view's rays; pseudo-Huber in mm, and only for samples at
  least ``order_margin_px`` inside that mask (a mask's edge is not exact).

Adam under the one cosine schedule (:mod:`lisa_hand.fitting.optim`), every hand at once. Hands
that do not meet (no hand inside another, no surface in front where a mask says another hand
is) are returned as fitted alone: there is nothing to resolve.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams
from ..optim import adam, lr_schedule
from ..outputs.records import fingertips_at_rest, posed_keypoints
from ..priors import prior_mean_fingers
from ..terms import HandTerms, hand_prior
from .config import JointConfig
from .contact import HandBody, penetration_depths

__all__ = ["HandView", "JointHand", "JointReport", "fit_hands_together"]


@dataclass(frozen=True)
class HandView:
    """One hand seen in one calibrated view.

    K: [3, 3] intrinsics, pixels; R: [3, 3], t: [3] world to camera (OpenCV). keypoints:
    [21, 2] pixels; visible: [21] bool. mask: [H, W] bool, the pixels that are this hand and no
    other, or None.
    """

    K: torch.Tensor
    keypoints: np.ndarray
    visible: np.ndarray
    R: torch.Tensor | None = None
    t: torch.Tensor | None = None
    mask: np.ndarray | None = None

    def camera_points(self, points: torch.Tensor) -> torch.Tensor:
        """World points [N, 3] -> this camera's frame [N, 3] (float64)."""
        if self.R is None:
            return points
        return points @ self.R.double().T + self.t.double()

    def pixels(self, points: torch.Tensor) -> torch.Tensor:
        """World points [N, 3] -> pixels [N, 2]."""
        return _project(self.K.double().cpu(), self.camera_points(points))


@dataclass(frozen=True)
class JointHand:
    """One hand as the joint fit sees it: its own fit (``params``, either side; world metres),
    its fitted mesh (world, with skinning weights), and its evidence: ``views`` (its keypoints
    and mask in each view) and ``points`` ([N, 3] world metres, its points of a scan, or
    None)."""

    params: HandParams
    mesh: Any
    views: tuple[HandView, ...] = ()
    points: np.ndarray | None = None


@dataclass
class JointReport:
    """What the joint stage did: steps, seconds, the energy's parts at the start and the end,
    each pair's penetration (mm, [K, K], entry (a, b): hand a inside hand b) and each hand's
    mean keypoint error (pixels) before and after."""

    iters: int
    seconds: float
    energy_start: dict[str, float] = field(default_factory=dict)
    energy_end: dict[str, float] = field(default_factory=dict)
    penetration_start_mm: np.ndarray | None = None
    penetration_end_mm: np.ndarray | None = None
    keypoint_error_start_px: list[float] = field(default_factory=list)
    keypoint_error_end_px: list[float] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        def deepest(depths: np.ndarray | None) -> float | None:
            return None if depths is None else float(depths.max(initial=0.0))

        return {"iters": self.iters, "seconds": self.seconds,
                "energy_start": self.energy_start, "energy_end": self.energy_end,
                "penetration_start_mm": deepest(self.penetration_start_mm),
                "penetration_end_mm": deepest(self.penetration_end_mm),
                "keypoint_error_start_px": self.keypoint_error_start_px,
                "keypoint_error_end_px": self.keypoint_error_end_px}


class _JointEnergy:
    """The energy of K hands (module docstring); unknowns stacked: pose [K, 48], translation
    [K, 3], shape [K, D], all of the right hands (a left hand mirrored)."""

    def __init__(self, model: Any, hands: list[JointHand], bodies: list[HandBody],
                 template: Any, config: JointConfig) -> None:
        from ..photo.mask import hand_scale_px
        from ..points.surface_stage import shape_code_scale

        self.model, self.hands, self.bodies, self.config = model, hands, bodies, config
        self.template = template
        self.prior = hand_prior(config, prior_mean_fingers(config.prior_pose).double())
        self.code_scale = shape_code_scale(model)
        self.size_px = [[max(hand_scale_px(view.keypoints), 1.0) for view in hand.views]
                        for hand in hands]
        self.targets = [[(torch.as_tensor(view.keypoints, dtype=torch.float64),
                          torch.as_tensor(view.visible, dtype=torch.bool)) for view in hand.views]
                        for hand in hands]  # per hand and view: (keypoints [21, 2], visible)
        generator = torch.Generator().manual_seed(config.seed)
        self.points = [None if hand.points is None else _subset(
            torch.as_tensor(hand.points, dtype=torch.float64), config.scan_points, generator)
            for hand in hands]
        self.start_pose = torch.stack([body.right.pose.double() for body in bodies])
        self.start_shape = torch.stack([body.right.shape_code.double() for body in bodies])
        self.start_translation = torch.stack([body.right.translation.double()
                                              for body in bodies])
        self.inner = [[None if view.mask is None else _eroded(view.mask, config.order_margin_px)
                       for view in hand.views] for hand in hands]
        with torch.no_grad():
            self.tips = [fingertips_at_rest(template, body.right.rest_joints.double(),
                                            _betas(body.right)) for body in bodies]

    def keypoints_3d(self, index: int, pose: torch.Tensor, translation: torch.Tensor
                     ) -> torch.Tensor:
        """Hand ``index``'s 21 keypoints in the world [21, 3] metres."""
        body = self.bodies[index]
        points = posed_keypoints(self.template, body.right.rest_joints.double(),
                                 _betas(body.right), pose[None], translation[None],
                                 self.tips[index])[0]
        return body.to_world(points)

    def _distances(self, index: int, pose: torch.Tensor, translation: torch.Tensor
                   ) -> list[torch.Tensor]:
        """Per view, hand ``index``'s visible keypoints' distances [V_k] pixels."""
        points = self.keypoints_3d(index, pose, translation)
        return [(view.pixels(points) - target).norm(dim=-1)[visible]
                for view, (target, visible) in zip(self.hands[index].views,
                                                   self.targets[index], strict=True)]

    def keypoint_errors(self, pose: torch.Tensor, translation: torch.Tensor) -> list[float]:
        """Each hand's mean distance to its visible keypoints over its views, pixels (NaN
        without views)."""
        with torch.no_grad():
            return [float(torch.cat(distances).mean()) if distances else float("nan")
                    for distances in (self._distances(k, pose[k], translation[k])
                                      for k in range(len(self.bodies)))]

    def parts(self, pose: torch.Tensor, translation: torch.Tensor, shape: torch.Tensor
              ) -> dict[str, torch.Tensor]:
        config = self.config
        keypoints, scan, stay = (pose.new_zeros(()) for _ in range(3))
        place = (1000.0 * (translation - self.start_translation)).square().sum()
        for k in range(len(self.bodies)):
            distances = self._distances(k, pose[k], translation[k])
            for distance, size in zip(distances, self.size_px[k], strict=True):
                keypoints = keypoints + _pseudo_huber(distance * (100.0 / size),
                                                      config.keypoint_scale).mean() / len(
                    distances)
            if self.points[k] is not None:
                sdf = self.bodies[k].sdf(self.model, pose[k], translation[k], shape[k],
                                         self.points[k])
                scan = scan + _pseudo_huber(1000.0 * sdf.double(), config.scan_scale_mm).mean()
            stay = stay + ((pose[k, 3:] - self.start_pose[k, 3:]) ** 2).sum() + (
                ((shape[k] - self.start_shape[k]) / self.code_scale) ** 2).mean()
        parts = {"keypoints": config.keypoint_weight * keypoints,
                 "scan": config.scan_weight * scan,
                 "prior": self.prior(HandTerms(pose=pose)).sum(),
                 "stay": config.stay_weight * stay, "place": config.place_weight * place}
        surfaces = [body.surface_points(pose[k], translation[k])
                    for k, body in enumerate(self.bodies)]
        inside, order = pose.new_zeros(()), pose.new_zeros(())
        for a, points in enumerate(surfaces):
            for b, other in enumerate(self.bodies):
                if a == b:
                    continue
                if config.penetration_weight > 0:
                    sdf = other.sdf(self.model, pose[b], translation[b], shape[b], points)
                    depth = torch.relu(-1000.0 * sdf.double() - config.contact_mm)
                    inside = inside + (depth ** 2).mean()
                if config.order_weight > 0:
                    for index, (view_a, view_b) in enumerate(zip(
                            self.hands[a].views, self.hands[b].views, strict=True)):
                        order = order + self._order(view_a, view_b, self.inner[b][index],
                                                    points, surfaces[b])
        parts["penetration"] = config.penetration_weight * inside
        parts["order"] = config.order_weight * order
        return parts

    def _order(self, view_a: HandView, view_b: HandView, inner_b: np.ndarray | None,
               points: torch.Tensor, front: torch.Tensor) -> torch.Tensor:
        """Hand a's samples seen well inside hand b's mask (``inner_b``: eroded by
        ``order_margin_px``; and not in a's own) in one view must lie behind hand b's nearest
        surface there: how far they are in front of it, mm, pseudo-Huber, summed over them and
        divided by hand a's samples."""
        if inner_b is None:
            return points.new_zeros(())
        with torch.no_grad():
            pixels = view_b.pixels(points)
            rows = _in_mask(inner_b, pixels) & ~_in_mask(view_a.mask, pixels)
        if not bool(rows.any()):
            return points.new_zeros(())
        depth_a = view_b.camera_points(points[rows])[:, 2]
        depth_front = view_b.camera_points(front)[:, 2]
        with torch.no_grad():
            near = torch.cdist(pixels[rows], view_b.pixels(front)) < self.config.order_radius_px
        depth_b = torch.where(near, depth_front[None].expand_as(near),
                              torch.full_like(near, float("inf"), dtype=front.dtype)).amin(1)
        seen = torch.isfinite(depth_b)
        ahead = torch.relu(1000.0 * (depth_b[seen] - depth_a[seen]))
        return _pseudo_huber(ahead, self.config.order_scale_mm).sum() / points.shape[0]


def _eroded(mask: np.ndarray, pixels: float) -> np.ndarray:
    """The mask [H, W] bool without its pixels within ``pixels`` of its outside."""
    if pixels <= 0:
        return np.asarray(mask, bool)
    from scipy import ndimage

    return ndimage.binary_erosion(np.asarray(mask, bool), iterations=int(round(pixels)))


def _pseudo_huber(values: torch.Tensor, scale: float) -> torch.Tensor:
    return scale ** 2 * (torch.sqrt(1.0 + (values / scale) ** 2) - 1.0)


def _subset(points: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """At most ``count`` of ``points`` [N, 3], a fixed random choice."""
    if points.shape[0] <= count:
        return points
    return points[torch.randperm(points.shape[0], generator=generator)[:count]]


def _betas(params: HandParams) -> torch.Tensor | None:
    return None if params.betas is None else params.betas.double()


def _project(K: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    projected = points @ K.T
    return projected[:, :2] / projected[:, 2:].clamp_min(1e-3)


def _in_mask(mask: np.ndarray | None, pixels: torch.Tensor) -> torch.Tensor:
    """[N] bool: pixels [N, 2] (continuous coordinates) inside the mask [H, W]."""
    if mask is None:
        return torch.zeros(pixels.shape[0], dtype=torch.bool)
    height, width = mask.shape
    column = pixels[:, 0].floor().long()
    row = pixels[:, 1].floor().long()
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    hits = torch.zeros(pixels.shape[0], dtype=torch.bool)
    lookup = torch.from_numpy(np.ascontiguousarray(mask))
    hits[inside] = lookup[row[inside], column[inside]]
    return hits


def _back_to_params(body: HandBody, pose: torch.Tensor, translation: torch.Tensor,
                    shape: torch.Tensor) -> HandParams:
    """The fitted right hand back to the hand's own side (world frame)."""
    from dataclasses import replace

    from ..sides import mirror_hand

    right = replace(body.right, pose=pose.detach().float().cpu(),
                    translation=translation.detach().float().cpu(),
                    shape_code=shape.detach().to(body.right.shape_code.dtype).cpu(),
                    extra=dict(body.right.extra))
    return mirror_hand(right) if body.flip else right


def fit_hands_together(model: Any, hands: list[JointHand], template: Any,
                       config: JointConfig | None = None, progress: bool = False
                       ) -> tuple[list[HandParams], JointReport]:
    """Refine K >= 2 hands together (module docstring).

    model: the trained model the hands were fitted with. hands: each hand's own fit, mesh and
    evidence. template: the mesh template (CPU, float64 is taken).
    -> (the hands, each of its own side, in the same order; the :class:`JointReport`).
    """
    from ..stages import progress_bar

    config = JointConfig() if config is None else config
    began = time.perf_counter()
    template = template.to(device=torch.device("cpu"), dtype=torch.float64)
    bodies = [HandBody.of(model, hand.params, hand.mesh, config.samples, config.seed + index)
              for index, hand in enumerate(hands)]
    energy = _JointEnergy(model, hands, bodies, template, config)
    pose = torch.stack([body.right.pose.double() for body in bodies]).requires_grad_(True)
    translation = torch.stack([body.right.translation.double() for body in bodies]
                              ).requires_grad_(True)
    shape = torch.stack([body.right.shape_code.double() for body in bodies]).requires_grad_(True)
    report = JointReport(iters=config.iters, seconds=0.0,
                         penetration_start_mm=penetration_depths(model, bodies),
                         keypoint_error_start_px=energy.keypoint_errors(pose, translation))
    with torch.no_grad():
        report.energy_start = {name: float(value) for name, value
                               in energy.parts(pose, translation, shape).items()}
    if not _interacting(report, config):
        report.iters = 0  # nothing to resolve: the hands as fitted alone
        report.penetration_end_mm = report.penetration_start_mm
        report.keypoint_error_end_px = report.keypoint_error_start_px
        report.energy_end = dict(report.energy_start)
        report.seconds = time.perf_counter() - began
        return [hand.params for hand in hands], report
    if config.iters > 0:
        optimizer = adam([(pose, config.pose_lr), (translation, config.translation_lr),
                          (shape, config.shape_lr)])
        schedule = lr_schedule(optimizer, config.iters, config.final_lr_fraction)
        bar = progress_bar(progress, config.iters, "hands together")
        for _ in range(config.iters):
            optimizer.zero_grad(set_to_none=True)
            sum(energy.parts(pose, translation, shape).values()).backward()
            optimizer.step()
            schedule.step()
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
    fitted = [_back_to_params(body, pose[k], translation[k], shape[k])
              for k, body in enumerate(bodies)]
    moved = [HandBody(right=_right(hand), flip=body.flip, surface=body.surface, rows=body.rows)
             for hand, body in zip(fitted, bodies, strict=True)]
    report.penetration_end_mm = penetration_depths(model, moved)
    report.keypoint_error_end_px = energy.keypoint_errors(pose, translation)
    with torch.no_grad():
        report.energy_end = {name: float(value) for name, value
                             in energy.parts(pose, translation, shape).items()}
    report.seconds = time.perf_counter() - began
    return fitted, report


def _interacting(report: JointReport, config: JointConfig) -> bool:
    """Whether the hands meet: one inside another beyond ``contact_mm``, or a hand's surface
    in front where a mask says another hand is. Hands that do not are left as fitted alone
    (the joint stage has nothing to resolve, and its keypoint term would only refit them)."""
    deepest = float(report.penetration_start_mm.max(initial=0.0))
    return deepest > config.contact_mm or report.energy_start.get("order", 0.0) > 0.0


def _right(params: HandParams) -> HandParams:
    from ..sides import mirror_hand

    return mirror_hand(params) if params.side == "left" else params
