"""Calibrated pinhole cameras, projection and camera rays. Pure tensor math, nothing learnable.

Conventions (OpenCV):

* extrinsics map world to camera: ``x_cam = R x_world + t``; the camera looks along its +z axis,
  image x points right and image y points down;
* intrinsics ``K`` are in pixels, ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``;
* pixel coordinates are continuous: pixel ``(u, v)`` (column ``u``, row ``v``, both integers)
  covers ``[u, u + 1) x [v, v + 1)`` and its centre is ``(u + 0.5, v + 0.5)``. The image centre is
  ``(width / 2, height / 2)``; keypoint pixels use the same continuous coordinates, so a keypoint
  at ``(10.0, 20.0)`` lies on the top-left corner of pixel ``(10, 20)``. Pixel ``(u, v)`` is
  ``image[v, u]``; "row-major" order is index ``v * width + u``, i.e. ``image.reshape(H * W, C)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from ..utils.io import read_json, write_json

__all__ = [
    "Camera",
    "project_points",
    "camera_center",
    "pixel_centers",
    "pixel_rays",
    "look_at",
    "intrinsics_from_fov",
    "make_rig",
    "save_cameras",
    "load_cameras",
    "MAX_IMAGE_SIDE",
    "FOCAL_RANGE",
]

# Tolerances for validating loaded matrices (float32 round trips through JSON stay far below).
_ROTATION_TOL = 1e-4
_K_LAST_ROW_TOL = 1e-6

MAX_IMAGE_SIDE = 16384
"""Largest image width or height in pixels a camera may have (a 16384 x 16384 RGB float image
is 3 GB; a larger one is a typo, not a camera)."""
FOCAL_RANGE = (0.01, 1000.0)
"""Focal lengths a camera may have, in units of its image's longer side: 0.01 is a field of
view of 179.4 degrees, 1000 one of 0.06 degrees; beyond either the pinhole model in float32
flattens the hand."""


def _as_tensor(value: Any, name: str, dtype: torch.dtype | None = None) -> torch.Tensor:
    """Convert lists/arrays to a float tensor; keep float32/float64 tensors as they are."""
    if isinstance(value, torch.Tensor):
        tensor = value
        if not tensor.is_floating_point():
            tensor = tensor.to(dtype or torch.get_default_dtype())
    else:
        try:
            tensor = torch.as_tensor(value, dtype=dtype or torch.float32)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise TypeError(f"{name} must be a numeric array, got {type(value).__name__} "
                            f"({exc})") from None
    if dtype is not None:
        tensor = tensor.to(dtype)
    return tensor


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated pinhole camera (OpenCV convention, see the module docstring).

    ``K``, ``R`` and ``t`` are stored as tensors of one dtype on one device; lists and numpy arrays
    are converted to float32. Construction validates shapes, that ``R`` is a rotation, that ``K``
    is invertible with last row ``[0, 0, 1]`` and focal lengths in :data:`FOCAL_RANGE`, and that
    the image is at most :data:`MAX_IMAGE_SIDE` pixels a side.
    """

    K: torch.Tensor
    """[3, 3] intrinsics in pixels."""
    R: torch.Tensor
    """[3, 3] rotation, world to camera."""
    t: torch.Tensor
    """[3] translation in metres, world to camera (``x_cam = R x_world + t``)."""
    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    name: str | None = field(default=None)
    """Optional camera name (serial number, ``cam007``)."""

    def __post_init__(self) -> None:
        K = _as_tensor(self.K, "K")
        R = _as_tensor(self.R, "R", dtype=K.dtype).to(K.device)
        t = _as_tensor(self.t, "t", dtype=K.dtype).to(K.device)
        if K.shape != (3, 3):
            raise ValueError(f"K must have shape [3, 3], got {list(K.shape)}")
        if R.shape != (3, 3):
            raise ValueError(f"R must have shape [3, 3], got {list(R.shape)}")
        if t.shape != (3,):
            raise ValueError(f"t must have shape [3], got {list(t.shape)}")
        for name, value in (("K", K), ("R", R), ("t", t)):
            if not bool(torch.isfinite(value).all()):
                raise ValueError(f"{name} has non-finite entries: {value.tolist()}")
        last_row = K[2].double().cpu()
        if not torch.allclose(last_row, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                              atol=_K_LAST_ROW_TOL):
            raise ValueError(f"K: last row must be [0, 0, 1], got {last_row.tolist()}")
        if not (float(K[0, 0]) > 0 and float(K[1, 1]) > 0):
            raise ValueError(f"K: focal lengths fx, fy must be positive, got "
                             f"{float(K[0, 0])}, {float(K[1, 1])}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ValueError(f"{name} must be a positive integer (pixels), got {value!r}")
            if value > MAX_IMAGE_SIDE:
                raise ValueError(f"{name} must be at most {MAX_IMAGE_SIDE} pixels, got {value}")
        side = max(self.width, self.height)
        for name, focal in (("fx", float(K[0, 0])), ("fy", float(K[1, 1]))):
            if not FOCAL_RANGE[0] * side <= focal <= FOCAL_RANGE[1] * side:
                raise ValueError(f"K: focal length {name} = {focal:g} px is implausible for a "
                                 f"{self.width}x{self.height} image (expected "
                                 f"{FOCAL_RANGE[0] * side:g} to {FOCAL_RANGE[1] * side:g} px)")
        K64 = K.double().cpu()
        if abs(float(torch.linalg.det(K64))) <= 1e-9 * float(K64[0, 0] * K64[1, 1]):
            raise ValueError(f"K is singular (not invertible): {K64.tolist()}")
        R64 = R.double().cpu()
        ortho_err = float((R64 @ R64.T - torch.eye(3, dtype=torch.float64)).abs().max())
        det = float(torch.linalg.det(R64))
        if ortho_err > _ROTATION_TOL or abs(det - 1.0) > _ROTATION_TOL:
            raise ValueError(f"R must be a rotation matrix (R R^T = I, det R = 1), got "
                             f"max |R R^T - I| = {ortho_err:.3g}, det R = {det:.6g}")
        if self.name is not None and not isinstance(self.name, str):
            raise TypeError(f"name must be a string or None, got {type(self.name).__name__}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @property
    def device(self) -> torch.device:
        return self.K.device

    @property
    def dtype(self) -> torch.dtype:
        return self.K.dtype

    @property
    def center(self) -> torch.Tensor:
        """[3] camera centre in world coordinates, metres (``-R^T t``)."""
        return camera_center(self.R, self.t)

    def to(self, device: torch.device | str | None = None,
           dtype: torch.dtype | None = None) -> Camera:
        """A copy with ``K``, ``R`` and ``t`` on ``device`` and/or in ``dtype``."""
        def move(x: torch.Tensor) -> torch.Tensor:
            return x.to(device=device if device is not None else x.device,
                        dtype=dtype if dtype is not None else x.dtype)

        return Camera(K=move(self.K), R=move(self.R), t=move(self.t), width=self.width,
                      height=self.height, name=self.name)

    def project(self, points_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Project points into this camera; see :func:`project_points`.

        points_world: [..., N, 3] metres -> pixels [..., N, 2], depth [..., N] metres
        """
        return project_points(self.K, self.R, self.t, points_world)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict ``{"name", "K", "R", "t", "width", "height"}`` (nested lists)."""
        return {
            "name": self.name,
            "K": self.K.detach().double().cpu().tolist(),
            "R": self.R.detach().double().cpu().tolist(),
            "t": self.t.detach().double().cpu().tolist(),
            "width": self.width,
            "height": self.height,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | None = None,
                  dtype: torch.dtype = torch.float32) -> Camera:
        """Build a camera from :meth:`to_dict`'s format.

        ``source`` (a file path, "cameras.json: camera 3") prefixes every error message, so a bad
        field in a file names both the file and the field.
        """
        prefix = f"{source}: " if source else ""
        if not isinstance(data, Mapping):
            raise ValueError(f"{prefix}a camera must be a JSON object with fields "
                             f"name, K, R, t, width, height; got {type(data).__name__}")
        missing = [key for key in ("K", "R", "t", "width", "height") if key not in data]
        if missing:
            raise ValueError(f"{prefix}missing camera field(s): {', '.join(missing)}")
        try:
            return cls(K=_as_tensor(data["K"], "K", dtype), R=_as_tensor(data["R"], "R", dtype),
                       t=_as_tensor(data["t"], "t", dtype), width=data["width"],
                       height=data["height"], name=data.get("name"))
        except (ValueError, TypeError) as exc:
            raise type(exc)(f"{prefix}{exc}") from None


def save_cameras(path: str | os.PathLike, cameras: Sequence[Camera]) -> Path:
    """Write cameras as a JSON list of :meth:`Camera.to_dict` (atomically); return the path."""
    for index, camera in enumerate(cameras):
        if not isinstance(camera, Camera):
            raise TypeError(f"cameras[{index}] must be a Camera, got {type(camera).__name__}")
    return write_json(path, [camera.to_dict() for camera in cameras])


def load_cameras(path: str | os.PathLike, dtype: torch.dtype = torch.float32) -> list[Camera]:
    """Read a JSON list of cameras written by :func:`save_cameras`.

    Errors name the file, the camera index and the missing or invalid field.
    """
    data = read_json(path)
    if not isinstance(data, list):
        raise ValueError(f"{path}: expected a JSON list of cameras, got {type(data).__name__}")
    return [Camera.from_dict(entry, source=f"{path}: camera {index}", dtype=dtype)
            for index, entry in enumerate(data)]


def _check_last_dim(tensor: torch.Tensor, name: str, shape: tuple[int, ...], spec: str) -> None:
    if tensor.ndim < len(shape) or tuple(tensor.shape[-len(shape):]) != shape:
        raise ValueError(f"{name} must have shape {spec}, got {list(tensor.shape)}")


def project_points(K: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                   points_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pinhole projection ``pixels = (K (R x + t))_{xy} / (R x + t)_z``, batched.

    K: [..., 3, 3] pixels, R: [..., 3, 3], t: [..., 3] metres, points_world: [..., N, 3] metres
    (batch dims broadcast) -> pixels [..., N, 2] (continuous coordinates, see the module
    docstring), depth [..., N] metres (z in the camera frame).

    Pixels of points with ``depth <= 0`` (behind the camera or on its plane) are meaningless
    (inf or mirrored); mask them with ``depth > 0``.
    """
    _check_last_dim(K, "K", (3, 3), "[..., 3, 3]")
    _check_last_dim(R, "R", (3, 3), "[..., 3, 3]")
    _check_last_dim(t, "t", (3,), "[..., 3]")
    _check_last_dim(points_world, "points_world", (3,), "[..., N, 3]")
    if points_world.ndim < 2:
        raise ValueError(
            f"points_world must have shape [..., N, 3], got {list(points_world.shape)}")
    x_cam = points_world @ R.transpose(-1, -2) + t[..., None, :]
    depth = x_cam[..., 2]
    homogeneous = x_cam @ K.transpose(-1, -2)
    pixels = homogeneous[..., :2] / depth[..., None]
    return pixels, depth


def camera_center(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Camera centre in world coordinates, ``-R^T t``.

    R: [..., 3, 3], t: [..., 3] metres -> [..., 3] metres
    """
    _check_last_dim(R, "R", (3, 3), "[..., 3, 3]")
    _check_last_dim(t, "t", (3,), "[..., 3]")
    return -(R.transpose(-1, -2) @ t[..., None])[..., 0]


def pixel_centers(width: int, height: int, device: torch.device | str | None = None,
                  dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Centres ``(u + 0.5, v + 0.5)`` of all pixels in row-major order.

    -> [height * width, 2] pixels, entry ``v * width + u`` is pixel ``(u, v)`` (``image[v, u]``)
    """
    u = torch.arange(width, device=device, dtype=dtype) + 0.5
    v = torch.arange(height, device=device, dtype=dtype) + 0.5
    return torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)


def pixel_rays(camera: Camera, pixels: torch.Tensor | None = None,
               device: torch.device | str | None = None,
               dtype: torch.dtype | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """World-frame rays through pixels: ``x(s) = origin + s * direction``.

    The direction through pixel coordinates ``(u, v)`` is ``R^T K^{-1} [u, v, 1]^T``, normalised,
    so a point at distance ``s`` along the ray lies ``s`` metres from the camera centre.

    camera: the camera; pixels: [R, 2] continuous pixel coordinates (use ``u + 0.5`` for the
    centre of pixel ``u``), or None for the centres of all ``height * width`` pixels in row-major
    order (see :func:`pixel_centers`); device/dtype default to the camera's.
    -> origins [R, 3] metres (the camera centre; a broadcast view, ``.contiguous()`` it before
    writing in place), directions [R, 3] unit vectors, world frame.
    """
    device = torch.device(device) if device is not None else camera.device
    dtype = dtype or camera.dtype
    K = camera.K.to(device=device, dtype=dtype)
    R = camera.R.to(device=device, dtype=dtype)
    t = camera.t.to(device=device, dtype=dtype)
    # M = R^T K^-1 maps homogeneous pixels straight to world directions.
    world_from_pixel = R.transpose(0, 1) @ torch.linalg.inv(K)
    if pixels is None:
        u = torch.arange(camera.width, device=device, dtype=dtype) + 0.5
        v = torch.arange(camera.height, device=device, dtype=dtype) + 0.5
        # direction[v, u] = u * M[:, 0] + v * M[:, 1] + M[:, 2]: an outer sum, no [R, 3] matmul.
        per_column = u[:, None] * world_from_pixel[:, 0]
        per_row = v[:, None] * world_from_pixel[:, 1] + world_from_pixel[:, 2]
        directions = (per_row[:, None, :] + per_column[None, :, :]).reshape(-1, 3)
    else:
        if not isinstance(pixels, torch.Tensor):
            raise TypeError(f"pixels must be a tensor [R, 2] or None, got {type(pixels).__name__}")
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(f"pixels must have shape [R, 2], got {list(pixels.shape)}")
        pixels = pixels.to(device=device, dtype=dtype)
        directions = pixels @ world_from_pixel[:, :2].transpose(0, 1) + world_from_pixel[:, 2]
    directions = directions / directions.norm(dim=-1, keepdim=True)
    origins = camera_center(R, t).expand(directions.shape[0], 3)
    return origins, directions


def look_at(eye: torch.Tensor, target: torch.Tensor,
            up: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Extrinsics of a camera at ``eye`` looking at ``target``, image "up" towards ``up``.

    The camera's +z axis points from ``eye`` to ``target`` (so ``target`` lands at the principal
    point), its +y axis (image down) is ``-up`` made orthogonal to the view direction.

    eye: [..., 3] metres, target: [..., 3] metres, up: [..., 3] world up (default ``+y``)
    -> R [..., 3, 3] world to camera, t [..., 3] metres
    """
    eye = _as_tensor(eye, "eye")
    target = _as_tensor(target, "target", eye.dtype).to(eye.device)
    if up is None:
        up = torch.tensor([0.0, 1.0, 0.0], dtype=eye.dtype, device=eye.device)
    up = _as_tensor(up, "up", eye.dtype).to(eye.device)
    for name, value in (("eye", eye), ("target", target), ("up", up)):
        _check_last_dim(value, name, (3,), "[..., 3]")
    forward = target - eye
    forward_norm = forward.norm(dim=-1, keepdim=True)
    if bool((forward_norm <= 0).any()):
        raise ValueError("eye and target must differ (the view direction is undefined)")
    forward = forward / forward_norm
    right = torch.linalg.cross(forward, up.expand_as(forward))
    right_norm = right.norm(dim=-1, keepdim=True)
    if bool((right_norm < 1e-6 * up.norm(dim=-1, keepdim=True).clamp_min(1e-30)).any()):
        raise ValueError("up must not be parallel to the view direction (target - eye); "
                         f"up = {up.tolist()}")
    right = right / right_norm
    down = torch.linalg.cross(forward, right)
    R = torch.stack([right, down, forward], dim=-2)
    t = -(R @ eye[..., None])[..., 0]
    return R, t


def intrinsics_from_fov(fov_deg: float, width: int, height: int,
                        dtype: torch.dtype = torch.float32,
                        device: torch.device | str | None = None) -> torch.Tensor:
    """Intrinsics with square pixels from the HORIZONTAL field of view.

    ``fx = fy = (width / 2) / tan(fov / 2)``, principal point at the image centre
    ``(width / 2, height / 2)`` (continuous pixel coordinates).
    -> K [3, 3] pixels
    """
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"fov_deg must be in (0, 180) degrees, got {fov_deg}")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{name} must be a positive integer (pixels), got {value!r}")
    focal = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    return torch.tensor([[focal, 0.0, 0.5 * width], [0.0, focal, 0.5 * height], [0.0, 0.0, 1.0]],
                        dtype=dtype, device=device)


def make_rig(num_views: int, target: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0),
             radius: float = 0.6, width: int = 1024, height: int = 667, fov_deg: float = 40.0,
             seed: int = 0, jitter: float = 0.01, coverage: float = 1.0,
             up: Sequence[float] = (0.0, 1.0, 0.0),
             dtype: torch.dtype = torch.float32) -> list[Camera]:
    """An InterHand-like multi-view rig: ``num_views`` cameras around ``target``, all looking at it.

    Camera directions are a Fibonacci sphere (near-uniform for any count); ``coverage < 1`` keeps
    only that fraction of the sphere's area as a dome around ``up`` (0.8 leaves out the cap
    below the hand). Each camera sits ``radius`` from ``target`` and aims at it; a deterministic
    jitter (seeded) moves each camera and its aim point by Gaussian offsets of std ``jitter``
    metres, as in a real rig that is not perfectly built.

    Defaults: 1024x667 images (InterHand2.6M), 40 degree horizontal field of view
    (``fx = fy ~ 1407`` px) at 0.6 m: a 20 cm hand spans about 470 px, most of the 667 px height,
    with a margin for the perspective of its near parts and for the jitter.

    target: [3] metres; up: [3] world up (the dome's pole and the image "up").
    -> list of ``num_views`` cameras named ``cam000``, ``cam001``, ...
    """
    if isinstance(num_views, bool) or not isinstance(num_views, int) or num_views < 1:
        raise ValueError(f"num_views must be a positive integer, got {num_views!r}")
    if not radius > 0:
        raise ValueError(f"radius must be positive (metres), got {radius}")
    if not 0.0 < coverage <= 1.0:
        raise ValueError(f"coverage must be in (0, 1], got {coverage}")
    if not jitter >= 0:
        raise ValueError(f"jitter must be >= 0 (metres), got {jitter}")
    target64 = _as_tensor(target, "target", torch.float64).cpu()
    up64 = _as_tensor(up, "up", torch.float64).cpu()
    _check_last_dim(target64, "target", (3,), "[3]")
    _check_last_dim(up64, "up", (3,), "[3]")
    if float(up64.norm()) == 0.0:
        raise ValueError("up must be a non-zero vector")
    up64 = up64 / up64.norm()
    K = intrinsics_from_fov(fov_deg, width, height, dtype=torch.float64)

    # Fibonacci sphere in a frame whose pole is `up`: heights evenly spaced in [1 - 2c, 1]
    # (equal areas), azimuths stepping by the golden angle.
    index = torch.arange(num_views, dtype=torch.float64)
    height_on_axis = 1.0 - 2.0 * coverage * (index + 0.5) / num_views
    ring = (1.0 - height_on_axis**2).clamp_min(0.0).sqrt()
    azimuth = index * math.pi * (3.0 - math.sqrt(5.0))
    helper = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    if abs(float(helper @ up64)) > 0.9:
        helper = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    axis_a = torch.linalg.cross(up64, helper)
    axis_a = axis_a / axis_a.norm()
    axis_b = torch.linalg.cross(up64, axis_a)
    directions = (height_on_axis[:, None] * up64 + (ring * torch.cos(azimuth))[:, None] * axis_a
                  + (ring * torch.sin(azimuth))[:, None] * axis_b)

    generator = torch.Generator().manual_seed(seed)
    eye_offsets = jitter * torch.randn(num_views, 3, generator=generator, dtype=torch.float64)
    aim_offsets = jitter * torch.randn(num_views, 3, generator=generator, dtype=torch.float64)
    eyes = target64 + radius * directions + eye_offsets
    aims = target64 + aim_offsets

    cameras = []
    for i in range(num_views):  # a few dozen cameras at most; each needs its own up fallback
        view = aims[i] - eyes[i]
        camera_up = up64
        if float(torch.linalg.cross(view / view.norm(), up64).norm()) < 1e-3:
            camera_up = axis_a  # looking straight along `up`: any perpendicular roll will do
        R, t = look_at(eyes[i], aims[i], camera_up)
        cameras.append(Camera(K=K.to(dtype), R=R.to(dtype), t=t.to(dtype), width=width,
                              height=height, name=f"cam{i:03d}"))
    return cameras
