"""Render rays through a signed-distance / colour field with VolSDF's density (LISA Section 4.1).

The field is a callback (the protocol of :mod:`lisa_hand.geometry.fields`, nerfacc style), so
the renderer never imports the model and is tested on analytic fields:

    field_fn(points [N, 3] metres, directions [N, 3] unit) -> (sdf [N] metres, rgb [N, C])
    sdf_fn(points [N, 3] metres) -> sdf [N] metres     (geometry only, used to place samples)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..geometry.fields import FieldFn, SdfFn, call_field
from .composite import RenderOutput, composite
from .density import LaplaceDensity
from .samplers import error_bounded_samples, uniform_samples
from .sphere_tracing import sphere_traced_samples

__all__ = [
    "SAMPLERS",
    "RenderConfig",
    "place_samples",
    "render_rays",
    "apply_gain_bias",
    "calibrate",
]

SAMPLERS = ("error_bounded", "sphere_traced", "uniform")


@dataclass(frozen=True)
class RenderConfig:
    """How rays are sampled and composited."""

    sampler: str = "error_bounded"
    """Sample placement: 'error_bounded' (VolSDF Algorithm 1), 'sphere_traced' (band around the
    sphere-traced surface, cheaper) or 'uniform'."""
    num_samples: int = 64
    """Uniform: samples per ray. Error-bounded: samples drawn from the opacity's inverse CDF.
    Sphere-traced: samples in the band around the surface."""
    num_samples_extra: int = 32
    """Error-bounded: samples of the bounding set T added to the final ones (VolSDF: 32).
    Sphere-traced: uniform samples over [near, far] added to the band. Unused by 'uniform'."""
    num_samples_eval: int = 128
    """Error-bounded: size of the initial uniform set and of each upsampling step (VolSDF: 128)."""
    eps: float = 0.1
    """Error-bounded: bound on the opacity approximation error (VolSDF: 0.1)."""
    num_bisection: int = 10
    """Error-bounded: bisection steps on beta+ per iteration (VolSDF: 10)."""
    max_iters: int = 5
    """Error-bounded: maximum upsampling iterations (VolSDF: 5)."""
    sphere_num_steps: int = 64
    """Sphere-traced: maximum marching steps per ray."""
    sphere_band_outside: float = 8.0
    """Sphere-traced: the band starts where sdf <= this many beta (density below e^-8 / 2beta)."""
    sphere_band_inside: float = 16.0
    """Sphere-traced: the band ends this many beta (metres along the ray) past the surface hit."""
    sphere_hit_tolerance: float = 0.1
    """Sphere-traced: a ray has reached the surface where ``sdf <= this many beta`` (the band
    ends ``sphere_band_inside`` beta past that point)."""
    sphere_full_steps: bool = False
    """Sphere-traced: once a ray has entered the band's shell, step the full SDF towards the
    surface instead of back to the shell's boundary (fewer steps for grazing rays; a
    non-hitting ray's band may end up to one step late)."""
    stratified: bool = False
    """Jitter the samples randomly inside their bins (training); False is deterministic."""
    chunk_size: int = 8192
    """Rays processed at once (bounds memory: chunk_size x samples field evaluations)."""
    background: tuple[float, ...] = (0.0, 0.0, 0.0)
    """Colour behind the volume, one value per channel (used when no per-ray background is
    given; also the colour of rays that miss the bounds)."""

    def __post_init__(self) -> None:
        if self.sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {SAMPLERS}, got {self.sampler!r}")
        for name in ("num_samples", "num_samples_eval", "sphere_num_steps", "chunk_size"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("num_samples_extra", "num_bisection", "max_iters"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative int, got {value!r}")
        if self.num_samples_eval < 2:
            raise ValueError(f"num_samples_eval must be >= 2, got {self.num_samples_eval}")
        if self.max_iters < 1:
            raise ValueError(f"max_iters must be >= 1, got {self.max_iters}")
        for name in ("eps", "sphere_band_outside", "sphere_band_inside", "sphere_hit_tolerance"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if len(self.background) < 1:
            raise ValueError("background must have at least one channel")

    @property
    def samples_per_ray(self) -> int:
        """S, the number of samples each processed ray gets."""
        if self.sampler == "uniform":
            return self.num_samples
        return self.num_samples + self.num_samples_extra


def place_samples(
    config: RenderConfig,
    sdf_fn: SdfFn | None,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    beta: torch.Tensor,
    generator: torch.Generator | None,
    groups: torch.Tensor | None = None,
) -> torch.Tensor:
    """Sample distances ``t_vals [R, S]`` (sorted, metres) by ``config.sampler``.

    sdf_fn: points [N, 3] metres -> sdf [N] metres (None only for 'uniform'). origins: [R, 3]
    metres. directions: [R, 3] unit. near, far: [R] metres. beta: the density's Laplace scale,
    metres ([] tensor). generator: for stratified draws. ``S = config.samples_per_ray``.
    groups: [R] long, the field of each ray, for a grouped ``sdf_fn`` (the 'sphere_traced' and
    'uniform' samplers only). Not differentiable (the samplers run under ``torch.no_grad``).
    """
    if groups is not None and config.sampler == "error_bounded":
        raise ValueError("the 'error_bounded' sampler does not take groups (several fields in "
                         "one pass); use 'sphere_traced' or 'uniform'")
    if config.sampler == "uniform":
        return uniform_samples(near, far, config.num_samples, config.stratified, generator,
                               groups)
    if sdf_fn is None:
        raise ValueError(f"sdf_fn is required by the {config.sampler!r} sampler")
    if config.sampler == "error_bounded":
        return error_bounded_samples(
            sdf_fn,
            origins,
            directions,
            near,
            far,
            beta,
            num_samples=config.num_samples,
            num_samples_eval=config.num_samples_eval,
            num_samples_extra=config.num_samples_extra,
            eps=config.eps,
            num_bisection=config.num_bisection,
            max_iters=config.max_iters,
            stratified=config.stratified,
            generator=generator,
        )
    return sphere_traced_samples(
        sdf_fn,
        origins,
        directions,
        near,
        far,
        beta,
        num_samples=config.num_samples,
        num_uniform=config.num_samples_extra,
        num_steps=config.sphere_num_steps,
        band_outside=config.sphere_band_outside,
        band_inside=config.sphere_band_inside,
        stratified=config.stratified,
        generator=generator,
        groups=groups,
        full_steps=config.sphere_full_steps,
        hit_tolerance=config.sphere_hit_tolerance,
    )


def _check_rays_and_background(origins, directions, near, far, config, hit, background):
    """Validate :func:`render_rays`' rays; -> (hit [R] bool, background [C] or [R, C])."""
    if not isinstance(config, RenderConfig):
        raise TypeError(f"config must be a RenderConfig, got {type(config).__name__}")
    if origins.dim() != 2 or origins.shape[-1] != 3:
        raise ValueError(f"origins must have shape [R, 3], got {tuple(origins.shape)}")
    num_rays, device, dtype = origins.shape[0], origins.device, origins.dtype
    if directions.shape != origins.shape:
        raise ValueError(
            f"directions must have shape [R, 3]={tuple(origins.shape)}, "
            f"got {tuple(directions.shape)}"
        )
    for name, value in (("near", near), ("far", far)):
        if value.shape != (num_rays,):
            raise ValueError(f"{name} must have shape [R]=({num_rays},), got {tuple(value.shape)}")
    if hit is None:
        hit = far > near
    elif hit.shape != (num_rays,) or hit.dtype != torch.bool:
        raise ValueError(
            f"hit must be a bool tensor of shape [R]=({num_rays},), got "
            f"{hit.dtype} {tuple(hit.shape)}"
        )
    norms = torch.linalg.vector_norm(directions.detach(), dim=-1)
    if num_rays > 0 and not bool(((norms - 1.0).abs() < 1e-3).all()):
        raise ValueError("directions must have unit length (t is measured in metres)")
    if background is None:
        background = torch.tensor(config.background, dtype=dtype, device=device)
    num_channels = background.shape[-1]
    if background.shape not in ((num_channels,), (num_rays, num_channels)):
        raise ValueError(f"background must have shape [C] or [R, C], got {tuple(background.shape)}")
    return hit, background


def _gather_chunks(chunks, ray_ids, background, origins, num_samples) -> RenderOutput:
    """The chunks' RenderOutputs scattered back to all R rays of origins [R, 3] (background and
    zeros for the skipped ones)."""
    num_rays, dtype, device = origins.shape[0], origins.dtype, origins.device
    full_bg = background.expand(num_rays, background.shape[-1])
    zeros = torch.zeros(num_rays, dtype=dtype, device=device)
    zeros_s = torch.zeros(num_rays, num_samples, dtype=dtype, device=device)
    if not chunks:
        return RenderOutput(
            rgb=full_bg.clone(),
            opacity=zeros,
            depth=zeros.clone(),
            weights=zeros_s,
            t_vals=zeros_s.clone(),
        )

    def gather(field: str, base: torch.Tensor) -> torch.Tensor:
        values = torch.cat([getattr(chunk, field) for chunk in chunks], dim=0)
        return base.to(values.dtype).index_copy(0, ray_ids, values)

    return RenderOutput(
        rgb=gather("rgb", full_bg),
        opacity=gather("opacity", zeros),
        depth=gather("depth", zeros),
        weights=gather("weights", zeros_s),
        t_vals=gather("t_vals", zeros_s),
    )


def render_rays(
    field_fn: FieldFn,
    sdf_fn: SdfFn | None,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    config: RenderConfig,
    density: LaplaceDensity,
    *,
    hit: torch.Tensor | None = None,
    background: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    groups: torch.Tensor | None = None,
) -> RenderOutput:
    """Volume-render rays: ``c = int_near^far T(t) sigma(r(t)) c(r(t), d) dt`` over a background.

    Only rays with ``hit`` are processed, in chunks of ``config.chunk_size``: samples are placed
    by ``config.sampler`` (:func:`place_samples`, using ``sdf_fn`` and the density's current
    beta, without gradients), ``field_fn`` is evaluated there, ``sigma = density(sdf)`` and the
    samples are composited (:func:`composite`). Other rays cost nothing and get the background,
    zero opacity, depth and weights.

    Differentiable w.r.t. the field outputs (hence the field's parameters), the density's beta
    and the background. *Not* differentiable w.r.t. the sample positions ``t``: they are chosen
    under ``torch.no_grad`` (points ``o + t d`` still carry gradients of ``origins`` and
    ``directions``, if those require them).

    field_fn: points [N, 3] metres, directions [N, 3] -> (sdf [N] metres, rgb [N, C]).
    sdf_fn: points [N, 3] -> sdf [N] metres, for sample placement; may be None for 'uniform'.
    origins: [R, 3] metres. directions: [R, 3] unit length.
    near, far: [R] metres along the ray (e.g. from
        :func:`~lisa_hand.geometry.rays.ray_sphere_bounds`).
    density: the VolSDF density (its ``beta`` drives the samplers).
    hit: [R] bool, rays to process; None means ``far > near``.
    background: [C] or [R, C]; None uses ``config.background``.
    generator: random generator for stratified sampling (on the rays' device), or one per group
        (:class:`~lisa_hand.render.samplers.GroupGenerators`, with ``groups``).
    groups: [R] long, the field each ray belongs to (several frames in one pass); the callbacks
        are then grouped (:class:`~lisa_hand.geometry.fields.GroupedFieldFn`,
        :class:`~lisa_hand.geometry.fields.GroupedSdfFn`): called with the group of every point.
    Returns RenderOutput with rgb [R, C], opacity [R], depth [R], weights [R, S], t_vals [R, S]
    (``S = config.samples_per_ray``; zeros for skipped rays).
    """
    hit, background = _check_rays_and_background(
        origins, directions, near, far, config, hit, background
    )
    if groups is not None and (groups.shape != hit.shape or groups.dtype != torch.long):
        raise ValueError(f"groups must be a long tensor of shape [R]=({hit.shape[0]},), got "
                         f"{groups.dtype} {tuple(groups.shape)}")
    num_channels = background.shape[-1]
    num_samples = config.samples_per_ray
    beta = density.beta.detach()
    ray_ids = torch.nonzero(hit).squeeze(-1)
    chunks = []
    for start in range(0, ray_ids.shape[0], config.chunk_size):
        ids = ray_ids[start : start + config.chunk_size]
        ray_o, ray_d, ray_far = origins[ids], directions[ids], far[ids]
        ray_groups = None if groups is None else groups[ids]
        t_vals = place_samples(
            config, sdf_fn, ray_o, ray_d, near[ids], ray_far, beta, generator, ray_groups
        ).detach()
        points = ray_o[:, None, :] + t_vals[..., None] * ray_d[:, None, :]
        view_dirs = ray_d[:, None, :].expand(-1, num_samples, -1)
        point_groups = None if groups is None else ray_groups.repeat_interleave(num_samples)
        sdf, rgb = call_field(
            field_fn, points.reshape(-1, 3), view_dirs.reshape(-1, 3), num_channels,
            groups=point_groups,
        )
        sigma = density(sdf).reshape(ids.shape[0], num_samples)
        chunk_bg = background if background.dim() == 1 else background[ids]
        colors = rgb.reshape(ids.shape[0], num_samples, num_channels)
        chunks.append(composite(sigma, colors, t_vals, ray_far, chunk_bg))
    return _gather_chunks(chunks, ray_ids, background, origins, num_samples)


def apply_gain_bias(rgb: torch.Tensor, gain: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """Per-camera, per-channel colour calibration ``gain * rgb + bias`` (Neural Volumes; LISA
    Section 4.2 "Color calibration").

    At training time each ray uses its camera's gain and bias; at inference LISA uses their
    average over the cameras (pass ``gain.mean(0)``, ``bias.mean(0)`` of the per-camera tables).

    rgb: [R, C] rendered colours. gain: [R, C] or [C] (unitless). bias: [R, C] or [C].
    Returns [R, C]; differentiable w.r.t. all three.
    """
    if rgb.dim() != 2:
        raise ValueError(f"rgb must have shape [R, C], got {tuple(rgb.shape)}")
    for name, value in (("gain", gain), ("bias", bias)):
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        if value.shape not in (rgb.shape, rgb.shape[-1:]):
            raise ValueError(
                f"{name} must have shape [R, C]={tuple(rgb.shape)} or [C]=({rgb.shape[-1]},), "
                f"got {tuple(value.shape)}"
            )
    return rgb * gain + bias


def calibrate(rgb_foreground: torch.Tensor, opacity: torch.Tensor, gain: torch.Tensor,
              bias: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Colour calibration of the hand only: ``g * c_fg + b * opacity + (1 - opacity) * bg``.

    The per-camera gain and bias of LISA (Section 4.2, after Neural Volumes) act on the hand's
    colour; the background keeps its colour (black in the dataset, whatever the camera).
    rgb_foreground: [R, 3] rendered colour over a black background (``sum_i w_i c_i``).
    opacity: [R] in [0, 1]. gain, bias: [R, 3] or [3]. background: [3] or [R, 3].
    -> [R, 3]; differentiable w.r.t. everything.
    """
    alpha = opacity[:, None]
    return apply_gain_bias(rgb_foreground, gain, bias * alpha) + (1.0 - alpha) * background
