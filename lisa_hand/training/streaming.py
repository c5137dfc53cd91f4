"""Streaming readers of a dataset split for training at dataset scale: drop-ins for
:class:`lisa_hand.data.datasets.RayFrames` and :class:`~lisa_hand.data.datasets.ScanFrames` that
keep only the frame table and the cameras in memory and read the frames a batch draws, when it
draws them.

* :class:`StreamingRayFrames`: per drawn frame and view, the image and mask are decoded, cropped
  to the hand (the mask's bounding box grown by ``max_band_px``; outside it every pixel is
  background) and turned into the same two pools as ``RayFrames`` (pixels within the band, by
  distance to the mask, and background pixels: ``background_per_view`` of them, chosen by a
  generator seeded with ``(seed, frame, view)``, so a frame's pools never depend on when it is
  read). A small cache keeps the last frames' pools; a thread pool decodes a batch's frames in
  parallel (image decoding releases the GIL).
* :class:`StreamingScanFrames`: the drawn frames' ``scan.npz`` read on demand (same cache).

Both draw everything random from the ``torch.Generator`` they are given, in a fixed order, so
a resumed run draws the batches the uninterrupted one would have drawn; the rays are not the
ones ``RayFrames`` draws for the same generator (its background pixels are chosen at load).
Memory: the frame table, about 60 bytes per view for the cameras, and the cache.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..data.datasets import RayBatch, ScanBatch
from ..data.frame_table import read_frame_table
from ..data.layout import FramePaths, read_image, read_mask, read_npz
from ..geometry.cameras import load_cameras

__all__ = ["StreamingRayFrames", "StreamingScanFrames"]


def _choose(num_frames: int, count: int, generator: torch.Generator,
            frames: torch.Tensor | None) -> torch.Tensor:
    """Frame indices [B]: given, or distinct random frames (with replacement if B > F)."""
    if frames is not None:
        frames = torch.as_tensor(frames, dtype=torch.long).reshape(-1)
        if frames.numel() == 0 or frames.min() < 0 or frames.max() >= num_frames:
            raise ValueError(f"frames must be indices in [0, {num_frames}), got "
                             f"{frames.tolist()}")
        return frames
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"the number of frames must be a positive int, got {count!r}")
    if count <= num_frames:
        return torch.randperm(num_frames, generator=generator)[:count]
    return torch.randint(num_frames, (count,), generator=generator)


class _Cache(OrderedDict):
    """A least-recently-used dict of at most ``size`` entries."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = max(1, int(size))

    def get_or(self, key, make):
        if key in self:
            self.move_to_end(key)
            return self[key]
        value = make()
        self[key] = value
        while len(self) > self.size:
            self.popitem(last=False)
        return value


@dataclass
class _FramePool:
    """One frame's drawable pixels over its views (local view index, pixel id, rgb, distance)."""

    near_view: np.ndarray
    near_pixel: np.ndarray
    near_rgb: np.ndarray
    near_distance: np.ndarray  # sorted ascending
    far_view: np.ndarray
    far_pixel: np.ndarray
    far_rgb: np.ndarray


