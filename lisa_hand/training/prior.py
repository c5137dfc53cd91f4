"""``lisa train-prior``: the geometric prior of LISA (paper Section 4.2, "Learning a prior for
human hand SDFs").

The geometry networks ``G_beta+`` — the per-bone SDF MLPs and the skinning-weight MLP — and one
shape latent ``beta+`` per training subject (an auto-decoder table, DeepSDF style) are trained on
posed 3D scans with

    L = lambda_surf L_surf + lambda_normal L_N + lambda_eik L_Eik + lambda_w L_w + lambda_reg L_reg

* ``L_surf = |G(x_surf)|`` at scan points (paper Eq. 19), metres;
* ``L_N = |grad G(x_surf) - N(x_surf)|_1`` at scan points (Eq. 20);
* ``L_Eik = (|grad G(x)| - 1)^2`` on the scan points and on off-surface points (Eq. 14; half of
  them near the surface from the scan's SDF samples, half uniform in the scan's bounding box);
* ``L_w = |w - w^|_1`` against the pseudo-ground-truth skinning weights at the scan points
  (``template_weights``, Eq. 15);
* ``L_reg = |beta+|_2`` (Eq. 16, shape code only: the prior has no colour).

Optionally (``lambda_sdf > 0``; NOT in the paper, off by default) an L1 term between the
predicted and the true signed distance at the near-surface samples.

The paper gives no loss weights; the defaults here were chosen on the synthetic data (see
:class:`PriorConfig`). The run folder holds the engine's files (``config.json``, ``log.jsonl``,
``last.pt``); the checkpoint holds the whole :class:`PriorConfig` and the subject ids, so
:func:`load_prior` rebuilds the model and its latent table from it alone.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ..data.datasets import SPLITS, ScanBatch, ScanFrames
from ..fields.config import FieldConfig
from ..fields.latents import LatentTable
from ..model.checkpoint import PRIOR_KIND, load_run_checkpoint
from ..model.lisa import LisaModel
from ..model.losses import eikonal_loss, latent_loss, normal_loss, skinning_loss, surface_loss
from ..model.trained import TRAINED_FORMAT, TrainedModel, load_trained, shipped_name
from ..utils.config import config_from_dict
from .config import TrainerConfig, build_optimizer, check_non_negative, check_positive_int
from .distributed import DistContext, shard_slice, unwrap
from .engine import StepContext, Trainer, TrainResult
from .runs import check_resumed_extra, seeded, weighted_total

__all__ = [
    "PriorConfig",
    "PriorModel",
    "train_prior",
    "load_prior",
]


def _default_prior_field() -> FieldConfig:
    return FieldConfig(use_color=False)


def _default_prior_trainer() -> TrainerConfig:
    return TrainerConfig(steps=20_000, lr=5e-4, lr_schedule="cosine", checkpoint_every=1000,
                         print_every=100, grad_sync="ddp",
                         find_unused_parameters=True)


@dataclass(frozen=True)
class PriorConfig:
    """Everything of a prior run (``lisa train-prior``): architecture, loop, data, losses."""

    field: FieldConfig = dataclasses.field(default_factory=_default_prior_field)
    """The field's architecture; the prior is geometry only (``use_color`` must be false). The
    image run that starts from this prior takes the geometry part of it."""
    trainer: TrainerConfig = dataclasses.field(default_factory=_default_prior_trainer)
    """The training loop (steps, learning rate and schedule, checkpoints, device). Several
    processes use DistributedDataParallel (grad_sync 'ddp') with find_unused_parameters, since a
    step can leave a culled bone without a gradient; 'allreduce' also works."""
    split: str = "train"
    """Dataset split whose subjects get a shape code and whose scans are fitted."""
    stream: bool = False
    """Read the frames' ``scan.npz`` while training runs
    (:class:`lisa_hand.training.streaming.StreamingScanFrames`: a DataLoader with
    ``stream_workers`` processes fills a buffer of ``stream_cache`` frames; under torchrun each
    rank reads its share of the split; memory flat in the size of the split) instead of loading
    every scan first."""
    stream_workers: int = 2
    """With ``stream``: the DataLoader's worker processes (0: scans read in the training
    process; the frames drawn are the same whatever this number)."""
    stream_cache: int = 256
    """With ``stream``: scans held in memory (the buffer a step draws its frames from); at
    least ``frames_per_step``."""
    frames_per_step: int = 8
    """Frames (posed scans) per step (the global batch, split among processes)."""
    surface_points: int = 2048
    """Scan points per frame and step (L_surf, L_N, L_Eik, L_w)."""
    space_points: int = 2048
    """Off-surface points per frame and step (L_Eik, and the optional L_sdf)."""
    near_fraction: float = 0.5
    """Fraction of the off-surface points taken from the scan's near-surface SDF samples; the
    rest are uniform in the scan's bounding box grown by ``uniform_margin``."""
    uniform_margin: float = 0.02
    """Metres added on every side of a scan's bounding box for the uniform points."""
    lambda_surf: float = 100.0
    """Weight of L_surf (metres: 1 mm of mean error costs 0.1)."""
    lambda_normal: float = 1.0
    """Weight of L_N."""
    lambda_eik: float = 0.1
    """Weight of L_Eik."""
    lambda_w: float = 1.0
    """Weight of L_w (L1 over the 16 weights, in [0, 2])."""
    lambda_reg: float = 1e-3
    """Weight of L_reg (mean L2 norm of the frames' shape codes)."""
    lambda_sdf: float = 0.0
    """Weight of an L1 loss on the SDF value at the near-surface samples (metres). Not in the
    paper (which supervises the SDF only on the surface); 0 turns it off."""
    latent_init_std: float = 0.01
    """Std of the zero-mean Gaussian the shape codes start from."""
    latent_lr: float | None = None
    """Learning rate of the shape codes (None: the trainer's lr; DeepSDF uses about 2x)."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        if not isinstance(self.field, FieldConfig):
            raise ValueError(f"field must be a FieldConfig, got {type(self.field).__name__}")
        if self.field.use_color:
            raise ValueError("field.use_color must be false: the shape prior is geometry only")
        if not isinstance(self.trainer, TrainerConfig):
            raise ValueError(f"trainer must be a TrainerConfig, got {type(self.trainer).__name__}")
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {self.split!r}")
        for name in ("frames_per_step", "surface_points"):
            check_positive_int(self, name)
        check_positive_int(self, "stream_workers", allow_zero=True)
        check_positive_int(self, "stream_cache")
        if self.stream and self.stream_cache < self.frames_per_step:
            raise ValueError(f"stream_cache ({self.stream_cache}) must be at least "
                             f"frames_per_step ({self.frames_per_step})")
        if isinstance(self.space_points, bool) or not isinstance(self.space_points, int) \
                or self.space_points < 0:
            raise ValueError(f"space_points must be an int >= 0, got {self.space_points!r}")
        if not 0.0 <= self.near_fraction <= 1.0:
            raise ValueError(f"near_fraction must be in [0, 1], got {self.near_fraction!r}")
        for name in ("uniform_margin", "lambda_surf", "lambda_normal", "lambda_eik", "lambda_w",
                     "lambda_reg", "lambda_sdf", "latent_init_std"):
            check_non_negative(self, name)
        if self.latent_lr is not None and not (self.latent_lr > 0):
            raise ValueError(f"latent_lr must be > 0 or None, got {self.latent_lr!r}")

    def loss_weights(self) -> dict[str, float]:
        """The weighted terms of the total loss, by log name (terms weighted 0 are left out)."""
        weights = {"surf": self.lambda_surf, "normal": self.lambda_normal, "eik": self.lambda_eik,
                   "w": self.lambda_w, "reg": self.lambda_reg, "sdf": self.lambda_sdf}
        return {name: value for name, value in weights.items() if value > 0}


class PriorModel(nn.Module):
    """The geometry networks of LISA and one shape code per training subject.

    field: :class:`LisaModel` (geometry only). shape_codes: :class:`LatentTable` [S, shape_dim].
    subject_ids: [S] the subjects of the codes' rows.
    """

    def __init__(
        self,
        field_config: FieldConfig,
        subject_ids: list[str],
        *,
        latent_init_std: float = 0.01,
        init_rest_joints: torch.Tensor | None = None,
    ) -> None:
        """
        field_config: the architecture (``use_color`` false).
        subject_ids: one shape code per id.
        init_rest_joints: [16, 3] metres, a typical skeleton for the geometric initialisation.
        """
        super().__init__()
        if not subject_ids:
            raise ValueError("subject_ids must not be empty")
        self.field = LisaModel(field_config, init_rest_joints=init_rest_joints)
        self.shape_codes = LatentTable(len(subject_ids), field_config.shape_dim, latent_init_std)
        self.subject_ids = list(subject_ids)

    @torch.no_grad()
    def start_from(self, prior: PriorModel) -> list[str]:
        """Copy ``prior``'s SDF and skinning networks and the shape codes of the subjects it
        knows (the others get its mean code) -> the subjects it did not know. The fields'
        configs must match (:func:`train_prior` takes the prior's)."""
        return copy_geometry(prior, self.field, self.shape_codes, self.subject_ids)

    def subject_index(self, subject_id: str) -> int:
        """Row of ``subject_id`` in the code table."""
        try:
            return self.subject_ids.index(subject_id)
        except ValueError:
            raise ValueError(f"subject {subject_id!r} has no shape code (known: "
                             f"{self.subject_ids})") from None

    def forward(self, batch: ScanBatch) -> dict[str, torch.Tensor]:
        """The prior's loss terms, each averaged over this batch (B frames, see ScanBatch).

        -> {"surf", "normal", "eik", "w", "reg", "sdf"}: scalar tensors (see the module
        docstring); "w" is 0 for the 'single' composition (no skinning weights).
        """
        model = self.field
        codes = self.shape_codes(batch.subject_index)
        state = model.prepare(batch.pose, batch.translation, batch.rest_joints, codes)
        num_surface = batch.surface_points.shape[1]
        num_near = batch.near_points.shape[1]
        points = torch.cat([batch.surface_points, batch.near_points, batch.uniform_points], 1)
        out = model.field(state, points, with_color=False, with_gradient=True)
        sdf_surface = out.sdf[:, :num_surface]
        grad_surface = out.sdf_grad[:, :num_surface]
        zero = out.sdf.new_zeros(())
        if out.weights is not None:
            weights = skinning_loss(out.weights[:, :num_surface], batch.surface_weights)
        else:
            weights = zero
        near = out.sdf[:, num_surface:num_surface + num_near]
        return {
            "surf": surface_loss(sdf_surface),
            "normal": normal_loss(grad_surface, batch.surface_normals),
            "eik": eikonal_loss(out.sdf_grad),
            "w": weights,
            "reg": latent_loss(codes),
            "sdf": (near - batch.near_sdf).abs().mean() if num_near else zero,
        }


@torch.no_grad()
def copy_geometry(prior: PriorModel, field: LisaModel, codes: LatentTable,
                  subject_ids: list[str]) -> list[str]:
    """Copy ``prior``'s SDF and skinning networks into ``field`` (its colour network, if any, is
    left as it is) and its shape codes into ``codes`` (rows in ``subject_ids`` order; a subject
    the prior has not seen gets the prior's mean code) -> the subjects it had not seen. Raises
    ValueError when the networks do not fit."""
    geometry = {k: v for k, v in prior.field.state_dict().items()
                if not k.startswith("color_mlp.")}
    missing, unexpected = field.load_state_dict(geometry, strict=False)
    missing = [k for k in missing if not k.startswith("color_mlp.")]
    if missing or unexpected:
        raise ValueError(f"the prior's weights do not fit: missing {missing}, unexpected "
                         f"{unexpected}")
    mean = prior.shape_codes.mean_code()
    unseen = []
    for row, subject in enumerate(subject_ids):
        if subject in prior.subject_ids:
            code = prior.shape_codes.weight[prior.subject_ids.index(subject)]
        else:
            code = mean
            unseen.append(subject)
        codes.weight[row] = code.to(codes.weight)
    return unseen


# ------------------------------------------------------------------------------------------------
# Training


def train_prior(
    data_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: PriorConfig | None = None,
    resume: bool | str | os.PathLike = True,
    *,
    init: str | os.PathLike | PriorModel | None = None,
    hooks=(),
    dist: DistContext | None = None,
) -> TrainResult:
    """Train LISA's geometric prior on the scans of ``data_dir`` into the run folder ``out_dir``.

    data_dir: a dataset (``lisa synth`` layout) with ``scan.npz`` in every frame of the split.
    config: the run's settings (default ``PriorConfig()``), saved to ``out_dir/config.json``.
    resume: True: continue from ``out_dir/last.pt`` if present; False: start afresh; a path:
        continue from that checkpoint. hooks, dist: see :class:`lisa_hand.training.engine.Trainer`.
    init: a prior to start from instead of the geometric initialisation (a run folder or
        checkpoint, an exported model or a shipped model's name, as :func:`load_prior` takes;
        e.g. to go on training a prior on more or other hands): its networks, its field's
        architecture (``config.field`` is replaced by it) and the codes of the subjects it
        knows (:meth:`PriorModel.start_from`). A run that resumes from its own checkpoint
        ignores it.
    Launch under ``torchrun`` for several processes (each draws the same global batch and keeps
    its share of the frames). -> :class:`TrainResult`; the model is in ``out_dir/last.pt``
    (:func:`load_prior`).
    """
    config = PriorConfig() if config is None else config
    if not isinstance(config, PriorConfig):
        raise TypeError(f"config must be a PriorConfig, got {type(config).__name__}")
    start, source = _start(init)
    if start is not None:
        config = dataclasses.replace(
            config, field=dataclasses.replace(start.field.config, use_color=False))
    if config.stream:
        from .streaming import StreamingScanFrames

        scans = StreamingScanFrames(data_dir, config.split, cache_frames=config.stream_cache,
                                    workers=config.stream_workers, seed=config.trainer.seed)
    else:
        scans = ScanFrames(data_dir, config.split)
    model = seeded(config.trainer.seed, lambda: PriorModel(
        config.field, scans.subject_ids, latent_init_std=config.latent_init_std,
        init_rest_joints=scans.table.rest_joints.mean(dim=0)))
    if start is not None:
        model.start_from(start)
    weights = config.loss_weights()
    if not weights:
        raise ValueError("every loss weight is 0: nothing to train")
    num_global = config.frames_per_step

    def step_fn(ctx: StepContext) -> dict[str, torch.Tensor]:
        batch = scans.sample(num_global, config.surface_points, config.space_points,
                             ctx.generator, near_fraction=config.near_fraction,
                             margin=config.uniform_margin)
        local = batch.select(shard_slice(num_global, ctx.dist))
        local = local.to(ctx.device, unwrap(ctx.model).field.dtype)
        terms = ctx.model(local)
        return weighted_total(terms, weights, local.num_frames, num_global, ctx.dist)

    extra = {"kind": PRIOR_KIND, "subject_ids": list(scans.subject_ids),
             "data_dir": str(Path(data_dir))}
    if source is not None:
        extra["init"] = source
    group_lrs = {("shape_codes",): config.latent_lr}
    trainer = Trainer(model, step_fn, config.trainer, out_dir, run_config=config,
                      optimizer_fn=lambda bare: build_optimizer(bare, config.trainer, group_lrs),
                      resume=resume, hooks=hooks, extra_state=extra, dist=dist,
                      name="lisa train-prior")
    check_resumed_extra(trainer, extra)
    return trainer.run()


def _start(init: str | os.PathLike | PriorModel | None) -> tuple[PriorModel | None, str | None]:
    """The prior a run starts from and where it came from (None, None: no ``init``)."""
    if init is None:
        return None, None
    if isinstance(init, PriorModel):
        return init, "<in memory>"
    return load_prior(init), str(init)


# ------------------------------------------------------------------------------------------------
# Loading


def load_prior(run: str | os.PathLike, map_location: Any = "cpu") -> PriorModel:
    """Rebuild a trained :class:`PriorModel` from a prior run folder or checkpoint file, or
    from an exported model (:func:`lisa_hand.model.trained.export_trained`, or a shipped
    model's name such as ``"geometry"``): its SDF and skinning networks and its shape codes."""
    exported = _exported_model(run)
    if exported is not None:
        return prior_from_trained(exported).to(map_location or "cpu").eval()
    ckpt = load_run_checkpoint(run, PRIOR_KIND)
    config = config_from_dict(PriorConfig, ckpt.config, source=str(ckpt.path))
    subject_ids = ckpt.extra.get("subject_ids")
    if not isinstance(subject_ids, list) or not subject_ids:
        raise ValueError(f"{ckpt.path}: the checkpoint lists no subject_ids")
    model = PriorModel(config.field, subject_ids,
                       latent_init_std=config.latent_init_std)
    try:
        model.load_state_dict(ckpt.model)
    except RuntimeError as exc:
        first = " ".join(line.strip() for line in str(exc).strip().splitlines()[:3])
        raise ValueError(f"{ckpt.path}: the weights do not fit the saved config ({first})") \
            from None
    if map_location is not None:
        model = model.to(map_location)
    return model.eval()


def _exported_model(run: str | os.PathLike) -> TrainedModel | None:
    """The exported model (or shipped model) ``run`` names, or None for a run or checkpoint."""
    path = Path(run)
    if path.is_dir():
        return None
    if not path.exists() and shipped_name(run) is None:
        return None  # load_run_checkpoint says what is missing
    if path.exists():
        try:
            data = torch.load(path, map_location="cpu", weights_only=True)
        except Exception:  # not a torch file: load_run_checkpoint says so in its own words
            return None
        if not (isinstance(data, dict) and data.get("format") == TRAINED_FORMAT):
            return None
    return load_trained(run)


def prior_from_trained(model: TrainedModel) -> PriorModel:
    """A :class:`PriorModel` holding ``model``'s SDF and skinning networks (not its colour
    network: an image run starts its colour afresh) and its shape codes."""
    config = dataclasses.replace(model.field.config, use_color=False)
    prior = PriorModel(config, model.subject_ids)
    state = {k: v for k, v in model.field.state_dict().items()
             if not k.startswith("color_mlp.")}
    missing, unexpected = prior.field.load_state_dict(state, strict=False)
    if unexpected or any(not k.startswith("color_mlp.") for k in missing):
        raise ValueError(f"{model.source}: its field does not fit a prior of the same config "
                         f"(missing {missing}, unexpected {unexpected})")
    with torch.no_grad():
        prior.shape_codes.weight.copy_(model.shape_codes.to(prior.shape_codes.weight))
    return prior
