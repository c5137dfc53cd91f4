"""Whole images of a field: novel views, depth, masks and normal maps, fast on a CPU.

:func:`render_image` renders one camera's image with the ray renderer of this package
(:func:`~lisa_hand.render.renderer.render_rays` and its samplers), doing work only where the
surface is:

1. One ray per pixel centre (:func:`~lisa_hand.geometry.cameras.pixel_rays`). Rays that miss the
   bounding sphere cost nothing.
2. Culling (``culling='grid'``, the default): a coarse-to-fine occupancy grid of the SDF
   (:func:`~lisa_hand.render.occupancy.build_occupancy_grid`, a few ten thousand SDF
   evaluations, reusable across views) marks the cells that may hold points of the shell
   ``|sdf| <= threshold`` (the sampler's shell around the surface). Each ray is walked through
   the grid with cheap lookups (no field evaluations); rays that meet no occupied cell are
   dropped and the others get ``[near, far]`` shrunk to the span of their occupied cells (a ray
   must cross the shell to reach the inside). ``'box'`` only clips rays to the occupied cells'
   bounding box; ``'sphere'`` keeps the sphere bounds.
3. ``mode='volume'`` (the default, what LISA renders): VolSDF compositing with the samples of the
   sphere-traced sampler (:func:`~lisa_hand.render.sphere_tracing.sphere_traced_samples`), which
   gathers them in a band around the surface. With ``color_weight_threshold > 0`` the densities
   come from ``sdf_fn`` at every sample, and ``field_fn`` (colour) runs only at the samples
   whose compositing weight exceeds the threshold (most samples of a band carry almost no
   weight). ``mode='surface'`` sphere traces to the zero level set
   (:func:`~lisa_hand.geometry.tracing.sphere_trace`) and shades one point per pixel with
   ``field_fn``'s colour there: a fast preview.
4. Normals: the normalised SDF gradient (``normal_fn``, or
   :func:`~lisa_hand.geometry.tracing.sdf_normals`: autograd through ``sdf_fn`` or central
   differences) at the surface hit (volume mode: at the composited depth), for the pixels of
   the mask.

Callbacks (the field protocol of :mod:`lisa_hand.geometry.fields`; the renderer never imports
the model):

    field_fn(points [N, 3] metres, directions [N, 3] unit) -> (sdf [N] metres, rgb [N, C])
    sdf_fn(points [N, 3] metres) -> sdf [N] metres, negative inside
    normal_fn(points [N, 3] metres) -> normals [N, 3] (any length; normalised here)

Saving the outputs: :mod:`lisa_hand.render.saving`. Nothing here is differentiable: images are
rendered under ``torch.no_grad``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import torch

from ..geometry.cameras import Camera, pixel_rays
from ..geometry.fields import FieldFn, NormalFn, SdfFn, call_field, call_normals, call_sdf
from ..geometry.rays import ray_box_bounds, ray_sphere_bounds
from ..geometry.tracing import sdf_normals, sphere_trace
from .composite import composite
from .density import LaplaceDensity
from .occupancy import OccupancyGrid, build_occupancy_grid
from .renderer import RenderConfig, place_samples, render_rays

__all__ = [
    "IMAGE_MODES",
    "CULLING_METHODS",
    "NORMAL_METHODS",
    "ImageRenderConfig",
    "ImageOutput",
    "grid_threshold",
    "render_image",
]

IMAGE_MODES = ("volume", "surface")
CULLING_METHODS = ("grid", "box", "sphere")
NORMAL_METHODS = ("finite_difference", "autograd", "none")


def _default_volume_render() -> RenderConfig:
    # 32 samples in the (8 + 16) beta band: 0.75 beta apart, close to a dense uniform reference
    # (768 samples a ray) on the hand's pixels; samples 2-3 beta apart save under half the time
    # and lose much of that accuracy.
    return RenderConfig(sampler="sphere_traced", num_samples=32, num_samples_extra=0)


@dataclass(frozen=True)
class ImageRenderConfig:
    """How a whole image is rendered (see the module docstring for the pipeline)."""

    mode: str = "volume"
    """'volume' (VolSDF compositing, what LISA renders) or 'surface' (sphere trace to the zero
    level set and shade one point per pixel: a fast preview)."""
    render: RenderConfig = field(default_factory=_default_volume_render)
    """Volume mode: the ray renderer's sampler settings (its ``background`` and ``chunk_size``
    are not used: see :attr:`background` and :attr:`points_per_call`)."""
    color_weight_threshold: float = 1e-2
    """Volume mode: evaluate ``field_fn`` only at samples whose compositing weight exceeds this
    (densities come from ``sdf_fn`` at all samples); the skipped weight is given the kept
    samples' mean colour. 0 renders through :func:`render_rays` unchanged (``field_fn`` at every
    sample)."""
    culling: str = "grid"
    """'grid' (occupancy grid: drop rays that meet no occupied cell, shrink the others' bounds),
    'box' (clip rays to the occupied cells' bounding box) or 'sphere' (bounding sphere only)."""
    grid_resolution: int = 64
    """Occupancy grid cells per side of the bounding sphere's cube."""
    grid_coarse_resolution: int = 16
    """Cells per side of the coarse pass (divides ``grid_resolution``); only the occupied coarse
    cells are refined."""
    grid_margin: float = 5e-4
    """Metres added to the occupancy threshold (a cell is occupied if it may hold points with
    ``|sdf| <= threshold``; the threshold is the sampler's shell in volume mode, the tracing
    tolerance in surface mode)."""
    lipschitz: float = 1.0
    """Bound on how much the SDF may overestimate the distance (>= 1 for a learned field that is
    not an exact SDF): sphere-tracing steps are divided by it and grid thresholds scaled."""
    surface_num_steps: int = 128
    """Surface mode: maximum sphere-tracing steps per ray."""
    surface_tolerance: float = 1e-5
    """Surface mode: a ray hits where ``sdf <= tolerance`` (metres); depth error about this over
    the cosine of the incidence angle."""
    normals: str = "autograd"
    """Normal maps when no ``normal_fn`` is given: 'autograd' (backpropagation through
    ``sdf_fn``; about 3 SDF evaluations a pixel for LISA), 'finite_difference' (central
    differences, 6 evaluations a pixel, for callbacks without gradients) or 'none'."""
    normal_step: float = 1e-4
    """Central-difference step, metres (error O(step^2 * third derivative))."""
    chunk_size: int = 65536
    """Rays rendered per pass (sample placement over many rays at once keeps the callbacks'
    batches large while the last rays finish tracing)."""
    points_per_call: int = 65536
    """Most points handed to ``field_fn`` / ``sdf_fn`` in one call (bounds the field's memory)."""
    beta: float = 1e-3
    """Volume mode: Laplace scale (metres) of the density when none is given."""
    background: tuple[float, ...] = (0.0, 0.0, 0.0)
    """Colour of the pixels the surface does not cover, one value per channel."""

    def __post_init__(self) -> None:
        if self.mode not in IMAGE_MODES:
            raise ValueError(f"mode must be one of {IMAGE_MODES}, got {self.mode!r}")
        if self.culling not in CULLING_METHODS:
            raise ValueError(f"culling must be one of {CULLING_METHODS}, got {self.culling!r}")
        if self.normals not in NORMAL_METHODS:
            raise ValueError(f"normals must be one of {NORMAL_METHODS}, got {self.normals!r}")
        if not isinstance(self.render, RenderConfig):
            raise TypeError(f"render must be a RenderConfig, got {type(self.render).__name__}")
        for name in (
            "grid_resolution",
            "grid_coarse_resolution",
            "surface_num_steps",
            "chunk_size",
            "points_per_call",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if self.grid_resolution % self.grid_coarse_resolution:
            raise ValueError(
                f"grid_coarse_resolution ({self.grid_coarse_resolution}) must divide "
                f"grid_resolution ({self.grid_resolution})"
            )
        if not self.color_weight_threshold >= 0:
            raise ValueError(
                f"color_weight_threshold must be >= 0, got {self.color_weight_threshold!r}"
            )
        if not self.grid_margin >= 0:
            raise ValueError(f"grid_margin must be >= 0 (metres), got {self.grid_margin!r}")
        if not self.lipschitz >= 1:
            raise ValueError(f"lipschitz must be >= 1, got {self.lipschitz!r}")
        for name in ("surface_tolerance", "normal_step", "beta"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 (metres), got {getattr(self, name)!r}")
        if len(self.background) < 1:
            raise ValueError("background must have at least one channel")


@dataclass
class ImageOutput:
    """One rendered image (pixel ``(u, v)`` is ``image[v, u]``).

    rgb: [H, W, C] colour over the background.
    opacity: [H, W] accumulated opacity in [0, 1] (surface mode: 1 on hits, 0 elsewhere).
    depth: [H, W] metres along the ray (expected termination distance in volume mode, the
        surface hit in surface mode; 0 where nothing is hit). Distance from the camera centre,
        not the camera z.
    normals: [H, W, 3] unit world-frame normals inside the mask, zeros outside (and everywhere
        when normals are off).
    mask: [H, W] bool, the surface covers the pixel (opacity > 0.5; surface mode: a hit).
    num_rays_rendered: rays that reached the sampler or the sphere tracer (after culling).
    stats: timings (seconds) and counts of the stages.
    """

    rgb: torch.Tensor
    opacity: torch.Tensor
    depth: torch.Tensor
    normals: torch.Tensor
    mask: torch.Tensor
    num_rays_rendered: int
    stats: dict = field(default_factory=dict)


def grid_threshold(config: ImageRenderConfig, beta: float) -> float:
    """The occupancy threshold (metres) a grid needs for ``config``: the volume sampler's shell
    ``band_outside * beta`` (volume mode) or the hit tolerance (surface mode), plus the margin."""
    if config.mode == "volume":
        base = config.render.sphere_band_outside * beta
    else:
        base = config.surface_tolerance
    return config.lipschitz * base + config.grid_margin


# ----------------------------------------------------------------------------------------------
# The steps of render_image


@dataclass
class _Rays:
    """The pixel rays left to render: ids [R] (row-major pixel index), origins [R, 3] metres,
    directions [R, 3] unit, near / far [R] metres."""

    ids: torch.Tensor
    origins: torch.Tensor
    directions: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor

    def select(self, keep: torch.Tensor) -> _Rays:
        return _Rays(
            self.ids[keep], self.origins[keep], self.directions[keep], self.near[keep],
            self.far[keep],
        )


def _check_render_args(field_fn, sdf_fn, camera, bound_radius, config, normal_fn):
    """Validate :func:`render_image`'s arguments; -> the config (default filled in)."""
    config = ImageRenderConfig() if config is None else config
    if not isinstance(config, ImageRenderConfig):
        raise TypeError(f"config must be an ImageRenderConfig, got {type(config).__name__}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    for name, fn in (("field_fn", field_fn), ("sdf_fn", sdf_fn)):
        if not callable(fn):
            raise TypeError(f"{name} must be callable, got {type(fn).__name__}")
    if normal_fn is not None and not callable(normal_fn):
        raise TypeError(f"normal_fn must be callable or None, got {type(normal_fn).__name__}")
    if not float(bound_radius) > 0:
        raise ValueError(f"bound_radius must be > 0 (metres), got {bound_radius!r}")
    return config


def _as_center(bound_center, camera: Camera) -> torch.Tensor:
    if isinstance(bound_center, torch.Tensor):
        if not bound_center.is_floating_point():
            bound_center = bound_center.to(camera.dtype)
        center = bound_center
    else:
        center = torch.as_tensor(bound_center, dtype=camera.dtype, device=camera.device)
    if center.shape != (3,):
        raise ValueError(f"bound_center must have shape [3] (metres), got {tuple(center.shape)}")
    return center


def _rays_to_render(sdf_fn, origins, directions, center, radius, config, density, grid, stats):
    """The pixel rays [P] (origins, directions) that meet the bounding sphere and survive
    ``config.culling``, as :class:`_Rays` (the occupancy grid is built when none is given;
    ``stats`` gets the counts and the grid's build time)."""
    near, far, in_sphere = ray_sphere_bounds(origins, directions, center, radius)
    stats["rays"] = origins.shape[0]
    stats["rays_in_bound"] = int(in_sphere.sum())
    if config.culling != "sphere" and grid is None:
        grid_start = time.perf_counter()
        grid = build_occupancy_grid(
            sdf_fn,
            center,
            radius,
            resolution=config.grid_resolution,
            coarse_resolution=config.grid_coarse_resolution,
            threshold=grid_threshold(config, float(density.beta.detach())),
            lipschitz=config.lipschitz,
            chunk_size=config.points_per_call,
        )
        stats["seconds_grid_build"] = time.perf_counter() - grid_start
        stats["grid_evaluations"] = grid.num_evaluations
    ids = torch.nonzero(in_sphere).squeeze(-1)
    rays = _Rays(ids, origins[ids], directions[ids], near[ids], far[ids])
    return _cull_rays(config, grid, rays)


def _cull_rays(config, grid, rays: _Rays) -> _Rays:
    """Drop the rays that cannot meet the shell and shrink the others' bounds (``culling``)."""
    if config.culling == "grid":
        near, far, keep = grid.ray_bounds(rays.origins, rays.directions, rays.near, rays.far)
        rays = _Rays(rays.ids, rays.origins, rays.directions, near, far)
    elif config.culling == "box":
        box = grid.bounding_box()
        if box is None:
            keep = torch.zeros_like(rays.near, dtype=torch.bool)
        else:
            box_near, box_far, keep = ray_box_bounds(rays.origins, rays.directions, *box)
            near = torch.maximum(rays.near, box_near)
            far = torch.minimum(rays.far, box_far)
            keep = keep & (far > near)
            rays = _Rays(rays.ids, rays.origins, rays.directions, near, far)
    else:
        keep = rays.far > rays.near
    return rays.select(keep)


def _render_chunks(field_fn, sdf_fn, place_fn, rays: _Rays, config, density, background, bar):
    """Render the rays in chunks of ``config.chunk_size``: -> ``(rgb [R, C], opacity [R],
    depth [R])`` pieces, one per chunk (``bar``: a tqdm bar or None)."""
    pieces = []
    for begin in range(0, rays.ids.shape[0], config.chunk_size):
        rows = slice(begin, begin + config.chunk_size)
        chunk = (rays.origins[rows], rays.directions[rows], rays.near[rows], rays.far[rows])
        if config.mode == "volume":
            piece = _volume_pass(
                field_fn, place_fn, sdf_fn, *chunk, config, density, background
            )
        else:
            piece = _surface_pass(field_fn, place_fn, *chunk, config, background)
        pieces.append(piece)
        if bar is not None:
            bar.update(rays.directions[rows].shape[0])
    return pieces


def _scatter_pixels(pieces, ids, background, num_pixels):
    """The chunks' outputs into full images: rgb [P, C], opacity [P], depth [P] (background,
    zeros where no ray was rendered)."""
    dtype, device = background.dtype, background.device
    rgb = background.expand(num_pixels, background.shape[-1]).clone()
    opacity = torch.zeros(num_pixels, dtype=dtype, device=device)
    depth = torch.zeros(num_pixels, dtype=dtype, device=device)
    if pieces:
        rgb[ids] = torch.cat([p[0] for p in pieces]).to(dtype)
        opacity[ids] = torch.cat([p[1] for p in pieces]).to(dtype)
        depth[ids] = torch.cat([p[2] for p in pieces]).to(dtype)
    return rgb, opacity, depth


def _normal_map(sdf_fn, normal_fn, config, origins, directions, depth, mask):
    """Unit normals [P, 3] at the depth of the mask's pixels (zeros elsewhere)."""
    normals = torch.zeros(origins.shape[0], 3, dtype=depth.dtype, device=depth.device)
    pixels = torch.nonzero(mask).squeeze(-1)
    points = origins[pixels] + depth[pixels, None] * directions[pixels]
    if normal_fn is not None:
        with torch.no_grad():
            values = call_normals(normal_fn, points)
    else:
        values = sdf_normals(
            sdf_fn, points, config.normals, config.normal_step, config.points_per_call
        )
    normals[pixels] = values.to(depth.dtype)
    return normals


def render_image(
    field_fn: FieldFn,
    sdf_fn: SdfFn,
    camera: Camera,
    bound_center: torch.Tensor,
    bound_radius: float,
    config: ImageRenderConfig | None = None,
    density: LaplaceDensity | None = None,
    normal_fn: NormalFn | None = None,
    progress: bool = False,
    *,
    grid: OccupancyGrid | None = None,
) -> ImageOutput:
    """Render the camera's whole image of a field (see the module docstring for the pipeline).

    field_fn: points [N, 3] metres, directions [N, 3] unit -> (sdf [N] metres, rgb [N, C]).
    sdf_fn: points [N, 3] metres -> sdf [N] metres (sample placement, tracing, grid, normals).
    camera: the camera; its width x height pixels are rendered.
    bound_center: [3] metres, centre of a sphere that holds the whole surface; the images are
        rendered in its dtype and on its device (a list or array uses the camera's).
    bound_radius: the sphere's radius, metres.
    config: :class:`ImageRenderConfig` (default: volume mode, grid culling).
    density: the VolSDF density (volume mode; on the render device); None makes
        ``LaplaceDensity(config.beta)``.
    normal_fn: points [N, 3] -> normals [N, 3]; None uses ``config.normals`` on ``sdf_fn``.
    progress: show a tqdm bar over the rays.
    grid: a prebuilt :class:`~lisa_hand.render.occupancy.OccupancyGrid` (e.g. shared by the
        views of a turntable; built with :func:`grid_threshold`'s threshold); None builds one
        when ``culling`` needs it.
    Returns :class:`ImageOutput`; runs under ``torch.no_grad``.
    """
    config = _check_render_args(field_fn, sdf_fn, camera, bound_radius, config, normal_fn)
    center = _as_center(bound_center, camera)
    device, dtype = center.device, center.dtype
    radius = float(bound_radius)
    if density is None:
        density = LaplaceDensity(beta_init=config.beta, beta_min=0.0).to(device)
    background = torch.tensor(config.background, dtype=dtype, device=device)
    lipschitz, per_call = config.lipschitz, config.points_per_call

    def place_fn(points: torch.Tensor) -> torch.Tensor:
        # Sample placement and tracing: any number of points, steps divided by the Lipschitz bound.
        return call_sdf(sdf_fn, points, per_call) / lipschitz

    height, width = camera.height, camera.width
    stats: dict = {}
    with torch.no_grad():
        start = time.perf_counter()
        origins, directions = pixel_rays(camera, device=device, dtype=dtype)
        origins = origins.contiguous()
        rays = _rays_to_render(
            sdf_fn, origins, directions, center, radius, config, density, grid, stats
        )
        num_rendered = int(rays.ids.shape[0])
        stats["seconds_culling"] = time.perf_counter() - start

        render_start = time.perf_counter()
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=num_rendered, unit="ray", desc=f"render {width}x{height}")
        pieces = _render_chunks(field_fn, sdf_fn, place_fn, rays, config, density, background, bar)
        if bar is not None:
            bar.close()
        stats["seconds_render"] = time.perf_counter() - render_start
        rgb, opacity, depth = _scatter_pixels(pieces, rays.ids, background, height * width)
        mask = opacity > 0.5

    if normal_fn is not None or config.normals != "none":
        normal_start = time.perf_counter()
        normals = _normal_map(sdf_fn, normal_fn, config, origins, directions, depth, mask)
        stats["seconds_normals"] = time.perf_counter() - normal_start
    else:
        normals = torch.zeros(height * width, 3, dtype=dtype, device=device)
    return ImageOutput(
        rgb=rgb.reshape(height, width, background.shape[-1]),
        opacity=opacity.reshape(height, width),
        depth=depth.reshape(height, width),
        normals=normals.reshape(height, width, 3),
        mask=mask.reshape(height, width),
        num_rays_rendered=num_rendered,
        stats=stats,
    )


# ----------------------------------------------------------------------------------------------
# The two passes: volume compositing and surface shading


def _volume_pass(
    field_fn, place_fn, sdf_fn, origins, directions, near, far, config, density, background
):
    """Volume-render rays [R] -> (rgb [R, C], opacity [R], depth [R])."""
    render = config.render
    per_call = config.points_per_call
    if config.color_weight_threshold == 0:
        # render_rays unchanged: field_fn at every sample, per_call / S rays a call.
        chunk = max(1, per_call // render.samples_per_ray)
        out = render_rays(
            field_fn,
            place_fn,
            origins,
            directions,
            near,
            far,
            replace(render, chunk_size=chunk),
            density,
            background=background,
        )
        return out.rgb, out.opacity, out.depth
    num_rays, num_channels = origins.shape[0], background.shape[-1]
    beta = density.beta.detach()
    t_vals = place_samples(render, place_fn, origins, directions, near, far, beta, None)
    num_samples = t_vals.shape[1]
    points = origins[:, None, :] + t_vals[..., None] * directions[:, None, :]
    sdf = call_sdf(sdf_fn, points.reshape(-1, 3), per_call)
    sigma = density(sdf).reshape(num_rays, num_samples)
    colourless = torch.zeros(num_rays, num_samples, 1, dtype=sigma.dtype, device=sigma.device)
    out = composite(sigma, colourless, t_vals, far)
    weights, opacity = out.weights, out.opacity
    rows, cols = torch.nonzero(weights > config.color_weight_threshold, as_tuple=True)
    kept_weights = weights[rows, cols]
    _, rgb = call_field(field_fn, points[rows, cols], directions[rows], num_channels, per_call)
    colour_sum = torch.zeros(num_rays, num_channels, dtype=sigma.dtype, device=sigma.device)
    colour_sum.index_add_(0, rows, kept_weights[:, None] * rgb.to(sigma.dtype))
    kept_mass = torch.zeros(num_rays, dtype=sigma.dtype, device=sigma.device)
    kept_mass.index_add_(0, rows, kept_weights)
    # The skipped weight (each sample below the threshold) takes the kept samples' mean colour.
    foreground = colour_sum * (opacity / kept_mass.clamp_min(1e-12))[:, None]
    rgb_out = foreground + (1.0 - opacity)[:, None] * background
    return rgb_out, opacity, out.depth


def _surface_pass(field_fn, place_fn, origins, directions, near, far, config, background):
    """Sphere trace and shade rays [R] -> (rgb [R, C], opacity [R], depth [R])."""
    hits = sphere_trace(
        place_fn,
        origins,
        directions,
        near,
        far,
        num_steps=config.surface_num_steps,
        tolerance=config.surface_tolerance,
        points_per_call=config.points_per_call,
    )
    rows = torch.nonzero(hits.hit).squeeze(-1)
    rgb_out = background.to(origins.dtype).expand(origins.shape[0], -1).clone()
    points = origins[rows] + hits.t[rows, None] * directions[rows]
    _, rgb = call_field(
        field_fn, points, directions[rows], background.shape[-1], config.points_per_call
    )
    rgb_out[rows] = rgb
    return rgb_out, hits.hit.to(origins.dtype), hits.t