class StreamingRayFrames:
    """Rays of one split, reading the drawn frames' views on demand (see the module docstring).

    root, split, max_band_px, background_per_view, seed: as :class:`RayFrames`.
    cache_frames: frames whose pools are kept. threads: decoding threads (1: none).
    """

    def __init__(self, root: str | os.PathLike, split: str = "train", *, max_band_px: int = 16,
                 background_per_view: int = 4096, seed: int = 0, cache_frames: int = 64,
                 threads: int = 4) -> None:
        if not 0 <= int(max_band_px) <= 254:
            raise ValueError(f"max_band_px must be in [0, 254], got {max_band_px!r}")
        self.max_band_px = int(max_band_px)
        self.background_per_view = int(background_per_view)
        self.seed = int(seed)
        self.table = read_frame_table(root, split)
        names, view_frame, world_from_pixel, centres, sizes, view_names = set(), [], [], [], [], []
        for frame, paths in enumerate(self.table.frames):
            cameras = load_cameras(paths.cameras)
            if not cameras:
                raise ValueError(f"{paths.cameras}: no cameras")
            for camera in cameras:
                if not camera.name:
                    raise ValueError(f"{paths.cameras}: a camera has no name")
                names.add(camera.name)
                view_frame.append(frame)
                world_from_pixel.append((camera.R.double().T @ torch.linalg.inv(
                    camera.K.double())).float())
                centres.append(camera.center.float())
                sizes.append((camera.width, camera.height))
                view_names.append(camera.name)
        self.camera_names = sorted(names)
        lookup = {name: i for i, name in enumerate(self.camera_names)}
        self.view_frame = torch.tensor(view_frame, dtype=torch.long)
        self.view_world_from_pixel = torch.stack(world_from_pixel)
        self.view_centre = torch.stack(centres)
        self.view_size = torch.tensor(sizes, dtype=torch.long)  # [V, 2] width, height
        self.view_camera = torch.tensor([lookup[n] for n in view_names], dtype=torch.long)
        self._view_names = view_names
        counts = torch.bincount(self.view_frame, minlength=self.table.num_frames)
        self.frame_view_start = torch.cumsum(counts, 0) - counts
        self.frame_view_count = counts
        self._cache = _Cache(cache_frames)
        self._threads = max(1, int(threads))

    num_frames = property(lambda self: self.table.num_frames)
    num_subjects = property(lambda self: self.table.num_subjects)
    num_cameras = property(lambda self: len(self.camera_names))
    subject_ids = property(lambda self: self.table.subject_ids)

    def _view_pixels(self, paths: FramePaths, view: int, local: int):
        """One view's near and far pixels (the hand's crop; background by a seeded draw)."""
        from scipy.ndimage import distance_transform_edt

        name = self._view_names[view]
        width, height = (int(v) for v in self.view_size[view])
        image, mask = read_image(paths.image(name)), read_mask(paths.mask(name))
        if image.shape[:2] != (height, width) or mask.shape != (height, width):
            raise ValueError(f"{paths.image(name)}: image or mask size differs from camera "
                             f"{name!r} ({width}x{height}) in {paths.cameras}")
        rng = np.random.default_rng([self.seed, int(self.view_frame[view]), local])
        near_ids = np.zeros(0, np.int64)
        distance = np.zeros(0)
        if mask.any():
            rows, cols = np.nonzero(mask)
            grow = self.max_band_px + 1
            r0, r1 = max(rows.min() - grow, 0), min(rows.max() + grow + 1, height)
            c0, c1 = max(cols.min() - grow, 0), min(cols.max() + grow + 1, width)
            crop = mask[r0:r1, c0:c1]
            crop_distance = np.ceil(distance_transform_edt(~crop))
            inside = crop_distance <= self.max_band_px
            rr, cc = np.nonzero(inside)
            near_ids = (rr + r0) * width + (cc + c0)
            distance = crop_distance[rr, cc]
        is_near = np.zeros(width * height, bool)
        is_near[near_ids] = True
        candidates = np.unique(rng.integers(0, width * height,
                                            size=2 * self.background_per_view + 8))
        far_ids = candidates[~is_near[candidates]]
        if far_ids.size > self.background_per_view:
            far_ids = np.sort(rng.choice(far_ids, self.background_per_view, replace=False))
        flat = image.reshape(-1, 3)

        def rgb(ids: np.ndarray) -> np.ndarray:
            return np.round(flat[ids] * 255.0).astype(np.uint8)

        return near_ids, distance, rgb(near_ids), far_ids, rgb(far_ids)

    def _load(self, frame: int) -> _FramePool:
        paths = self.table.frames[frame]
        start, count = int(self.frame_view_start[frame]), int(self.frame_view_count[frame])
        parts = [self._view_pixels(paths, start + k, k) for k in range(count)]
        near_view = np.concatenate([np.full(p[0].size, k) for k, p in enumerate(parts)])
        near_distance = np.concatenate([p[1] for p in parts])
        order = np.argsort(near_distance, kind="stable")
        pool = _FramePool(
            near_view=near_view[order], near_pixel=np.concatenate([p[0] for p in parts])[order],
            near_rgb=np.concatenate([p[2] for p in parts])[order],
            near_distance=near_distance[order],
            far_view=np.concatenate([np.full(p[3].size, k) for k, p in enumerate(parts)]),
            far_pixel=np.concatenate([p[3] for p in parts]),
            far_rgb=np.concatenate([p[4] for p in parts]))
        if pool.near_pixel.size + pool.far_pixel.size == 0:
            raise ValueError(f"{paths.root}: no pixel to draw rays from")
        return pool

    def _pools(self, frames: list[int]) -> list[_FramePool]:
        """The pools of ``frames``: cached ones, the others read (in parallel), then cached."""
        found = {f: self._cache.get_or(f, None) for f in dict.fromkeys(frames)
                 if f in self._cache}
        missing = [f for f in dict.fromkeys(frames) if f not in found]
        if len(missing) > 1 and self._threads > 1:
            with ThreadPoolExecutor(min(self._threads, len(missing))) as executor:
                found.update(zip(missing, executor.map(self._load, missing), strict=True))
        else:
            found.update((f, self._load(f)) for f in missing)
        for f in missing:
            self._cache.get_or(f, lambda f=f: found[f])
        return [found[f] for f in frames]

    def sample_rays(self, num_rays: int, generator: torch.Generator, mask_fraction: float = 0.9,
                    band_px: int = 4, *, num_frames: int = 1,
                    frames: torch.Tensor | None = None) -> RayBatch:
        """As :meth:`RayFrames.sample_rays` (same arguments, same batch)."""
        if not 0.0 <= mask_fraction <= 1.0:
            raise ValueError(f"mask_fraction must be in [0, 1], got {mask_fraction!r}")
        if not 0 <= int(band_px) <= self.max_band_px:
            raise ValueError(f"band_px must be in [0, max_band_px={self.max_band_px}], got "
                             f"{band_px!r}")
        frame = _choose(self.num_frames, num_frames, generator, frames)
        if num_rays < 1 or num_rays % frame.shape[0]:
            raise ValueError(f"num_rays ({num_rays}) must be a positive multiple of the number "
                             f"of frames ({frame.shape[0]})")
        per_frame = num_rays // frame.shape[0]
        num_near = int(round(mask_fraction * per_frame))
        unit = torch.rand(frame.shape[0], per_frame, generator=generator, dtype=torch.float64)
        views, pixels, colours, in_mask = [], [], [], []
        for row, pool in enumerate(self._pools(frame.tolist())):
            inner = int(np.searchsorted(pool.near_distance, band_px, side="right"))
            outer = pool.near_pixel.size - inner + pool.far_pixel.size
            use_near = ((np.arange(per_frame) < num_near) & (inner > 0)) | (outer == 0)
            count = np.where(use_near, inner, outer)
            offset = np.minimum((unit[row].numpy() * count).astype(np.int64), count - 1)
            index = np.where(use_near, offset, inner + offset)  # into near, then far
            from_near = index < pool.near_pixel.size
            far_index = np.clip(index - pool.near_pixel.size, 0, max(pool.far_pixel.size - 1, 0))
            near_index = np.clip(index, 0, max(pool.near_pixel.size - 1, 0))

            def pick(near, far, near_index=near_index, far_index=far_index,
                     from_near=from_near):
                chosen_near = near[near_index] if near.size else np.zeros_like(far[far_index])
                chosen_far = far[far_index] if far.size else np.zeros_like(chosen_near)
                shape = (-1,) + (1,) * (chosen_near.ndim - 1)
                return np.where(from_near.reshape(shape), chosen_near, chosen_far)

            views.append(pick(pool.near_view, pool.far_view)
                         + int(self.frame_view_start[frame[row]]))
            pixels.append(pick(pool.near_pixel, pool.far_pixel))
            colours.append(pick(pool.near_rgb, pool.far_rgb))
            distance = pool.near_distance[near_index] if pool.near_distance.size else np.ones(
                per_frame)
            in_mask.append(from_near & (distance == 0))
        return self._batch(frame, views, pixels, colours, in_mask)

    def _batch(self, frame, views, pixels, colours, in_mask) -> RayBatch:
        view = torch.from_numpy(np.stack(views)).long()
        pixel = torch.from_numpy(np.stack(pixels)).long()
        width = self.view_size[view, 0]
        coords = torch.stack([(pixel % width).float() + 0.5,
                              torch.div(pixel, width, rounding_mode="floor").float() + 0.5], -1)
        homogeneous = torch.cat([coords, torch.ones_like(coords[..., :1])], dim=-1)
        directions = (self.view_world_from_pixel[view] @ homogeneous[..., None])[..., 0]
        subject = self.table.frame_subject[frame]
        return RayBatch(
            frame_index=frame, subject_index=subject, pose=self.table.pose[frame],
            translation=self.table.translation[frame],
            rest_joints=self.table.rest_joints[subject], origins=self.view_centre[view],
            directions=directions / directions.norm(dim=-1, keepdim=True),
            rgb=torch.from_numpy(np.stack(colours)).float() / 255.0,
            in_mask=torch.from_numpy(np.stack(in_mask)), camera_index=self.view_camera[view],
            pixels=coords)


