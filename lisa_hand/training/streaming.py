"""Streaming readers of a dataset split for training at dataset scale: drop-ins for
:class:`lisa_hand.data.datasets.RayFrames` and :class:`~lisa_hand.data.datasets.ScanFrames` that
keep only the frame table and the cameras in memory and read frames while training runs.

* :class:`RayFrameDataset` (a map-style ``torch.utils.data.Dataset``): item ``i`` is frame
  ``i``'s pools: per view the image and mask are decoded and cropped to the hand (the mask's
  bounding box grown by ``max_band_px + 1``; only the pixels within ``max_band_px`` of the mask
  are kept, by distance to it) plus ``background_per_view`` background pixels chosen by a
  generator seeded with ``(seed, frame, view)``, so a frame's pools never depend on when, or in
  which process, it is read. :class:`ScanFrameDataset`: item ``i`` is frame ``i``'s ``scan.npz``.
* :func:`frame_loader`: a ``DataLoader`` over such a dataset with ``workers`` worker processes
  (0: in this process) and a ``DistributedSampler`` (shuffled per epoch from ``seed``): under
  ``torchrun`` (``torch.distributed`` initialised) each rank reads only its share of the frames
  each epoch; alone, the whole split.
* :class:`FrameBuffer`: at most ``size`` loaded frames, filled from the loader's iterator (epoch
  after epoch). A step draws its frames as distinct random slots of the buffer (from the
  trainer's generator); the slots this rank trains on are then refilled with the next frames
  of the loader, so every loaded frame is trained on once and each frame of the split once per
  epoch. Each row of a step is a uniform draw over the split, as with the in-memory readers;
  within an epoch no frame comes back.

:class:`StreamingRayFrames` and :class:`StreamingScanFrames` keep the in-memory readers' API
(``sample_rays`` / ``sample``, the same batches' layout). Under torchrun every rank still returns
a whole global batch (the trainers keep their rank's slice, ``shard_slice``): the rows of its
slice come from its own share and are consumed; the other rows are frames of its share too,
drawn but not consumed (and never trained on by this rank). Explicit ``frames=`` are read on
demand through a small LRU cache. Results are deterministic for a fixed seed whatever the number
of workers (the loader keeps the sampler's order); a resumed run starts a fresh buffer (the same
statistics, not the same batches as the uninterrupted run). Memory: the frame table, about 60
bytes per view for the cameras, the buffer (``cache_frames`` frames) and the loader's prefetch
(2 frames per worker).
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler

from ..data.datasets import RayBatch, ScanBatch
from ..data.frame_table import read_frame_table
from ..data.layout import read_image, read_mask, read_npz
from ..geometry.cameras import load_cameras
from .distributed import DistContext, shard_slice

__all__ = ["RayFrameDataset", "ScanFrameDataset", "frame_loader", "FrameBuffer",
           "StreamingRayFrames", "StreamingScanFrames"]

_SCAN_KEYS = ("points", "normals", "template_weights", "sdf_points", "sdf")


def _check_frames(frames: torch.Tensor, num_frames: int) -> torch.Tensor:
    """Given frame indices [B], checked to lie in [0, num_frames)."""
    frames = torch.as_tensor(frames, dtype=torch.long).reshape(-1)
    if frames.numel() == 0 or frames.min() < 0 or frames.max() >= num_frames:
        raise ValueError(f"frames must be indices in [0, {num_frames}), got {frames.tolist()}")
    return frames


def _check_count(count: int) -> int:
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"the number of frames must be a positive int, got {count!r}")
    return count


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

    frame: int
    near_view: np.ndarray  # int16
    near_pixel: np.ndarray  # int32, row * width + column in the full image
    near_rgb: np.ndarray  # uint8
    near_distance: np.ndarray  # uint8, pixels to the mask (0 inside), sorted ascending
    far_view: np.ndarray  # int16
    far_pixel: np.ndarray  # int32
    far_rgb: np.ndarray  # uint8
    crop: np.ndarray  # [views, 4] row0, row1, col0, col1 of the hand's crop (empty mask: 0s)


def _identity(item):
    return item


class RayFrameDataset(Dataset):
    """Frames of a split as items: ``dataset[i]`` is frame ``i``'s pools (see the module
    docstring). frames: the frames' folders (FramePaths); views: per frame its
    ``(camera name, width, height)``; the other arguments as :class:`RayFrames`."""

    def __init__(self, frames, views, *, max_band_px: int, background_per_view: int,
                 seed: int) -> None:
        self.frames, self.views = list(frames), [list(v) for v in views]
        self.max_band_px = int(max_band_px)
        self.background_per_view = int(background_per_view)
        self.seed = int(seed)

    def __len__(self) -> int:
        return len(self.frames)

    def _view_pixels(self, frame: int, local: int):
        """One view's near pixels (in the hand's crop), their distances, rgb, the far pixels
        (a seeded draw), their rgb and the crop box."""
        from scipy.ndimage import distance_transform_edt

        paths = self.frames[frame]
        name, width, height = self.views[frame][local]
        image, mask = read_image(paths.image(name)), read_mask(paths.mask(name))
        if image.shape[:2] != (height, width) or mask.shape != (height, width):
            raise ValueError(f"{paths.image(name)}: image or mask size differs from camera "
                             f"{name!r} ({width}x{height}) in {paths.cameras}")
        if width * height >= 2**31:
            raise ValueError(f"{paths.image(name)}: {width}x{height} is too large to stream")
        rng = np.random.default_rng([self.seed, frame, local])
        near_ids, distance, box = np.zeros(0, np.int64), np.zeros(0), np.zeros(4, np.int64)
        if mask.any():
            rows, cols = np.nonzero(mask)
            grow = self.max_band_px + 1
            box = np.array([max(rows.min() - grow, 0), min(rows.max() + grow + 1, height),
                            max(cols.min() - grow, 0), min(cols.max() + grow + 1, width)])
            r0, r1, c0, c1 = (int(v) for v in box)
            crop_distance = np.ceil(distance_transform_edt(~mask[r0:r1, c0:c1]))
            rr, cc = np.nonzero(crop_distance <= self.max_band_px)
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

        return near_ids, distance, rgb(near_ids), far_ids, rgb(far_ids), box

    def __getitem__(self, frame: int) -> _FramePool:
        frame = int(frame)
        parts = [self._view_pixels(frame, k) for k in range(len(self.views[frame]))]
        # compact dtypes (9 bytes a pixel): views < 2**15, pixels < 2**31, distances <= 254
        near_view = np.concatenate([np.full(p[0].size, k, np.int16) for k, p in enumerate(parts)])
        near_distance = np.concatenate([p[1] for p in parts]).astype(np.uint8)
        order = np.argsort(near_distance, kind="stable")
        pool = _FramePool(
            frame=frame, near_view=near_view[order],
            near_pixel=np.concatenate([p[0] for p in parts])[order].astype(np.int32),
            near_rgb=np.concatenate([p[2] for p in parts])[order],
            near_distance=near_distance[order],
            far_view=np.concatenate([np.full(p[3].size, k, np.int16)
                                     for k, p in enumerate(parts)]),
            far_pixel=np.concatenate([p[3] for p in parts]).astype(np.int32),
            far_rgb=np.concatenate([p[4] for p in parts]), crop=np.stack([p[5] for p in parts]))
        if pool.near_pixel.size + pool.far_pixel.size == 0:
            raise ValueError(f"{self.frames[frame].root}: no pixel to draw rays from")
        return pool


class ScanFrameDataset(Dataset):
    """Frames of a split as items: ``dataset[i]`` is frame ``i``'s ``scan.npz`` (a dict of
    arrays: points, normals, template_weights, sdf_points, sdf) plus ``frame``."""

    def __init__(self, frames) -> None:
        self.frames = list(frames)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, frame: int) -> dict:
        scan = dict(read_npz(Path(self.frames[int(frame)].scan), required=_SCAN_KEYS))
        scan["frame"] = int(frame)
        return scan


def frame_loader(dataset: Dataset, *, workers: int = 0, seed: int = 0, epoch: int = 0,
                 num_replicas: int = 1, rank: int = 0) -> DataLoader:
    """A ``DataLoader`` yielding ``dataset``'s items one by one, in the order of a
    ``DistributedSampler(num_replicas, rank, shuffle=True, seed)`` at ``epoch``: this rank's
    share (``ceil(len / num_replicas)`` frames, padded by repeats; the shares of the ranks are
    disjoint otherwise and cover the split). workers: worker processes (0: this process);
    the order does not depend on it. Advance epochs with ``loader.sampler.set_epoch``."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be a non-negative int, got {workers!r}")
    sampler = DistributedSampler(dataset, num_replicas=num_replicas, rank=rank, shuffle=True,
                                 seed=seed)
    sampler.set_epoch(epoch)
    return DataLoader(dataset, batch_size=None, sampler=sampler, num_workers=workers,
                      collate_fn=_identity, persistent_workers=workers > 0,
                      prefetch_factor=2 if workers else None)


