"""Depth images, a depth camera's frames, as point clouds (``lisa fit-points depth.png --camera
cam.json``).

A depth camera (RealSense, Kinect, Azure Kinect, a phone's depth map) writes each frame as a
one-channel image of integers, the depth of each pixel along the camera's axis in a fixed unit
(millimetres for most: ``scale_m`` 0.001), 0 where it measured nothing. With the camera's
intrinsics (the ``cameras.json`` convention of :mod:`lisa_hand.geometry.cameras`: ``K``, the
image's ``width`` and ``height``, optional ``R``, ``t``) each pixel with a depth is a point: pixel
``(u, v)`` (column, row; its centre at ``u + 0.5, v + 0.5``) at depth ``z`` is
``z K^-1 [u + 0.5, v + 0.5, 1]`` in the camera's frame, ``R^T (x - t)`` in the world's. The
camera's centre is the scan's sensor position, known exactly (``fit_points(viewpoint=)``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.cameras import Camera
from ..utils.io import require_file

__all__ = ["DEPTH_SUFFIXES", "DepthFrame", "read_depth_image", "read_mask_image", "depth_points",
           "read_depth_cloud"]

DEPTH_SUFFIXES = (".png", ".tif", ".tiff")
"""Image files :func:`read_depth_image` reads."""


def _read_image(path: Path, what: str) -> np.ndarray:
    import imageio.v3 as iio

    require_file(path)
    try:
        return np.asarray(iio.imread(path))
    except Exception:  # imageio raises many types for a bad file (and suggests plugins)
        state = ("the file is empty" if path.stat().st_size == 0 else
                 "unreadable (not a PNG or TIFF file, or a truncated or corrupted one)")
        raise ValueError(f"{path}: cannot read this {what}: {state}") from None


def read_depth_image(path: str | os.PathLike, scale_m: float = 0.001) -> np.ndarray:
    """A depth image in metres: [H, W] float64, 0 where the camera measured nothing.

    path: a one-channel PNG or TIFF of 16- or 32-bit integers (the depth in units of
    ``scale_m`` metres) or of floats (the depth times ``scale_m``). Errors name the file: a
    colour image, an 8-bit one (no depth camera writes depth in 256 steps), no depth at all.
    """
    path = Path(path)
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"the depth scale must be > 0 (metres per unit), got {scale_m!r}")
    image = _read_image(path, "depth image")
    if image.ndim == 3 and image.shape[-1] == 1:
        image = image[..., 0]
    if image.ndim != 2:
        raise ValueError(f"{path}: a depth image has one channel; this one has shape "
                         f"{list(image.shape)} (a colour image?)")
    if image.dtype in (np.uint8, np.int8, bool):
        raise ValueError(f"{path}: an 8-bit image is not a depth image (a depth camera writes "
                         "16-bit PNGs, the depth in millimetres)")
    if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
        raise ValueError(f"{path}: depth values must be numbers, got dtype {image.dtype}")
    depth = image.astype(np.float64) * scale_m
    depth[~np.isfinite(depth) | (depth <= 0)] = 0.0
    if not (depth > 0).any():
        raise ValueError(f"{path}: no pixel has a depth (every value is 0)")
    return depth


def read_mask_image(path: str | os.PathLike, size: tuple[int, int]) -> np.ndarray:
    """[H, W] bool, True where the mask image is white (over half its range; the first channel
    of a colour image); size: (width, height) it must have."""
    path = Path(path)
    image = _read_image(path, "mask")
    if image.ndim == 3:
        image = image[..., 0]
    if image.ndim != 2 or (image.shape[1], image.shape[0]) != tuple(size):
        raise ValueError(f"{path}: the mask is {image.shape[1] if image.ndim == 2 else '?'}x"
                         f"{image.shape[0]} pixels, the depth image {size[0]}x{size[1]}")
    top = 1.0 if np.issubdtype(image.dtype, np.floating) else float(np.iinfo(image.dtype).max)
    return image.astype(np.float64) > 0.5 * top


def depth_points(depth: np.ndarray, camera: Camera, mask: np.ndarray | None = None,
                 name: str = "the depth image") -> tuple[np.ndarray, np.ndarray]:
    """The points of a depth image (see the module docstring).

    depth: [H, W] metres, 0 where none (:func:`read_depth_image`). camera: its camera, at the
    image's size. mask: [H, W] bool, the pixels to keep (the hand's), or None: all. name: how
    errors call the image.
    -> (points [N, 3] float64 world metres, row by row; the camera's centre [3] world metres).
    """
    height, width = depth.shape
    if (camera.width, camera.height) != (width, height):
        raise ValueError(f"{name} is {width}x{height} pixels, its camera "
                         f"{camera.width}x{camera.height}: give the camera of this image")
    keep = depth > 0 if mask is None else (depth > 0) & mask
    if not keep.any():
        raise ValueError(f"{name}: no pixel with a depth is inside the mask")
    rows, columns = np.nonzero(keep)
    z = depth[rows, columns]
    pixels = np.stack([columns + 0.5, rows + 0.5, np.ones_like(z)], 1)
    K = camera.K.double().cpu().numpy()
    R = camera.R.double().cpu().numpy()
    t = camera.t.double().cpu().numpy()
    in_camera = (pixels @ np.linalg.inv(K).T) * z[:, None]
    return (in_camera - t) @ R, -R.T @ t


@dataclass(frozen=True)
class DepthFrame:
    """What a depth image needs to be a cloud (:func:`read_depth_cloud`)."""

    camera: Camera
    """The camera that took it, at the image's size."""
    scale_m: float = 0.001
    """Metres per unit of the image's values (0.001: millimetres)."""
    mask: Path | np.ndarray | None = None
    """A mask image of the hand's pixels (white), or those pixels as an [H, W] bool array (the
    image's size), or None: every pixel with a depth."""
    colour: Path | None = None
    """The colour image registered to the depth camera (RGB-D), whose pixels colour the points,
    or None."""


def read_depth_cloud(path: str | os.PathLike, frame: DepthFrame
                     ) -> tuple[np.ndarray, np.ndarray, str]:
    """A depth image file as a cloud -> (points [N, 3] world metres, the camera's centre [3]
    world metres, a sentence saying what was read)."""
    depth = read_depth_image(path, frame.scale_m)
    size = (depth.shape[1], depth.shape[0])
    mask = frame.mask
    if isinstance(mask, np.ndarray):
        if mask.shape != depth.shape:
            raise ValueError(f"{path}: the mask is {mask.shape[1]}x{mask.shape[0]} pixels, the "
                             f"depth image {size[0]}x{size[1]}")
        mask = mask.astype(bool)
    elif mask is not None:
        mask = read_mask_image(mask, size)
    points, centre = depth_points(depth, frame.camera, mask, name=str(path))
    within = ("" if frame.mask is None else " inside the hand's mask"
              if isinstance(frame.mask, np.ndarray) else f" inside the mask {frame.mask}")
    note = (f"read {len(points)} pixels with a depth{within} from a {size[0]}x{size[1]} depth "
            f"image ({frame.scale_m:g} m a unit), the sensor at its camera's centre")
    return points, centre, note
