"""``lisa train``: LISA from multi-view images (paper Section 4.2, Eq. 13-17).

Learned: the per-bone SDF and colour MLPs and the skinning MLP (:class:`LisaModel`), one shape
code ``beta+`` and one colour code ``gamma`` per subject (auto-decoder tables), VolSDF's Laplace
scale ``beta``, a per-camera, per-channel gain and bias (colour calibration, after Neural
Volumes) and, after the first ``pose_refine_start`` fraction of the steps (paper: 10%), a
per-frame offset of the given pose (48 axis-angle values) and translation, zero at the start.

Each step draws ``num_frames`` frames and ``num_rays / num_frames`` camera rays in each, mostly
through the mask and a band around it (:meth:`RayFrames.sample_rays`), renders them with VolSDF
(:func:`lisa_hand.render.render_rays`; samples from ``render.sampler``) and minimises

    L = lambda_col L_col + lambda_eik L_Eik + lambda_w L_w + lambda_reg L_reg     (Eq. 17)

* ``L_col = |c_k - c^_k|_1`` (Eq. 13), with the calibration applied to the hand's colour only
  (the dataset's backgrounds are black whatever the camera):
  ``c_k = g_cam * c_fg + b_cam * opacity + (1 - opacity) * background``, where ``c_fg`` is the
  rendered colour over a zero background. At inference LISA uses the mean gain and bias
  (:meth:`ImageModel.mean_calibration`).
* ``L_Eik`` (Eq. 14) on ``eikonal_ray_points`` of the rays' samples and ``eikonal_uniform_points``
  uniform points per frame (in the box around the bones' regions: outside them the field is an
  analytic stand-in with a unit gradient).
* ``L_w = |w - w^|_1`` (Eq. 15) at ``skinning_points`` points of each frame's ``scan.npz`` against
  its ``template_weights``: the paper's "approximate 3D mesh and its skinning weights" from the
  pseudo-ground-truth template. Only these weights are read from the scans, never the geometry
  (unless ``lambda_surface > 0``, below).
* ``L_reg = |beta+|_2 + |gamma|_2`` (Eq. 16).
* Optionally (``lambda_mask > 0``; NOT in the paper, off by default) a binary cross-entropy
  between the rendered opacity and the mask.
* Optionally (``lambda_surface > 0``; NOT in the paper, off by default) the prior's
  ``L_surf = |G(x)|_1`` at the same scan points: the scans' geometry kept as a constraint.

With a prior (``lisa train-prior``), the SDF and skinning MLPs and the shape codes start from it
(subjects the prior has not seen start from its mean code); without one the model trains from
images alone (the paper's LISA-im).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..data.datasets import SPLITS, RayFrames, ScanFrames
from ..fields.config import FieldConfig
from ..model.checkpoint import IMAGE_KIND, load_run_checkpoint
from ..render import RenderConfig
from ..render.shading import SHADING_MODES
from ..skeleton import NUM_JOINTS
from ..utils.config import config_from_dict
from .config import TrainerConfig, build_optimizer, check_non_negative, check_positive_int
from .distributed import DistContext, shard_slice, unwrap
from .engine import StepContext, Trainer, TrainResult
from .image_model import ImageBatch, ImageModel, geometry_from_prior, geometry_mismatch
from .prior import PriorModel, load_prior
from .runs import check_resumed_extra, seeded, weighted_total

__all__ = [
    "ImageTrainConfig",
    "pose_refine_step",
    "resolve_prior",
    "build_image_model",
    "load_image_data",
    "sample_image_batch",
    "train_images",
    "load_image_model",
]


def _default_image_field() -> FieldConfig:
    return FieldConfig()


def _default_image_trainer() -> TrainerConfig:
    return TrainerConfig(steps=20_000, lr=5e-4, lr_schedule="cosine", checkpoint_every=1000,
                         print_every=100, grad_sync="ddp",
                         find_unused_parameters=True)


def _default_image_render() -> RenderConfig:
    # 12 samples in the band [-4 beta, +8 beta] around the traced surface (one per beta) and
    # 4 uniform ones; 12 marching steps, full steps after entering the band's shell and the
    # surface reached within 1 beta: full steps let most rays find their band within these few
    # steps, and fewer steps start to cost held-out PSNR. ``python -m benchmarks train``
    # compares this with a denser reference (48 + 16 samples in [-8 beta, +16 beta], 64 steps).
    return RenderConfig(sampler="sphere_traced", num_samples=12, num_samples_extra=4,
                        stratified=True, sphere_num_steps=12, sphere_band_outside=4.0,
                        sphere_band_inside=8.0, sphere_full_steps=True,
                        sphere_hit_tolerance=1.0)


@dataclass(frozen=True)
class ImageTrainConfig:
    """Everything of an image run (``lisa train``): architecture, loop, rendering, data, losses."""

    field: FieldConfig = dataclasses.field(default_factory=_default_image_field)
    """The field's architecture (with colour). With a prior and ``field_from_prior``, the
    geometry fields are replaced by the prior's."""
    trainer: TrainerConfig = dataclasses.field(default_factory=_default_image_trainer)
    """The training loop. Several processes use DistributedDataParallel (grad_sync 'ddp'), which
    needs find_unused_parameters: steps leave some parameters without a gradient (the pose
    offsets before refinement starts, rarely a bone); 'allreduce' also works."""
    render: RenderConfig = dataclasses.field(default_factory=_default_image_render)
    """Ray sampling and compositing (VolSDF). Default: the sphere-traced sampler, 12 samples in
    the band around the surface + 4 uniform ones, stratified (jittered) for training."""
    split: str = "train"
    """Dataset split whose subjects get codes and whose images are fitted."""
    field_from_prior: bool = True
    """With a prior: take the geometry part of ``field`` (everything but the colour MLPs) from
    the prior run. False: the two must agree, else an error."""
    num_rays: int = 1024
    """Rays per step (the global batch), a multiple of ``num_frames``."""
    num_frames: int = 4
    """Frames per step; each gets ``num_rays / num_frames`` rays from any of its views."""
    mask_fraction: float = 0.9
    """Fraction of each frame's rays through the mask or the band around it; the others go
    through the background."""
    band_px: int = 4
    """Width of the band around the mask, pixels."""
    max_band_px: int = 16
    """The widest band kept in memory (``band_px`` must not exceed it)."""
    background_per_view: int = 4096
    """Background pixels kept per view (chosen once at load) for the background rays."""
    batched_step: bool = True
    """Render every frame of a step in one pass (one sphere trace and one field evaluation for
    all of them, grouped by frame) and skip the gradient pass for the skinning points. False:
    frame after frame (``python -m benchmarks train``'s reference step). The same losses
    either way."""
    stream: bool = False
    """Read frames while training runs (:mod:`lisa_hand.training.streaming`: a DataLoader with
    ``stream_workers`` processes decodes the images and masks, cropped to the hand, into a
    buffer of ``stream_cache`` frames; under torchrun each rank reads its share of the split;
    memory flat in the size of the split) instead of loading the whole split first."""
    stream_workers: int = 2
    """With ``stream``: the DataLoader's worker processes (0: frames read in the training
    process; the frames drawn are the same whatever this number)."""
    stream_cache: int = 64
    """With ``stream``: frames held in memory (the buffer a step draws its frames from); at
    least ``num_frames``."""
    eikonal_ray_points: int = 64
    """Per frame: samples of the rendered rays where L_Eik is evaluated (64 + 64 Eikonal and 128
    skinning points do as well in PSNR and surface error as twice as many, at less cost:
    ``python -m benchmarks train`` compares them)."""
    eikonal_uniform_points: int = 64
    """Per frame: uniform points (in the box around the bones' regions) for L_Eik."""
    skinning_points: int = 128
    """Per frame: scan points where L_w is evaluated (0 with lambda_w = 0)."""
    lambda_col: float = 1.0
    """Weight of L_col (L1 over RGB in [0, 1], per ray)."""
    lambda_eik: float = 0.1
    """Weight of L_Eik."""
    lambda_w: float = 1.0
    """Weight of L_w; needs ``scan.npz`` (its ``points`` and ``template_weights``) per frame."""
    lambda_reg: float = 1e-3
    """Weight of L_reg."""
    lambda_mask: float = 0.0
    """Weight of a BCE loss between the rendered opacity and the mask. Not in the paper
    (which relies on the colour of black backgrounds); 0 turns it off."""
    lambda_surface: float = 0.0
    """Weight of L_surf = mean |SDF| (metres) at the ``skinning_points`` scan points of each
    frame (the prior's Eq. 19 kept on during image training; the prior weighs it 100). NOT in
    the paper, whose image stage reads only skinning weights from the scans: with it the colour
    loss cannot thin the prior's surface (VolSDF's density reaches about a beta beyond the zero
    level, so matching the silhouette shrinks the SDF while beta is large). Needs ``scan.npz``
    per frame; 0 (default): the paper's losses."""
    freeze_geometry: bool = False
    """Keep the prior's SDF and skinning MLPs as they are (needs a prior): only the colour MLP,
    the codes, beta, the calibration, the shading and the pose offsets learn. The images then
    teach colour on the prior's geometry, which learnt from exact signed distances in every
    pose of its training, rather than reshaping it from a few poses' pixels. NOT in the paper."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Colour of the images' background (black in the dataset and in InterHand2.6M)."""
    beta_init: float = 0.003
    """Initial Laplace scale beta of the VolSDF density, metres (learned)."""
    beta_min: float = 1e-4
    """Lower bound of beta, metres."""
    pose_refine_start: float = 0.1
    """Fraction of the steps during which the given poses stay fixed (paper: 10%); after it,
    per-frame pose and translation offsets are optimised. 1 disables the refinement."""
    refine_translation: bool = True
    """Refine the translation together with the pose."""
    latent_init_std: float = 0.01
    """Std of the zero-mean Gaussian the codes start from (without a prior)."""
    latent_lr: float | None = None
    """Learning rate of the shape and colour codes (None: the trainer's lr)."""
    pose_lr: float | None = 1e-5
    """Learning rate of the pose (radians) and translation (metres) offsets (None: the
    trainer's lr). Small: the offsets correct annotation errors of a few degrees and
    millimetres; at the trainer's lr (5e-4) they wander off even exact poses and raise the
    colour and skinning losses."""
    shading: str = "none"
    """How the rendered colour is lit (:mod:`lisa_hand.render.shading`): "none", the field's
    colour as it is (the paper, the shipped model); "headlight", the composited colour times a
    learned Lambert term lit from the camera (``1 - k + k max(0, n . -d)``, ``k`` one learned
    number, ``n`` the SDF's normal at the ray's surface point): for images lit from the camera
    (``lisa synth``'s), so that the colour field learns an albedo rather than the shading;
    "camera_light", the same with the light's direction fixed to the camera but learned (three
    more numbers: a light beside the lens, as ``lisa synth``'s, 27 degrees above it)."""
    shading_lr: float | None = 0.01
    """Learning rate of the shading's diffuse fraction and light direction (None: the
    trainer's lr). At the trainer's 5e-4 its terms moved by 0.03 in 400 steps: too slow for a
    number that sets the look of every pixel."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        if not isinstance(self.field, FieldConfig):
            raise ValueError(f"field must be a FieldConfig, got {type(self.field).__name__}")
        if not self.field.use_color:
            raise ValueError("field.use_color must be true: training from images needs colour")
        if not isinstance(self.trainer, TrainerConfig):
            raise ValueError(f"trainer must be a TrainerConfig, got {type(self.trainer).__name__}")
        if self.trainer.grad_sync == "ddp" and not self.trainer.find_unused_parameters:
            raise ValueError("trainer.grad_sync 'ddp' needs trainer.find_unused_parameters=true "
                             "for image training: the pose offsets get no gradient before "
                             "refinement starts")
        if not isinstance(self.render, RenderConfig):
            raise ValueError(f"render must be a RenderConfig, got {type(self.render).__name__}")
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {self.split!r}")
        if self.shading not in SHADING_MODES:
            raise ValueError(f"shading must be one of {SHADING_MODES}, got {self.shading!r}")
        for name in ("num_rays", "num_frames"):
            check_positive_int(self, name)
        if self.num_rays % self.num_frames:
            raise ValueError(f"num_rays ({self.num_rays}) must be a multiple of num_frames "
                             f"({self.num_frames})")
        check_positive_int(self, "stream_workers", allow_zero=True)
        check_positive_int(self, "stream_cache")
        if self.stream and self.stream_cache < self.num_frames:
            raise ValueError(f"stream_cache ({self.stream_cache}) must be at least num_frames "
                             f"({self.num_frames})")
        for name in ("band_px", "max_band_px", "background_per_view", "eikonal_ray_points",
                     "eikonal_uniform_points", "skinning_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
        if self.max_band_px > 254:
            raise ValueError(f"max_band_px must be <= 254, got {self.max_band_px}")
        if self.band_px > self.max_band_px:
            raise ValueError(f"band_px ({self.band_px}) must not exceed max_band_px "
                             f"({self.max_band_px})")
        if not 0.0 <= self.mask_fraction <= 1.0:
            raise ValueError(f"mask_fraction must be in [0, 1], got {self.mask_fraction!r}")
        if not 0.0 <= self.pose_refine_start <= 1.0:
            raise ValueError(f"pose_refine_start must be in [0, 1], got "
                             f"{self.pose_refine_start!r}")
        for name in ("lambda_col", "lambda_eik", "lambda_w", "lambda_reg", "lambda_mask",
                     "lambda_surface", "latent_init_std", "beta_min"):
            check_non_negative(self, name)
        if not self.beta_init > self.beta_min:
            raise ValueError(f"beta_init ({self.beta_init!r}) must be > beta_min "
                             f"({self.beta_min!r})")
        if len(self.background) != 3 or not all(0.0 <= c <= 1.0 for c in self.background):
            raise ValueError(f"background must be 3 values in [0, 1], got {self.background!r}")
        for name in ("latent_lr", "pose_lr", "shading_lr"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be > 0 or None, got {value!r}")
        if self.lambda_eik > 0 and self.eikonal_ray_points + self.eikonal_uniform_points == 0:
            raise ValueError("lambda_eik > 0 needs eikonal_ray_points or eikonal_uniform_points")
        if self.lambda_w > 0 and self.skinning_points == 0:
            raise ValueError("lambda_w > 0 needs skinning_points > 0")
        if self.lambda_surface > 0 and self.skinning_points == 0:
            raise ValueError("lambda_surface > 0 needs skinning_points > 0 (its scan points)")

    def loss_weights(self) -> dict[str, float]:
        """The weighted terms of the total loss, by log name (terms weighted 0 are left out)."""
        weights = {"col": self.lambda_col, "eik": self.lambda_eik, "w": self.lambda_w,
                   "reg": self.lambda_reg, "mask": self.lambda_mask, "surf": self.lambda_surface}
        return {name: value for name, value in weights.items() if value > 0}


def pose_refine_step(config: ImageTrainConfig) -> int:
    """First step (0-based) at which the pose offsets are optimised: ``ceil(fraction * steps)``."""
    return math.ceil(config.pose_refine_start * config.trainer.steps)


# ------------------------------------------------------------------------------------------------
# Training


def resolve_prior(
    config: ImageTrainConfig, prior: str | os.PathLike | PriorModel | None
) -> tuple[ImageTrainConfig, PriorModel | None, str | None]:
    """Load the prior (a run folder, a checkpoint or a model) and resolve the field config.

    -> (config with the prior's geometry settings when ``field_from_prior``, the prior model or
    None, where it came from or None). Raises ValueError when ``field_from_prior`` is false and
    the geometry settings differ.
    """
    if prior is None:
        return config, None, None
    if isinstance(prior, PriorModel):
        prior_model, source = prior, "<in memory>"
    else:
        prior_model, source = load_prior(prior), str(Path(prior))
    if config.field_from_prior:
        config = dataclasses.replace(config, field=geometry_from_prior(prior_model.field.config,
                                                                       config.field))
    else:
        mismatch = geometry_mismatch(prior_model.field.config, config.field)
        if mismatch:
            raise ValueError(f"prior {source}: its field differs in {mismatch}; set "
                             "field_from_prior=true or the same field values")
    return config, prior_model, source


def build_image_model(
    rays: RayFrames, config: ImageTrainConfig, prior_model: PriorModel | None = None
) -> tuple[ImageModel, list[str]]:
    """The model of an image run on ``rays``'s frames, initialised from ``prior_model`` if given.

    -> (model, subjects initialised with the prior's mean shape code).
    """
    model = ImageModel(config.field, rays.subject_ids, rays.camera_names, rays.table.frame_keys,
                       latent_init_std=config.latent_init_std, beta_init=config.beta_init,
                       beta_min=config.beta_min, shading=config.shading,
                       init_rest_joints=rays.table.rest_joints.mean(dim=0))
    unseen: list[str] = []
    if prior_model is not None:
        unseen = model.init_from_prior(prior_model)
    if config.freeze_geometry:
        if prior_model is None:
            raise ValueError("freeze_geometry keeps a prior's geometry: give a prior "
                             "(lisa train --prior RUN)")
        for mlp in (model.field.sdf_mlp, model.field.skinning_mlp):
            mlp.requires_grad_(False)
    return model, unseen


def load_image_data(
    data_dir: str | os.PathLike, config: ImageTrainConfig
) -> tuple[RayFrames, ScanFrames | None]:
    """The rays of ``data_dir``'s split and, for L_w (``lambda_w > 0`` with skinning points),
    its scans (their points and template weights), else None."""
    if config.stream:
        from .streaming import StreamingRayFrames, StreamingScanFrames

        ray_type, scan_type = StreamingRayFrames, StreamingScanFrames
        ray_options = dict(cache_frames=config.stream_cache, workers=config.stream_workers)
        scan_options = dict(cache_frames=config.stream_cache)  # read by frame, no loader
    else:
        ray_type, scan_type = RayFrames, ScanFrames
        ray_options, scan_options = {}, {}
    rays = ray_type(data_dir, config.split, max_band_px=config.max_band_px,
                    background_per_view=config.background_per_view, seed=config.trainer.seed,
                    **ray_options)
    if not ((config.lambda_w > 0 or config.lambda_surface > 0) and config.skinning_points):
        return rays, None
    try:
        return rays, scan_type(data_dir, config.split, **scan_options)
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{exc} (L_w reads the frames' scan.npz: points and "
                                "template_weights; set lambda_w=0 and lambda_surface=0 to "
                                "train without)") from None


def sample_image_batch(
    rays: RayFrames, scans: ScanFrames | None, config: ImageTrainConfig,
    generator: torch.Generator,
) -> ImageBatch:
    """The global batch of one step (``config.num_frames`` frames), drawn from ``generator``
    only: the rays, the skinning points of the same frames (none without ``scans``), the
    uniform and ray Eikonal picks and the frames' render seeds, in this order."""
    num_global = config.num_frames
    ray_batch = rays.sample_rays(config.num_rays, generator, config.mask_fraction,
                                 config.band_px, num_frames=num_global)
    if scans is not None:
        scan_batch = scans.sample(num_global, config.skinning_points, 0, generator,
                                  frames=ray_batch.frame_index)
        skin_points, skin_weights = scan_batch.surface_points, scan_batch.surface_weights
    else:
        skin_points = torch.zeros(num_global, 0, 3)
        skin_weights = torch.zeros(num_global, 0, NUM_JOINTS)
    return ImageBatch(
        rays=ray_batch,
        skin_points=skin_points,
        skin_weights=skin_weights,
        uniform_unit=torch.rand(num_global, config.eikonal_uniform_points, 3,
                                generator=generator),
        eikonal_pick=torch.rand(num_global, config.eikonal_ray_points, 2,
                                generator=generator),
        seeds=torch.randint(0, 2**62, (num_global,), generator=generator),
    )


def _image_step_fn(rays: RayFrames, scans: ScanFrames | None, config: ImageTrainConfig):
    """The engine's step function of an image run: sample, keep this rank's frames, render and
    weigh the losses (plus ``beta`` for the log)."""
    weights = config.loss_weights()
    num_global = config.num_frames
    refine_from = pose_refine_step(config)

    def step_fn(ctx: StepContext) -> dict[str, torch.Tensor]:
        batch = sample_image_batch(rays, scans, config, ctx.generator)
        bare = unwrap(ctx.model)
        local = batch.select(shard_slice(num_global, ctx.dist)).to(ctx.device, bare.field.dtype)
        terms = ctx.model(local, render=config.render, refine_pose=ctx.step >= refine_from,
                          refine_translation=config.refine_translation,
                          background=config.background, batched=config.batched_step)
        out = weighted_total(terms, weights, local.num_frames, num_global, ctx.dist)
        out["beta"] = bare.density.beta.detach()
        return out

    return step_fn


def train_images(
    data_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: ImageTrainConfig | None = None,
    prior: str | os.PathLike | PriorModel | None = None,
    resume: bool | str | os.PathLike = True,
    *,
    hooks=(),
    dist: DistContext | None = None,
) -> TrainResult:
    """Train LISA on the multi-view images of ``data_dir`` into the run folder ``out_dir``.

    data_dir: a dataset (``lisa synth`` layout): per frame ``cameras.json``, ``images/``,
        ``masks/`` and, for L_w, ``scan.npz`` (its ``points`` and ``template_weights``).
    config: the run's settings (default ``ImageTrainConfig()``), resolved (the prior's geometry
        settings) and saved to ``out_dir/config.json``.
    prior: a prior run folder or checkpoint (``lisa train-prior``), an exported model or a
        shipped model's name (:func:`~lisa_hand.training.prior.load_prior`), a
        :class:`PriorModel`, or None (LISA-im: from images only).
    resume: True: continue from ``out_dir/last.pt`` if present; False: start afresh; a path:
        continue from that checkpoint. hooks, dist: see :class:`lisa_hand.training.engine.Trainer`.
    -> :class:`TrainResult`; the model is in ``out_dir/last.pt`` (:func:`load_image_model`).
    """
    config = ImageTrainConfig() if config is None else config
    if not isinstance(config, ImageTrainConfig):
        raise TypeError(f"config must be an ImageTrainConfig, got {type(config).__name__}")
    config, prior_model, prior_source = resolve_prior(config, prior)
    if not config.loss_weights():
        raise ValueError("every loss weight is 0: nothing to train")
    rays, scans = load_image_data(data_dir, config)
    model, _ = seeded(config.trainer.seed, lambda: build_image_model(rays, config, prior_model))
    extra = {"kind": IMAGE_KIND, "subject_ids": list(rays.subject_ids),
             "camera_names": list(rays.camera_names), "frame_keys": rays.table.frame_keys,
             "data_dir": str(Path(data_dir)), "prior": prior_source}
    group_lrs = {("shape_codes", "color_codes"): config.latent_lr,
                 ("pose_offsets", "translation_offsets"): config.pose_lr,
                 ("shading",): config.shading_lr}
    trainer = Trainer(model, _image_step_fn(rays, scans, config), config.trainer, out_dir,
                      run_config=config, resume=resume, hooks=hooks, extra_state=extra,
                      dist=dist,
                      optimizer_fn=lambda bare: build_optimizer(bare, config.trainer, group_lrs))
    check_resumed_extra(trainer, extra)
    return trainer.run()


def load_image_model(run: str | os.PathLike, map_location: Any = "cpu") -> ImageModel:
    """Rebuild a trained :class:`ImageModel` from an image run folder or checkpoint file."""
    ckpt = load_run_checkpoint(run, IMAGE_KIND)
    config = config_from_dict(ImageTrainConfig, ckpt.config, source=str(ckpt.path))
    names = {}
    for key in ("subject_ids", "camera_names", "frame_keys"):
        value = ckpt.extra.get(key)
        if not isinstance(value, list) or not value:
            raise ValueError(f"{ckpt.path}: the checkpoint lists no {key}")
        names[key] = value
    model = ImageModel(config.field, names["subject_ids"], names["camera_names"],
                       names["frame_keys"], latent_init_std=config.latent_init_std,
                       beta_init=config.beta_init, beta_min=config.beta_min,
                       shading=config.shading)
    try:
        model.load_state_dict(ckpt.model)
    except RuntimeError as exc:
        first = " ".join(line.strip() for line in str(exc).strip().splitlines()[:3])
        raise ValueError(f"{ckpt.path}: the weights do not fit the saved config ({first})") \
            from None
    if map_location is not None:
        model = model.to(map_location)
    return model.eval()