def _world(num_replicas: int | None, rank: int | None) -> tuple[int, int]:
    """(num_replicas, rank): given, else torch.distributed's when initialised, else (1, 0)."""
    if num_replicas is not None:
        rank = 0 if rank is None else int(rank)
        if not 0 <= rank < int(num_replicas):
            raise ValueError(f"rank must be in [0, {num_replicas}), got {rank}")
        return int(num_replicas), rank
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        return dist.get_world_size(), dist.get_rank()
    return 1, 0


class FrameBuffer:
    """At most ``size`` loaded frames, filled from :func:`frame_loader` (see the module
    docstring). num_replicas, rank: the loader's sampler; None: torch.distributed's (read at
    the first draw, after the trainer has joined the process group) or one process."""

    def __init__(self, dataset: Dataset, size: int, *, workers: int = 0, seed: int = 0,
                 num_replicas: int | None = None, rank: int | None = None) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"the buffer size must be a positive int, got {size!r}")
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
            raise ValueError(f"workers must be a non-negative int, got {workers!r}")
        self.dataset, self.size, self.workers, self.seed = dataset, size, workers, seed
        self._replicas, self._rank = num_replicas, rank
        self.slots: list = []
        self.epoch, self.loaded, self.capacity = 0, 0, size
        self._loader = self._iterator = None

    def _start(self) -> None:
        """Learn this rank's share and start the loader (at the current epoch)."""
        self._replicas, self._rank = _world(self._replicas, self._rank)
        self._loader = frame_loader(self.dataset, workers=self.workers, seed=self.seed,
                                    epoch=self.epoch, num_replicas=self._replicas,
                                    rank=self._rank)
        self._iterator = iter(self._loader)
        # no more slots than the share has frames (a tiny split is not loaded many times over)
        self.capacity = min(self.size, len(self._loader.sampler))

    def _next(self):
        """The loader's next item, starting the next epoch when one ends."""
        if self._loader is None:
            self._start()
        try:
            item = next(self._iterator)
        except StopIteration:
            self.epoch += 1
            self._loader.sampler.set_epoch(self.epoch)
            self._iterator = iter(self._loader)
            item = next(self._iterator)
        self.loaded += 1
        return item

    def draw(self, count: int, generator: torch.Generator) -> list:
        """``count`` items of distinct random slots (with repeats only if ``count`` exceeds the
        capacity: ``size``, or this rank's share of the split if smaller),
        from ``generator``; the rows of this rank's ``shard_slice`` (padded to
        ``ceil(count / num_replicas)`` rows, so that ranks move through epochs together) are
        replaced by the loader's next items."""
        _check_count(count)
        if self._loader is None:
            self._start()
        while len(self.slots) < self.capacity:
            self.slots.append(self._next())
        if count <= self.capacity:
            slots = torch.randperm(self.capacity, generator=generator)[:count].tolist()
        else:
            slots = torch.randint(self.capacity, (count,), generator=generator).tolist()
        items = [self.slots[s] for s in slots]
        context = DistContext(rank=self._rank, world_size=self._replicas)
        local = shard_slice(count, context) if count >= self._replicas else slice(0, 0)
        rows = list(range(count))[local]
        need = math.ceil(count / self._replicas) - len(rows)
        rows += [r for r in range(count) if r not in rows][:need]
        for slot in dict.fromkeys(slots[r] for r in rows):
            self.slots[slot] = self._next()
        return items

    def close(self) -> None:
        """Stop the loader's worker processes (a later draw starts them again, at the start of
        the current epoch)."""
        self._iterator = self._loader = None


