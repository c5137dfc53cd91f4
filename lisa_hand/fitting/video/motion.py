"""A tracked hand's pose and translation in every frame, and its one skeleton
(:func:`fit_motion`): the motion fit of ``lisa fit-video``.

The hand's skeleton (the mesh template's betas) starts as its keyframe's; per frame the pose
[48] and translation [3] are unknown, and in the final pass the skeleton too, one for every
frame. The energy of a set of frames (:class:`MotionEnergy`) is a
sum of per-frame data and prior terms and of motion terms between consecutive frames:

* keypoints: each frame's 21 keypoints (:func:`lisa_hand.fitting.outputs.posed_keypoints`)
  projected and compared with the detector's, the distance in percent of the hand's size in the
  image, pseudo-Huber, weighed by the detector's score (a bridged frame has weight 0);
* landmarks: the directions of the 20 bones against those of the detector's 3D landmarks
  (:func:`lisa_hand.fitting.images.terms.direction_misfit`), where it gave them: which way
  each finger bends in depth, which the pixels leave open;
* the prior of every fitter (:func:`lisa_hand.fitting.terms.hand_prior`: finger pose toward
  the relaxed hand, joint limits);
* motion: the mean squared velocity (m/s) and acceleration (m/s^2) of the 3D keypoints, from
  the frames' own times (a variable frame rate is taken as it comes); the acceleration of the
  keypoints relative to the wrist (the hand's own motion), split along each keypoint's camera
  ray (depth, which one view leaves open) and across it (what the image sees: smoothing it
  costs agreement with the detections), each with its weight; and
  the finger joints' turning speed above ``max_joint_speed`` (rad/s).

Solved in two passes from an anchor frame whose pose is known (the keyframe's fit): windows of
``window`` frames stepping away from the anchor, forward then backward in time, each window's
first ``overlap`` frames already solved and held (they carry position and velocity across),
its new frames starting from the last solved frame, a few steps each to bring every frame near
its pose; then every frame of every segment at once, until it converges (each frame between
both neighbours; with too few steps the fit stays smoother than its energy and off the
keypoints), with the skeleton's betas free (``betas_lr``; under the betas prior of every
fitter, ``betas_weight``): one keyframe's keypoints leave the bone lengths loosely set, the
clip's frames in their many poses set them better. With ``temporal=False`` the motion terms
are off, the skeleton stays the keyframe's and each frame is fitted alone (from its
predecessor's fit: the ``--independent`` reference).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...skeleton import NUM_KEYPOINTS
from ..images.terms import direction_misfit
from ..optim import lr_schedule
from ..outputs.records import fingertips_at_rest, posed_keypoints
from ..priors import prior_mean_fingers
from ..terms import HandTerms, hand_prior
from .config import MotionConfig

__all__ = ["MotionData", "MotionResult", "MotionEnergy", "fit_motion"]


@dataclass(frozen=True)
class MotionData:
    """What the motion fit sees of one RIGHT hand (a left hand's keypoints mirrored first:
    ``u -> 2 cx - u``), N frames.

    K: [3, 3] the camera's intrinsics (processing pixels; the camera frame is the world).
    keypoints: [N, 21, 2] pixels (any value where ``weights`` is 0). weights: [N] the keypoint
    term's weight per frame (the detector's score; 0: no keypoints). times: [N] seconds,
    increasing. size_px: the hand's size in the image, pixels (the residuals' unit is 1 % of it).
    directions: [N, 20, 3] the unit bone directions of the detector's 3D landmarks (camera
    axes; a left hand's mirrored, x negated), any value where ``direction_weights`` is 0;
    None: no landmarks. direction_weights: [N] their weight per frame (None: no landmarks).
    """

    K: torch.Tensor
    keypoints: torch.Tensor
    weights: torch.Tensor
    times: torch.Tensor
    size_px: float
    directions: torch.Tensor | None = None
    direction_weights: torch.Tensor | None = None


@dataclass(frozen=True)
class MotionResult:
    """pose: [N, 48] radians, translation: [N, 3] metres, keypoints_3d: [N, 21, 3] metres (NaN
    rows: frames outside every fitted segment). seconds; iterations (Adam steps in all).
    betas: [K] and rest_joints: [16, 3] metres: the skeleton the motion was fitted with (the
    keyframe's, or the clip's own when ``MotionConfig.betas_lr`` > 0)."""

    pose: np.ndarray
    translation: np.ndarray
    keypoints_3d: np.ndarray
    seconds: float
    iterations: int
    betas: torch.Tensor | None = None
    rest_joints: torch.Tensor | None = None


class MotionEnergy:
    """The energy of consecutive frames (module docstring). ``temporal``: with the motion
    terms. All rows of one call are consecutive frames of the data, ``rows`` [W] their indices."""

    def __init__(self, template: Any, rest_joints: torch.Tensor, betas: torch.Tensor | None,
                 data: MotionData, config: MotionConfig, temporal: bool) -> None:
        self.template, self.rest_joints, self.betas = template, rest_joints, betas
        self.data, self.config, self.temporal = data, config, temporal
        self.prior = hand_prior(config, prior_mean_fingers(config.prior_pose))
        with torch.no_grad():  # the same for every frame and step
            self.tips_rest = fingertips_at_rest(template, rest_joints, betas)

    def keypoints(self, pose: torch.Tensor, translation: torch.Tensor,
                  betas: torch.Tensor | None = None) -> torch.Tensor:
        """[W, 48], [W, 3] -> [W, 21, 3] metres; ``betas`` [K]: with the skeleton of these
        template betas (differentiable) instead of the fixed one."""
        if betas is None:
            return posed_keypoints(self.template, self.rest_joints, self.betas, pose,
                                   translation, self.tips_rest)
        rest_joints = self.template.rest_joints(betas[None])[0]
        return posed_keypoints(self.template, rest_joints, betas, pose, translation)

    def __call__(self, rows: torch.Tensor, pose: torch.Tensor, translation: torch.Tensor,
                 data_rows: torch.Tensor, betas: torch.Tensor | None = None) -> torch.Tensor:
        """rows: [W] consecutive frame indices; pose [W, 48], translation [W, 3];
        data_rows: [W] bool, the frames whose data and prior terms count (the others are
        context: they enter only the motion terms); betas: [K] the skeleton's template betas
        when they are fitted too (None: the fixed skeleton). -> the energy (a scalar)."""
        config, data = self.config, self.data
        points = self.keypoints(pose, translation, betas)
        depth = points[..., 2].clamp_min(1e-3)
        pixels = (points @ data.K.T)[..., :2] / depth[..., None]
        distance = (pixels - data.keypoints[rows]).norm(dim=-1) * (100.0 / data.size_px)
        scale = config.keypoint_scale
        huber = scale ** 2 * (torch.sqrt(1.0 + (distance / scale) ** 2) - 1.0)
        weight = data.weights[rows] * data_rows
        energy = config.keypoint_weight * (huber.mean(-1) * weight).sum()
        if data.directions is not None and config.landmark_weight > 0:
            misfit = direction_misfit(points, data.directions[rows])
            energy = energy + config.landmark_weight * (
                misfit * data.direction_weights[rows] * data_rows).sum()
        energy = energy + (self.prior(HandTerms(pose=pose)) * data_rows).sum()
        behind = torch.relu(0.05 - points[..., 2]).sum()  # stay in front of the camera
        energy = energy + 1e4 * behind
        if not self.temporal or len(rows) < 2:
            return energy
        times = data.times[rows]
        step = (times[1:] - times[:-1]).abs().clamp_min(1e-4)  # [W-1] seconds
        velocity = (points[1:] - points[:-1]) / step[:, None, None]  # [W-1, 21, 3] m/s
        energy = energy + config.velocity_weight * (velocity ** 2).sum(-1).mean(-1).sum()
        if len(rows) > 2:
            middle = 0.5 * (step[1:] + step[:-1])
            acceleration = (velocity[1:] - velocity[:-1]) / middle[:, None, None]
            energy = energy + config.acceleration_weight * (
                acceleration ** 2).sum(-1).mean(-1).sum()
            relative = acceleration - acceleration[:, :1]  # the hand's own motion, wrist held
            ray = points[1:-1].detach()
            ray = ray / ray.norm(dim=-1, keepdim=True).clamp_min(1e-6)  # [W-2, 21, 3]
            along = (relative * ray).sum(-1) ** 2  # toward / away from the camera
            across = ((relative ** 2).sum(-1) - along).clamp_min(0.0)
            energy = energy + (config.articulation_weight * across.mean(-1).sum()
                               + config.depth_articulation_weight * along.mean(-1).sum())
        turning = (pose[1:, 3:] - pose[:-1, 3:]).abs() / step[:, None]
        excess = torch.relu(turning - config.max_joint_speed)
        return energy + config.joint_speed_weight * (excess ** 2).sum()


def _optimise(energy: MotionEnergy, spans: list[tuple[torch.Tensor, torch.Tensor]],
              pose: torch.Tensor, translation: torch.Tensor, iterations: int, bar: Any = None,
              betas: torch.Tensor | None = None) -> torch.Tensor | None:
    """Adam under the cosine schedule on the free rows of ``spans`` of ``pose`` [N, 48] and
    ``translation`` [N, 3] (in place) and, where ``betas`` [K] is given, on the one skeleton
    of them all (its template betas, under ``config.betas_weight`` x their mean square, as in
    every fitter). spans: (rows [W] consecutive frame indices, free [W] bool) each, an energy
    each: its held rows are context, fixed. ``bar`` (a progress bar, or None) counts the
    steps. -> the fitted betas (None where not given)."""
    config = energy.config
    moving = torch.cat([rows[free] for rows, free in spans])
    free_pose = pose[moving].clone().requires_grad_(True)
    free_translation = translation[moving].clone().requires_grad_(True)
    groups = [{"params": [free_pose], "lr": config.pose_lr},
              {"params": [free_translation], "lr": config.translation_lr}]
    free_betas = None
    if betas is not None:
        free_betas = betas.detach().float().clone().requires_grad_(True)
        groups.append({"params": [free_betas], "lr": config.betas_lr})
    optimizer = torch.optim.Adam(groups)
    schedule = lr_schedule(optimizer, iterations, config.final_lr_fraction)
    held = [(pose[rows].detach(), translation[rows].detach()) for rows, _ in spans]
    bounds = np.cumsum([0] + [int(free.sum()) for _, free in spans])
    for _ in range(iterations):
        optimizer.zero_grad(set_to_none=True)
        total = 0.0
        for (rows, free), (held_pose, held_translation), begin, end in zip(
                spans, held, bounds[:-1], bounds[1:], strict=True):
            span_pose, span_translation = held_pose.clone(), held_translation.clone()
            span_pose[free] = free_pose[begin:end]
            span_translation[free] = free_translation[begin:end]
            total = total + energy(rows, span_pose, span_translation, free, free_betas)
        if free_betas is not None:
            total = total + config.betas_weight * free_betas.square().mean()
        total.backward()
        optimizer.step()
        schedule.step()
        if bar is not None:
            bar.update(1)
    with torch.no_grad():
        pose[moving] = free_pose.detach()
        translation[moving] = free_translation.detach()
    return None if free_betas is None else free_betas.detach()


def _sweep(energy: MotionEnergy, order: list[int], pose: torch.Tensor,
           translation: torch.Tensor, bar: Any = None) -> int:
    """Windows along ``order`` (frame rows, the first one solved): each window's first
    ``overlap`` rows held, the rest started from the last solved row -> Adam steps taken."""
    config = energy.config
    steps, done = 0, 1
    fresh = config.window - config.overlap
    while done < len(order):
        held = order[max(0, done - config.overlap):done]
        new = order[done:done + fresh]
        with torch.no_grad():
            pose[new] = pose[order[done - 1]].clone()
            translation[new] = translation[order[done - 1]].clone()
        window = sorted(held + new)  # frame order, whichever way the sweep goes
        free = torch.tensor([row in new for row in window])
        _optimise(energy, [(torch.tensor(window), free)], pose, translation,
                  config.window_iters, bar)
        steps += config.window_iters
        done += len(new)
    return steps


def _planned_steps(segments: list, config: MotionConfig) -> int:
    """The Adam steps :func:`fit_motion` takes on ``segments`` (for its progress bar)."""
    fresh = config.window - config.overlap
    total = 0
    for first, end, anchor, *_ in segments:
        windows = -(-(end - anchor - 1) // fresh) + -(-(anchor - first) // fresh)
        total += windows * config.window_iters
    if any(end - first > 1 for first, end, *_ in segments):
        total += config.refine_iters
    return total


def fit_motion(template: Any, rest_joints: torch.Tensor, betas: torch.Tensor | None,
               data: MotionData, segments: list[tuple[int, int, int, torch.Tensor, torch.Tensor]],
               config: MotionConfig, temporal: bool = True, progress: bool = False
               ) -> MotionResult:
    """Fit the pose and translation of a RIGHT hand in the frames of ``segments``.

    template: the mesh template (float32, CPU). rest_joints: [16, 3] metres; betas: [K] or
    None: the hand's skeleton and template shape (the keyframe's: fixed with
    ``config.betas_lr`` = 0, without betas or with ``temporal=False``; else the start of the
    clip's, ``template.rest_joints(betas)`` then). data: :class:`MotionData` of all N
    frames. segments: (first, end, anchor, anchor_pose [48], anchor_translation [3]) per run
    of frames to fit, rows [first, end) with the pose known at row ``anchor``.
    temporal: with the motion terms (False: each frame alone; the final pass over all frames,
    ``config.refine_iters`` steps, is then more steps for each alone). progress: a progress
    bar of the steps.
    -> :class:`MotionResult` (NaN outside the segments).
    """
    from ..stages import progress_bar

    began = time.perf_counter()
    count = data.keypoints.shape[0]
    energy = MotionEnergy(template, rest_joints, betas, data, config, temporal)
    pose = torch.full((count, 48), float("nan"))
    translation = torch.full((count, 3), float("nan"))
    steps = 0
    refine_iters = config.refine_iters
    for first, end, anchor, *_ in segments:
        if not 0 <= first <= anchor < end <= count:
            raise ValueError(f"segment ({first}, {end}) must hold its anchor row {anchor}")
    bar = progress_bar(progress, _planned_steps(segments, config), "motion")
    for first, end, anchor, anchor_pose, anchor_translation in segments:
        pose[anchor] = anchor_pose.float()
        translation[anchor] = anchor_translation.float()
        steps += _sweep(energy, list(range(anchor, end)), pose, translation, bar)
        steps += _sweep(energy, list(range(anchor, first - 1, -1)), pose, translation, bar)
    spans = [(first, end) for first, end, *_ in segments if end - first > 1]
    fit_skeleton = temporal and config.betas_lr > 0 and betas is not None
    if refine_iters > 0 and spans:
        fitted_betas = _optimise(energy, [(torch.arange(first, end),
                                           torch.ones(end - first, dtype=torch.bool))
                                          for first, end in spans], pose, translation,
                                 refine_iters, bar, betas if fit_skeleton else None)
        steps += refine_iters
        if fitted_betas is not None:
            betas = fitted_betas
            rest_joints = template.rest_joints(betas[None])[0]
            energy = MotionEnergy(template, rest_joints, betas, data, config, temporal)
    if bar is not None:
        bar.close()
    keypoints = torch.full((count, NUM_KEYPOINTS, 3), float("nan"))
    fitted = torch.isfinite(pose).all(-1)
    with torch.no_grad():
        if fitted.any():
            keypoints[fitted] = energy.keypoints(pose[fitted], translation[fitted])
    return MotionResult(pose=pose.numpy().astype(np.float64),
                        translation=translation.numpy().astype(np.float64),
                        keypoints_3d=keypoints.numpy().astype(np.float64),
                        seconds=time.perf_counter() - began, iterations=steps,
                        betas=None if betas is None else betas.detach().float(),
                        rest_joints=rest_joints.detach().float())
