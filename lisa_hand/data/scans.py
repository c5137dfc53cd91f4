"""Simulated 3D scans of a triangle mesh, and SDF samples near its surface.

* :func:`sample_surface`: area-weighted uniform samples with exact barycentric coordinates and
  their normals (flat face normals or interpolated vertex normals).
* :func:`simulate_scan`: a scan as a sensor would deliver it (:class:`ScanConfig`): full or
  partial (only the points a single viewpoint sees, tested by casting rays through the mesh with
  Embree, like a depth sensor), Gaussian noise along the normal and/or isotropic, and a fraction
  of outliers uniform in an enlarged bounding box.
* :func:`depth_camera_scan`: one frame of a depth camera (:class:`DepthCameraConfig`): a ray
  through every pixel, the first hit kept, noise along the ray growing with the square of the
  depth (stereo and structured-light cameras): what such a camera returns of a whole scene.
* :func:`sdf_samples`: points perturbed off the surface with their exact signed distance, from an
  SDF callback or a watertight mesh (point-cloud-utils' fast winding numbers), for SDF
  supervision near the surface.

Arrays are numpy, float32 for points (float64 inside the sampling); randomness comes only from
the numpy Generator (or int seed) given, so the same seed gives the same scan. Nothing here is
differentiable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from ..geometry.fields import SdfFn, call_sdf
from ..geometry.mesh_distance import mesh_distance
from ..handmodel.hand import SurfaceSamples
from ..render.raycast import MeshRayCaster, check_mesh, vertex_normals
from ..utils.arrays import as_numpy

__all__ = [
    "ScanConfig",
    "Scan",
    "SurfaceSamples",
    "SdfSamples",
    "sample_surface",
    "simulate_scan",
    "DepthCameraConfig",
    "depth_camera_scan",
    "sdf_samples",
]

# Visible points lie on the surface, so the first hit along the ray to them is the point itself,
# up to float32 rounding: the hit may come this much (relative to the distance) short of it.
_VISIBILITY_REL_TOL = 1e-4
_VISIBILITY_ABS_TOL = 1e-5  # metres
# Chunk of points per SDF callback call.
_CHUNK = 1 << 17
# Partial scans draw this many candidates per missing point per round (visible fraction ~0.4).
_OVERSAMPLE = 3.0
_MAX_ROUNDS = 20


@dataclass(frozen=True)
class ScanConfig:
    """How :func:`simulate_scan` turns a mesh into a scan."""

    num_points: int = 20000
    """Total points in the scan, outliers included."""
    noise_normal_std: float = 0.0
    """Std of the Gaussian displacement along the surface normal, metres (sensor depth noise)."""
    noise_isotropic_std: float = 0.0
    """Std of an isotropic Gaussian displacement (each coordinate), metres."""
    outlier_fraction: float = 0.0
    """Fraction of the points that are outliers; ``round(fraction * num_points)`` exactly."""
    outlier_box_scale: float = 1.2
    """Outliers are uniform in the mesh's bounding box scaled by this about its centre."""
    partial: bool = False
    """Keep only points visible from one viewpoint (a single depth-sensor view)."""
    viewpoint: tuple[float, float, float] | None = None
    """The sensor position of a partial scan, world metres; None: a random direction (from the
    seed) at ``viewpoint_distance`` from the bounding box centre."""
    viewpoint_distance: float = 0.5
    """Sensor distance from the bounding box centre for a random viewpoint, metres."""
    max_incidence_deg: float = 90.0
    """Partial scans also drop points seen at an angle to the normal above this (depth sensors
    lose grazing surfaces); 90 keeps every visible point."""
    smooth_normals: bool = True
    """Normals from interpolated vertex normals (True) or from the flat faces (False)."""

    def __post_init__(self) -> None:
        if isinstance(self.num_points, bool) or not isinstance(self.num_points, int) \
                or self.num_points < 1:
            raise ValueError(f"num_points must be a positive integer, got {self.num_points!r}")
        for name in ("noise_normal_std", "noise_isotropic_std"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0 (metres), got {value!r}")
        if not 0.0 <= self.outlier_fraction <= 1.0:
            raise ValueError(f"outlier_fraction must be in [0, 1], got {self.outlier_fraction}")
        if not (math.isfinite(self.outlier_box_scale) and self.outlier_box_scale > 0):
            raise ValueError(f"outlier_box_scale must be > 0, got {self.outlier_box_scale}")
        if self.viewpoint is not None:
            viewpoint = np.asarray(self.viewpoint, dtype=np.float64)
            if viewpoint.shape != (3,) or not np.isfinite(viewpoint).all():
                raise ValueError(f"viewpoint must be 3 finite numbers (metres) or None, got "
                                 f"{self.viewpoint!r}")
        if not (math.isfinite(self.viewpoint_distance) and self.viewpoint_distance > 0):
            raise ValueError(f"viewpoint_distance must be > 0 (metres), got "
                             f"{self.viewpoint_distance}")
        if not 0.0 < self.max_incidence_deg <= 90.0:
            raise ValueError(f"max_incidence_deg must be in (0, 90], got {self.max_incidence_deg}")


@dataclass(eq=False)
class Scan:
    """A simulated scan of N points (numpy)."""

    points: np.ndarray
    """[N, 3] float32 world metres."""
    normals: np.ndarray
    """[N, 3] float32 unit normals: the true outward surface normal at each inlier's sample
    before noise; a random unit vector for outliers."""
    is_outlier: np.ndarray
    """[N] bool."""
    face_ids: np.ndarray
    """[N] int64 face each inlier was sampled on, -1 for outliers."""
    viewpoint: np.ndarray | None = None
    """[3] float32 sensor position of a partial scan, world metres; None for a full scan."""


class SdfSamples(NamedTuple):
    """Points near a surface and their signed distances (``points, sdf = ...`` works)."""

    points: np.ndarray
    """[M, 3] float32 world metres."""
    sdf: np.ndarray
    """[M] float32 signed distance, metres, negative inside."""


def _as_rng(generator, name: str = "generator") -> np.random.Generator:
    if isinstance(generator, np.random.Generator):
        return generator
    if isinstance(generator, (int, np.integer)) and not isinstance(generator, bool):
        return np.random.default_rng(int(generator))
    raise TypeError(f"{name} must be a numpy Generator or an int seed, got "
                    f"{type(generator).__name__}")


def _check_count(value, name: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


class _SurfaceSampler:
    """Area-weighted sampling on one mesh (areas and normals computed once)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, smooth_normals: bool) -> None:
        self.vertices = vertices.astype(np.float64)
        self.faces = faces
        corners = self.vertices[faces]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        double_area = np.linalg.norm(cross, axis=1)
        total = double_area.sum()
        if not total > 0:
            raise ValueError("the mesh has zero surface area: cannot sample points on it")
        self.cumulative = np.cumsum(double_area) / total
        self.face_normals = cross / np.where(double_area > 0, double_area, 1.0)[:, None]
        self.vertex_normals = (vertex_normals(vertices, faces).astype(np.float64)
                               if smooth_normals else None)

    def sample(self, num_points: int, rng: np.random.Generator) -> SurfaceSamples:
        # Face by inverse CDF of the areas; barycentrics uniform on the triangle by folding the
        # unit square's upper half back onto the lower one (exact, no rejection).
        face_ids = np.searchsorted(self.cumulative, rng.random(num_points) * self.cumulative[-1],
                                   side="right")
        face_ids = np.minimum(face_ids, len(self.faces) - 1).astype(np.int64)
        first, second = rng.random(num_points), rng.random(num_points)
        fold = first + second > 1.0
        first = np.where(fold, 1.0 - first, first)
        second = np.where(fold, 1.0 - second, second)
        weights = np.stack([1.0 - first - second, first, second], axis=1)[:, :, None]
        corner_ids = self.faces[face_ids]
        points = (weights * self.vertices[corner_ids]).sum(axis=1)
        if self.vertex_normals is None:
            normals = self.face_normals[face_ids]
        else:
            normals = (weights * self.vertex_normals[corner_ids]).sum(axis=1)
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            # A degenerate interpolation (opposite vertex normals) falls back to the face normal.
            normals = np.where(length > 1e-8, normals / np.maximum(length, 1e-12),
                               self.face_normals[face_ids])
        return SurfaceSamples(points=points.astype(np.float32), normals=normals.astype(np.float32),
                              face_ids=face_ids)


def sample_surface(vertices, faces, num_points: int, generator: np.random.Generator | int,
                   smooth_normals: bool = True) -> SurfaceSamples:
    """Uniform random points on a triangle mesh (area-weighted, exact barycentric coordinates).

    vertices: [V, 3] metres; faces: [F, 3] vertex indices, counter-clockwise seen from outside
    (numpy or torch). generator: numpy Generator or int seed (reproducible).
    smooth_normals: interpolate angle-weighted vertex normals (True) or use face normals.
    -> :class:`SurfaceSamples` ``(points [N, 3], normals [N, 3], face_ids [N])``.
    """
    vertices, faces = check_mesh(vertices, faces)
    num_points = _check_count(num_points, "num_points")
    return _SurfaceSampler(vertices, faces, smooth_normals).sample(num_points,
                                                                    _as_rng(generator))


def _random_unit_vectors(count: int, rng: np.random.Generator) -> np.ndarray:
    vectors = rng.standard_normal((count, 3))
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    return vectors / np.maximum(length, 1e-12)


def _visible(caster: MeshRayCaster, points: np.ndarray, normals: np.ndarray,
             viewpoint: np.ndarray, max_incidence_deg: float) -> np.ndarray:
    """[N] bool: the ray from ``viewpoint`` to each point first meets the surface at the point,
    and the point faces the viewpoint within ``max_incidence_deg``."""
    offsets = points.astype(np.float64) - viewpoint
    distance = np.linalg.norm(offsets, axis=1)
    directions = offsets / np.maximum(distance, 1e-12)[:, None]
    cos_incidence = -(directions * normals).sum(axis=1)
    facing = cos_incidence > max(math.cos(math.radians(max_incidence_deg)), 0.0)
    hits = caster.intersect(np.broadcast_to(viewpoint, points.shape).astype(np.float32),
                            directions.astype(np.float32))
    slack = _VISIBILITY_REL_TOL * distance + _VISIBILITY_ABS_TOL
    return facing & hits.hit & (hits.distances >= distance - slack)


def simulate_scan(vertices, faces, config: ScanConfig | None = None,
                  seed: np.random.Generator | int = 0) -> Scan:
    """Simulate a scan of a triangle mesh (see :class:`ScanConfig` and the module docstring).

    Steps: ``num_inliers = num_points - round(outlier_fraction * num_points)`` surface samples
    (for a partial scan, drawn until that many are visible from the viewpoint, so the count is
    exact), displaced by the noise; outliers uniform in the enlarged box; all shuffled together.

    vertices: [V, 3] metres; faces: [F, 3] counter-clockwise seen from outside (numpy or torch);
    the visibility test of partial scans assumes a closed surface seen from outside.
    seed: numpy Generator or int seed; the same seed gives the same scan.
    -> :class:`Scan`.
    """
    config = ScanConfig() if config is None else config
    if not isinstance(config, ScanConfig):
        raise TypeError(f"config must be a ScanConfig or None, got {type(config).__name__}")
    vertices, faces = check_mesh(vertices, faces)
    rng = _as_rng(seed, "seed")
    sampler = _SurfaceSampler(vertices, faces, config.smooth_normals)
    num_outliers = int(round(config.outlier_fraction * config.num_points))
    num_inliers = config.num_points - num_outliers
    bbox_min, bbox_max = vertices.min(0).astype(np.float64), vertices.max(0).astype(np.float64)
    centre = 0.5 * (bbox_min + bbox_max)

    viewpoint = None
    if not config.partial:
        samples = sampler.sample(num_inliers, rng)
    else:
        if config.viewpoint is None:
            viewpoint = centre + config.viewpoint_distance * _random_unit_vectors(1, rng)[0]
        else:
            viewpoint = np.asarray(config.viewpoint, dtype=np.float64)
        caster = MeshRayCaster(vertices, faces)
        kept: list[SurfaceSamples] = []
        num_kept = 0
        for _ in range(_MAX_ROUNDS):
            if num_kept >= num_inliers:
                break
            missing = num_inliers - num_kept
            candidates = sampler.sample(int(_OVERSAMPLE * missing) + 16, rng)
            visible = _visible(caster, candidates.points, candidates.normals, viewpoint,
                               config.max_incidence_deg)
            kept.append(candidates.select(visible))
            num_kept += int(visible.sum())
        if num_kept < num_inliers:
            raise ValueError(f"partial scan: only {num_kept} of {num_inliers} points are visible "
                             f"from viewpoint {viewpoint.tolist()} after {_MAX_ROUNDS} rounds; "
                             f"is the viewpoint inside the mesh or the mesh open?")
        samples = SurfaceSamples.concatenate(kept).select(slice(0, num_inliers))

    points = samples.points.astype(np.float64)
    normals = samples.normals.astype(np.float64)
    if config.noise_normal_std > 0:
        points += config.noise_normal_std * rng.standard_normal(num_inliers)[:, None] * normals
    if config.noise_isotropic_std > 0:
        points += config.noise_isotropic_std * rng.standard_normal((num_inliers, 3))

    half_extent = 0.5 * (bbox_max - bbox_min) * config.outlier_box_scale
    outliers = rng.uniform(centre - half_extent, centre + half_extent, size=(num_outliers, 3))
    outlier_normals = _random_unit_vectors(num_outliers, rng)

    order = rng.permutation(config.num_points)
    all_points = np.concatenate([points, outliers])[order]
    all_normals = np.concatenate([normals, outlier_normals])[order]
    is_outlier = np.concatenate([np.zeros(num_inliers, bool), np.ones(num_outliers, bool)])[order]
    face_ids = np.concatenate([samples.face_ids, np.full(num_outliers, -1, np.int64)])[order]
    return Scan(points=all_points.astype(np.float32), normals=all_normals.astype(np.float32),
                is_outlier=is_outlier, face_ids=face_ids,
                viewpoint=None if viewpoint is None else viewpoint.astype(np.float32))


@dataclass(frozen=True)
class DepthCameraConfig:
    """A depth camera at the origin looking along +z (x right, y down, a pinhole at the image
    centre), as :func:`depth_camera_scan` simulates it."""

    width: int = 320
    """Pixels across."""
    height: int = 240
    """Pixels down."""
    focal_px: float = 290.0
    """Focal length, pixels (58 x 45 degrees at 320 x 240, a common depth camera's field)."""
    noise_m: float = 1e-3
    """Standard deviation of the depth noise along the ray at ``noise_depth_m``, metres."""
    noise_depth_m: float = 0.4
    """The depth ``noise_m`` holds at; the noise grows with the square of the depth."""
    max_depth_m: float = 1.5
    """Hits farther than this are dropped (the camera's range), metres."""

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("focal_px", "noise_depth_m", "max_depth_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not (math.isfinite(self.noise_m) and self.noise_m >= 0):
            raise ValueError(f"noise_m must be >= 0 (metres), got {self.noise_m!r}")


def depth_camera_scan(vertices, faces, config: DepthCameraConfig | None = None,
                      seed: np.random.Generator | int = 0) -> Scan:
    """One frame of a depth camera at the origin (:class:`DepthCameraConfig`) looking at a mesh:
    the first hit of a ray through each pixel centre, moved along its ray by Gaussian noise of
    standard deviation ``noise_m * (z / noise_depth_m)^2`` (z the hit's depth); pixels that hit
    nothing, or farther than ``max_depth_m``, give no point. Unlike :func:`simulate_scan`, which
    samples the visible surface evenly by area, the points are as dense as the pixels: a
    surface seen at a grazing angle gets few.

    vertices: [V, 3] metres in the camera's frame; faces: [F, 3] (numpy or torch).
    -> :class:`Scan`: the points in pixel order (row by row), the hit faces' normals turned
    towards the camera, no outliers, ``viewpoint`` the origin.
    """
    config = DepthCameraConfig() if config is None else config
    vertices, faces = check_mesh(vertices, faces)
    rng = _as_rng(seed, "seed")
    u, v = np.meshgrid(np.arange(config.width) + 0.5, np.arange(config.height) + 0.5)
    rays = np.stack([(u - 0.5 * config.width) / config.focal_px,
                     (v - 0.5 * config.height) / config.focal_px,
                     np.ones_like(u)], -1).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    caster = MeshRayCaster(vertices, faces)
    hits = caster.intersect(np.zeros_like(rays), rays, far=config.max_depth_m * 2.0)
    distance = hits.distances.astype(np.float64)
    points = rays * np.where(hits.hit, distance, 0.0)[:, None]
    kept = hits.hit & (points[:, 2] <= config.max_depth_m)
    depth = points[:, 2]
    sigma = config.noise_m * (depth / config.noise_depth_m) ** 2
    points = points + rays * (sigma * rng.standard_normal(len(rays)))[:, None]
    normals = caster.face_normals[np.where(hits.hit, hits.face_ids, 0)].astype(np.float64)
    normals *= -np.sign((normals * rays).sum(1, keepdims=True) + 1e-12)  # towards the camera
    return Scan(points=points[kept].astype(np.float32), normals=normals[kept].astype(np.float32),
                is_outlier=np.zeros(int(kept.sum()), bool), face_ids=hits.face_ids[kept],
                viewpoint=np.zeros(3, np.float32))


def _mesh_of(target) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices, faces) of a (vertices, faces) pair or an object with those attributes."""
    if isinstance(target, (tuple, list)) and len(target) == 2:
        return check_mesh(*target)
    if hasattr(target, "vertices") and hasattr(target, "faces"):
        return check_mesh(target.vertices, target.faces)
    return None


def sdf_samples(target: SdfFn | tuple | object, surface_points, normals=None,
                num_samples: int = 10000, sigma: float | Sequence[float] = 0.005,
                generator: np.random.Generator | int = 0) -> SdfSamples:
    """Points perturbed off a surface and their exact signed distances (SDF supervision).

    Each sample picks a surface point at random (with replacement) and a scale ``sigma_k`` at
    random among ``sigma`` (several scales mix near and far samples, as in DeepSDF/IGR), then
    moves it by ``sigma_k z``: along the point's normal (``z`` ~ N(0, 1)) when ``normals`` is
    given, otherwise isotropically (``z`` ~ N(0, I_3)). The signed distance is then computed
    exactly, not taken from the offset.

    target: ``sdf_fn(points [N, 3] float32 torch) -> [N] metres`` (negative inside), or a
        watertight mesh as ``(vertices [V, 3], faces [F, 3])`` or any object with ``vertices``
        and ``faces`` (``lisa_hand.geometry.meshing.Mesh``, trimesh): distances from
        :func:`lisa_hand.geometry.mesh_distance.mesh_distance` (sign by fast winding numbers).
    surface_points: [N, 3] metres; normals: [N, 3] unit or None.
    num_samples: M; sigma: metres, > 0, one value or several.
    generator: numpy Generator or int seed.
    -> :class:`SdfSamples` ``(points [M, 3], sdf [M])``.
    """
    surface_points = np.asarray(as_numpy(surface_points, "surface_points"), np.float64)
    if surface_points.ndim != 2 or surface_points.shape[1] != 3 or surface_points.shape[0] == 0:
        raise ValueError(f"surface_points must have shape [N, 3] with N > 0, got "
                         f"{list(surface_points.shape)}")
    if normals is not None:
        normals = np.asarray(as_numpy(normals, "normals"), np.float64)
        if normals.shape != surface_points.shape:
            raise ValueError(f"normals must have the shape of surface_points "
                             f"{list(surface_points.shape)}, got {list(normals.shape)}")
    num_samples = _check_count(num_samples, "num_samples")
    sigmas = np.atleast_1d(np.asarray(sigma, dtype=np.float64))
    if sigmas.ndim != 1 or sigmas.size == 0 or not (np.isfinite(sigmas) & (sigmas > 0)).all():
        raise ValueError(f"sigma must be a positive number or a list of them (metres), got "
                         f"{sigma!r}")
    mesh = _mesh_of(target)
    if mesh is None and not callable(target):
        raise TypeError(f"target must be an sdf_fn callable, a (vertices, faces) pair or a mesh "
                        f"object, got {type(target).__name__}")
    rng = _as_rng(generator)

    index = rng.integers(0, surface_points.shape[0], size=num_samples)
    scale = sigmas[rng.integers(0, sigmas.size, size=num_samples)]
    if normals is not None:
        offsets = (scale * rng.standard_normal(num_samples))[:, None] * normals[index]
    else:
        offsets = scale[:, None] * rng.standard_normal((num_samples, 3))
    points = (surface_points[index] + offsets).astype(np.float32)

    if mesh is not None:
        vertices, faces = mesh
        sdf = mesh_distance(points, vertices, faces).sdf.astype(np.float32)
    else:
        values = []
        with torch.no_grad():
            query = torch.from_numpy(points)
            for start in range(0, num_samples, _CHUNK):
                chunk = query[start:start + _CHUNK]
                values.append(call_sdf(target, chunk).detach().cpu().numpy())
        sdf = (np.concatenate(values) if values else np.zeros(0)).astype(np.float32)
    return SdfSamples(points=points, sdf=sdf)
