"""Beyond the shape space (``lisa fit-points --refine``): the per-bone SDF networks fine-tuned
on one scan, after the fit.

The shape code can only reach hands like the training subjects; a real hand (a rounded palm, a
thenar eminence the training hands did not have) stays millimetres off. The refinement copies
the trained model and fine-tunes its per-bone SDF MLPs (``sdf_mlp``: all 16 bones at once, in
their bone-local coordinates) on the scan, the fitted hand's pose, skeleton and codes fixed:

    E = mean_i rho(G(x_i)) / 1 mm + eikonal_weight * mean_j (|grad G(y_j)| - 1)^2
        + anchor_weight * (|theta - theta_0|^2 / |theta|) / (1e-3)^2

over ``points_per_iteration`` random scan points ``x_i`` per step (``rho``: Geman-McClure at
``robust_scale_mm``; with normals, also points ``eps`` outside and inside along them at
``-+eps``), ``y_j`` the same points moved by Gaussian offsets (``eikonal_offset_mm``), and the
anchor pulling the weights towards the trained ones (``theta_0``; mean over the weights), so the
surface only moves where the scan says so. Everything else of the model (skinning, colour, the
latent tables) is kept: the refined hand is posed, meshed, rendered and re-posed like any other
(the SDF is in bone-local coordinates, so a new pose carries the refinement along; the skinning
MLP sees the refined per-bone distances). The refined model is written beside the hand
(``model.pt``) and ``params.json`` names it.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import torch

from ...skeleton.params import HandParams
from ...utils.config import check_int_fields
from ..optim import lr_schedule
from ..robust import robust_loss
from ..stages import StageReport, progress_bar

__all__ = ["RefineConfig", "refine_surface"]

_MM = 1e-3
_ANCHOR_UNIT = 1e-3  # a root-mean-square change of the weights that costs anchor_weight


@dataclass(frozen=True)
class RefineConfig:
    """Settings of :func:`refine_surface` (defaults: about 20 s on one CPU thread)."""

    iters: int = 300
    """Adam steps."""
    points_per_iteration: int = 1024
    """Scan points per step."""
    lr: float = 5e-4
    """Adam learning rate of the SDF MLP weights (cosine decay to a tenth)."""
    anchor_weight: float = 0.1
    """Weight of the mean squared change of the weights from the trained ones."""
    eikonal_weight: float = 0.1
    """Weight of the Eikonal term at the offset points."""
    eikonal_offset_mm: float = 4.0
    """Standard deviation of the offsets of the Eikonal points, mm."""
    robust_scale_mm: float = 2.0
    """Scale of the Geman-McClure penalty of the distances, mm."""
    normal_offset_mm: float = 2.0
    """With normals: offset ``eps`` of the points outside (SDF +eps) and inside (-eps), mm."""
    seed: int = 0
    """Seed of the point subsets and offsets."""

    def __post_init__(self) -> None:
        check_int_fields(self, ("iters", "points_per_iteration"), 1)
        for name in ("lr", "eikonal_offset_mm", "robust_scale_mm", "normal_offset_mm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name in ("anchor_weight", "eikonal_weight"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {value!r}")


def _state(field, hand: HandParams, device, dtype):
    batch = {key: None if value is None else value.to(device=device, dtype=dtype)
             for key, value in hand.batch().items()}
    return field.prepare(batch["pose"], batch["translation"], batch["rest_joints"],
                         batch["shape_code"], batch.get("color_code"))


def refine_surface(model, hand: HandParams, points: torch.Tensor,
                   normals: torch.Tensor | None = None, config: RefineConfig | None = None,
                   progress: bool = False):
    """Fine-tune a copy of ``model``'s per-bone SDF MLPs on a scan (see the module docstring).

    model: a :class:`lisa_hand.model.trained.TrainedModel` (not changed). hand: the fitted
    right hand (a left one's cloud and hand mirrored first). points: [N, 3] metres, the scan
    (without what lies beyond the wrist); normals: [N, 3] unit or None.
    -> (the refined :class:`~lisa_hand.model.trained.TrainedModel`, a :class:`StageReport`
    ('refine'): ``energies`` [the mean |G| over the scan before, after] metres, ``seconds``,
    ``history`` per step: energy, data, eikonal, anchor).
    """
    config = RefineConfig() if config is None else config
    began = time.perf_counter()
    refined = copy.deepcopy(model)
    field = refined.field
    field.eval()
    device, dtype = next(field.parameters()).device, next(field.parameters()).dtype
    points = torch.as_tensor(points, device=device, dtype=dtype)
    normals = None if normals is None else torch.as_tensor(normals, device=device, dtype=dtype)
    for weight in field.parameters():
        weight.requires_grad_(False)
    weights = list(field.sdf_mlp.parameters())
    anchors = [weight.detach().clone() for weight in weights]
    count = sum(weight.numel() for weight in weights)
    for weight in weights:
        weight.requires_grad_(True)
    optimizer = torch.optim.Adam(weights, lr=config.lr)
    schedule = lr_schedule(optimizer, config.iters, 0.1)
    generator = torch.Generator().manual_seed(config.seed)
    before = _mean_abs_sdf(field, hand, points)
    history = []
    bar = progress_bar(progress, config.iters, "refine")
    for step in range(config.iters):
        index = torch.randperm(points.shape[0], generator=generator)[:config.points_per_iteration]
        sample = points[index.to(device)]
        state = _state(field, hand, device, dtype)
        query = sample
        if normals is not None:
            offset = config.normal_offset_mm * _MM * normals[index.to(device)]
            query = torch.cat([sample, sample + offset, sample - offset])
        sdf = field.field(state, query[None], with_color=False).sdf[0]
        scale = config.robust_scale_mm * _MM
        num = sample.shape[0]
        data = robust_loss(sdf[:num], "geman_mcclure", scale).mean()
        if normals is not None:
            eps = config.normal_offset_mm * _MM
            data = data + 0.5 * (robust_loss(sdf[num:2 * num] - eps, "geman_mcclure", scale).mean()
                                 + robust_loss(sdf[2 * num:] + eps, "geman_mcclure",
                                               scale).mean())
        noise = torch.randn(sample.shape, generator=generator).to(device, dtype)
        moved = sample + config.eikonal_offset_mm * _MM * noise
        gradient = field.field(state, moved[None], with_color=False, with_gradient=True,
                               create_graph=True).sdf_grad[0]
        eikonal = (gradient.norm(dim=-1) - 1.0).square().mean()
        anchor = sum((w - a).square().sum() for w, a in zip(weights, anchors, strict=True)) / count
        # The data term in mm; the anchor in units of a mean weight change of 1e-3.
        loss = (data / _MM + config.eikonal_weight * eikonal
                + config.anchor_weight * anchor / _ANCHOR_UNIT ** 2)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        schedule.step()
        history.append({"stage": "refine", "iteration": step, "energy": float(loss.detach()),
                        "data": float(data.detach()), "eikonal": float(eikonal.detach()),
                        "anchor": float(anchor.detach())})
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    for weight in weights:
        weight.requires_grad_(False)
    after = _mean_abs_sdf(field, hand, points)
    refined.source = f"{model.source} refined on a scan"
    return refined, StageReport(stage="refine", seconds=time.perf_counter() - began,
                                loss=after, energies=[before, after], history=history)


@torch.no_grad()
def _mean_abs_sdf(field, hand: HandParams, points: torch.Tensor) -> float:
    """Mean |G| (metres) of the field at the points, in chunks."""
    device, dtype = points.device, points.dtype
    state = _state(field, hand, device, dtype)
    total = 0.0
    for begin in range(0, points.shape[0], 8192):
        chunk = points[begin:begin + 8192]
        total += float(field.field(state, chunk[None], with_color=False).sdf.abs().sum())
    return total / max(points.shape[0], 1)