class StreamingScanFrames:
    """:class:`ScanFrames` reading the drawn frames' ``scan.npz`` on demand (skinning points
    and weights, surface and near-surface samples), with an LRU cache of ``cache_frames``."""

    def __init__(self, root: str | os.PathLike, split: str = "train", *,
                 cache_frames: int = 256) -> None:
        self.table = read_frame_table(root, split)
        self._cache = _Cache(cache_frames)

    num_frames = property(lambda self: self.table.num_frames)
    num_subjects = property(lambda self: self.table.num_subjects)
    subject_ids = property(lambda self: self.table.subject_ids)

    def _scan(self, frame: int) -> dict[str, np.ndarray]:
        path = Path(self.table.frames[frame].scan)
        return self._cache.get_or(frame, lambda: read_npz(
            path, required=("points", "normals", "template_weights", "sdf_points", "sdf")))

    def sample(self, batch_frames: int, num_surface: int, num_space: int,
               generator: torch.Generator, *, near_fraction: float = 0.5, margin: float = 0.02,
               frames: torch.Tensor | None = None) -> ScanBatch:
        """As :meth:`ScanFrames.sample` (same arguments, same batch)."""
        frame = _choose(self.num_frames, batch_frames, generator, frames)
        num_near = int(round(near_fraction * num_space))
        num_uniform = num_space - num_near
        rows = {key: [] for key in ("points", "normals", "weights", "near", "sdf", "uniform")}
        for index in frame.tolist():
            scan = self._scan(index)
            count, sdf_count = len(scan["points"]), len(scan["sdf"])
            if num_near and sdf_count == 0:
                raise ValueError(f"{self.table.frames[index].scan}: no sdf_points for the "
                                 "near-surface samples (set near_fraction=0)")
            pick = (torch.rand(num_surface, generator=generator, dtype=torch.float64)
                    * count).long().clamp_max(count - 1).numpy()
            near = (torch.rand(num_near, generator=generator, dtype=torch.float64)
                    * max(sdf_count, 1)).long().clamp_max(max(sdf_count - 1, 0)).numpy()
            low = scan["points"].min(0) - margin
            high = scan["points"].max(0) + margin
            unit = torch.rand(num_uniform, 3, generator=generator).numpy()
            rows["points"].append(scan["points"][pick])
            rows["normals"].append(scan["normals"][pick])
            rows["weights"].append(scan["template_weights"][pick])
            rows["near"].append(scan["sdf_points"][near] if num_near else np.zeros((0, 3)))
            rows["sdf"].append(scan["sdf"][near] if num_near else np.zeros(0))
            rows["uniform"].append(low + unit * (high - low))

        def stacked(key: str) -> torch.Tensor:
            return torch.from_numpy(np.stack(rows[key]).astype(np.float32))

        subject = self.table.frame_subject[frame]
        return ScanBatch(
            frame_index=frame, subject_index=subject, pose=self.table.pose[frame],
            translation=self.table.translation[frame],
            rest_joints=self.table.rest_joints[subject], surface_points=stacked("points"),
            surface_normals=stacked("normals"), surface_weights=stacked("weights"),
            near_points=stacked("near"), near_sdf=stacked("sdf"),
            uniform_points=stacked("uniform"))
