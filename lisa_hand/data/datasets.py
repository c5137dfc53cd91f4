"""Torch-side readers of a LISA-open dataset (the layout of :mod:`lisa_hand.data.layout`).

Two readers, one per training stage of LISA (paper Section 4.2), each loading one split into
memory once and then drawing random batches from a ``torch.Generator`` only (so that a resumed
training run draws exactly the batches the uninterrupted one would have drawn):

* :class:`ScanFrames` (the geometric prior): per frame the pose, translation, the template
  skeleton LISA is trained with, the subject, and the frame's scan: surface points, normals,
  pseudo-ground-truth skinning weights and near-surface SDF samples.
  :meth:`ScanFrames.sample` gives a :class:`ScanBatch`.
* :class:`RayFrames` (training from images): per frame and view the image, mask and camera.
  :meth:`RayFrames.sample_rays` gives a :class:`RayBatch` of camera rays, grouped by frame,
  mostly through the mask and a band around it (LISA renders "rays through the mask"), plus a
  fraction of background rays.

Both share :class:`FrameTable` (the split's subjects and frames, in sorted order), so frame
``i`` of a :class:`ScanFrames` and of a :class:`RayFrames` of the same split is the same frame.
Subject indices index the sorted list of the split's subjects. Errors for a missing or
malformed dataset name the file.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.cameras import Camera, load_cameras
from ..skeleton import NUM_JOINTS
from .frame_table import SPLITS, FrameTable, read_frame_table
from .layout import FramePaths, read_image, read_mask, read_npz

__all__ = [
    "SPLITS",
    "FrameTable",
    "read_frame_table",
    "ScanBatch",
    "ScanFrames",
    "RayBatch",
    "RayFrames",
]

_SCAN_ARRAYS = ("points", "normals", "template_weights", "sdf_points", "sdf")
_MAX_BAND_LIMIT = 254  # pixel distances are stored as uint8, 255 meaning "further"


# ------------------------------------------------------------------------------------------------
# Batches


def _choose_frames(num_frames_total: int, batch_frames: int, generator: torch.Generator,
                   frames: torch.Tensor | None) -> torch.Tensor:
    """Frame indices [B]: given, or distinct random frames (with replacement if B > F)."""
    if frames is not None:
        frames = torch.as_tensor(frames, dtype=torch.long).reshape(-1)
        if frames.numel() == 0 or frames.min() < 0 or frames.max() >= num_frames_total:
            raise ValueError(f"frames must be indices in [0, {num_frames_total}), got "
                             f"{frames.tolist()}")
        return frames
    if isinstance(batch_frames, bool) or not isinstance(batch_frames, int) or batch_frames < 1:
        raise ValueError(f"batch_frames must be a positive int, got {batch_frames!r}")
    if batch_frames <= num_frames_total:
        return torch.randperm(num_frames_total, generator=generator)[:batch_frames]
    return torch.randint(num_frames_total, (batch_frames,), generator=generator)


def _draw(start: torch.Tensor, count: torch.Tensor, num: int,
          generator: torch.Generator) -> torch.Tensor:
    """Uniform indices into per-row ranges ``[start, start + count)``: [B] -> [B, num]."""
    unit = torch.rand(start.shape[0], num, generator=generator, dtype=torch.float64)
    offset = (unit * count[:, None]).long().clamp_max((count[:, None] - 1).clamp_min(0))
    return start[:, None] + offset


def _check_count(value: object, name: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")
    return value


class _Batch:
    """Shared helpers of the batch dataclasses: every tensor field has the frame axis first."""

    def map(self, fn):
        changes = {f.name: fn(getattr(self, f.name)) for f in dataclasses.fields(self)
                   if isinstance(getattr(self, f.name), torch.Tensor)}
        return dataclasses.replace(self, **changes)

    def to(self, device: torch.device | str, dtype: torch.dtype | None = None):
        """A copy on ``device``; floating tensors also cast to ``dtype`` when given."""
        def move(tensor: torch.Tensor) -> torch.Tensor:
            if dtype is not None and tensor.is_floating_point():
                return tensor.to(device=device, dtype=dtype)
            return tensor.to(device=device)

        return self.map(move)

    def select(self, index: slice | torch.Tensor):
        """The frames ``index`` (a slice or a long tensor) of the batch."""
        return self.map(lambda tensor: tensor[index])

    @property
    def num_frames(self) -> int:
        return int(self.frame_index.shape[0])


# ------------------------------------------------------------------------------------------------
# Scans


@dataclass(eq=False)
class ScanBatch(_Batch):
    """Random frames of a :class:`ScanFrames` with random points of their scans. B frames."""

    frame_index: torch.Tensor
    """[B] long."""
    subject_index: torch.Tensor
    """[B] long."""
    pose: torch.Tensor
    """[B, 48] axis-angle radians."""
    translation: torch.Tensor
    """[B, 3] metres."""
    rest_joints: torch.Tensor
    """[B, 16, 3] metres (the subject's template skeleton)."""
    surface_points: torch.Tensor
    """[B, Ns, 3] world metres, scan points."""
    surface_normals: torch.Tensor
    """[B, Ns, 3] unit outward normals at the scan points."""
    surface_weights: torch.Tensor
    """[B, Ns, 16] pseudo-ground-truth skinning weights (``template_weights``)."""
    near_points: torch.Tensor
    """[B, Nn, 3] world metres, near-surface samples."""
    near_sdf: torch.Tensor
    """[B, Nn] metres, their signed distances (negative inside)."""
    uniform_points: torch.Tensor
    """[B, Nu, 3] world metres, uniform in the scan's bounding box grown by the margin."""


def _read_scan(paths: FramePaths) -> dict[str, np.ndarray]:
    """The arrays of a frame's ``scan.npz`` that the prior trains on, checked (shapes agree,
    values finite); ValueError naming the file."""
    arrays = read_npz(paths.scan, required=_SCAN_ARRAYS)
    num = arrays["points"].shape[0] if arrays["points"].ndim == 2 else -1
    expected = {"points": (num, 3), "normals": (num, 3), "template_weights": (num, NUM_JOINTS)}
    for key, shape in expected.items():
        if num < 1 or arrays[key].shape != shape:
            raise ValueError(f"{paths.scan}: {key!r} must have shape "
                             f"[N, {shape[1]}] with N >= 1 shared by points, normals and "
                             f"template_weights; got {list(arrays[key].shape)}")
    num_sdf = arrays["sdf"].shape[0] if arrays["sdf"].ndim == 1 else -1
    if num_sdf < 0 or arrays["sdf_points"].shape != (num_sdf, 3):
        raise ValueError(f"{paths.scan}: 'sdf_points' [M, 3] and 'sdf' [M] disagree: "
                         f"{list(arrays['sdf_points'].shape)} and "
                         f"{list(arrays['sdf'].shape)}")
    for key in _SCAN_ARRAYS:
        if not np.isfinite(arrays[key]).all():
            raise ValueError(f"{paths.scan}: {key!r} has non-finite values")
    return arrays


class ScanFrames:
    """All scans of one split in memory, for the geometric prior (paper Section 4.2).

    Reads ``scan.npz`` (points, normals, template_weights, sdf_points, sdf) of every frame; frames
    may have different point counts. Memory: about 64 bytes per scan point and 16 per SDF sample
    (a few hundred frames of 20k points: a few hundred MB).

    root: the dataset folder; split: 'train', 'val' or 'test'.
    """

    def __init__(self, root: str | os.PathLike, split: str = "train") -> None:
        self.table = read_frame_table(root, split)
        points, normals, weights, sdf_points, sdf_values = [], [], [], [], []
        for paths in self.table.frames:
            arrays = _read_scan(paths)
            points.append(arrays["points"].astype(np.float32))
            normals.append(arrays["normals"].astype(np.float32))
            weights.append(arrays["template_weights"].astype(np.float16))
            sdf_points.append(arrays["sdf_points"].astype(np.float32))
            sdf_values.append(arrays["sdf"].astype(np.float32))

        def starts(counts: torch.Tensor) -> torch.Tensor:
            return torch.cumsum(counts, 0) - counts

        self.surface_count = torch.tensor([p.shape[0] for p in points], dtype=torch.long)
        self.surface_start = starts(self.surface_count)
        self.surface_points = torch.from_numpy(np.concatenate(points))
        self.surface_normals = torch.from_numpy(np.concatenate(normals))
        self.surface_weights = torch.from_numpy(np.concatenate(weights))
        self.sdf_count = torch.tensor([p.shape[0] for p in sdf_points], dtype=torch.long)
        self.sdf_start = starts(self.sdf_count)
        self.sdf_points = torch.from_numpy(np.concatenate(sdf_points))
        self.sdf_values = torch.from_numpy(np.concatenate(sdf_values))
        self.bbox_min = torch.stack([torch.from_numpy(p).amin(0) for p in points])
        self.bbox_max = torch.stack([torch.from_numpy(p).amax(0) for p in points])

    @property
    def num_frames(self) -> int:
        return self.table.num_frames

    @property
    def num_subjects(self) -> int:
        return self.table.num_subjects

    @property
    def subject_ids(self) -> list[str]:
        return self.table.subject_ids

    def sample(
        self,
        batch_frames: int,
        num_surface: int,
        num_space: int,
        generator: torch.Generator,
        *,
        near_fraction: float = 0.5,
        margin: float = 0.02,
        frames: torch.Tensor | None = None,
    ) -> ScanBatch:
        """Draw frames and points (everything random comes from ``generator``).

        batch_frames: B distinct frames (with replacement when B exceeds the split's frames);
            ignored when ``frames`` [B] long is given.
        num_surface: Ns scan points per frame (with their normals and weights).
        num_space: points off the surface per frame: ``Nn = round(near_fraction * num_space)``
            near-surface SDF samples and ``Nu = num_space - Nn`` uniform in the scan's bounding
            box grown by ``margin`` metres on every side.
        """
        num_surface = _check_count(num_surface, "num_surface")
        num_space = _check_count(num_space, "num_space")
        if not 0.0 <= near_fraction <= 1.0:
            raise ValueError(f"near_fraction must be in [0, 1], got {near_fraction!r}")
        if not margin >= 0:
            raise ValueError(f"margin must be >= 0 (metres), got {margin!r}")
        frame = _choose_frames(self.num_frames, batch_frames, generator, frames)
        num_near = int(round(near_fraction * num_space))
        num_uniform = num_space - num_near
        if num_near and bool((self.sdf_count[frame] == 0).any()):
            raise ValueError("near-surface samples requested but a frame's scan.npz has no "
                             "sdf_points (set near_fraction=0)")
        surface = _draw(self.surface_start[frame], self.surface_count[frame], num_surface,
                        generator)
        near = _draw(self.sdf_start[frame], self.sdf_count[frame], num_near, generator)
        unit = torch.rand(frame.shape[0], num_uniform, 3, generator=generator)
        low = self.bbox_min[frame] - margin
        high = self.bbox_max[frame] + margin
        uniform = low[:, None] + unit * (high - low)[:, None]
        subject = self.table.frame_subject[frame]
        return ScanBatch(
            frame_index=frame,
            subject_index=subject,
            pose=self.table.pose[frame],
            translation=self.table.translation[frame],
            rest_joints=self.table.rest_joints[subject],
            surface_points=self.surface_points[surface],
            surface_normals=self.surface_normals[surface],
            surface_weights=self.surface_weights[surface].float(),
            near_points=self.sdf_points[near],
            near_sdf=self.sdf_values[near],
            uniform_points=uniform,
        )


# ------------------------------------------------------------------------------------------------
# Images


@dataclass(eq=False)
class RayBatch(_Batch):
    """Random camera rays of B frames, R rays per frame (each from any of the frame's views)."""

    frame_index: torch.Tensor
    """[B] long."""
    subject_index: torch.Tensor
    """[B] long."""
    pose: torch.Tensor
    """[B, 48] axis-angle radians (as given by the dataset)."""
    translation: torch.Tensor
    """[B, 3] metres."""
    rest_joints: torch.Tensor
    """[B, 16, 3] metres (the subject's template skeleton)."""
    origins: torch.Tensor
    """[B, R, 3] world metres (camera centres)."""
    directions: torch.Tensor
    """[B, R, 3] unit world directions through the pixel centres."""
    rgb: torch.Tensor
    """[B, R, 3] target colours in [0, 1]."""
    in_mask: torch.Tensor
    """[B, R] bool, the pixel is in the foreground mask."""
    camera_index: torch.Tensor
    """[B, R] long, index into :attr:`RayFrames.camera_names` (per-camera calibration)."""
    pixels: torch.Tensor
    """[B, R, 2] continuous pixel coordinates (u, v) of the ray (pixel centres)."""
    rotations: torch.Tensor
    """[B, R, 3, 3] the world-to-camera rotation ``R`` of the ray's view (a light fixed to the
    camera, :mod:`lisa_hand.render.shading`)."""


def _camera_names(frames: list[FramePaths], frame_cameras: list[list[Camera]]) -> list[str]:
    """The sorted names of every camera of the split; ValueError for a frame without cameras
    or a camera without a name."""
    names = set()
    for paths, cameras in zip(frames, frame_cameras, strict=True):
        if not cameras:
            raise ValueError(f"{paths.cameras}: no cameras")
        for index, camera in enumerate(cameras):
            if not camera.name:
                raise ValueError(f"{paths.cameras}: camera {index} has no name (the image "
                                 "files are images/NAME.png)")
            names.add(camera.name)
    return sorted(names)


def _view_pixels(paths: FramePaths, camera: Camera, view: int, max_band_px: int,
                 background_per_view: int, rng: np.random.Generator
                 ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """The drawable pixels of one view (index ``view``) -> (near, far): near = (view ids, pixel
    ids, rgb uint8, distance to the mask in pixels uint8) of the pixels within ``max_band_px``
    of the mask; far = (view ids, pixel ids, rgb) of up to ``background_per_view`` others."""
    from scipy.ndimage import distance_transform_edt

    image = read_image(paths.image(camera.name))
    mask = read_mask(paths.mask(camera.name))
    expected = (camera.height, camera.width)
    for path, shape in ((paths.image(camera.name), image.shape[:2]),
                        (paths.mask(camera.name), mask.shape)):
        if shape != expected:
            raise ValueError(f"{path}: image is {shape[1]}x{shape[0]} but camera "
                             f"{camera.name!r} in {paths.cameras} is "
                             f"{camera.width}x{camera.height}")
    rgb = np.round(image.reshape(-1, 3) * 255.0).astype(np.uint8)
    if mask.any():
        distance = np.ceil(distance_transform_edt(~mask)).reshape(-1)
    else:
        distance = np.full(mask.size, np.inf)
    near = np.flatnonzero(distance <= max_band_px)
    far = np.flatnonzero(distance > max_band_px)
    if far.size > background_per_view:
        far = np.sort(rng.choice(far, size=background_per_view, replace=False))
    dist_u8 = distance[near].astype(np.uint8)
    return ((np.full(near.size, view, np.int32), near.astype(np.int32), rgb[near], dist_u8),
            (np.full(far.size, view, np.int32), far.astype(np.int32), rgb[far]))


def _frame_pools(frame_near: list[tuple], frame_far: list[tuple], max_band_px: int
                 ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], np.ndarray]:
    """One frame's views' pixels in two pools -> (near sorted by distance to the mask, far,
    cumulative near counts by distance [max_band_px + 1])."""
    near_arrays = [np.concatenate(part) for part in zip(*frame_near, strict=True)]
    order = np.argsort(near_arrays[3], kind="stable")  # by distance to the mask
    near = tuple(array[order] for array in near_arrays)
    far = tuple(np.concatenate(part) for part in zip(*frame_far, strict=True))
    counts = np.bincount(near_arrays[3], minlength=max_band_px + 1)[:max_band_px + 1]
    return near, far, np.cumsum(counts)


def _starts(counts: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.cumsum(counts) - counts)


class RayFrames:
    """All images of one split in memory as candidate rays, for training from images.

    Per frame, every camera of ``cameras.json`` with its ``images/NAME.png`` and
    ``masks/NAME.png``. Only the pixels that can be drawn are kept: those within
    ``max_band_px`` pixels of the mask (the mask itself included) and, per view, up to
    ``background_per_view`` other pixels chosen once at load (seeded by ``seed``). About 12 bytes
    per kept pixel. Cameras are identified across frames by name (``camera_names``, sorted).

    root: the dataset folder; split: 'train', 'val' or 'test'.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        split: str = "train",
        *,
        max_band_px: int = 16,
        background_per_view: int = 4096,
        seed: int = 0,
    ) -> None:
        if isinstance(max_band_px, bool) or not isinstance(max_band_px, int) \
                or not 0 <= max_band_px <= _MAX_BAND_LIMIT:
            raise ValueError(f"max_band_px must be an int in [0, {_MAX_BAND_LIMIT}], got "
                             f"{max_band_px!r}")
        self.max_band_px = max_band_px
        _check_count(background_per_view, "background_per_view")
        self.table = read_frame_table(root, split)
        rng = np.random.default_rng(seed)
        frame_cameras = [load_cameras(paths.cameras) for paths in self.table.frames]
        self.camera_names = _camera_names(self.table.frames, frame_cameras)
        camera_lookup = {name: i for i, name in enumerate(self.camera_names)}

        views: list[tuple[Camera, int]] = []  # (camera, frame) of every view
        near_parts: list[tuple[np.ndarray, ...]] = []
        far_parts: list[tuple[np.ndarray, ...]] = []
        near_cum = np.zeros((self.table.num_frames, max_band_px + 1), dtype=np.int64)
        for frame, (paths, cameras) in enumerate(zip(self.table.frames, frame_cameras,
                                                     strict=True)):
            frame_near, frame_far = [], []
            for camera in cameras:
                near, far = _view_pixels(paths, camera, len(views), max_band_px,
                                         background_per_view, rng)
                frame_near.append(near)
                frame_far.append(far)
                views.append((camera, frame))
            near, far, near_cum[frame] = _frame_pools(frame_near, frame_far, max_band_px)
            near_parts.append(near)
            far_parts.append(far)
            if near[3].size + far[0].size == 0:
                raise ValueError(f"{paths.root}: no pixel to draw rays from")
        self._init_views(views, camera_lookup)
        self._init_pools(near_parts, far_parts, near_cum)

    def _init_views(self, views: list[tuple[Camera, int]], camera_lookup: dict[str, int]) -> None:
        """Per view V: the pixel-to-ray matrix, the camera centre, image width, camera and frame."""
        world_from_pixel = []
        for camera, _ in views:
            K = camera.K.double()
            R = camera.R.double()
            # As geometry.cameras.pixel_rays: direction = R^T K^-1 [u, v, 1], normalised.
            world_from_pixel.append((R.T @ torch.linalg.inv(K)).float())
        self.view_world_from_pixel = torch.stack(world_from_pixel)  # [V, 3, 3]
        self.view_centre = torch.stack([camera.center.float() for camera, _ in views])  # [V, 3]
        self.view_rotation = torch.stack([camera.R.float() for camera, _ in views])  # [V, 3, 3]
        self.view_width = torch.tensor([camera.width for camera, _ in views], dtype=torch.long)
        self.view_camera = torch.tensor([camera_lookup[camera.name] for camera, _ in views],
                                        dtype=torch.long)
        self.view_frame = torch.tensor([frame for _, frame in views], dtype=torch.long)

    def _init_pools(self, near_parts: list[tuple[np.ndarray, ...]],
                    far_parts: list[tuple[np.ndarray, ...]], near_cum: np.ndarray) -> None:
        """The frames' pools concatenated, each frame's slice given by its start and count."""
        near_total = np.array([part[3].size for part in near_parts], dtype=np.int64)
        far_count = np.array([part[0].size for part in far_parts], dtype=np.int64)
        # One dummy entry at the end of each pool (never drawn): keeps gathers in range.
        near_parts = near_parts + [(np.zeros(1, np.int32), np.zeros(1, np.int32),
                                    np.zeros((1, 3), np.uint8), np.full(1, 255, np.uint8))]
        far_parts = far_parts + [(np.zeros(1, np.int32), np.zeros(1, np.int32),
                                  np.zeros((1, 3), np.uint8))]
        self.near_view = torch.from_numpy(np.concatenate([p[0] for p in near_parts]))
        self.near_pixel = torch.from_numpy(np.concatenate([p[1] for p in near_parts]))
        self.near_rgb = torch.from_numpy(np.concatenate([p[2] for p in near_parts]))
        self.near_distance = torch.from_numpy(np.concatenate([p[3] for p in near_parts]))
        self.near_start = _starts(near_total)
        self.near_cumulative = torch.from_numpy(near_cum)  # [F, max_band + 1]
        self.near_total = torch.from_numpy(near_total)
        self.far_view = torch.from_numpy(np.concatenate([p[0] for p in far_parts]))
        self.far_pixel = torch.from_numpy(np.concatenate([p[1] for p in far_parts]))
        self.far_rgb = torch.from_numpy(np.concatenate([p[2] for p in far_parts]))
        self.far_start = _starts(far_count)
        self.far_count = torch.from_numpy(far_count)

    @property
    def num_frames(self) -> int:
        return self.table.num_frames

    @property
    def num_subjects(self) -> int:
        return self.table.num_subjects

    @property
    def num_cameras(self) -> int:
        return len(self.camera_names)

    @property
    def subject_ids(self) -> list[str]:
        return self.table.subject_ids

    def sample_rays(
        self,
        num_rays: int,
        generator: torch.Generator,
        mask_fraction: float = 0.9,
        band_px: int = 4,
        *,
        num_frames: int = 1,
        frames: torch.Tensor | None = None,
    ) -> RayBatch:
        """Draw ``num_frames`` frames and ``num_rays / num_frames`` rays in each.

        In each frame, ``round(mask_fraction * R)`` rays go through pixels in the mask or within
        ``band_px`` pixels of it (uniform over those pixels of all the frame's views) and the
        rest through other pixels (the kept background pixels); if one of the two pools of a
        frame is empty, its rays come from the other one. Everything random comes from
        ``generator``.

        num_rays: total rays, a multiple of the number of frames.
        mask_fraction: in [0, 1]. band_px: in [0, max_band_px].
        num_frames: B distinct random frames (ignored when ``frames`` [B] long is given).
        """
        if not 0.0 <= mask_fraction <= 1.0:
            raise ValueError(f"mask_fraction must be in [0, 1], got {mask_fraction!r}")
        if isinstance(band_px, bool) or not isinstance(band_px, int) \
                or not 0 <= band_px <= self.max_band_px:
            raise ValueError(f"band_px must be an int in [0, max_band_px={self.max_band_px}] "
                             f"(the band the dataset was loaded with), got {band_px!r}")
        frame = _choose_frames(self.num_frames, num_frames, generator, frames)
        batch = frame.shape[0]
        num_rays = _check_count(num_rays, "num_rays", minimum=1)
        if num_rays % batch:
            raise ValueError(f"num_rays ({num_rays}) must be a multiple of the number of frames "
                             f"({batch})")
        per_frame = num_rays // batch
        num_near = int(round(mask_fraction * per_frame))
        from_near, near_index, far_index = self._draw_pixels(frame, per_frame, num_near, band_px,
                                                             generator)
        return self._rays(frame, from_near, near_index, far_index)

    def _draw_pixels(self, frame: torch.Tensor, per_frame: int, num_near: int, band_px: int,
                     generator: torch.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pool entries of ``per_frame`` rays in each frame [B], the first ``num_near`` from the
        pixels within ``band_px`` of the mask -> (from the near pool [B, R] bool, near index
        [B, R], far index [B, R]; the index into the other pool is its dummy entry)."""
        inner = self.near_cumulative[frame, band_px]  # [B] pixels within the band
        outer = self.near_total[frame] - inner + self.far_count[frame]  # [B] the others
        want_near = torch.arange(per_frame)[None, :] < num_near
        use_near = (want_near & (inner[:, None] > 0)) | (outer[:, None] == 0)  # [B, R]
        unit = torch.rand(frame.shape[0], per_frame, generator=generator, dtype=torch.float64)
        count = torch.where(use_near, inner[:, None], outer[:, None])
        offset = (unit * count).long().clamp_max(count - 1)
        # Background offsets beyond the band's prefix: the near pool's tail, then the far pool.
        in_tail = offset < (self.near_total[frame] - inner)[:, None]
        near_index = self.near_start[frame][:, None] + torch.where(
            use_near, offset, inner[:, None] + offset)
        far_index = self.far_start[frame][:, None] + offset - (
            self.near_total[frame] - inner)[:, None]
        from_near = use_near | in_tail
        # Both pools end with a dummy entry (see _init_pools), so every index below is valid.
        near_index = torch.where(from_near, near_index, self.near_view.numel() - 1)
        far_index = torch.where(from_near, self.far_view.numel() - 1, far_index)
        return from_near, near_index, far_index

    def _rays(self, frame: torch.Tensor, from_near: torch.Tensor, near_index: torch.Tensor,
              far_index: torch.Tensor) -> RayBatch:
        """The rays of the drawn pool entries (see :meth:`_draw_pixels`)."""

        def pick(near_values: torch.Tensor, far_values: torch.Tensor) -> torch.Tensor:
            mask = from_near.reshape(from_near.shape + (1,) * (near_values.dim() - 1))
            return torch.where(mask, near_values[near_index], far_values[far_index])

        view = pick(self.near_view, self.far_view).long()
        pixel = pick(self.near_pixel, self.far_pixel).long()
        rgb = pick(self.near_rgb, self.far_rgb).float() / 255.0
        in_mask = from_near & (self.near_distance[near_index] == 0)
        width = self.view_width[view]
        pixels = torch.stack([(pixel % width).float() + 0.5,
                              torch.div(pixel, width, rounding_mode="floor").float() + 0.5],
                             dim=-1)
        homogeneous = torch.cat([pixels, torch.ones_like(pixels[..., :1])], dim=-1)
        directions = (self.view_world_from_pixel[view] @ homogeneous[..., None])[..., 0]
        directions = directions / directions.norm(dim=-1, keepdim=True)
        subject = self.table.frame_subject[frame]
        return RayBatch(
            frame_index=frame,
            subject_index=subject,
            pose=self.table.pose[frame],
            translation=self.table.translation[frame],
            rest_joints=self.table.rest_joints[subject],
            origins=self.view_centre[view],
            directions=directions,
            rgb=rgb,
            in_mask=in_mask,
            camera_index=self.view_camera[view],
            pixels=pixels,
            rotations=self.view_rotation[view],
        )