class StreamingRayFrames:
    """Rays of one split, reading frames through a :class:`FrameBuffer` (see the module
    docstring).

    root, split, max_band_px, background_per_view, seed: as :class:`RayFrames` (``seed`` also
    shuffles the loader's epochs). cache_frames: frames held by the buffer (and by the cache of
    explicitly requested ``frames=``). workers: the loader's worker processes (0: in this
    process). num_replicas, rank: the sampler's; None: from ``torch.distributed``.
    """

    def __init__(self, root: str | os.PathLike, split: str = "train", *, max_band_px: int = 16,
                 background_per_view: int = 4096, seed: int = 0, cache_frames: int = 64,
                 workers: int = 0, num_replicas: int | None = None,
                 rank: int | None = None) -> None:
        if not 0 <= int(max_band_px) <= 254:
            raise ValueError(f"max_band_px must be in [0, 254], got {max_band_px!r}")
        self.max_band_px = int(max_band_px)
        self.table = read_frame_table(root, split)
        names, view_frame, world_from_pixel, centres, sizes, frame_views = set(), [], [], [], [], []
        rotations = []
        for frame, paths in enumerate(self.table.frames):
            cameras = load_cameras(paths.cameras)
            if not cameras:
                raise ValueError(f"{paths.cameras}: no cameras")
            frame_views.append([])
            for camera in cameras:
                if not camera.name:
                    raise ValueError(f"{paths.cameras}: a camera has no name")
                names.add(camera.name)
                view_frame.append(frame)
                world_from_pixel.append((camera.R.double().T @ torch.linalg.inv(
                    camera.K.double())).float())
                centres.append(camera.center.float())
                rotations.append(camera.R.float())
                sizes.append((camera.width, camera.height))
                frame_views[-1].append((camera.name, int(camera.width), int(camera.height)))
        self.camera_names = sorted(names)
        lookup = {name: i for i, name in enumerate(self.camera_names)}
        self.view_frame = torch.tensor(view_frame, dtype=torch.long)
        self.view_world_from_pixel = torch.stack(world_from_pixel)
        self.view_centre = torch.stack(centres)
        self.view_rotation = torch.stack(rotations)  # [V, 3, 3] world-to-camera
        self.view_size = torch.tensor(sizes, dtype=torch.long)  # [V, 2] width, height
        self.view_camera = torch.tensor([lookup[n] for views in frame_views for n, _, _ in views],
                                        dtype=torch.long)
        counts = torch.bincount(self.view_frame, minlength=self.table.num_frames)
        self.frame_view_start = torch.cumsum(counts, 0) - counts
        self.frame_view_count = counts
        self.dataset = RayFrameDataset(self.table.frames, frame_views, max_band_px=max_band_px,
                                       background_per_view=background_per_view, seed=seed)
        self.buffer = FrameBuffer(self.dataset, cache_frames, workers=workers, seed=seed,
                                  num_replicas=num_replicas, rank=rank)
        self._cache = _Cache(cache_frames)

    num_frames = property(lambda self: self.table.num_frames)
    num_subjects = property(lambda self: self.table.num_subjects)
    num_cameras = property(lambda self: len(self.camera_names))
    subject_ids = property(lambda self: self.table.subject_ids)

    def _pools(self, count: int, generator: torch.Generator,
               frames: torch.Tensor | None) -> tuple[torch.Tensor, list[_FramePool]]:
        """The step's frames [B] and their pools: given frames read through the LRU cache,
        else ``count`` frames drawn from the buffer."""
        if frames is not None:
            frame = _check_frames(frames, self.num_frames)
            return frame, [self._cache.get_or(f, lambda f=f: self.dataset[f])
                           for f in frame.tolist()]
        pools = self.buffer.draw(count, generator)
        return torch.tensor([p.frame for p in pools], dtype=torch.long), pools

    def close(self) -> None:
        """Stop the loader's worker processes."""
        self.buffer.close()

    def sample_rays(self, num_rays: int, generator: torch.Generator, mask_fraction: float = 0.9,
                    band_px: int = 4, *, num_frames: int = 1,
                    frames: torch.Tensor | None = None) -> RayBatch:
        """As :meth:`RayFrames.sample_rays` (same arguments, a batch of the same layout)."""
        if not 0.0 <= mask_fraction <= 1.0:
            raise ValueError(f"mask_fraction must be in [0, 1], got {mask_fraction!r}")
        if not 0 <= int(band_px) <= self.max_band_px:
            raise ValueError(f"band_px must be in [0, max_band_px={self.max_band_px}], got "
                             f"{band_px!r}")
        count = _check_count(num_frames) if frames is None else int(torch.as_tensor(
            frames).numel())
        if num_rays < 1 or count < 1 or num_rays % count:
            raise ValueError(f"num_rays ({num_rays}) must be a positive multiple of the number "
                             f"of frames ({count})")
        frame, pools = self._pools(count, generator, frames)
        per_frame = num_rays // count
        num_near = int(round(mask_fraction * per_frame))
        unit = torch.rand(frame.shape[0], per_frame, generator=generator, dtype=torch.float64)
        views, pixels, colours, in_mask = [], [], [], []
        for row, pool in enumerate(pools):
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

            views.append(pick(pool.near_view, pool.far_view).astype(np.int64)
                         + int(self.frame_view_start[frame[row]]))
            pixels.append(pick(pool.near_pixel, pool.far_pixel).astype(np.int64))
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
            pixels=coords, rotations=self.view_rotation[view])


