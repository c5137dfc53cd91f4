"""Many views of one field: orbit cameras, turntable frames, GIF files, saved novel views.

All views share one occupancy grid (built once by :func:`shared_grid`), so a turntable costs
the grid plus its frames. GIFs are written with Pillow through imageio.
MP4 needs an FFmpeg or PyAV backend for imageio (``imageio-ffmpeg`` or ``av``), which this
package does not install and never downloads: :func:`save_video` raises a clear error without it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from ..geometry.cameras import Camera, intrinsics_from_fov, look_at
from ..geometry.fields import FieldFn, NormalFn, SdfFn
from ..utils.io import atomic_path
from .density import LaplaceDensity
from .image import ImageOutput, ImageRenderConfig, grid_threshold, render_image
from .occupancy import OccupancyGrid, build_occupancy_grid
from .saving import image_to_uint8, normals_to_rgb, save_image_outputs

__all__ = [
    "FRAME_KINDS",
    "orbit_cameras",
    "shared_grid",
    "render_turntable",
    "render_views",
    "save_gif",
    "save_video",
    "mp4_backend",
]

FRAME_KINDS = ("rgb", "normals", "rgb+normals")


def orbit_cameras(
    num_views: int,
    center: Sequence[float] | torch.Tensor,
    radius: float,
    elevation_deg: float = 15.0,
    width: int = 512,
    height: int = 512,
    fov_deg: float = 40.0,
    up: Sequence[float] | torch.Tensor = (0.0, 1.0, 0.0),
    *,
    start_azimuth_deg: float = 0.0,
    front: Sequence[float] | torch.Tensor | None = None,
    dtype: torch.dtype = torch.float32,
) -> list[Camera]:
    """``num_views`` cameras on a horizontal circle around ``up`` through ``center``, all looking
    at ``center`` (which projects to the image centre), image "up" towards ``up``.

    View ``k`` sits at azimuth ``start_azimuth_deg + 360 k / num_views`` degrees (measured from
    ``front`` towards ``up x front``, right-handed about ``up``) and ``elevation_deg`` above
    the circle's plane, ``radius`` metres from ``center``.

    center: [3] metres. up: [3] the orbit axis (any length). front: [3] direction of azimuth 0
    (made perpendicular to ``up``); default: the world axis least aligned with ``up``.
    Horizontal field of view ``fov_deg`` (:func:`~lisa_hand.geometry.cameras.intrinsics_from_fov`).
    -> list of cameras named ``orbit000``, ``orbit001``, ...
    """
    if isinstance(num_views, bool) or not isinstance(num_views, int) or num_views < 1:
        raise ValueError(f"num_views must be a positive integer, got {num_views!r}")
    if not radius > 0:
        raise ValueError(f"radius must be > 0 (metres), got {radius!r}")
    if not -90.0 < elevation_deg < 90.0:
        raise ValueError(f"elevation_deg must be in (-90, 90) degrees, got {elevation_deg!r}")
    center64 = torch.as_tensor(center, dtype=torch.float64).cpu()
    up64 = torch.as_tensor(up, dtype=torch.float64).cpu()
    if center64.shape != (3,):
        raise ValueError(f"center must have shape [3] (metres), got {tuple(center64.shape)}")
    if up64.shape != (3,) or float(up64.norm()) == 0.0:
        raise ValueError(f"up must be a non-zero vector of shape [3], got {up64.tolist()}")
    up64 = up64 / up64.norm()
    if front is None:
        front64 = torch.zeros(3, dtype=torch.float64)
        front64[int(up64.abs().argmin())] = 1.0
    else:
        front64 = torch.as_tensor(front, dtype=torch.float64).cpu()
        if front64.shape != (3,):
            raise ValueError(f"front must have shape [3], got {tuple(front64.shape)}")
    front64 = front64 - (front64 @ up64) * up64
    if float(front64.norm()) < 1e-9:
        raise ValueError(f"front must not be parallel to up, got front={front!r}, up={up!r}")
    axis_a = front64 / front64.norm()
    axis_b = torch.linalg.cross(up64, axis_a)
    K = intrinsics_from_fov(fov_deg, width, height, dtype=torch.float64)
    elevation = math.radians(elevation_deg)
    cameras = []
    for index in range(num_views):  # a few dozen views; one look_at each
        azimuth = math.radians(start_azimuth_deg + 360.0 * index / num_views)
        direction = (
            math.cos(elevation) * (math.cos(azimuth) * axis_a + math.sin(azimuth) * axis_b)
            + math.sin(elevation) * up64
        )
        rotation, translation = look_at(center64 + radius * direction, center64, up64)
        cameras.append(
            Camera(
                K=K.to(dtype),
                R=rotation.to(dtype),
                t=translation.to(dtype),
                width=width,
                height=height,
                name=f"orbit{index:03d}",
            )
        )
    return cameras


def shared_grid(
    sdf_fn: SdfFn,
    bound_center: torch.Tensor,
    bound_radius: float,
    config: ImageRenderConfig,
    density: LaplaceDensity | None = None,
) -> OccupancyGrid | None:
    """The occupancy grid :func:`render_image` would build for ``config``, to share across views
    (None when ``config.culling`` is 'sphere'). bound_center: [3] metres (tensor)."""
    if config.culling == "sphere":
        return None
    beta = config.beta if density is None else float(density.beta.detach())
    return build_occupancy_grid(
        sdf_fn,
        bound_center,
        float(bound_radius),
        resolution=config.grid_resolution,
        coarse_resolution=config.grid_coarse_resolution,
        threshold=grid_threshold(config, beta),
        lipschitz=config.lipschitz,
        chunk_size=config.points_per_call,
    )


def _center_tensor(bound_center, camera: Camera) -> torch.Tensor:
    if isinstance(bound_center, torch.Tensor):
        return bound_center
    return torch.as_tensor(bound_center, dtype=camera.dtype, device=camera.device)


def _frame(output: ImageOutput, kind: str):
    rgb = image_to_uint8(output.rgb[..., :3])
    if kind == "rgb":
        return rgb
    normals = image_to_uint8(normals_to_rgb(output.normals, output.mask))
    if kind == "normals":
        return normals
    import numpy as np

    return np.concatenate([rgb, normals], axis=1)


def render_turntable(
    field_fn: FieldFn,
    sdf_fn: SdfFn,
    cameras: Sequence[Camera],
    bound_center: torch.Tensor,
    bound_radius: float,
    config: ImageRenderConfig | None = None,
    density: LaplaceDensity | None = None,
    normal_fn: NormalFn | None = None,
    kind: str = "rgb",
    progress: bool = False,
) -> list:
    """Render every camera (e.g. :func:`orbit_cameras`) with one shared occupancy grid.

    kind: 'rgb', 'normals' (``(n + 1) / 2`` of the world-frame normals, black outside the mask)
    or 'rgb+normals' (side by side). Normals are only computed when the kind needs them (with
    ``config.normals``, 'autograd' when that is 'none', or ``normal_fn``).
    Other arguments as for :func:`~lisa_hand.render.image.render_image`.
    -> list of numpy uint8 frames [H, W, 3] (``[H, 2 W, 3]`` for 'rgb+normals').
    """
    if kind not in FRAME_KINDS:
        raise ValueError(f"kind must be one of {FRAME_KINDS}, got {kind!r}")
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    config = ImageRenderConfig() if config is None else config
    if kind == "rgb":
        config, normal_fn = replace(config, normals="none"), None
    elif config.normals == "none" and normal_fn is None:
        config = replace(config, normals="autograd")
    center = _center_tensor(bound_center, cameras[0])
    grid = shared_grid(sdf_fn, center, bound_radius, config, density)
    views = cameras
    if progress:
        from tqdm.auto import tqdm

        views = tqdm(cameras, unit="view", desc="turntable")
    return [
        _frame(
            render_image(
                field_fn,
                sdf_fn,
                camera,
                center,
                bound_radius,
                config,
                density,
                normal_fn,
                grid=grid,
            ),
            kind,
        )
        for camera in views
    ]


def render_views(
    field_fn: FieldFn,
    sdf_fn: SdfFn,
    cameras: Sequence[Camera],
    bound_center: torch.Tensor,
    bound_radius: float,
    out_dir: str | os.PathLike,
    config: ImageRenderConfig | None = None,
    density: LaplaceDensity | None = None,
    normal_fn: NormalFn | None = None,
    progress: bool = False,
) -> list[dict[str, Path]]:
    """Render novel views and write each one's files
    (:func:`~lisa_hand.render.saving.save_image_outputs`: RGB, normal
    map, mask PNGs and depth .npy) into ``out_dir``, named after the camera (``view000`` when it
    has no name). Returns the written paths, one dict per camera."""
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    config = ImageRenderConfig() if config is None else config
    center = _center_tensor(bound_center, cameras[0])
    grid = shared_grid(sdf_fn, center, bound_radius, config, density)
    written = []
    for index, camera in enumerate(cameras):
        output = render_image(
            field_fn,
            sdf_fn,
            camera,
            center,
            bound_radius,
            config,
            density,
            normal_fn,
            progress=progress,
            grid=grid,
        )
        written.append(save_image_outputs(out_dir, output, camera.name or f"view{index:03d}"))
    return written


def _check_frames(frames) -> list:
    import numpy as np

    frames = [np.asarray(frame) for frame in frames]
    if not frames:
        raise ValueError("frames must not be empty")
    shape = frames[0].shape
    for index, frame in enumerate(frames):
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[-1] not in (3, 4):
            raise ValueError(
                f"frames[{index}] must be uint8 [H, W, 3], got {frame.dtype} {frame.shape}"
            )
        if frame.shape != shape:
            raise ValueError(f"frames[{index}] has shape {frame.shape}, frames[0] {shape}")
    return frames


def save_gif(path: str | os.PathLike, frames: Sequence, fps: float = 24.0) -> Path:
    """Write frames (uint8 [H, W, 3] arrays) as a looping GIF, atomically; return the path.

    GIF stores durations in hundredths of a second, so the rate is rounded to that; Pillow
    merges identical consecutive frames into one longer frame.
    """
    import imageio.v3 as iio

    frames = _check_frames(frames)
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"{path}: a GIF path must end in .gif")
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    return path


def mp4_backend() -> str | None:
    """'pyav' or 'FFMPEG' when imageio can write MP4 here, else None (nothing is downloaded)."""
    import importlib.util

    if importlib.util.find_spec("av") is not None:
        return "pyav"
    if importlib.util.find_spec("imageio_ffmpeg") is not None:
        return "FFMPEG"
    return None


def save_video(path: str | os.PathLike, frames: Sequence, fps: float = 24.0) -> Path:
    """Write frames as ``.gif`` (:func:`save_gif`) or ``.mp4`` (H.264 through imageio's PyAV or
    FFmpeg plugin, whichever is installed), atomically; return the path.

    Raises OSError for ``.mp4`` when neither ``av`` nor ``imageio-ffmpeg`` is installed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".gif":
        return save_gif(path, frames, fps)
    if suffix != ".mp4":
        raise ValueError(f"{path}: video path must end in .gif or .mp4")
    frames = _check_frames(frames)
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    backend = mp4_backend()
    if backend is None:
        raise OSError(
            f"{path}: writing MP4 needs the 'av' or 'imageio-ffmpeg' package, neither is "
            "installed; write a .gif instead"
        )
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        if backend == "pyav":
            iio.imwrite(tmp, frames, plugin="pyav", codec="libx264", fps=fps)
        else:
            iio.imwrite(tmp, frames, plugin="FFMPEG", fps=fps)
    return path
