"""The model of an image run (``lisa train``, :mod:`lisa_hand.training.images`): the field, the
subjects' shape and colour codes, VolSDF's density, the per-camera colour calibration and the
per-frame pose offsets (:class:`ImageModel`), what one step feeds it (:class:`ImageBatch`) and
its loss terms (``ImageModel.forward``, paper Eq. 13-17; see :mod:`lisa_hand.training.images`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from ..data.datasets import RayBatch
from ..fields.config import FieldConfig
from ..fields.latents import LatentTable
from ..model.lisa import FrameState, LisaModel, region_bounds
from ..model.losses import color_loss, eikonal_loss, latent_loss, skinning_loss, surface_loss
from ..render import LaplaceDensity, RenderConfig, calibrate, ray_sphere_bounds, render_rays
from ..render.samplers import GroupGenerators
from ..render.shading import SHADING_MODES, HeadlightShading, surface_normals
from ..skeleton import POSE_DIM
from .prior import PriorModel, copy_geometry

__all__ = [
    "NON_GEOMETRY_FIELDS",
    "geometry_from_prior",
    "geometry_mismatch",
    "select_frame",
    "ImageBatch",
    "ImageModel",
]

NON_GEOMETRY_FIELDS = (
    "use_color", "color_hidden", "color_depth", "color_dim", "inference_precision",
)
"""The :class:`FieldConfig` fields that do not define the geometry (the colour MLPs, the
inference precision): an image run keeps its own; all others come from the prior."""


def geometry_from_prior(prior: FieldConfig, field: FieldConfig) -> FieldConfig:
    """``field`` with every geometry setting (all but :data:`NON_GEOMETRY_FIELDS`) taken from
    ``prior``."""
    kept = {name: getattr(field, name) for name in NON_GEOMETRY_FIELDS}
    return dataclasses.replace(prior, **kept)


def geometry_mismatch(prior: FieldConfig, field: FieldConfig) -> list[str]:
    """The geometry settings (all but :data:`NON_GEOMETRY_FIELDS`) where the two differ."""
    return [f.name for f in dataclasses.fields(FieldConfig) if f.name not in NON_GEOMETRY_FIELDS
            and getattr(prior, f.name) != getattr(field, f.name)]


# ------------------------------------------------------------------------------------------------
# Frame-state helpers


def select_frame(state: FrameState, index: int) -> FrameState:
    """The one-frame state of frame ``index`` of a batched :class:`FrameState` (differentiable).

    Every tensor of a state (and of its kinematics) has the frame axis first.
    """

    def take(value: Any) -> Any:
        if isinstance(value, torch.Tensor):
            return value[index:index + 1]
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return dataclasses.replace(value, **{f.name: take(getattr(value, f.name))
                                                 for f in dataclasses.fields(value)})
        return value

    return take(state)


# ------------------------------------------------------------------------------------------------
# The model


@dataclass(eq=False)
class ImageBatch:
    """What one step of image training consumes. B frames (the rays' frames)."""

    rays: RayBatch
    """R rays per frame."""
    skin_points: torch.Tensor
    """[B, Nw, 3] world metres, scan points for L_w."""
    skin_weights: torch.Tensor
    """[B, Nw, 16] their pseudo-ground-truth skinning weights."""
    uniform_unit: torch.Tensor
    """[B, Nu, 3] in [0, 1): uniform points in the region box (scaled to it in the model)."""
    eikonal_pick: torch.Tensor
    """[B, Ne, 2] in [0, 1): which hit ray and which of its samples for each ray Eikonal point."""
    seeds: torch.Tensor
    """[B] long, seed of each frame's stratified ray sampling (per frame, so that a frame
    renders the same whichever process gets it)."""

    def select(self, index: slice) -> ImageBatch:
        return dataclasses.replace(
            self, rays=self.rays.select(index), skin_points=self.skin_points[index],
            skin_weights=self.skin_weights[index], uniform_unit=self.uniform_unit[index],
            eikonal_pick=self.eikonal_pick[index], seeds=self.seeds[index])

    def to(self, device: torch.device | str, dtype: torch.dtype | None = None) -> ImageBatch:
        def move(tensor: torch.Tensor) -> torch.Tensor:
            return tensor.to(device=device, dtype=dtype or tensor.dtype)

        return dataclasses.replace(
            self, rays=self.rays.to(device, dtype), skin_points=move(self.skin_points),
            skin_weights=move(self.skin_weights), uniform_unit=move(self.uniform_unit),
            eikonal_pick=move(self.eikonal_pick))

    @property
    def num_frames(self) -> int:
        return self.rays.num_frames


class ImageModel(nn.Module):
    """Everything an image run learns.

    field: :class:`LisaModel` with colour. shape_codes, color_codes: :class:`LatentTable`
    [S, D]. density: :class:`LaplaceDensity`. gain, bias: [C, 3] per camera and channel.
    shading: :class:`~lisa_hand.render.shading.HeadlightShading` (``shading="headlight"`` or
    ``"camera_light"``) or None (colours as the field gives them).
    pose_offsets: [F, 48] radians; translation_offsets: [F, 3] metres (per training frame).
    subject_ids [S], camera_names [C], frame_keys [F] name the rows.
    """

    def __init__(
        self,
        field_config: FieldConfig,
        subject_ids: list[str],
        camera_names: list[str],
        frame_keys: list[str],
        *,
        latent_init_std: float = 0.01,
        beta_init: float = 0.003,
        beta_min: float = 1e-4,
        init_rest_joints: torch.Tensor | None = None,
        shading: str = "none",
    ) -> None:
        super().__init__()
        if shading not in SHADING_MODES:
            raise ValueError(f"shading must be one of {SHADING_MODES}, got {shading!r}")
        if not subject_ids or not camera_names or not frame_keys:
            raise ValueError("subject_ids, camera_names and frame_keys must not be empty")
        self.field = LisaModel(field_config, init_rest_joints=init_rest_joints)
        self.shape_codes = LatentTable(len(subject_ids), field_config.shape_dim, latent_init_std)
        self.color_codes = LatentTable(len(subject_ids), field_config.color_dim, latent_init_std)
        self.density = LaplaceDensity(beta_init, beta_min)
        self.gain = nn.Parameter(torch.ones(len(camera_names), 3))
        self.bias = nn.Parameter(torch.zeros(len(camera_names), 3))
        self.pose_offsets = nn.Parameter(torch.zeros(len(frame_keys), POSE_DIM))
        self.translation_offsets = nn.Parameter(torch.zeros(len(frame_keys), 3))
        self.shading = HeadlightShading.for_mode(shading)
        self.subject_ids = list(subject_ids)
        self.camera_names = list(camera_names)
        self.frame_keys = list(frame_keys)

    def mean_calibration(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Gain [3] and bias [3] averaged over the cameras (LISA's calibration at inference)."""
        return self.gain.mean(dim=0), self.bias.mean(dim=0)

    @torch.no_grad()
    def init_from_prior(self, prior: PriorModel) -> list[str]:
        """Copy the prior's SDF and skinning MLPs and shape codes; -> the subjects that got the
        prior's mean code (not in the prior). The geometry configs must match."""
        mismatch = geometry_mismatch(prior.field.config, self.field.config)
        if mismatch:
            raise ValueError(f"the prior's field differs from this model's in {mismatch}")
        return copy_geometry(prior, self.field, self.shape_codes, self.subject_ids)

    def frame_parameters(
        self, frame_index: torch.Tensor, pose: torch.Tensor, translation: torch.Tensor,
        refine_pose: bool, refine_translation: bool = True,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The given pose [B, 48] and translation [B, 3] plus the frames' learned offsets (only
        with ``refine_pose``; otherwise the offsets are not used and get no gradient)."""
        if refine_pose:
            pose = pose + self.pose_offsets[frame_index]
            if refine_translation:
                translation = translation + self.translation_offsets[frame_index]
        return pose, translation

    def forward(
        self,
        batch: ImageBatch,
        *,
        render: RenderConfig,
        refine_pose: bool = False,
        refine_translation: bool = True,
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
        batched: bool = True,
    ) -> dict[str, torch.Tensor]:
        """The loss terms of one batch, each averaged over it (see the module docstring).

        batched: render every frame's rays in one pass (grouped field callbacks: one sphere
            trace and one field evaluation for the batch) and evaluate the skinning points
            without the gradient pass they do not need; False renders frame after frame (one
            stratified generator each, seeded by ``batch.seeds``) and runs the skinning points
            through the Eikonal gradient pass: the reference step of
            ``python -m benchmarks train``. Both compute the same losses; the random jitter
            of the samples differs.
        -> {"col", "eik", "w", "surf", "reg", "mask"} scalar tensors.
        """
        rays = batch.rays
        device, dtype = rays.origins.device, rays.origins.dtype
        pose, translation = self.frame_parameters(rays.frame_index, rays.pose, rays.translation,
                                                  refine_pose, refine_translation)
        shape = self.shape_codes(rays.subject_index)
        color = self.color_codes(rays.subject_index)
        state = self.field.prepare(pose, translation, rays.rest_joints, shape, color)
        low, high = region_bounds(state, self.field)
        centre, radius = 0.5 * (low + high), 0.5 * (high - low).norm(dim=-1)
        background_rgb = torch.tensor(background, dtype=dtype, device=device)
        if batched:
            prediction, opacity, ray_points = self._render_batched(
                batch, state, centre, radius, render, background_rgb)
            return self._loss_terms(batch, state, low, high, prediction, opacity, ray_points,
                                    shape, color, skin_with_gradient=False)
        black = torch.zeros(3, dtype=dtype, device=device)
        seeds = batch.seeds.tolist()
        predictions, opacities, ray_points = [], [], []
        for frame in range(rays.num_frames):
            generator = None
            if render.stratified:
                generator = torch.Generator(device=device).manual_seed(seeds[frame])
            frame_state = select_frame(state, frame)
            origins, directions = rays.origins[frame], rays.directions[frame]
            near, far, hit = ray_sphere_bounds(origins, directions, centre[frame], radius[frame])
            sdf_fn = self.field.sdf_fn(frame_state)
            out = render_rays(self.field.field_fn(frame_state), sdf_fn, origins, directions,
                              near, far, render, self.density, hit=hit, background=black,
                              generator=generator)
            camera = rays.camera_index[frame]
            rgb = self._shaded(out, sdf_fn, origins, directions, rays.rotations[frame])
            predictions.append(calibrate(rgb, out.opacity, self.gain[camera],
                                         self.bias[camera], background_rgb))
            opacities.append(out.opacity)
            ray_points.append(_pick_ray_samples(origins, directions, out.t_vals, hit,
                                                batch.eikonal_pick[frame], centre[frame]))
        prediction = torch.stack(predictions)  # [B, R, 3]
        opacity = torch.stack(opacities)  # [B, R]
        return self._loss_terms(batch, state, low, high, prediction, opacity,
                                torch.stack(ray_points), shape, color, skin_with_gradient=True)

    def _render_batched(self, batch: ImageBatch, state: FrameState, centre: torch.Tensor,
                        radius: torch.Tensor, render: RenderConfig,
                        background_rgb: torch.Tensor):
        """Every frame's rays in one :func:`render_rays` pass with grouped callbacks.

        centre: [B, 3], radius: [B] metres (the frames' bounding spheres).
        -> (calibrated colours [B, R, 3], opacity [B, R], ray Eikonal points [B, Ne, 3]).
        """
        rays = batch.rays
        num_frames, num_rays = rays.origins.shape[:2]
        device, dtype = rays.origins.device, rays.origins.dtype
        groups = torch.arange(num_frames, device=device).repeat_interleave(num_rays)
        origins, directions = rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3)
        near, far, hit = ray_sphere_bounds(origins, directions, centre[groups], radius[groups])
        generator = None
        if render.stratified:  # one generator a frame: the same samples in any process
            generator = GroupGenerators([torch.Generator(device=device).manual_seed(seed)
                                         for seed in batch.seeds.tolist()])
        sdf_fn = self.field.grouped_sdf_fn(state)
        out = render_rays(self.field.grouped_field_fn(state), sdf_fn, origins, directions, near,
                          far, render, self.density, hit=hit,
                          background=torch.zeros(3, dtype=dtype, device=device),
                          generator=generator, groups=groups)
        camera = rays.camera_index.reshape(-1)  # [B R]
        rgb = self._shaded(out, sdf_fn, origins, directions, rays.rotations.reshape(-1, 3, 3),
                           groups)
        prediction = calibrate(rgb, out.opacity, self.gain[camera], self.bias[camera],
                               background_rgb)
        t_vals, hit = out.t_vals.reshape(num_frames, num_rays, -1), hit.reshape(num_frames, -1)
        ray_points = torch.stack([
            _pick_ray_samples(rays.origins[frame], rays.directions[frame], t_vals[frame],
                              hit[frame], batch.eikonal_pick[frame], centre[frame])
            for frame in range(num_frames)])
        return (prediction.reshape(num_frames, num_rays, 3),
                out.opacity.reshape(num_frames, num_rays), ray_points)

    def _shaded(self, out: Any, sdf_fn: Any, origins: torch.Tensor, directions: torch.Tensor,
                rotations: torch.Tensor, groups: torch.Tensor | None = None) -> torch.Tensor:
        """The rays' composited colours over black [R, 3], lit by :attr:`shading` if any
        (rotations: [R, 3, 3] the rays' world-to-camera rotations)."""
        if self.shading is None:
            return out.rgb
        normals = surface_normals(sdf_fn, origins, directions, out.depth, out.opacity, groups)
        return self.shading(out.rgb, normals, directions, rotations)

    def _loss_terms(self, batch: ImageBatch, state: FrameState, low: torch.Tensor,
                    high: torch.Tensor, prediction: torch.Tensor, opacity: torch.Tensor,
                    ray_points: torch.Tensor, shape: torch.Tensor, color: torch.Tensor, *,
                    skin_with_gradient: bool) -> dict[str, torch.Tensor]:
        """The losses of a rendered batch: prediction [B, R, 3], opacity [B, R], ray Eikonal
        points [B, Ne, 3]; low, high [B, 3] the region boxes (uniform Eikonal points)."""
        rays = batch.rays
        dtype = prediction.dtype
        uniform = low[:, None] + batch.uniform_unit * (high - low)[:, None]
        num_skin = batch.skin_points.shape[1]
        zero = prediction.new_zeros(())
        eik = weights = surf = zero
        if skin_with_gradient:
            points = torch.cat([batch.skin_points, ray_points, uniform], dim=1)
            if points.shape[1]:
                geometry = self.field.field(state, points, with_color=False, with_gradient=True)
                if points.shape[1] > num_skin:
                    eik = eikonal_loss(geometry.sdf_grad[:, num_skin:])
                if num_skin:
                    surf = surface_loss(geometry.sdf[:, :num_skin])
                if num_skin and geometry.weights is not None:
                    weights = skinning_loss(geometry.weights[:, :num_skin], batch.skin_weights)
        else:
            points = torch.cat([ray_points, uniform], dim=1)
            if points.shape[1]:
                geometry = self.field.field(state, points, with_color=False, with_gradient=True)
                eik = eikonal_loss(geometry.sdf_grad)
            if num_skin:
                skin = self.field.field(state, batch.skin_points, with_color=False)
                surf = surface_loss(skin.sdf)
                if skin.weights is not None:
                    weights = skinning_loss(skin.weights, batch.skin_weights)
        mask = F.binary_cross_entropy(opacity.clamp(1e-5, 1.0 - 1e-5), rays.in_mask.to(dtype))
        return {
            "col": color_loss(prediction.reshape(-1, 3), rays.rgb.reshape(-1, 3)),
            "eik": eik,
            "w": weights,
            "surf": surf,
            "reg": latent_loss(shape, color),
            "mask": mask,
        }


def _pick_ray_samples(origins, directions, t_vals, hit, pick, fallback) -> torch.Tensor:
    """Points at random samples of the rays that hit the bounds: [R, S] t_vals -> [Ne, 3].

    pick: [Ne, 2] in [0, 1) (ray among the hit rays, sample along it); no hit: ``fallback`` [3].
    """
    hit_rays = hit.nonzero()[:, 0]
    num_hit, num_samples = hit_rays.numel(), t_vals.shape[1]
    if num_hit == 0:
        return fallback.expand(pick.shape[0], 3)
    ray = hit_rays[(pick[:, 0] * num_hit).long().clamp_max(num_hit - 1)]
    sample = (pick[:, 1] * num_samples).long().clamp_max(num_samples - 1)
    t = t_vals[ray, sample].detach()
    return (origins[ray] + t[:, None] * directions[ray]).detach()
