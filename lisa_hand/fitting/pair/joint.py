"""Several hands of one photo refined together after each was fitted alone
(:func:`fit_hands_together`).

Per hand the unknowns are its pose [48], translation [3] and shape code; its skeleton, colour
and the mesh whose vertices are its surface samples stay its own fit's. The energy:

* each hand's 2D keypoints (projected and compared with the detector's, pseudo-Huber in percent
  of the hand's size, as the video fit's) and the prior of every fitter
  (:func:`lisa_hand.fitting.terms.hand_prior`);
* staying near its own fit: the finger pose and the shape code (the joint stage moves them only
  as far as the contact needs; the hand's place, its root rotation and translation, is free);
* **interpenetration**: each hand's field evaluated at every other hand's surface samples, the
  depth inside beyond ``contact_mm`` squared (mm^2) and averaged: contact is allowed, overlap
  is not (:mod:`lisa_hand.fitting.pair.contact`);
* **depth order from the masks**: where a hand's surface samples project into another hand's
  mask (and not into its own), that hand is in front there: the samples must lie behind the
  other hand's nearest surface at that pixel (its samples within ``order_radius_px``).

Adam under the one cosine schedule (:mod:`lisa_hand.fitting.optim`), every hand at once.
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

__all__ = ["HandInPhoto", "JointReport", "fit_hands_together"]


@dataclass(frozen=True)
class HandInPhoto:
    """One hand of a photo as the joint fit sees it.

    params: its own fit (either side; world = the photo's camera frame, metres). mesh: its
    fitted mesh (world, with skinning weights). keypoints: [21, 2] pixels of the photo the
    camera ``K`` belongs to. visible: [21] bool. mask: [H, W] bool, the pixels that are this
    hand and no other (the photo's size), or None.
    """

    params: HandParams
    mesh: Any
    keypoints: np.ndarray
    visible: np.ndarray
    mask: np.ndarray | None = None


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

    def __init__(self, model: Any, hands: list[HandInPhoto], bodies: list[HandBody],
                 K: torch.Tensor, template: Any, config: JointConfig) -> None:
        from ..photo.mask import hand_scale_px
        from ..points.surface_stage import shape_code_scale

        self.model, self.hands, self.bodies, self.config = model, hands, bodies, config
        self.template = template
        self.K = K.double().cpu()
        self.prior = hand_prior(config, prior_mean_fingers(config.prior_pose).double())
        self.code_scale = shape_code_scale(model)
        self.targets = [torch.as_tensor(hand.keypoints, dtype=torch.float64) for hand in hands]
        self.visible = [torch.as_tensor(hand.visible, dtype=torch.bool) for hand in hands]
        self.size_px = [max(hand_scale_px(hand.keypoints), 1.0) for hand in hands]
        self.start_pose = torch.stack([body.right.pose.double() for body in bodies])
        self.start_shape = torch.stack([body.right.shape_code.double() for body in bodies])
        with torch.no_grad():
            self.tips = [fingertips_at_rest(template, body.right.rest_joints.double(),
                                            _betas(body.right)) for body in bodies]

    def pixels(self, index: int, pose: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        """Hand ``index``'s keypoints projected: [21, 2] pixels."""
        body = self.bodies[index]
        points = posed_keypoints(self.template, body.right.rest_joints.double(),
                                 _betas(body.right), pose[None], translation[None],
                                 self.tips[index])[0]
        points = body.to_world(points)
        projected = points @ self.K.T
        return projected[:, :2] / projected[:, 2:].clamp_min(1e-3)

    def keypoint_errors(self, pose: torch.Tensor, translation: torch.Tensor) -> list[float]:
        """Each hand's mean distance to its visible keypoints, pixels."""
        with torch.no_grad():
            return [float((self.pixels(k, pose[k], translation[k]) - self.targets[k])
                          .norm(dim=-1)[self.visible[k]].mean())
                    for k in range(len(self.bodies))]

    def parts(self, pose: torch.Tensor, translation: torch.Tensor, shape: torch.Tensor
              ) -> dict[str, torch.Tensor]:
        config = self.config
        parts: dict[str, torch.Tensor] = {}
        keypoints, stay = pose.new_zeros(()), pose.new_zeros(())
        for k in range(len(self.bodies)):
            distance = (self.pixels(k, pose[k], translation[k]) - self.targets[k]).norm(dim=-1)
            distance = distance[self.visible[k]] * (100.0 / self.size_px[k])
            scale = config.keypoint_scale
            keypoints = keypoints + (scale ** 2 * (torch.sqrt(1.0 + (distance / scale) ** 2)
                                                   - 1.0)).mean()
            stay = stay + ((pose[k, 3:] - self.start_pose[k, 3:]) ** 2).sum() + (
                ((shape[k] - self.start_shape[k]) / self.code_scale) ** 2).mean()
        parts["keypoints"] = config.keypoint_weight * keypoints
        parts["prior"] = self.prior(HandTerms(pose=pose)).sum()
        parts["stay"] = config.stay_weight * stay
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
                    order = order + self._order(a, b, points, surfaces[b])
        parts["penetration"] = config.penetration_weight * inside
        parts["order"] = config.order_weight * order
        return parts

    def _order(self, a: int, b: int, points: torch.Tensor, front: torch.Tensor) -> torch.Tensor:
        """Hand a's samples seen in hand b's mask (and not in a's own) must lie behind hand
        b's nearest surface there: their squared depth in front of it, mm^2, averaged over
        hand a's samples."""
        mask_b, mask_a = self.hands[b].mask, self.hands[a].mask
        if mask_b is None:
            return points.new_zeros(())
        with torch.no_grad():
            pixels = _project(self.K, points)
            rows = _in_mask(mask_b, pixels) & ~_in_mask(mask_a, pixels)
        if not bool(rows.any()):
            return points.new_zeros(())
        pixels_a = _project(self.K, points[rows])
        pixels_b = _project(self.K, front)
        near = torch.cdist(pixels_a.detach(), pixels_b.detach()) < self.config.order_radius_px
        depth_b = torch.where(near, front[:, 2][None].expand_as(near),
                              torch.full_like(near, float("inf"), dtype=front.dtype)).amin(1)
        seen = torch.isfinite(depth_b)
        ahead = torch.relu(1000.0 * (depth_b[seen] - points[rows][seen][:, 2]))
        return (ahead ** 2).sum() / points.shape[0]


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


def fit_hands_together(model: Any, hands: list[HandInPhoto], K: torch.Tensor, template: Any,
                       config: JointConfig | None = None, progress: bool = False
                       ) -> tuple[list[HandParams], JointReport]:
    """Refine K >= 2 hands of one photo together (module docstring).

    model: the trained model the hands were fitted with. hands: each hand's own fit, mesh,
    keypoints and exclusive mask. K: [3, 3] the photo's intrinsics (pixels of the keypoints and
    masks; the camera frame is the world). template: the mesh template (CPU, float64 is taken).
    -> (the hands, each of its own side, in the same order; the :class:`JointReport`).
    """
    from ..stages import progress_bar

    config = JointConfig() if config is None else config
    began = time.perf_counter()
    template = template.to(device=torch.device("cpu"), dtype=torch.float64)
    bodies = [HandBody.of(hand.params, hand.mesh, config.samples, config.seed + index)
              for index, hand in enumerate(hands)]
    energy = _JointEnergy(model, hands, bodies, K, template, config)
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


def _right(params: HandParams) -> HandParams:
    from ..sides import mirror_hand

    return mirror_hand(params) if params.side == "left" else params