class StreamingScanFrames:
    """:class:`ScanFrames` reading frames' ``scan.npz`` (skinning points and weights, surface
    and near-surface samples) through a :class:`FrameBuffer` of ``cache_frames`` frames (given
    ``frames=``: through an LRU cache of as many). workers, seed, num_replicas, rank: as
    :class:`StreamingRayFrames`."""

    def __init__(self, root: str | os.PathLike, split: str = "train", *,
                 cache_frames: int = 256, workers: int = 0, seed: int = 0,
                 num_replicas: int | None = None, rank: int | None = None) -> None:
        self.table = read_frame_table(root, split)
        self.dataset = ScanFrameDataset(self.table.frames)
        self.buffer = FrameBuffer(self.dataset, cache_frames, workers=workers, seed=seed,
                                  num_replicas=num_replicas, rank=rank)
        self._cache = _Cache(cache_frames)

    num_frames = property(lambda self: self.table.num_frames)
    num_subjects = property(lambda self: self.table.num_subjects)
    subject_ids = property(lambda self: self.table.subject_ids)

    def close(self) -> None:
        """Stop the loader's worker processes."""
        self.buffer.close()

    def sample(self, batch_frames: int, num_surface: int, num_space: int,
               generator: torch.Generator, *, near_fraction: float = 0.5, margin: float = 0.02,
               frames: torch.Tensor | None = None) -> ScanBatch:
        """As :meth:`ScanFrames.sample` (same arguments, a batch of the same layout)."""
        if frames is not None:
            frame = _check_frames(frames, self.num_frames)
            scans = [self._cache.get_or(f, lambda f=f: self.dataset[f]) for f in frame.tolist()]
        else:
            scans = self.buffer.draw(_check_count(batch_frames), generator)
            frame = torch.tensor([scan["frame"] for scan in scans], dtype=torch.long)
        num_near = int(round(near_fraction * num_space))
        num_uniform = num_space - num_near
        rows = {key: [] for key in ("points", "normals", "weights", "near", "sdf", "uniform")}
        for index, scan in zip(frame.tolist(), scans, strict=True):
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
