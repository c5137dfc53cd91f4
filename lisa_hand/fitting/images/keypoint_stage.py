"""The keypoint stage of the image fit (:func:`fit_keypoints`; paper Section 4.3: 1k
iterations): pose, translation and the template's ``betas`` from 2D keypoints and masks, on the
MANO-like mesh template (no LISA model: the result depends on the views and the template only).

Objective, per candidate: the posed template's 21 keypoints are projected into every view and
compared with the given ones (L1 in pixels over the visible keypoints, as L_joints). Where a
view has a mask, the projected template vertices must fall inside it (the mask's outside
distance transform at each vertex, pixels) and the mask's contour must be covered by them
(distance from contour pixels to the nearest projected vertex;
:func:`lisa_hand.fitting.images.terms.silhouette_terms`). Where a view has the detector's 3D
landmarks, each bone's lean along the camera's rays is pulled toward theirs
(``landmark_weight``, :func:`lisa_hand.fitting.images.terms.direction_misfit`): which way a
finger bends in depth, which the pixels leave open. Priors
(:func:`lisa_hand.fitting.terms.hand_prior`): soft joint limits, a small L2 pull of the
finger pose towards ``prior_pose`` ("relaxed") and of ``betas`` towards 0, and the training
subjects' hand size (``size_weight``, :class:`lisa_hand.fitting.images.shape_prior.HandSizePrior`:
with one view, it is what sets the depth). The hand is kept 5 cm in front of every camera.

Restarts: the ``restarts`` starts of the global-pose search
(:func:`lisa_hand.fitting.images.pose_search.view_candidate_rotations`, the fingers relaxed,
the translation in closed form) are optimised rigidly (palm keypoints only) for
``rigid_fraction`` of the iterations, the ``keep_restarts`` best then with every parameter, and
for the last ``finger_restart_fraction`` the best one beside copies of it in which each finger
whose keypoints are off by more than ``finger_restart_px`` restarts from the flat, relaxed and
fist poses (a finger bent the wrong way is a local minimum). The lowest objective wins.

One view leaves the depth open: the keypoints fit to a fraction of a pixel with the hand 10-15%
too near, its fingers curled to match, a local minimum the objective does not prefer. So with
one view, before the finger restarts, the best
candidate also restarts at ``depth_factors`` times its distance from the camera, for
``depth_restart_fraction`` more of the iterations, and the candidates are ranked by the
objective without the silhouette terms: the template's silhouette is not the subject's, and its
vertices outside the mask cost less the farther (smaller) the hand, which would rank a hand
that is too far first. The best candidate stays as it was unless a moved copy
ranks lower.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from ...skeleton import FINGER_JOINTS, FINGER_NAMES
from ...skeleton.params import HandParams
from ..optim import lr_schedule
from ..priors import prior_mean_fingers
from ..stages import HistoryRecord, StageReport, progress_bar, template_on
from ..terms import HandTerms, hand_prior
from .config import FitImagesConfig
from .pose_search import (
    solve_translation,
    translation_from_masks,
    view_candidate_rotations,
)
from .shape_prior import HandSizePrior
from .terms import (
    ViewData,
    keypoint_l1,
    keypoint_px,
    silhouette_terms,
)
from .views import ImageView, check_views

__all__ = ["fit_keypoints", "keypoint_errors", "mean_keypoint_error"]

_START_POSE = "relaxed"
"""Finger pose the candidates start from (and that the global-pose search turns)."""
_FINGER_KEYPOINTS = {"thumb": (2, 3, 4), "index": (6, 7, 8), "middle": (10, 11, 12),
                     "ring": (14, 15, 16), "pinky": (18, 19, 20)}
"""Keypoints that each finger's pose moves (its knuckle keypoint moves with the palm)."""
_FINGER_STARTS = ("flat", "relaxed", "fist")
"""Named poses whose finger chains restart a badly fitted finger."""
_MIN_CAMERA_DISTANCE = 0.05  # metres: the hand stays this far in front of every camera
_BEHIND_WEIGHT = 1e4


