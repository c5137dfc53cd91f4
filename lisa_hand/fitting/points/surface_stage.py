"""The surface stage of the point fit ('field'): every unknown on the LISA field.

Field energy (lengths in metres), per candidate: the data terms of :mod:`.field_terms` and the
prior terms of :func:`lisa_hand.fitting.terms.hand_prior`::

    E = mean_i rho(G(x_i))
        + w_n mean_i [rho(G(x_i + eps n_i) - eps) + rho(G(x_i - eps n_i) + eps)] / 2
        + w_f mean_j rho(min(G(f_j), 0))
        + w_s mean (beta+ / s)^2 + w_p prior(theta_fingers) + w_l limits(theta)
        + w_b mean betas^2

``rho`` is :func:`lisa_hand.fitting.robust.robust_loss` at scale ``robust_scale_mm`` (the paper's
``|G|`` with 'l1'). The free-space term (only for a one-view scan whose sensor position is known,
:mod:`.free_space`) asks the field to be outside at points ``f_j`` the sensor saw to be empty: some
spread over the view, the rest near the candidates' surfaces. The normal term (only with normals)
asks the field to grow outwards along the normals, which fixes the side of the surface the points
are on. With a wrist cut (``config.wrist_clip_m``) each candidate's means run over the points
on its own hand's side of its own cut (scan points) and of its wrist joint (free points): a
scan's forearm, or the space beyond where a scan stops, weighs on no candidate, whatever their
wrists (with one cut for all, the best proxy candidate's, a forearm that the model's stub does
not match can cost the right hand more than a wrong one that covers it with its palm). Far from
the hand ``G`` does not vanish: outside every bone region the field is the distance to the
regions plus a margin, so far points still pull the hand towards them. The data term only asks
every scan point to be on the surface, never every surface point to be seen, so partial scans
work; what the scan does not see stays near the prior (shape code near the mean, fingers near
``prior_pose`` and within the joint limits).

The unknowns: the global rotation, the translation, the finger pose, the shape code and the
template's betas (whose joint regressor gives the skeleton LISA is conditioned on), on
``points_per_iteration`` random points per iteration, every candidate batched in one field
evaluation (bones culled). The field tells candidates apart much better than the proxy (a hand
turned over fits a one-sided scan's proxy almost as well), so several go on, and at the
fractions ``prune_after`` of the iterations the worse ones stop (8 -> 3 -> 1).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace

import torch

from ...skeleton.params import HandParams
from ..optim import adam, keep_rows, lr_schedule
from ..priors import prior_mean_fingers
from ..stages import StageReport
from ..terms import hand_prior
from .candidates import CandidateBatch
from .cloud import TargetCloud
from .field_terms import FieldSample, field_energy, field_terms
from .monitor import FitMonitor

__all__ = ["frozen_field", "shape_code_scale", "fit_surface", "surface_residuals"]

_MM = 1e-3
_MIN_SHAPE_SCALE = 1e-3  # floor of the shape code's unit
_EVALUATION_POINTS = 2048  # cloud points of the fixed subset that ranks candidates


@contextlib.contextmanager
def frozen_field(model) -> Iterator[None]:
    """The block runs with the model's field in eval mode and its weights without gradients
    (only a fit's unknowns need them); both are given back afterwards."""
    field_model = model.field
    was_training = field_model.training
    requires_grad = [p.requires_grad for p in field_model.parameters()]
    field_model.eval()
    for weight in field_model.parameters():
        weight.requires_grad_(False)
    try:
        yield
    finally:
        for weight, flag in zip(field_model.parameters(), requires_grad, strict=True):
            weight.requires_grad_(flag)
        field_model.train(was_training)


def shape_code_scale(model) -> float:
    """The unit of the shape code's step and prior: the training codes' root mean square entry
    (floored for a model whose codes are all zero, e.g. a fresh one)."""
    return max(float(model.shape_codes.square().mean().sqrt()), _MIN_SHAPE_SCALE)


class _FieldEnergy:
    """The field energy of a batch of candidates on one cloud (see the module docstring)."""

    def __init__(self, model, cloud: TargetCloud, config, hands: Sequence[HandParams],
                 template, unseen: torch.Tensor | None = None) -> None:
        field_model = model.field
        self.field = field_model
        self.cloud = cloud
        self.config = config
        like = dict(device=cloud.points.device, dtype=cloud.points.dtype)
        self.template = template
        color = hands[0].color_code
        self.color_code = None if color is None else color.to(**like)
        self.code_scale = shape_code_scale(model)
        self.shape_scale = self.code_scale if config.fit_shape else None
        self.mean_fingers = prior_mean_fingers(config.prior_pose, **like)
        self.prior = hand_prior(config, self.mean_fingers, shape_scale=self.shape_scale,
                                coupling=unseen)
        self.terms = field_terms(config)
        self.cuts: tuple[torch.Tensor, torch.Tensor] | None = None  # see place_cuts

    def rest_joints(self, batch: CandidateBatch) -> torch.Tensor:
        """[K, 16, 3] the candidates' skeletons: fixed, or the template's for their betas."""
        if self.template is None:
            return batch.rest_joints
        return self.template.rest_joints(batch.betas)

    def state(self, batch: CandidateBatch):
        rest_joints = self.rest_joints(batch)
        pose, translation = batch.mano(rest_joints)
        color = None if self.color_code is None else self.color_code.expand(batch.count, -1)
        return self.field.prepare(pose, translation, rest_joints, batch.shape_code, color)

    @torch.no_grad()
    def place_cuts(self, batch: CandidateBatch) -> None:
        """Fix each candidate's wrist cut where its hand is now (:meth:`hand_side` uses it
        until the next call). Placed at the start, before each pruning and before the final
        ranking, not at every step: a cut that followed every step would let the optimiser
        drop the points it fits worst behind its wrist."""
        if self.config.wrist_clip_m is None:
            self.cuts = None
            return
        rest_joints = self.rest_joints(batch)
        _, translation = batch.mano(rest_joints)
        # the wrist joints [K, 3] and a right hand's forearm axes [K, 3]
        self.cuts = (rest_joints[:, 0] + translation, batch.rotation()[:, :, 0])

    @torch.no_grad()
    def hand_side(self, batch: CandidateBatch, points: torch.Tensor, offset: float
                  ) -> torch.Tensor | None:
        """[K, N] 1 where each candidate keeps a point [N, 3] (on its hand's side of its
        wrist cut ``offset`` metres beyond the wrist joint, as :meth:`place_cuts` placed it;
        placed now when it was not, for this batch), else 0; None without a cut
        (``config.wrist_clip_m`` None)."""
        if self.config.wrist_clip_m is None:
            return None
        if self.cuts is None or self.cuts[0].shape[0] != batch.count:
            self.place_cuts(batch)
        wrist, forearm = self.cuts
        beyond = ((points[None] - wrist[:, None]) * forearm[:, None]).sum(-1)  # [K, N]
        return (beyond <= offset).to(points.dtype)

    def data(self, batch: CandidateBatch, index: torch.Tensor, scale: float,
             free_index: torch.Tensor | None = None) -> torch.Tensor:
        """[K] the data terms (:mod:`.field_terms`) at the cloud points ``index`` and its free
        points ``free_index`` (when it has any), one field evaluation for all. With a wrist
        cut, each candidate counts only the points on its own hand's side of it (the means
        over those: :meth:`hand_side`), so that a scan's forearm, or the model's stub where a
        scan stops short, weighs on no candidate."""
        config, cloud = self.config, self.cloud
        has_free = free_index is not None and free_index.numel() > 0
        sample = FieldSample(
            cloud=cloud, index=index, free_index=free_index,
            keep=self.hand_side(batch, cloud.points[index], config.wrist_clip_m or 0.0),
            free_keep=self.hand_side(batch, cloud.free[free_index], 0.0) if has_free else None,
            scale=scale, robust=config.robust_loss, count=batch.count)
        state = self.state(batch)

        def evaluate(points: torch.Tensor) -> torch.Tensor:
            return self.field.field(state, points.expand(batch.count, -1, -1).contiguous(),
                                    with_color=False).sdf

        return field_energy(self.terms, sample, evaluate)

    def free_sample(self, count: int) -> torch.Tensor | None:
        """[min(M, count)] random indices of the cloud's free points, or None without any."""
        free = self.cloud.free
        if free is None or self.config.free_space_weight <= 0 or free.shape[0] == 0:
            return None
        if free.shape[0] <= count:
            return torch.arange(free.shape[0], device=free.device)
        return torch.randperm(free.shape[0], generator=self.cloud.generator)[:count].to(
            free.device)

    def total(self, batch: CandidateBatch, index: torch.Tensor,
              free_index: torch.Tensor | None = None) -> torch.Tensor:
        """[K] data term at the final robust scale plus the prior."""
        data = self.data(batch, index, self.config.robust_scale_mm * _MM, free_index)
        return data + self.prior(batch.terms())

    @torch.no_grad()
    def evaluate(self, batch: CandidateBatch) -> torch.Tensor:
        """[K] the energy on a fixed subset of the cloud (seed ``config.seed + 1``) and the first
        :data:`_EVALUATION_POINTS` of its free points."""
        generator = torch.Generator(device="cpu").manual_seed(self.config.seed + 1)
        num = self.cloud.num_points
        index = torch.arange(num) if num <= _EVALUATION_POINTS else torch.randperm(
            num, generator=generator)[:_EVALUATION_POINTS]
        free = None
        if self.free_sample(1) is not None:
            free = torch.arange(min(self.cloud.free.shape[0], _EVALUATION_POINTS),
                                device=self.cloud.free.device)
        return self.total(batch, index.to(self.cloud.points.device), free)


def _prune_schedule(config, count: int) -> dict[int, int]:
    """Iteration -> candidates left: ``K -> K^(1 - i/n) -> ... -> 1`` at the fractions
    ``prune_after`` of the field iterations."""
    iterations = config.field_iters
    return {int(round(fraction * iterations)):
            max(1, round(count ** (1.0 - (number + 1) / len(config.prune_after))))
            for number, fraction in enumerate(config.prune_after)}


def fit_surface(model, cloud: TargetCloud, candidates: Sequence[HandParams], config, *,
                template=None, pivot: torch.Tensor | None = None,
                monitor: FitMonitor | None = None,
                free_near: Callable[[CandidateBatch], torch.Tensor] | None = None,
                unseen: torch.Tensor | None = None) -> tuple[HandParams, StageReport]:
    """The surface stage (see the module docstring): ``config.field_iters`` Adam steps of all
    candidates on the LISA field, pruned to the best one.

    model: a :class:`lisa_hand.model.trained.TrainedModel` on the cloud's device and dtype.
    candidates: right hands (pose, translation, skeleton, shape and colour codes).
    config: a :class:`~lisa_hand.fitting.points.config.FitPointsConfig`.
    template: the mesh template whose betas give the skeleton (fitted when
        ``config.fit_betas``, from the hands' betas, zeros where a hand has none; the hands'
        skeletons should be the template's for their betas); None: the hands' skeletons stay.
    pivot: [3] metres in the rest frame, the point the candidates rotate about while they are
        optimised (default: the first hand's mean rest joint); it changes the steps, not the
        energy.
    free_near: batch -> [M, 3] world metres, free-space points near the batch's surfaces
        (:func:`lisa_hand.fitting.points.stages._free_near`), added to the cloud's own at the start
        and drawn again every ``config.free_near_every`` steps and at each pruning, so that a
        part of a candidate that moves (an unseen finger straightening) still meets the space
        the sensor saw empty; None: the cloud's free points only.
    unseen: [5] weights of the fingers a one-view sensor could not see
        (:func:`.proxy.unseen_fingers`), for the prior's coupling; None: none.
    -> (the best hand; the :class:`StageReport` ('field'): its energy on a fixed subset of the
    cloud, ``loss`` and ``energies[0]``).
    """
    began = len(monitor.history) if monitor is not None else 0
    start = time.perf_counter()
    like = dict(device=cloud.points.device, dtype=cloud.points.dtype)
    pivot = candidates[0].rest_joints.mean(0).to(**like) if pivot is None else pivot.to(**like)
    fit_betas = template is not None and config.fit_betas
    template = template if fit_betas else None
    if fit_betas:  # a hand without betas starts from the template's mean shape
        candidates = [hand if hand.betas is not None else
                      replace(hand, betas=torch.zeros(template.num_betas), extra={})
                      for hand in candidates]
    with frozen_field(model):
        energy = _FieldEnergy(model, cloud, config, candidates, template, unseen)
        batch = CandidateBatch.from_hands(candidates, pivot, with_betas=fit_betas)
        batch = _optimise(energy, batch, candidates[0], monitor, free_near)
        energy.place_cuts(batch)
        if batch.count > 1:
            batch = batch.select(torch.argmin(energy.evaluate(batch)).reshape(1))
        scores = energy.evaluate(batch)
        with torch.no_grad():
            hand = batch.hand(0, candidates[0], energy.rest_joints(batch))
    history = monitor.history[began:] if monitor is not None else []
    return hand, StageReport(stage="field", seconds=time.perf_counter() - start,
                             loss=float(scores[0]), energies=[float(scores[0])], history=history)


def _optimise(energy: _FieldEnergy, batch: CandidateBatch, like: HandParams,
              monitor: FitMonitor | None,
              free_near: Callable[[CandidateBatch], torch.Tensor] | None = None
              ) -> CandidateBatch:
    """The surface stage's Adam loop, with the pruning of :func:`_prune_schedule` and the
    free points near the candidates drawn again (``free_near``, see :func:`fit_surface`)."""
    config, base = energy.config, energy.cloud
    iterations = config.field_iters
    prunes = _prune_schedule(config, batch.count)
    rates = (config.rotation_lr, config.translation_lr, config.pose_lr,
             config.shape_lr * energy.code_scale, config.betas_lr)
    groups = [(t, lr) for t, lr in zip(batch.unknowns(config.fit_shape), rates, strict=True)
              if t is not None]
    optimizer = adam(groups)
    schedule = lr_schedule(optimizer, iterations, config.final_lr_fraction)
    for step in range(iterations):
        if free_near is not None and (step in prunes or step % config.free_near_every == 0):
            near = free_near(batch)
            energy.cloud = base.replace(free=near if base.free is None else
                                        torch.cat([base.free, near]))
        cloud = energy.cloud
        if step == 0 or step in prunes:
            energy.place_cuts(batch)
        if step in prunes and batch.count > prunes[step]:
            best = torch.argsort(energy.evaluate(batch))[: prunes[step]]
            batch = batch.select(best)
            keep_rows(optimizer, best, [t for t in batch.unknowns(config.fit_shape)
                                        if t is not None])
        total = energy.total(batch, cloud.sample(config.points_per_iteration),
                             energy.free_sample(config.points_per_iteration))
        batch.clear_grads()
        total.sum().backward()
        optimizer.step()
        schedule.step()
        if monitor is not None:
            monitor.record("field", step, iterations, total, lambda index, batch=batch:
                           batch.hand(index, like, energy.rest_joints(batch)))
    batch.fold()
    return batch


@torch.no_grad()
def surface_residuals(model, hand: HandParams, points: torch.Tensor) -> torch.Tensor:
    """[N] ``|G(x)|`` metres of the right hand ``hand`` at the points [N, 3] world metres (on
    the field's device and dtype), in chunks of 65536 points."""
    field_model = model.field

    def one(value: torch.Tensor | None) -> torch.Tensor | None:
        return None if value is None else value[None].to(device=points.device,
                                                         dtype=points.dtype)

    state = field_model.prepare(one(hand.pose), one(hand.translation), one(hand.rest_joints),
                                one(hand.shape_code), one(hand.color_code))
    parts = [field_model.field(state, chunk[None], with_color=False).sdf[0].abs()
             for chunk in points.split(65536)]
    return torch.cat(parts)
