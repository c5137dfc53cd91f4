"""Ground-truth multi-view images of a surface: RGB, foreground mask, depth, normals, keypoints.

Two ways to find the first surface point along each camera ray, with the same outputs:

* :func:`render_views` casts the rays against a triangle mesh with Embree (through
  point-cloud-utils' ``RayMeshIntersector``, wrapped by
  :class:`~lisa_hand.render.raycast.MeshRayCaster`) and shades with smooth normals (vertex normals
  interpolated with the hit's barycentric coordinates);
* :func:`sphere_trace_views` sphere traces a signed distance callback on the rays that hit a
  bounding sphere (the package's one tracer, :func:`~lisa_hand.geometry.tracing.sphere_trace`),
  with normals from the SDF gradient (:func:`~lisa_hand.geometry.tracing.sdf_normals`, autograd).

The two agree to within the mesh's marching-cubes error (a mask IoU above 0.99), and Embree is
more than ten times faster (8 views at 512x334 of the open hand in well under a second on one
CPU core), so the dataset writer uses :func:`render_views`.

Shading is Lambertian plus ambient (:mod:`lisa_hand.data.shading`), per pixel::

    rgb = clip(gain * albedo * (ambient + diffuse / L * sum_l max(0, n . l)) + bias, 0, 1)

with ``n`` the unit outward normal, ``l`` the unit direction *towards* light ``l`` (L lights,
:class:`~lisa_hand.data.shading.ShadingConfig`) and ``gain``, ``bias`` a per-camera,
per-channel colour response (:class:`~lisa_hand.data.shading.GainBiasConfig`, as the
"color calibration" of LISA Section 4.2 models it). Gain and bias act on the hand only: the
background keeps ``ShadingConfig.background`` (black by default), as in InterHand2.6M, whose
backgrounds are removed with hand masks after capture. A renderer that models the calibration
should therefore apply it to the foreground colour before compositing over the background.

Anti-aliasing is optional: ``supersample = s`` traces ``s x s`` rays per pixel on a regular
sub-grid and averages them (RGB over hits and background; depth and normals over the hits); the
mask is "at least half the sub-rays hit". The default ``s = 1`` gives hard edges, one ray through
each pixel centre, and a mask that equals "depth > 0".

Images are numpy arrays (the ray caster runs on the CPU); pixel ``(u, v)`` is ``image[v, u]``
and covers ``[u, u + 1) x [v, v + 1)`` in the continuous pixel coordinates of
:mod:`lisa_hand.geometry.cameras`. Nothing here is differentiable.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.cameras import Camera, pixel_rays, project_points
from ..geometry.fields import SdfFn
from ..geometry.rays import ray_sphere_bounds
from ..geometry.tracing import sdf_normals, sphere_trace
from ..render.raycast import MeshRayCaster
from ..utils.arrays import as_numpy
from .shading import (
    GainBias,
    GainBiasConfig,
    ShadingConfig,
    as_generator,
    lights_per_view,
    resolve_gain_bias,
    shade,
)

__all__ = [
    "ViewImage",
    "KeypointProjection",
    "render_views",
    "sphere_trace_views",
    "project_keypoints",
]

AlbedoFn = Callable[[torch.Tensor], "torch.Tensor | np.ndarray"]

# Points per albedo / SDF callback call: bounds the memory of per-part intermediates.
_CHUNK = 1 << 17
# Slack on the albedo range check (callbacks computed in float32).
_ALBEDO_TOL = 1e-4








@dataclass(eq=False)
class ViewImage:
    """One rendered view (numpy arrays; pixel ``(u, v)`` is ``array[v, u]``)."""

    rgb: np.ndarray
    """[H, W, 3] float32 in [0, 1]."""
    mask: np.ndarray
    """[H, W] bool foreground (the surface covers the pixel)."""
    depth: np.ndarray
    """[H, W] float32 metres along the camera's z axis; 0 where ``mask`` is False."""
    gain: np.ndarray
    """[3] float32 colour gain applied to this view (ones without gain/bias)."""
    bias: np.ndarray
    """[3] float32 colour bias applied to this view (zeros without gain/bias)."""
    light_directions: np.ndarray
    """[L, 3] float32 unit directions towards the lights used, world frame."""
    normals: np.ndarray | None = None
    """[H, W, 3] float32 unit outward normals, world frame, 0 on the background; None unless
    asked for."""