@dataclass
class _Candidates:
    """The stage's unknowns for B candidates (private to this stage)."""

    global_orient: torch.Tensor  # [B, 3] radians
    fingers: torch.Tensor  # [B, 45] radians
    translation: torch.Tensor  # [B, 3] metres
    betas: torch.Tensor  # [B, K]

    def pose(self) -> torch.Tensor:
        return torch.cat([self.global_orient, self.fingers], dim=-1)

    def select(self, index: torch.Tensor) -> _Candidates:
        return _Candidates(*(value[index].detach().clone() for value in
                             (self.global_orient, self.fingers, self.translation, self.betas)))


def _objective(template: Any, state: _Candidates, data: ViewData, config: FitImagesConfig,
               mean_fingers: torch.Tensor, rigid: bool = False,
               size_prior: HandSizePrior | None = None, silhouette: bool = True
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (loss [B], keypoint error [B] pixels). ``rigid``: only the palm's keypoints count
    (the fingers' pose is not known yet). ``silhouette``: with the mask terms (when the views
    have masks)."""
    pose = state.pose()
    out = template.forward(pose, state.betas, state.translation)
    keypoint_pixels, keypoint_depth = data.project(out.keypoints)
    loss = keypoint_l1(keypoint_pixels, data, palm_only=rigid)
    if config.landmark_weight > 0 and not rigid:
        loss = loss + config.landmark_weight * data.direction_misfit(out.keypoints)
    vertex_pixels, vertex_depth = data.project(out.vertices)
    if data.num_masks and silhouette:
        outside, coverage = silhouette_terms(vertex_pixels, data)
        loss = loss + config.silhouette_weight * outside + config.coverage_weight * coverage
    # Keep the hand in front of every camera (5 cm at least): pixels are meaningless behind.
    behind = (F.relu(_MIN_CAMERA_DISTANCE - vertex_depth).mean((1, 2))
              + F.relu(_MIN_CAMERA_DISTANCE - keypoint_depth).mean((1, 2)))
    prior = hand_prior(config, mean_fingers, size_prior=size_prior)
    loss = loss + _BEHIND_WEIGHT * behind + prior(HandTerms(pose=pose, betas=state.betas,
                                                            joints=out.joints))
    return loss, keypoint_px(keypoint_pixels.detach(), data)


def _finger_residuals(template: Any, state: _Candidates, data: ViewData) -> torch.Tensor:
    """Mean keypoint error (pixels) of each finger over its visible keypoints, in
    :data:`lisa_hand.skeleton.FINGER_NAMES` order: [B, 5] (0 where none is visible)."""
    keypoints = template.forward(state.pose(), state.betas, state.translation).keypoints
    pixels, _ = data.project(keypoints)
    distance = (pixels - data.keypoints).norm(dim=-1) * data.visible  # [B, C, 21]
    residuals = []
    for name in FINGER_NAMES:
        index = list(_FINGER_KEYPOINTS[name])
        count = data.visible[:, index].sum().clamp_min(1.0)
        residuals.append(distance[..., index].sum((1, 2)) / count)
    return torch.stack(residuals, dim=-1)


def _depth_copies(template: Any, state: _Candidates, data: ViewData,
                  factors: Sequence[float]) -> _Candidates:
    """``state`` (batch of one) followed by one copy per factor of ``factors``, moved along the
    ray from the (first) camera's centre through its keypoints' centre to that multiple of its
    distance: the same image, up to perspective, of a hand nearer or farther."""
    with torch.no_grad():
        centre = -(data.R[0].transpose(0, 1) @ data.t[0])  # [3] the camera centre, world
        keypoints = template.forward(state.pose(), state.betas, state.translation).keypoints[0]
        ray = keypoints.mean(0) - centre
        translation = torch.stack([state.translation[0]] + [
            state.translation[0] + (float(factor) - 1.0) * ray for factor in factors])
    count = translation.shape[0]

    def repeat(value: torch.Tensor) -> torch.Tensor:
        return value.expand(count, -1).clone()

    return _Candidates(repeat(state.global_orient), repeat(state.fingers), translation,
                       repeat(state.betas))


def _restart_fingers(state: _Candidates, fingers: Sequence[str]) -> _Candidates:
    """``state`` (batch of one) followed by one copy per finger of ``fingers`` and named pose
    of :data:`_FINGER_STARTS`, with that finger's three joints set to the named pose's."""
    from ...handmodel.poses import named_pose

    rows = [state.fingers[0]]
    for finger in fingers:
        slots = [3 * (joint - 1) + axis for joint in FINGER_JOINTS[finger] for axis in range(3)]
        for name in _FINGER_STARTS:
            start = named_pose(name)[3:].to(state.fingers)
            row = state.fingers[0].clone()
            row[slots] = start[slots]
            rows.append(row)
    count = len(rows)

    def repeat(value: torch.Tensor) -> torch.Tensor:
        return value.expand(count, -1).clone()

    return _Candidates(repeat(state.global_orient), torch.stack(rows),
                       repeat(state.translation), repeat(state.betas))


class _Optimiser:
    """Runs Adam on candidates for a number of iterations, recording per iteration (numbered
    across runs) the best candidate's loss ("energy") and keypoint error ("kp_px", pixels)."""

    def __init__(self, template: Any, data: ViewData, config: FitImagesConfig,
                 mean_fingers: torch.Tensor, bar: Any) -> None:
        self.template, self.data, self.config = template, data, config
        self.mean_fingers, self.bar = mean_fingers, bar
        self.size_prior = HandSizePrior.from_template(template).for_keypoints(
            data.num_visible)
        self.history: list[HistoryRecord] = []

    def objective(self, state: _Candidates, rigid: bool) -> tuple[torch.Tensor, torch.Tensor]:
        return _objective(self.template, state, self.data, self.config, self.mean_fingers,
                          rigid, self.size_prior)

    def run(self, state: _Candidates, iterations: int, rigid: bool
            ) -> tuple[torch.Tensor, torch.Tensor]:
        """Optimise ``state`` in place (``rigid``: rotation and translation only) -> the final
        (loss [B], keypoint error [B] px)."""
        config = self.config
        free = [state.global_orient, state.translation]
        if not rigid:
            free += [state.fingers, state.betas]
        for value in free:
            value.requires_grad_(True)
        groups = [{"params": [state.global_orient], "lr": config.keypoint_pose_lr},
                  {"params": [state.translation], "lr": config.keypoint_translation_lr}]
        if not rigid:
            groups.append({"params": [state.fingers], "lr": config.keypoint_pose_lr})
            if config.keypoint_betas_lr > 0:
                groups.append({"params": [state.betas], "lr": config.keypoint_betas_lr})
        optimizer = torch.optim.Adam(groups)
        schedule = lr_schedule(optimizer, iterations, config.final_lr_fraction)
        for _ in range(iterations):
            optimizer.zero_grad(set_to_none=True)
            loss, error = self.objective(state, rigid)
            loss.sum().backward()
            optimizer.step()
            schedule.step()
            best = int(loss.detach().argmin())
            self.history.append({"stage": "keypoints", "iteration": len(self.history),
                                 "energy": float(loss.detach()[best]),
                                 "kp_px": float(error[best])})
            if self.bar is not None:
                self.bar.update(1)
                self.bar.set_postfix(px=f"{float(error[best]):.2f}")
        for value in free:
            value.requires_grad_(False)
        with torch.no_grad():
            return self.objective(state, rigid)


def _restart_depth(optimiser: _Optimiser, state: _Candidates, loss: torch.Tensor,
                   error: torch.Tensor, best: int, iterations: int
                   ) -> tuple[_Candidates, torch.Tensor, torch.Tensor, int]:
    """The depth restarts of a one-view fit (module docstring): candidate ``best`` of ``state``
    (its ``loss`` and keypoint ``error`` [B]) beside its copies at ``depth_factors`` times its
    distance, ``iterations`` steps, ranked without the silhouette terms -> (state, loss, error,
    best) to go on with: the winning copy, or candidate ``best`` as it was."""
    template, data, config = optimiser.template, optimiser.data, optimiser.config
    kept = state.select(torch.tensor([best], device=data.device))
    kept_loss, kept_error = loss[best:best + 1].clone(), error[best:best + 1].clone()
    moved = _depth_copies(template, kept, data, config.depth_factors)
    loss, error = optimiser.run(moved, iterations, rigid=False)
    with torch.no_grad():
        score, _ = _objective(template, moved, data, config, optimiser.mean_fingers,
                              size_prior=optimiser.size_prior, silhouette=False)
    winner = int(score.argmin())
    if winner == 0:  # the unmoved hand, as it was before these steps
        return kept, kept_loss, kept_error, 0
    return moved, loss, error, winner


def _start(template: Any, data: ViewData, config: FitImagesConfig,
           generator: torch.Generator) -> _Candidates:
    """The candidates of the global-pose search, fingers relaxed, translation in closed form."""
    start_fingers = prior_mean_fingers(_START_POSE, data.device)
    with torch.no_grad():
        rotations = view_candidate_rotations(template, data, config, start_fingers, generator)
        count = rotations.shape[0]
        fingers = start_fingers.expand(count, -1).clone()
        betas = torch.zeros(count, int(template.num_betas), device=data.device)
        posed = template.forward(torch.cat([rotations, fingers], dim=-1), betas, None)
        if data.num_visible:
            translation = solve_translation(posed.keypoints, data)
        else:
            translation = translation_from_masks(posed.vertices, data)
    return _Candidates(rotations.clone(), fingers, translation, betas)


def fit_keypoints(
    views: Sequence[ImageView],
    config: FitImagesConfig | None = None,
    template: Any = None,
    progress: bool = False,
) -> tuple[HandParams, StageReport]:
    """The keypoint stage: pose, translation and template betas from 2D keypoints and masks
    (see the module docstring for the objective and the restarts).

    views: the views (:func:`lisa_hand.fitting.images.views.read_views`), at least one with
    keypoints
        or a mask; all tensors on one device (the fit's). A right hand (mirror a left one's
        views first, :func:`lisa_hand.fitting.images.views.mirror_view`).
    template: the MANO-like template (:func:`lisa_hand.handmodel.template.load_template`, the
        default): ``forward(pose [B, 48], betas [B, K], translation [B, 3])`` with
        ``.vertices`` [B, V, 3] and ``.keypoints`` [B, 21, 3], ``rest_joints(betas)`` and
        ``num_betas``.
    -> (hand, report): the hand's pose [48] radians, translation [3] metres, betas [K] and
    rest_joints [16, 3] metres (``template.rest_joints(betas)``), an empty ``shape_code`` and no
    colour code (the template has no LISA codes; see
    :func:`lisa_hand.fitting.images.color_stage.with_mean_codes`), ``model="template"``; the
    :class:`StageReport` ("keypoints"): history records with "energy" and "kp_px" (the best
    candidate's loss and keypoint error, pixels, per iteration), keypoint error, loss (and
    ``energies == [loss]``), seconds and the winning candidate.
    """
    began = time.perf_counter()
    config = FitImagesConfig() if config is None else config
    views = check_views(views)
    device = views[0].rgb.device
    template = template_on(template, device)
    generator = torch.Generator().manual_seed(config.seed)
    data = ViewData(views, config.coverage_pixels, generator)
    mean_fingers = prior_mean_fingers(config.prior_pose, device)
    state = _start(template, data, config, generator)

    total_iters = config.keypoint_iters
    rigid_iters = int(round(config.rigid_fraction * total_iters))
    finger_iters = int(round(config.finger_restart_fraction * total_iters))
    one_view = data.K.shape[0] == 1 and len(config.depth_factors) > 0
    depth_iters = int(round(config.depth_restart_fraction * total_iters)) if one_view else 0
    bar = progress_bar(progress, total_iters + depth_iters, "keypoints")
    optimiser = _Optimiser(template, data, config, mean_fingers, bar)
    loss, _ = optimiser.run(state, rigid_iters, rigid=True)
    keep = min(config.keep_restarts, state.global_orient.shape[0])
    state = state.select(loss.argsort()[:keep])
    loss, error = optimiser.run(state, total_iters - rigid_iters - finger_iters, rigid=False)
    best = int(loss.argmin())
    if depth_iters > 0:
        state, loss, error, best = _restart_depth(optimiser, state, loss, error, best,
                                                  depth_iters)
    if finger_iters > 0:
        # The best candidate goes on, beside copies of it with each badly fitted finger
        # restarted from other poses (a finger bent the wrong way is a local minimum).
        state = state.select(torch.tensor([best], device=device))
        with torch.no_grad():
            bad = _finger_residuals(template, state, data)[0] > config.finger_restart_px
        state = _restart_fingers(state, [name for name, flag in zip(FINGER_NAMES, bad.tolist(),
                                                                     strict=True) if flag])
        loss, error = optimiser.run(state, finger_iters, rigid=False)
        best = int(loss.argmin())
    if bar is not None:
        bar.close()
    betas = state.betas[best].detach()
    with torch.no_grad():
        rest_joints = template.rest_joints(betas[None])[0]
    hand = HandParams(pose=state.pose()[best].detach(), translation=state.translation[best],
                      rest_joints=rest_joints, shape_code=torch.zeros(0), betas=betas,
                      model="template")
    return hand, StageReport(stage="keypoints", seconds=time.perf_counter() - began,
                             loss=float(loss[best]), energies=[float(loss[best])],
                             history=optimiser.history, keypoint_error_px=float(error[best]),
                             candidate=best)


def _view_distances(template: Any, views: Sequence[ImageView], hand: HandParams
                    ) -> dict[str, torch.Tensor]:
    """{view with keypoints: [n] distances (pixels) of its visible keypoints to the hand's
    projected template keypoints}."""
    device = views[0].rgb.device if views else torch.device("cpu")
    betas = (torch.zeros(int(template.num_betas)) if hand.betas is None else hand.betas)
    with torch.no_grad():
        keypoints = template.forward(hand.pose[None].to(device), betas[None].to(device),
                                     hand.translation[None].to(device)).keypoints[0]
    distances = {}
    for view in views:
        if not view.has_keypoints:
            continue
        pixels, _ = view.camera.project(keypoints.to(view.camera.K))
        distances[view.name] = (pixels - view.keypoints).norm(dim=-1)[view.visible]
    return distances


def keypoint_errors(template: Any, views: Sequence[ImageView], hand: HandParams
                    ) -> dict[str, float]:
    """Mean reprojection error (pixels) of the template's keypoints in each view with keypoints.

    template: on the views' device (float32). hand: a right hand in the views' world (its pose,
    translation and betas) -> {view name: mean px over its visible keypoints}.
    """
    return {name: float(distance.mean())
            for name, distance in _view_distances(template, views, hand).items()}


def mean_keypoint_error(template: Any, views: Sequence[ImageView], hand: HandParams) -> float:
    """Mean reprojection error (pixels) over the visible keypoints of all views (NaN without
    keypoints); as :func:`keypoint_errors`."""
    distances = list(_view_distances(template, views, hand).values())
    if not distances:
        return math.nan
    return float(torch.cat(distances).mean())
