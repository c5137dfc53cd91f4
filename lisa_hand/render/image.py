"""Whole images of a field: novel views, depth, masks and normal maps, fast on a CPU.

:func:`render_image` renders one camera's image with the ray renderer of this package
(:func:`~lisa_hand.render.renderer.render_rays` and its samplers), doing work only where the
surface is:

1. One ray per pixel centre (:func:`~lisa_hand.geometry.cameras.pixel_rays`). Rays that miss the
   bounding sphere cost nothing.
2. Culling (``culling='grid'``, the default): a coarse-to-fine occupancy grid of the SDF
   (:func:`build_occupancy_grid`, a few ten thousand SDF evaluations, reusable across views)
   marks the cells that may hold points of the shell ``|sdf| <= threshold`` (the sampler's shell
   around the surface). Each ray is walked through the grid with cheap lookups (no field
   evaluations); rays that meet no occupied cell are dropped and the others get ``[near, far]``
   shrunk to the span of their occupied cells (a ray must cross the shell to reach the inside).
   ``'box'`` only clips rays to the occupied cells' bounding box; ``'sphere'`` keeps the sphere
   bounds.
3. ``mode='volume'`` (the default, what LISA renders): VolSDF compositing with the samples of the
   sphere-traced sampler (:func:`~lisa_hand.render.samplers.sphere_traced_samples`), which
   gathers them in a band around the surface. With ``color_weight_threshold > 0`` the densities
   come from ``sdf_fn`` at every sample, and ``field_fn`` (colour) runs only at the samples
   whose compositing weight exceeds the threshold (most samples of a band carry almost no
   weight). ``mode='surface'`` sphere traces to the zero level set (:func:`sphere_trace`) and
   shades one point per pixel with ``field_fn``'s colour there: a fast preview.
4. Normals: the normalised SDF gradient (``normal_fn``, autograd through ``sdf_fn`` or
   central differences) at the surface hit (volume mode: at the composited depth), for the
   pixels of the mask.

Callbacks (nerfacc style; the renderer never imports the model):

    field_fn(points [N, 3] metres, directions [N, 3] unit) -> (sdf [N] metres, rgb [N, C])
    sdf_fn(points [N, 3] metres) -> sdf [N] metres, negative inside
    normal_fn(points [N, 3] metres) -> normals [N, 3] (any length; normalised here)

Nothing here is differentiable: images are rendered under ``torch.no_grad``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from ..geometry.cameras import Camera, pixel_rays
from ..utils.io import atomic_path
from .bounds import ray_sphere_bounds
from .composite import composite
from .density import LaplaceDensity
from .renderer import FieldFn, RenderConfig, _place_samples, render_rays
from .samplers import SdfFn

__all__ = [
    "IMAGE_MODES",
    "CULLING_METHODS",
    "NORMAL_METHODS",
    "NormalFn",
    "ImageRenderConfig",
    "ImageOutput",
    "OccupancyGrid",
    "build_occupancy_grid",
    "ray_box_bounds",
    "SurfaceHits",
    "sphere_trace",
    "sdf_normals",
    "render_image",
    "grid_threshold",
    "image_to_uint8",
    "normals_to_rgb",
    "save_image_outputs",
]

IMAGE_MODES = ("volume", "surface")
CULLING_METHODS = ("grid", "box", "sphere")
NORMAL_METHODS = ("finite_difference", "autograd", "none")

NormalFn = Callable[[torch.Tensor], torch.Tensor]
"""``normal_fn(points [N, 3] metres) -> normals [N, 3]`` (world frame, any length)."""

_SQRT3 = math.sqrt(3.0)


def _default_volume_render() -> RenderConfig:
    # 32 samples in the (8 + 16) beta band: 0.75 beta apart. On the shipped model at 384x250,
    # against 768 uniform samples a ray, the hand pixels reach 46 dB; 8 samples (3 beta apart)
    # gave 24 dB and 16 gave 32 dB, for 54% and 68% of the time.
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


# ----------------------------------------------------------------------------------------------
# Empty-space skipping


def _call_sdf_chunked(sdf_fn: SdfFn, points: torch.Tensor, chunk_size: int) -> torch.Tensor:
    """sdf_fn on points [N, 3] in chunks -> [N], with the shape checked."""
    values = []
    for start in range(0, points.shape[0], chunk_size):
        chunk = points[start : start + chunk_size]
        value = sdf_fn(chunk)
        if not isinstance(value, torch.Tensor) or value.shape != chunk.shape[:1]:
            raise ValueError(
                f"sdf_fn must return a tensor of shape [N]=({chunk.shape[0]},) for points "
                f"[N, 3], got {getattr(value, 'shape', type(value).__name__)}"
            )
        values.append(value.to(points.dtype))
    return torch.cat(values) if values else points.new_zeros(0)


@dataclass
class OccupancyGrid:
    """Lower bounds of ``|sdf|`` on a grid over the bounding sphere's cube, and the cells that may
    hold points of the shell ``|sdf| <= threshold`` around the surface.

    Cell ``[i, j, k]`` covers ``low + cell_size * ([i, i+1] x [j, j+1] x [k, k+1])`` (x, y, z).
    For an SDF whose absolute value is ``lipschitz``-Lipschitz (it overestimates distances by at
    most that factor), ``|sdf(x)| >= distance_bound[cell] - lipschitz * |x - centre|`` for every
    point ``x`` (of any cell), and a cell is occupied when that bound may reach the threshold
    somewhere in it: ``distance_bound <= lipschitz * half_diagonal + threshold``. Cells deep inside
    are empty too: a ray reaches them only through the shell.

    distance_bound: [G, G, G] metres, a lower bound of ``|sdf|`` at each cell centre (the value
        itself where it was evaluated). occupied: [G, G, G] bool. low: [3] metres, the cube's
        minimum corner. cell_size, threshold: metres. lipschitz: >= 1.
    num_evaluations: SDF evaluations spent building it.
    """

    distance_bound: torch.Tensor
    occupied: torch.Tensor
    low: torch.Tensor
    cell_size: float
    threshold: float
    lipschitz: float
    num_evaluations: int

    @property
    def resolution(self) -> int:
        return self.occupied.shape[0]

    def bounding_box(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(low [3], high [3])`` metres of the occupied cells grown by one cell; None if empty."""
        index = torch.nonzero(self.occupied)
        if index.numel() == 0:
            return None
        dtype = self.low.dtype
        first = index.amin(dim=0).to(dtype) - 1.0
        last = index.amax(dim=0).to(dtype) + 2.0
        return self.low + self.cell_size * first, self.low + self.cell_size * last

    @torch.no_grad()
    def ray_bounds(
        self,
        origins: torch.Tensor,
        directions: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        chunk_size: int = 16384,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Shrink ``[near, far]`` to where the ray may meet the shell ``|sdf| <= threshold``.

        Table lookups only, no field evaluations: each ray is probed at ``G + 1`` evenly spaced
        points ``t_k`` of ``[near, far]`` (spacing ``delta`` below one cell). A probe's bound
        ``b_k = distance_bound[cell] - L |x_k - centre|`` holds ``|sdf| >= b_k`` there, so on the
        piece ``[t_k, t_k+1]`` ``|sdf| >= (b_k + b_k+1 - L delta) / 2`` (and ``b - L delta / 2``
        on the two half pieces at the ends). Rays with no piece reaching the threshold miss the
        shell (``hit = False``); the others start at the first such piece, advanced by the
        sphere-tracing step ``(b_k - threshold) / L`` that is safe from its probe, and end at the
        last one, moved back the same way.

        origins, directions: [R, 3] metres / unit. near, far: [R] metres, inside the cube
        (e.g. from the sphere the grid was built in).
        Returns ``(near [R], far [R], hit [R] bool)``; rays without a hit get near = far = 0.
        """
        res = self.resolution
        padded = res + 2  # a border of "far from everything": probes outside clamp onto it
        device, dtype = origins.device, origins.dtype
        lipschitz, threshold = self.lipschitz, self.threshold
        table = torch.full((padded, padded, padded), 1e3, dtype=dtype, device=device)
        table[1:-1, 1:-1, 1:-1] = self.distance_bound.to(device=device, dtype=dtype)
        table = table.reshape(-1)
        num_probes = res + 1
        # Probe positions in grid units (cell i spans [i + 1, i + 2) with the border).
        low = self.low.to(device=device, dtype=dtype)
        start_grid = (origins - low) / self.cell_size + 1.0
        dir_grid = directions / self.cell_size
        offsets = torch.arange(num_probes, device=device, dtype=dtype) + 0.5
        weights = torch.tensor([padded * padded, padded, 1.0], device=device, dtype=dtype)
        new_near, new_far = torch.zeros_like(near), torch.zeros_like(far)
        hit = torch.zeros(near.shape, dtype=torch.bool, device=device)
        for start in range(0, origins.shape[0], chunk_size):
            rows = slice(start, start + chunk_size)
            ray_near, ray_far = near[rows], far[rows]
            spacing = (ray_far - ray_near) / num_probes  # [R]
            t_probe = ray_near[:, None] + offsets * spacing[:, None]  # [R, P]
            position = start_grid[rows, None, :] + t_probe[..., None] * dir_grid[rows, None, :]
            position = position.clamp_(0.0, padded - 1e-3)
            cells = position.floor()
            from_centre = torch.linalg.vector_norm(position - cells - 0.5, dim=-1)
            bound = table[(cells @ weights).long()] - lipschitz * self.cell_size * from_centre
            # Lower bounds of |sdf| on the pieces: [near, t_0], [t_k, t_k+1], [t_P-1, far].
            half_step = 0.5 * lipschitz * spacing[:, None]
            pieces = torch.cat(
                [
                    bound[:, :1] - half_step,
                    0.5 * (bound[:, :-1] + bound[:, 1:]) - half_step,
                    bound[:, -1:] - half_step,
                ],
                dim=-1,
            )  # [R, P + 1]
            reach = (pieces <= threshold).to(torch.uint8)
            first = reach.argmax(dim=-1)  # piece index; piece k > 0 starts at probe k - 1
            any_hit = reach.gather(-1, first[:, None])[:, 0] > 0
            last = num_probes - reach.flip(-1).argmax(dim=-1)  # piece k < P ends at probe k
            safe = (bound - threshold).clamp_min(0.0) / lipschitz  # [R, P]
            from_probe = (first - 1).clamp(min=0)
            lo = (
                t_probe.gather(-1, from_probe[:, None])[:, 0]
                + safe.gather(-1, from_probe[:, None])[:, 0]
            )
            lo = torch.where(first == 0, ray_near, lo)
            to_probe = last.clamp(max=num_probes - 1)
            hi = (
                t_probe.gather(-1, to_probe[:, None])[:, 0]
                - safe.gather(-1, to_probe[:, None])[:, 0]
            )
            hi = torch.where(last == num_probes, ray_far, hi)
            # The safe steps from both ends may cover a lone piece: then it misses too.
            any_hit &= hi > lo
            new_near[rows] = torch.where(any_hit, lo, torch.zeros_like(lo))
            new_far[rows] = torch.where(any_hit, hi, torch.zeros_like(hi))
            hit[rows] = any_hit
        return new_near, new_far, hit


@torch.no_grad()
def build_occupancy_grid(
    sdf_fn: SdfFn,
    center: torch.Tensor,
    radius: float,
    *,
    resolution: int = 64,
    coarse_resolution: int = 16,
    threshold: float = 0.0,
    lipschitz: float = 1.0,
    chunk_size: int = 65536,
) -> OccupancyGrid:
    """Occupancy grid of the shell ``{|sdf| <= threshold}`` in the cube around a bounding sphere.

    Coarse to fine: the SDF is evaluated at the centres of ``coarse_resolution^3`` cells; only
    the occupied ones (``|sdf| <= lipschitz * half_diagonal + threshold``) are split into
    ``(resolution / coarse_resolution)^3`` cells whose centres are evaluated and tested the same
    way. The other fine cells get the bound ``|sdf(C)| - lipschitz * |c - C|`` from their coarse
    centre ``C``. For a hand in its bounding sphere that is some 50k SDF evaluations for 64^3.

    sdf_fn: points [N, 3] metres -> sdf [N] metres (an SDF that overestimates distances by at
        most ``lipschitz``). center: [3] metres (its dtype and device are used). radius: metres.
    threshold: metres (e.g. the sampler's shell ``band_outside * beta`` plus a margin).
    """
    if not isinstance(center, torch.Tensor) or center.shape != (3,):
        shape = getattr(center, "shape", center)
        raise ValueError(f"center must be a tensor of shape [3] (metres), got {shape}")
    if not radius > 0:
        raise ValueError(f"radius must be > 0 (metres), got {radius!r}")
    if coarse_resolution < 1 or resolution % coarse_resolution:
        raise ValueError(
            f"coarse_resolution ({coarse_resolution}) must divide resolution ({resolution})"
        )
    if not lipschitz >= 1:
        raise ValueError(f"lipschitz must be >= 1, got {lipschitz!r}")
    device, dtype = center.device, center.dtype
    low = center - radius
    factor = resolution // coarse_resolution
    coarse_cell = 2.0 * radius / coarse_resolution
    cell = 2.0 * radius / resolution

    def cube_index(size: int) -> torch.Tensor:
        axis = torch.arange(size, device=device)
        return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)

    coarse_index = cube_index(coarse_resolution)
    centres = low + (coarse_index.to(dtype) + 0.5) * coarse_cell
    coarse_abs = _call_sdf_chunked(sdf_fn, centres, chunk_size).abs()
    coarse_occupied = coarse_abs <= lipschitz * 0.5 * _SQRT3 * coarse_cell + threshold
    num_evaluations = centres.shape[0]

    # Every fine cell: the bound from its coarse cell's centre.
    fine_index = cube_index(resolution)
    parent = fine_index // factor
    parent_flat = (
        parent * torch.tensor([coarse_resolution**2, coarse_resolution, 1], device=device)
    ).sum(-1)
    offset = ((fine_index % factor).to(dtype) + 0.5) / factor - 0.5  # in coarse cells
    bound = coarse_abs[parent_flat] - lipschitz * coarse_cell * offset.norm(dim=-1)
    # The fine cells of occupied coarse cells: evaluated.
    refine = coarse_occupied[parent_flat]
    if bool(refine.any()):
        centres = low + (fine_index[refine].to(dtype) + 0.5) * cell
        bound[refine] = _call_sdf_chunked(sdf_fn, centres, chunk_size).abs()
        num_evaluations += centres.shape[0]
    occupied = bound <= lipschitz * 0.5 * _SQRT3 * cell + threshold
    shape = (resolution, resolution, resolution)
    return OccupancyGrid(
        distance_bound=bound.reshape(shape),
        occupied=occupied.reshape(shape),
        low=low,
        cell_size=cell,
        threshold=float(threshold),
        lipschitz=float(lipschitz),
        num_evaluations=num_evaluations,
    )


def ray_box_bounds(
    origins: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays ``o + t d`` (``t >= 0``) with the axis-aligned box ``[low, high]`` (slabs).

    origins: [R, 3] metres. directions: [R, 3]. low, high: [3] metres.
    Returns ``(near [R], far [R], hit [R] bool)``; near = 0 for origins inside the box;
    near = far = 0 where the ray misses.
    """
    with torch.no_grad():
        inverse = 1.0 / directions  # +-inf on axis-parallel rays: the slab test still works
        t_low = (low - origins) * inverse
        t_high = (high - origins) * inverse
        # 0 * inf = nan for origins on a slab plane parallel to the ray: treat as inside.
        t_low = torch.nan_to_num(t_low, nan=-math.inf)
        t_high = torch.nan_to_num(t_high, nan=math.inf)
        t_enter = torch.minimum(t_low, t_high).amax(dim=-1).clamp_min(0.0)
        t_exit = torch.maximum(t_low, t_high).amin(dim=-1)
        hit = t_exit > t_enter
        zeros = torch.zeros_like(t_enter)
        return torch.where(hit, t_enter, zeros), torch.where(hit, t_exit, zeros), hit


def grid_threshold(config: ImageRenderConfig, beta: float) -> float:
    """The occupancy threshold (metres) a grid needs for ``config``: the volume sampler's shell
    ``band_outside * beta`` (volume mode) or the hit tolerance (surface mode), plus the margin."""
    if config.mode == "volume":
        base = config.render.sphere_band_outside * beta
    else:
        base = config.surface_tolerance
    return config.lipschitz * base + config.grid_margin


# ----------------------------------------------------------------------------------------------
# Surfaces and normals


@dataclass
class SurfaceHits:
    """Result of :func:`sphere_trace`.

    t: [R] metres along the ray to the surface (0 where there is no hit).
    hit: [R] bool. num_evaluations: SDF evaluations spent.
    """

    t: torch.Tensor
    hit: torch.Tensor
    num_evaluations: int


@torch.no_grad()
def sphere_trace(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    *,
    num_steps: int = 128,
    tolerance: float = 1e-5,
    lipschitz: float = 1.0,
    points_per_call: int = 65536,
) -> SurfaceHits:
    """First zero crossing of the SDF along each ray, by sphere tracing (Hart 1996).

    ``t <- t + sdf(o + t d) / lipschitz`` from ``near`` on the still-active rays, until
    ``sdf <= tolerance`` (a hit), ``t > far`` or ``num_steps`` run out (misses). A step that
    lands inside (``sdf < -tolerance``, possible when the SDF overestimates distances) is
    corrected by one secant step between the last two points. Not differentiable.

    sdf_fn: points [N, 3] metres -> sdf [N] metres. origins: [R, 3]. directions: [R, 3] unit.
    near, far: [R] metres. tolerance: metres. lipschitz: >= 1, divides every step.
    points_per_call: most points per ``sdf_fn`` call.
    """
    if origins.dim() != 2 or origins.shape[-1] != 3 or directions.shape != origins.shape:
        raise ValueError(
            f"origins and directions must have shape [R, 3], got {tuple(origins.shape)} and "
            f"{tuple(directions.shape)}"
        )
    if near.shape != origins.shape[:1] or far.shape != near.shape:
        raise ValueError(
            f"near and far must have shape [R]=({origins.shape[0]},), got {tuple(near.shape)} "
            f"and {tuple(far.shape)}"
        )
    if num_steps < 1 or not tolerance > 0 or not lipschitz >= 1:
        raise ValueError(
            f"need num_steps >= 1, tolerance > 0, lipschitz >= 1; got {num_steps}, {tolerance}, "
            f"{lipschitz}"
        )
    t_cur = near.clone()
    t_prev = near.clone()
    sdf_prev = torch.full_like(near, math.inf)
    hit = torch.zeros(near.shape, dtype=torch.bool, device=near.device)
    active = torch.arange(near.shape[0], device=near.device)
    num_evaluations = 0
    for _ in range(num_steps):
        if active.numel() == 0:
            break
        t_act = t_cur[active]
        points = origins[active] + t_act[:, None] * directions[active]
        sdf = _call_sdf_chunked(sdf_fn, points, points_per_call)
        num_evaluations += points.shape[0]
        done = sdf <= tolerance
        # Overshoot: the surface lies between the previous point (sdf > 0) and this one.
        prev_sdf, prev_t = sdf_prev[active], t_prev[active]
        overshoot = (sdf < -tolerance) & torch.isfinite(prev_sdf)
        secant = prev_t + (t_act - prev_t) * prev_sdf / (prev_sdf - sdf).clamp_min(1e-30)
        t_done = torch.where(overshoot, secant, t_act)
        t_next = t_act + torch.clamp(sdf, min=tolerance) / lipschitz
        t_prev[active] = t_act
        sdf_prev[active] = sdf
        t_cur[active] = torch.where(done, t_done, t_next)
        hit[active] = done & (t_done <= far[active])
        active = active[~done & (t_next <= far[active])]
    t_hit = torch.where(hit, t_cur, torch.zeros_like(t_cur))
    return SurfaceHits(t=t_hit, hit=hit, num_evaluations=num_evaluations)


def sdf_normals(
    sdf_fn: SdfFn,
    points: torch.Tensor,
    method: str = "autograd",
    step: float = 1e-4,
    chunk_size: int = 16384,
) -> torch.Tensor:
    """Unit outward normals ``grad sdf / |grad sdf|`` at points.

    'autograd': backpropagation through ``sdf_fn`` in chunks (exact; needs a differentiable
    callback; measured on the LISA field as fast as 3 forward evaluations). 'finite_difference':
    central differences ``(sdf(x + h e_i) - sdf(x - h e_i)) / 2h`` (6 evaluations a point,
    error O(h^2); the 4-point tetrahedral rule would be cheaper but its error is O(h) times the
    Hessian's off-diagonal, about a degree at a fingertip's curvature with h = 0.1 mm).

    sdf_fn: points [N, 3] metres -> sdf [N]. points: [N, 3] metres. step: h, metres.
    Returns [N, 3] unit vectors (zero where the gradient vanishes). Not differentiable.
    """
    if points.dim() != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {tuple(points.shape)}")
    if method not in ("finite_difference", "autograd"):
        raise ValueError(f"method must be 'finite_difference' or 'autograd', got {method!r}")
    grads = []
    if method == "finite_difference":
        axes = torch.eye(3, dtype=points.dtype, device=points.device)
        offsets = torch.cat([axes, -axes]) * step  # [6, 3]: +x, +y, +z, -x, -y, -z
        per_call = max(1, chunk_size // 6)
        with torch.no_grad():
            for start in range(0, points.shape[0], per_call):
                chunk = points[start : start + per_call]
                probes = (chunk[:, None, :] + offsets).reshape(-1, 3)
                values = _call_sdf_chunked(sdf_fn, probes, probes.shape[0]).reshape(-1, 6)
                grads.append((values[:, :3] - values[:, 3:]) / (2.0 * step))
    else:
        for start in range(0, points.shape[0], chunk_size):
            with torch.enable_grad():
                chunk = points[start : start + chunk_size].detach().requires_grad_(True)
                value = sdf_fn(chunk)
                if not isinstance(value, torch.Tensor) or value.shape != chunk.shape[:1]:
                    raise ValueError(
                        f"sdf_fn must return a tensor of shape [N]=({chunk.shape[0]},), got "
                        f"{getattr(value, 'shape', type(value).__name__)}"
                    )
                if not value.requires_grad:
                    raise ValueError(
                        "sdf_fn returned values without gradients; use normals="
                        "'finite_difference' (or a normal_fn) for such a callback"
                    )
                (grad,) = torch.autograd.grad(value.sum(), chunk)
            grads.append(grad.detach())
    grads = torch.cat(grads) if grads else points.new_zeros(0, 3)
    return grads / grads.norm(dim=-1, keepdim=True).clamp_min(1e-12)


# ----------------------------------------------------------------------------------------------
# Rendering


def _call_field_chunked(
    field_fn: FieldFn,
    points: torch.Tensor,
    directions: torch.Tensor,
    num_channels: int,
    points_per_call: int,
) -> torch.Tensor:
    """The colours of field_fn at points [N, 3] seen along directions [N, 3] -> [N, C]."""
    colours = []
    for start in range(0, points.shape[0], points_per_call):
        rows = slice(start, start + points_per_call)
        sdf, rgb = field_fn(points[rows], directions[rows])
        count = points[rows].shape[0]
        if (
            not isinstance(rgb, torch.Tensor)
            or getattr(sdf, "shape", None) != (count,)
            or rgb.shape != (count, num_channels)
        ):
            raise ValueError(
                f"field_fn must return sdf [N]=({count},) and rgb [N, C]=({count}, "
                f"{num_channels}), got {tuple(getattr(sdf, 'shape', ()))} and "
                f"{tuple(getattr(rgb, 'shape', ()))}"
            )
        colours.append(rgb.to(points.dtype))
    if not colours:
        return points.new_zeros(0, num_channels)
    return torch.cat(colours)


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
    t_vals = _place_samples(render, place_fn, origins, directions, near, far, beta, None)
    num_samples = t_vals.shape[1]
    points = origins[:, None, :] + t_vals[..., None] * directions[:, None, :]
    sdf = _call_sdf_chunked(sdf_fn, points.reshape(-1, 3), per_call)
    sigma = density(sdf).reshape(num_rays, num_samples)
    colourless = torch.zeros(num_rays, num_samples, 1, dtype=sigma.dtype, device=sigma.device)
    out = composite(sigma, colourless, t_vals, far)
    weights, opacity = out.weights, out.opacity
    rows, cols = torch.nonzero(weights > config.color_weight_threshold, as_tuple=True)
    kept_weights = weights[rows, cols]
    rgb = _call_field_chunked(
        field_fn, points[rows, cols], directions[rows], num_channels, per_call
    )
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
    rgb_out[rows] = _call_field_chunked(
        field_fn, points, directions[rows], background.shape[-1], config.points_per_call
    )
    return rgb_out, hits.hit.to(origins.dtype), hits.t


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
    grid: a prebuilt :class:`OccupancyGrid` (e.g. shared by the views of a turntable; built
        with :func:`grid_threshold`'s threshold); None builds one when ``culling`` needs it.
    Returns :class:`ImageOutput`; runs under ``torch.no_grad``.
    """
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
    center = _as_center(bound_center, camera)
    device, dtype = center.device, center.dtype
    radius = float(bound_radius)
    if density is None:
        density = LaplaceDensity(beta_init=config.beta, beta_min=0.0).to(device)
    beta = float(density.beta.detach())
    background = torch.tensor(config.background, dtype=dtype, device=device)
    lipschitz = config.lipschitz
    per_call = config.points_per_call

    def place_fn(points: torch.Tensor) -> torch.Tensor:
        # Sample placement and tracing: any number of points, steps divided by the Lipschitz bound.
        return _call_sdf_chunked(sdf_fn, points, per_call) / lipschitz

    height, width = camera.height, camera.width
    stats: dict = {}

    with torch.no_grad():
        start = time.perf_counter()
        origins, directions = pixel_rays(camera, device=device, dtype=dtype)
        origins = origins.contiguous()
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
                threshold=grid_threshold(config, beta),
                lipschitz=lipschitz,
                chunk_size=per_call,
            )
            stats["seconds_grid_build"] = time.perf_counter() - grid_start
            stats["grid_evaluations"] = grid.num_evaluations
        ray_ids = torch.nonzero(in_sphere).squeeze(-1)
        ray_o, ray_d = origins[ray_ids], directions[ray_ids]
        ray_near, ray_far = near[ray_ids], far[ray_ids]
        if config.culling == "grid":
            ray_near, ray_far, keep = grid.ray_bounds(ray_o, ray_d, ray_near, ray_far)
        elif config.culling == "box":
            box = grid.bounding_box()
            if box is None:
                keep = torch.zeros_like(ray_near, dtype=torch.bool)
            else:
                box_near, box_far, keep = ray_box_bounds(ray_o, ray_d, *box)
                ray_near = torch.maximum(ray_near, box_near)
                ray_far = torch.minimum(ray_far, box_far)
                keep = keep & (ray_far > ray_near)
        else:
            keep = ray_far > ray_near
        ray_ids, ray_o, ray_d = ray_ids[keep], ray_o[keep], ray_d[keep]
        ray_near, ray_far = ray_near[keep], ray_far[keep]
        num_rendered = int(ray_ids.shape[0])
        stats["seconds_culling"] = time.perf_counter() - start

        render_start = time.perf_counter()
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=num_rendered, unit="ray", desc=f"render {width}x{height}")
        pieces = []
        for begin in range(0, num_rendered, config.chunk_size):
            rows = slice(begin, begin + config.chunk_size)
            if config.mode == "volume":
                piece = _volume_pass(
                    field_fn,
                    place_fn,
                    sdf_fn,
                    ray_o[rows],
                    ray_d[rows],
                    ray_near[rows],
                    ray_far[rows],
                    config,
                    density,
                    background,
                )
            else:
                piece = _surface_pass(
                    field_fn,
                    place_fn,
                    ray_o[rows],
                    ray_d[rows],
                    ray_near[rows],
                    ray_far[rows],
                    config,
                    background,
                )
            pieces.append(piece)
            if bar is not None:
                bar.update(ray_d[rows].shape[0])
        if bar is not None:
            bar.close()
        stats["seconds_render"] = time.perf_counter() - render_start

        num_pixels, num_channels = height * width, background.shape[-1]
        rgb = background.expand(num_pixels, num_channels).clone()
        opacity = torch.zeros(num_pixels, dtype=dtype, device=device)
        depth = torch.zeros(num_pixels, dtype=dtype, device=device)
        if pieces:
            rgb[ray_ids] = torch.cat([p[0] for p in pieces]).to(dtype)
            opacity[ray_ids] = torch.cat([p[1] for p in pieces]).to(dtype)
            depth[ray_ids] = torch.cat([p[2] for p in pieces]).to(dtype)
        mask = opacity > 0.5

    normals = torch.zeros(num_pixels, 3, dtype=dtype, device=device)
    if normal_fn is not None or config.normals != "none":
        normal_start = time.perf_counter()
        pixels = torch.nonzero(mask).squeeze(-1)
        points = origins[pixels] + depth[pixels, None] * directions[pixels]
        if normal_fn is not None:
            with torch.no_grad():
                values = normal_fn(points)
            if not isinstance(values, torch.Tensor) or values.shape != points.shape:
                raise ValueError(
                    f"normal_fn must return [N, 3]=({points.shape[0]}, 3), got "
                    f"{tuple(getattr(values, 'shape', ()))}"
                )
            values = values / values.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        else:
            values = sdf_normals(sdf_fn, points, config.normals, config.normal_step, per_call)
        normals[pixels] = values.to(dtype)
        stats["seconds_normals"] = time.perf_counter() - normal_start

    return ImageOutput(
        rgb=rgb.reshape(height, width, num_channels),
        opacity=opacity.reshape(height, width),
        depth=depth.reshape(height, width),
        normals=normals.reshape(height, width, 3),
        mask=mask.reshape(height, width),
        num_rays_rendered=num_rendered,
        stats=stats,
    )


# ----------------------------------------------------------------------------------------------
# Saving


def image_to_uint8(image: torch.Tensor):
    """[H, W, C] floats in [0, 1] (clipped) -> numpy uint8 [H, W, C] (rounded)."""
    if not isinstance(image, torch.Tensor) or image.dim() != 3:
        raise ValueError(f"image must be a tensor [H, W, C], got {getattr(image, 'shape', image)}")
    values = (image.detach().float().clamp(0.0, 1.0) * 255.0).round()
    return values.to(torch.uint8).cpu().numpy()


def normals_to_rgb(
    normals: torch.Tensor, mask: torch.Tensor, background: tuple[float, float, float] = (0, 0, 0)
) -> torch.Tensor:
    """Encode unit normals as colours ``(n + 1) / 2`` inside the mask, ``background`` outside.

    normals: [H, W, 3] unit vectors. mask: [H, W] bool. Returns [H, W, 3] in [0, 1].
    """
    if normals.dim() != 3 or normals.shape[-1] != 3 or mask.shape != normals.shape[:2]:
        raise ValueError(
            f"normals must be [H, W, 3] and mask [H, W], got {tuple(normals.shape)} and "
            f"{tuple(mask.shape)}"
        )
    fill = torch.tensor(background, dtype=normals.dtype, device=normals.device)
    return torch.where(mask[..., None], 0.5 * (normals + 1.0), fill)


def save_image_outputs(
    out_dir: str | os.PathLike, output: ImageOutput, name: str = "view"
) -> dict[str, Path]:
    """Write ``{name}_rgb.png``, ``{name}_normals.png`` (``(n + 1) / 2``, world frame; only when
    normals were computed), ``{name}_mask.png`` and ``{name}_depth.npy`` (float32 metres along
    the ray) into ``out_dir`` atomically. Returns the paths by kind."""
    import imageio.v3 as iio
    import numpy as np

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    images = {"rgb": image_to_uint8(output.rgb[..., :3])}
    if bool((output.normals != 0).any()):
        images["normals"] = image_to_uint8(normals_to_rgb(output.normals, output.mask))
    images["mask"] = output.mask.cpu().numpy().astype(np.uint8) * 255
    paths = {}
    for kind, array in images.items():
        path = out_dir / f"{name}_{kind}.png"
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, array, extension=".png")
        paths[kind] = path
    path = out_dir / f"{name}_depth.npy"
    with atomic_path(path) as tmp:
        np.save(tmp, output.depth.detach().float().cpu().numpy())
    paths["depth"] = path
    return paths