@dataclass(eq=False)
class KeypointProjection:
    """Keypoints seen by one camera. K keypoints."""

    pixels: np.ndarray
    """[K, 2] float32 continuous pixel coordinates (meaningless where ``depth <= 0``)."""
    depth: np.ndarray
    """[K] float32 metres along the camera's z axis."""
    in_image: np.ndarray
    """[K] bool: in front of the camera and inside ``[0, W) x [0, H)``."""
    visible: np.ndarray
    """[K] bool: ``in_image`` and, when a depth map was given, not behind another surface."""










# --------------------------------------------------------------------------------------------
# Shared pipeline: rays -> hits (per backend) -> albedo (one call for all views) -> shading.


@dataclass(eq=False)
class _ViewHits:
    """Hits of one view's (possibly supersampled) rays; Nh hits among P = H s * W s rays."""

    ray_index: np.ndarray  # [Nh] int64 row-major index in the supersampled image
    depth: np.ndarray  # [Nh] float32 camera z, metres
    normals: np.ndarray  # [Nh, 3] float32 unit world normals
    points: np.ndarray  # [Nh, 3] float32 world hit points
    albedo_points: np.ndarray | None  # [Nh, 3] points handed to albedo_fn (None: use `points`)
    albedo: np.ndarray | None = None  # [Nh, 3] float32, filled in later


def _check_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    if isinstance(cameras, Camera):
        cameras = [cameras]
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must hold at least one Camera")
    for index, camera in enumerate(cameras):
        if not isinstance(camera, Camera):
            raise TypeError(f"cameras[{index}] must be a Camera, got {type(camera).__name__}")
    return cameras


def _check_supersample(supersample: int) -> int:
    if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"supersample must be a positive integer, got {supersample!r}")
    return supersample


def _supersampled(camera: Camera, factor: int) -> Camera:
    """The camera with ``factor`` times the resolution: its pixel centres are the sub-pixel grid."""
    if factor == 1:
        return camera
    scale = torch.tensor([factor, factor, 1.0], dtype=camera.dtype, device=camera.device)
    return Camera(K=camera.K * scale[:, None], R=camera.R, t=camera.t,
                  width=camera.width * factor, height=camera.height * factor, name=camera.name)






def _bounding_rectangle(camera: Camera, bbox_min: np.ndarray,
                        bbox_max: np.ndarray) -> tuple[int, int, int, int] | None:
    """Pixel columns ``[u0, u1)`` and rows ``[v0, v1)`` that can see the box, or None for all.

    The box's projection lies in the bounding rectangle of its 8 projected corners whenever all
    of them are in front of the camera; otherwise (a camera inside or beside the box) every pixel
    may see it.
    """
    box = np.stack([bbox_min, bbox_max]).astype(np.float64)  # [2, 3]
    choice = np.indices((2, 2, 2)).reshape(3, 8).T  # [8, 3]: min (0) or max (1) per axis
    corners = box[choice, np.arange(3)]
    # The pinhole projection of project_points, on 8 points in numpy (no torch dispatch).
    K, R, t = (x.detach().cpu().double().numpy() for x in (camera.K, camera.R, camera.t))
    homogeneous = (corners @ R.T + t) @ K.T
    depth = homogeneous[:, 2]
    if not (depth > 1e-9).all():
        return None
    pixels = homogeneous[:, :2] / depth[:, None]
    low = np.floor(pixels.min(0)).astype(np.int64) - 1
    high = np.ceil(pixels.max(0)).astype(np.int64) + 1
    u0, v0 = max(int(low[0]), 0), max(int(low[1]), 0)
    u1, v1 = min(int(high[0]), camera.width), min(int(high[1]), camera.height)
    return u0, max(u1, u0), v0, max(v1, v0)


def _rectangle_rays(camera: Camera, rectangle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays through the centres of the pixels in ``rectangle`` (None: the whole image).

    -> origins [P, 3], directions [P, 3] (float32 numpy) and their row-major pixel indices [P].
    """
    if rectangle is None:
        origins, directions = pixel_rays(camera, device="cpu", dtype=torch.float32)
        pixel_index = np.arange(origins.shape[0])
    else:
        u0, u1, v0, v1 = rectangle
        columns, rows = np.meshgrid(np.arange(u0, u1), np.arange(v0, v1), indexing="xy")
        columns, rows = columns.reshape(-1), rows.reshape(-1)
        centres = torch.from_numpy(np.stack([columns, rows], 1).astype(np.float32) + 0.5)
        origins, directions = pixel_rays(camera, centres, device="cpu", dtype=torch.float32)
        pixel_index = rows * camera.width + columns
    return (np.ascontiguousarray(origins.numpy()), np.ascontiguousarray(directions.numpy()),
            pixel_index)


def _call_albedo(albedo_fn: AlbedoFn, points: np.ndarray | torch.Tensor) -> np.ndarray:
    """Evaluate ``albedo_fn`` in chunks on [N, 3] points; -> [N, 3] float32 numpy in [0, 1]."""
    num_points = points.shape[0]
    if num_points == 0:
        return np.zeros((0, 3), np.float32)
    if isinstance(points, np.ndarray):
        points = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32))
    chunks = []
    with torch.no_grad():
        for start in range(0, num_points, _CHUNK):
            chunk = points[start:start + _CHUNK]
            values = np.asarray(as_numpy(albedo_fn(chunk), "albedo_fn(points)"), np.float32)
            if values.shape != (chunk.shape[0], 3):
                raise ValueError(f"albedo_fn(points [N, 3]) must return [N, 3] colours, got shape "
                                 f"{list(values.shape)} for N = {chunk.shape[0]}")
            chunks.append(values)
    albedo = np.concatenate(chunks, axis=0)
    low, high = float(albedo.min()), float(albedo.max())
    if not (np.isfinite(albedo).all() and low >= -_ALBEDO_TOL and high <= 1.0 + _ALBEDO_TOL):
        raise ValueError(f"albedo_fn must return colours in [0, 1], got values in "
                         f"[{low:.4g}, {high:.4g}]")
    return np.clip(albedo, 0.0, 1.0)






def _pool(values: np.ndarray, shape: tuple[int, int], factor: int) -> np.ndarray:
    """Sum [H f * W f, C] (or [H f * W f]) sub-pixel values into [H, W, C]."""
    grid = values.reshape(shape[0], factor, shape[1], factor, -1)
    return grid.sum(axis=(1, 3))


def _assemble(cameras: list[Camera], view_hits: list[_ViewHits], shading: ShadingConfig,
              generator, gain_bias, supersample: int, return_normals: bool) -> list[ViewImage]:
    """Shade the hits, composite over the background, average the sub-pixels."""
    needs_random = shading.random_light or isinstance(gain_bias, GainBiasConfig)
    generator = as_generator(generator, needs_random,
                              "random_light is on or gain_bias is a GainBiasConfig")
    # Randomness in a fixed order: lights (world once / per view), then gains, then biases.
    lights = lights_per_view(cameras, shading, generator)
    responses = resolve_gain_bias(gain_bias, len(cameras), generator)
    background = np.asarray(shading.background, np.float32)
    factor = supersample
    images = []
    for index, (camera, hits) in enumerate(zip(cameras, view_hits, strict=True)):
        if responses is None:
            gain, bias = np.ones(3, np.float32), np.zeros(3, np.float32)
        else:
            gain, bias = responses.for_camera(index, len(cameras))
        colour = shade(hits.normals, hits.albedo, lights[index], gain, bias, shading)
        height, width = camera.height * factor, camera.width * factor
        num_rays = height * width
        rgb = np.broadcast_to(background, (num_rays, 3)).copy()
        rgb[hits.ray_index] = colour
        hit = np.zeros(num_rays, np.float32)
        hit[hits.ray_index] = 1.0
        depth = np.zeros(num_rays, np.float32)
        depth[hits.ray_index] = hits.depth
        normals = None
        if return_normals:
            normals = np.zeros((num_rays, 3), np.float32)
            normals[hits.ray_index] = hits.normals
        if factor == 1:
            mask = hit.reshape(camera.height, camera.width) > 0
            rgb = rgb.reshape(camera.height, camera.width, 3)
            depth = depth.reshape(camera.height, camera.width)
            if normals is not None:
                normals = normals.reshape(camera.height, camera.width, 3)
        else:
            shape = (camera.height, camera.width)
            hit_count = _pool(hit, shape, factor)[..., 0]
            mask = hit_count >= 0.5 * factor * factor
            rgb = _pool(rgb, shape, factor) / (factor * factor)
            depth = np.where(mask, _pool(depth, shape, factor)[..., 0]
                             / np.maximum(hit_count, 1.0), 0.0)
            if normals is not None:
                summed = _pool(normals, shape, factor)
                length = np.linalg.norm(summed, axis=-1, keepdims=True)
                normals = np.where(mask[..., None] & (length > 0),
                                   summed / np.maximum(length, 1e-12), 0.0)
        images.append(ViewImage(
            rgb=rgb.astype(np.float32), mask=mask, depth=depth.astype(np.float32),
            gain=np.asarray(gain, np.float32), bias=np.asarray(bias, np.float32),
            light_directions=lights[index],
            normals=None if normals is None else normals.astype(np.float32)))
    return images


def _fill_albedo(view_hits: list[_ViewHits], albedo_fn) -> None:
    """One albedo evaluation for the hits of all views (fewer, larger callback calls)."""
    if callable(albedo_fn):
        queries = [h.points if h.albedo_points is None else h.albedo_points for h in view_hits]
        albedo = _call_albedo(albedo_fn, np.concatenate(queries, axis=0))
        splits = np.cumsum([len(q) for q in queries])[:-1]
        for hits, values in zip(view_hits, np.split(albedo, splits), strict=True):
            hits.albedo = values
    else:  # already filled by the caller (constant or per-vertex colours)
        assert all(h.albedo is not None for h in view_hits)


def render_views(
    vertices,
    faces,
    cameras: Sequence[Camera],
    albedo_fn: AlbedoFn | np.ndarray | torch.Tensor,
    shading: ShadingConfig | None = None,
    generator: np.random.Generator | int | None = None,
    gain_bias: GainBiasConfig | GainBias | None = None,
    *,
    albedo_vertices=None,
    supersample: int = 1,
    return_normals: bool = False,
    caster: MeshRayCaster | None = None,
) -> list[ViewImage]:
    """Render a triangle mesh into each camera with Embree ray casting (see the module docstring).

    vertices: [V, 3] metres, world frame; faces: [F, 3] vertex indices, counter-clockwise seen
        from outside (numpy or torch; rays hitting a back face get the flipped normal).
    cameras: the views (any sizes); images are ``camera.height x camera.width``.
    albedo_fn: a callback ``points [N, 3] float32 torch (CPU) -> [N, 3] in [0, 1]`` (torch or
        numpy), evaluated once on the hits of all views; or per-vertex colours [V, 3] in [0, 1]
        interpolated with the barycentric coordinates; or one colour [3].
    shading: lights, ambient, background (default :class:`ShadingConfig()`).
    generator: numpy Generator or int seed; required when ``shading.random_light`` is on or
        ``gain_bias`` is a :class:`GainBiasConfig`.
    gain_bias: None (gain 1, bias 0), a :class:`GainBiasConfig` to sample per camera and channel,
        or explicit :class:`GainBias` values. What was applied is stored in each view.
    albedo_vertices: optional [V, 3] points, one per vertex (the rest-pose vertices of a posed
        mesh): ``albedo_fn`` then gets their barycentric interpolation at each hit instead of the
        world hit point, so a texture defined in the rest pose follows the surface.
    supersample: sub-rays per pixel side (anti-aliasing, see the module docstring).
    return_normals: also return world-frame normal maps.
    caster: a :class:`MeshRayCaster` already built on these vertices and faces (reuse it when
        rendering one mesh several times); ``vertices`` and ``faces`` are then ignored.
    -> one :class:`ViewImage` per camera.
    """
    cameras = _check_cameras(cameras)
    supersample = _check_supersample(supersample)
    shading = _check_shading(shading)
    if caster is None:
        caster = MeshRayCaster(vertices, faces)
    elif not isinstance(caster, MeshRayCaster):
        raise TypeError(f"caster must be a MeshRayCaster or None, got {type(caster).__name__}")
    vertex_colours, albedo_vertices = _check_vertex_albedo(
        albedo_fn, albedo_vertices, caster.vertices.shape[0]
    )
    bbox_min, bbox_max = caster.vertices.min(0), caster.vertices.max(0)
    view_hits = []
    for camera in cameras:
        fine_camera = _supersampled(camera, supersample)
        # Only the pixels inside the mesh's projected bounding box can hit it.
        rectangle = _bounding_rectangle(fine_camera, bbox_min, bbox_max)
        origins, directions, pixel_index = _rectangle_rays(fine_camera, rectangle)
        z_axis = fine_camera.R[2].detach().cpu().to(torch.float32).numpy()
        view_hits.append(_mesh_view_hits(caster, origins, directions, pixel_index, z_axis,
                                         vertex_colours, albedo_vertices))
    _fill_albedo(view_hits, albedo_fn)
    return _assemble(cameras, view_hits, shading, generator, gain_bias, supersample,
                     return_normals)


def _check_shading(shading: ShadingConfig | None) -> ShadingConfig:
    shading = ShadingConfig() if shading is None else shading
    if not isinstance(shading, ShadingConfig):
        raise TypeError(f"shading must be a ShadingConfig or None, got {type(shading).__name__}")
    return shading


def _check_vertex_albedo(albedo_fn, albedo_vertices, num_vertices: int):
    """-> (vertex_colours: [3] or [V, 3] float32 when ``albedo_fn`` is colours, else None;
    albedo_vertices: [V, 3] float32 or None), checked."""
    vertex_colours = None
    if not callable(albedo_fn):
        vertex_colours = np.asarray(as_numpy(albedo_fn, "albedo_fn"), np.float32)
        if vertex_colours.shape not in ((3,), (num_vertices, 3)):
            raise ValueError(f"albedo_fn must be a callable, a colour [3] or per-vertex colours "
                             f"[V, 3] = [{num_vertices}, 3], got shape "
                             f"{list(vertex_colours.shape)}")
        if not ((vertex_colours >= 0) & (vertex_colours <= 1)).all():
            raise ValueError("albedo_fn colours must be in [0, 1]")
    if albedo_vertices is not None:
        albedo_vertices = np.asarray(as_numpy(albedo_vertices, "albedo_vertices"), np.float32)
        if albedo_vertices.shape != (num_vertices, 3):
            raise ValueError(f"albedo_vertices must have shape [V, 3] = [{num_vertices}, 3], "
                             f"got {list(albedo_vertices.shape)}")
    return vertex_colours, albedo_vertices


def _mesh_view_hits(caster: MeshRayCaster, origins, directions, pixel_index, z_axis,
                    vertex_colours, albedo_vertices) -> _ViewHits:
    """Cast one view's rays (origins, directions [P, 3] float32, their pixel indices [P]) and
    interpolate the smooth normals (flipped on back faces), the albedo points and the vertex
    colours at the hits. z_axis: [3] the camera's z axis, for the depth."""
    hits = caster.intersect(origins, directions)
    ray_index = np.flatnonzero(hits.hit)
    face_ids = hits.face_ids[ray_index]
    weights = hits.barycentrics[ray_index][:, :, None]  # [Nh, 3, 1]
    corner_ids = caster.faces[face_ids]  # [Nh, 3]
    ray_dirs = directions[ray_index]
    distances = hits.distances[ray_index]
    points = origins[ray_index] + distances[:, None] * ray_dirs
    normals = (weights * caster.vertex_normals[corner_ids]).sum(axis=1)
    back_facing = (caster.face_normals[face_ids] * ray_dirs).sum(axis=1) > 0
    normals[back_facing] *= -1.0
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    view = _ViewHits(ray_index=pixel_index[ray_index], depth=(distances * (ray_dirs @ z_axis)),
                     normals=normals.astype(np.float32), points=points.astype(np.float32),
                     albedo_points=None)
    if albedo_vertices is not None:
        view.albedo_points = (weights * albedo_vertices[corner_ids]).sum(axis=1)
    if vertex_colours is not None:
        if vertex_colours.ndim == 1:
            view.albedo = np.broadcast_to(vertex_colours, (len(ray_index), 3))
        else:
            view.albedo = (weights * vertex_colours[corner_ids]).sum(axis=1)
    return view


# --------------------------------------------------------------------------------------------
# Sphere tracing backend.


def sphere_trace_views(
    sdf_fn: SdfFn,
    cameras: Sequence[Camera],
    albedo_fn: AlbedoFn,
    bound_center,
    bound_radius: float,
    shading: ShadingConfig | None = None,
    generator: np.random.Generator | int | None = None,
    gain_bias: GainBiasConfig | GainBias | None = None,
    *,
    tolerance: float = 5e-5,
    max_steps: int = 128,
    step_scale: float = 1.0,
    supersample: int = 1,
    return_normals: bool = False,
    chunk_size: int = _CHUNK,
) -> list[ViewImage]:
    """Render the zero level set of ``sdf_fn`` into each camera by sphere tracing.

    Rays of all views are traced together by the package's one sphere tracer
    (:func:`~lisa_hand.geometry.tracing.sphere_trace`); only those that hit the bounding sphere
    are marched, from its entry point: ``s <- s + step_scale * sdf(o + s d)`` on the
    still-active rays until ``sdf <= tolerance`` (a hit) or ``s`` leaves the sphere or
    ``max_steps`` run out (a miss). The normal is the normalised SDF gradient at the hit
    (:func:`~lisa_hand.geometry.tracing.sdf_normals`, autograd); shading, gain/bias and the
    outputs are those of :func:`render_views`. Runs on the cameras' device.

    sdf_fn: ``points [N, 3] metres (cameras' dtype and device) -> [N] or [N, 1] metres``
        (:class:`~lisa_hand.geometry.fields.SdfFn`), negative inside; must not overestimate the
        distance (an exact SDF, a union or a log-sum-exp smooth union of exact SDFs), or use
        ``step_scale < 1`` (the tracer's ``lipschitz = 1 / step_scale``); differentiable.
    albedo_fn: ``points [N, 3] world (torch, the cameras' device) -> [N, 3] in [0, 1]``.
    bound_center: [3] metres; bound_radius: metres, a sphere holding the whole surface.
    tolerance: hit threshold on the SDF, metres (depth error about this over the cosine of the
        incidence angle).
    """
    cameras = _check_cameras(cameras)
    supersample = _check_supersample(supersample)
    shading = _check_shading(shading)
    if not callable(sdf_fn):
        raise TypeError(f"sdf_fn must be callable, got {type(sdf_fn).__name__}")
    if not callable(albedo_fn):
        raise TypeError(f"albedo_fn must be callable, got {type(albedo_fn).__name__}")
    if not (tolerance > 0 and 0 < step_scale <= 1 and max_steps >= 1 and bound_radius > 0):
        raise ValueError(f"need tolerance > 0, 0 < step_scale <= 1, max_steps >= 1 and "
                         f"bound_radius > 0; got {tolerance}, {step_scale}, {max_steps}, "
                         f"{bound_radius}")
    device, dtype = cameras[0].device, cameras[0].dtype
    center = torch.as_tensor(as_numpy(bound_center, "bound_center"), dtype=dtype, device=device)
    if center.shape != (3,):
        raise ValueError(f"bound_center must have shape [3], got {list(center.shape)}")

    origins, directions, view_of_ray, z_axes = _all_view_rays(cameras, supersample)
    near, far, in_bound = ray_sphere_bounds(origins, directions, center, float(bound_radius))
    ray_ids = torch.nonzero(in_bound)[:, 0]
    hits = sphere_trace(sdf_fn, origins[ray_ids], directions[ray_ids], near[ray_ids],
                        far[ray_ids], num_steps=max_steps, tolerance=tolerance,
                        lipschitz=1.0 / step_scale, points_per_call=chunk_size)
    hit_rays = ray_ids[hits.hit]
    hit_distance = hits.t[hits.hit]
    hit_dirs = directions[hit_rays]
    hit_points = origins[hit_rays] + hit_distance[:, None] * hit_dirs
    normals = sdf_normals(sdf_fn, hit_points, "autograd", chunk_size=chunk_size)
    albedo = _call_albedo(albedo_fn, hit_points)
    hit_view = view_of_ray[hit_rays]
    depth = hit_distance * (hit_dirs * z_axes[hit_view]).sum(-1)

    hit_view = hit_view.cpu().numpy()
    offsets = np.cumsum([0] + [_num_rays(camera, supersample) for camera in cameras])
    hit_rays_np = hit_rays.cpu().numpy()
    depth_np = depth.detach().cpu().numpy().astype(np.float32)
    normals_np = normals.detach().cpu().numpy().astype(np.float32)
    points_np = hit_points.detach().cpu().numpy().astype(np.float32)
    view_hits = []
    for index in range(len(cameras)):
        select = hit_view == index
        view_hits.append(_ViewHits(ray_index=hit_rays_np[select] - offsets[index],
                                   depth=depth_np[select], normals=normals_np[select],
                                   points=points_np[select], albedo_points=None,
                                   albedo=albedo[select]))
    return _assemble(cameras, view_hits, shading, generator, gain_bias, supersample,
                     return_normals)


def _num_rays(camera: Camera, supersample: int) -> int:
    return camera.width * supersample * camera.height * supersample


def _all_view_rays(cameras: list[Camera], supersample: int):
    """The (supersampled) pixel rays of all views, on the first camera's device and dtype:
    origins [P, 3], directions [P, 3], the view of each ray [P] long, and the views' z axes
    [C, 3] (each ray's depth is its distance times ``direction . z``)."""
    device, dtype = cameras[0].device, cameras[0].dtype
    all_origins, all_dirs, view_of_ray, z_axes = [], [], [], []
    for index, camera in enumerate(cameras):
        origins, directions = pixel_rays(_supersampled(camera, supersample), device=device,
                                         dtype=dtype)
        all_origins.append(origins)
        all_dirs.append(directions)
        view_of_ray.append(torch.full((origins.shape[0],), index, device=device))
        z_axes.append(camera.R[2].to(device=device, dtype=dtype))
    return (torch.cat(all_origins), torch.cat(all_dirs), torch.cat(view_of_ray),
            torch.stack(z_axes))


# --------------------------------------------------------------------------------------------
# Keypoints.


def project_keypoints(keypoints_world, camera: Camera, depth=None,
                      depth_tolerance: float = 0.025) -> KeypointProjection:
    """Project 3D keypoints (the 21 hand keypoints, or any K) into one camera.

    keypoints_world: [K, 3] metres (numpy or torch).
    depth: optional rendered depth map [H, W] metres (0 = background) of the same camera; a
        keypoint whose pixel holds a surface more than ``depth_tolerance`` in front of it is
        occluded. Hand keypoints are joint centres, inside the finger (about its radius, ~1 cm,
        under the surface; the wrist ~1.5 cm): the default 2.5 cm tolerance lets a joint's own
        finger pass and catches another finger or the palm in front of it.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    keypoints = torch.as_tensor(np.asarray(as_numpy(keypoints_world, "keypoints_world"),
                                           np.float64))
    if keypoints.ndim != 2 or keypoints.shape[1] != 3:
        raise ValueError(f"keypoints_world must have shape [K, 3], got {list(keypoints.shape)}")
    cam = camera.to(device="cpu", dtype=torch.float64)
    pixels, depths = project_points(cam.K, cam.R, cam.t, keypoints)
    pixels, depths = pixels.numpy(), depths.numpy()
    in_front = depths > 0
    with np.errstate(invalid="ignore"):
        in_image = (in_front & (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width)
                    & (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height))
    visible = in_image.copy()
    if depth is not None:
        depth_map = np.asarray(as_numpy(depth, "depth"), np.float32)
        if depth_map.shape != (camera.height, camera.width):
            raise ValueError(f"depth must have shape [H, W] = [{camera.height}, {camera.width}], "
                             f"got {list(depth_map.shape)}")
        columns = np.floor(np.where(in_image, pixels[:, 0], 0)).astype(np.int64)
        rows = np.floor(np.where(in_image, pixels[:, 1], 0)).astype(np.int64)
        surface = depth_map[rows, columns]
        occluded = (surface > 0) & (surface < depths - depth_tolerance)
        visible &= ~occluded
    return KeypointProjection(pixels=pixels.astype(np.float32), depth=depths.astype(np.float32),
                              in_image=in_image, visible=visible)
