"""On-disk layout of a LISA-open dataset (written by ``lisa synth``) and of image-fitting input.

::

    DATA/
      dataset.json              generator settings, counts, format version
      split.json                {"train": [subject ids], "val": [...], "test": [...]}
      s000/                     one folder per subject
        subject.json            "id", "side" ("right"/"left"), "shape" (named open-hand shape
                                parameters), "appearance" (named albedo parameters), "detail_seed",
                                "rest_joints" [16,3] m (the open hand's true skeleton),
                                "template_betas" [10] and "template_rest_joints" [16,3] m (pseudo
                                ground truth: the MANO-like template fitted to this subject; this
                                skeleton is the one LISA is trained and fitted with)
        f000/                   one folder per frame (a pose of that subject)
          params.json           "pose" [48] axis-angle rad, "translation" [3] m, "joints" [16,3] m,
                                "keypoints" [21,3] m, "pose_name" (or null), "camera_gain" and
                                "camera_bias" ({camera name: [3]}, the simulated calibration)
          mesh.ply              ground-truth mesh, metres, vertex colours (albedo), skinning weights
          scan.npz              points [N,3], normals [N,3], weights [N,16] (ground-truth owners),
                                template_weights [N,16] (pseudo ground truth, nearest template
                                vertex), sdf_points [M,3], sdf [M] (metres)
          cameras.json          list of {name, K, R, t, width, height} (OpenCV, world to camera)
          keypoints.json        {"names": [21], "views": {name: {"keypoints": [21,2] px,
                                "visible": [21]}}}
          images/NAME.png       RGB, 8 bit
          masks/NAME.png        foreground mask, 8 bit (0 or 255)
          depth/NAME.png        depth along the camera z axis, uint16, units of 0.1 mm, 0 = none
          sources.json          optional (written by ``lisa import``): {"images": {NAME: path},
                                "masks": {NAME: path}}, the original files of views that have no
                                ``images/NAME.png`` / ``masks/NAME.png`` here (paths absolute or
                                relative to the frame folder; any format imageio reads, e.g. JPEG)

A frame folder is also the input format of ``lisa fit-images``: ``cameras.json`` and ``images/``
are required; ``masks/`` and ``keypoints.json`` are optional. Every writer here is atomic.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..utils.io import atomic_path, read_json, read_numpy, require_file

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "DEPTH_UNIT_M",
    "FramePaths",
    "subject_id",
    "frame_id",
    "write_image",
    "read_image",
    "write_mask",
    "read_mask",
    "write_depth",
    "read_depth",
    "write_npz",
    "read_npz",
    "read_split",
    "list_frames",
    "SOURCES_FILE",
    "read_sources",
    "DATASET_FILES",
    "prepare_dataset_folder",
]

FORMAT_NAME = "lisa-synth"
FORMAT_VERSION = 1
DEPTH_UNIT_M = 1e-4  # depth PNGs store units of 0.1 mm: up to 6.5 m in uint16
SOURCES_FILE = "sources.json"
"""A frame's references to original image and mask files outside the frame folder."""


DATASET_FILES = ("dataset.json", "split.json", "import_report.json")
"""The files of a dataset folder besides its subject folders (``import_report.json``: ``lisa
import``'s)."""
_SUBJECT_DIR = re.compile(r"^s\d{3,}$")


def prepare_dataset_folder(out: str | os.PathLike, overwrite: bool, hint: str = "--overwrite"
                           ) -> Path:
    """Make ``out`` ready for a dataset (``lisa synth``, ``lisa import``) and return it: created
    if missing; it must be empty unless ``overwrite``, which removes a previous dataset's subject
    folders and :data:`DATASET_FILES` only (anything else is left alone). ``hint``: how the
    error message names the way to overwrite."""
    from ..utils.io import ensure_writable_dir

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a folder")
    if out.is_dir():
        entries = sorted(p.name for p in out.iterdir())
        if entries and not overwrite:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise FileExistsError(f"{out}: output folder is not empty ({shown}); choose another "
                                  f"folder or pass {hint}")
        for name in entries if overwrite else ():
            path = out / name
            if path.is_dir() and _SUBJECT_DIR.match(name):
                shutil.rmtree(path)
            elif name in DATASET_FILES and path.is_file():
                path.unlink()
    return ensure_writable_dir(out)


def subject_id(index: int) -> str:
    """Folder name of subject ``index``: ``s000``."""
    return f"s{index:03d}"


def frame_id(index: int) -> str:
    """Folder name of frame ``index`` of a subject: ``f000``."""
    return f"f{index:03d}"


@dataclass(frozen=True)
class FramePaths:
    """The files of one frame folder (see the module docstring)."""

    root: Path
    """The frame folder (``DATA/s000/f000``); a ``str`` or any path-like is converted."""

    def __post_init__(self) -> None:
        if not isinstance(self.root, (str, os.PathLike)):
            raise TypeError(f"FramePaths.root must be a path, got {type(self.root).__name__}")
        object.__setattr__(self, "root", Path(self.root))

    @property
    def params(self) -> Path:
        return self.root / "params.json"

    @property
    def mesh(self) -> Path:
        return self.root / "mesh.ply"

    @property
    def scan(self) -> Path:
        return self.root / "scan.npz"

    @property
    def cameras(self) -> Path:
        return self.root / "cameras.json"

    @property
    def keypoints(self) -> Path:
        return self.root / "keypoints.json"

    def image(self, view: str) -> Path:
        """``images/NAME.png``, or the original file ``sources.json`` names when that is absent."""
        return _local_or_source(self.root, "images", view)

    def mask(self, view: str) -> Path:
        """``masks/NAME.png``, or the original file ``sources.json`` names when that is absent."""
        return _local_or_source(self.root, "masks", view)

    def depth(self, view: str) -> Path:
        return self.root / "depth" / f"{view}.png"


def _local_or_source(root: Path, kind: str, view: str) -> Path:
    local = root / kind / f"{view}.png"
    if local.exists() or not (root / SOURCES_FILE).is_file():
        return local
    source = read_sources(root).get(kind, {}).get(view)
    return local if source is None else source


def read_sources(root: str | os.PathLike) -> dict[str, dict[str, Path]]:
    """The ``sources.json`` of a frame folder: ``{"images": {view: Path}, "masks": {...}}``,
    relative paths resolved against the folder; empty when there is none. ValueError naming the
    file when it is malformed. Cached per file modification time."""
    path = Path(root) / SOURCES_FILE
    if not path.is_file():
        return {}
    cached = _read_sources(path, path.stat().st_mtime_ns)
    return {kind: dict(entries) for kind, entries in cached.items()}  # the cache stays intact


@functools.lru_cache(maxsize=256)
def _read_sources(path: Path, mtime_ns: int) -> dict[str, dict[str, Path]]:
    data = read_json(path)
    if not isinstance(data, Mapping):
        raise ValueError(f"{path}: expected a JSON object with 'images' and/or 'masks'")
    sources: dict[str, dict[str, Path]] = {}
    for kind in ("images", "masks"):
        entries = data.get(kind, {})
        if not isinstance(entries, Mapping) or not all(
                isinstance(value, str) for value in entries.values()):
            raise ValueError(f"{path}: {kind!r} must map view names to file paths")
        sources[kind] = {str(view): (path.parent / value) for view, value in entries.items()}
    return sources


def write_image(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """Write an RGB image ``[H, W, 3]`` (float in [0, 1] or uint8) as an 8-bit PNG."""
    import imageio.v3 as iio

    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"{path}: an RGB image must be [H, W, 3], got {rgb.shape}")
    if rgb.dtype != np.uint8:
        rgb = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, rgb, extension=".png")
    return Path(path)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float32 ``[H, W, 3]`` in [0, 1] (grey or RGBA are converted)."""
    image = _read_png(path)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    if image.shape[-1] == 4:
        image = image[..., :3]
    if image.shape[-1] != 3:
        raise ValueError(f"{path}: expected an RGB image, got shape {image.shape}")
    scale = 65535.0 if image.dtype == np.uint16 else 255.0
    return image.astype(np.float32) / scale


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> Path:
    """Write a boolean mask ``[H, W]`` as an 8-bit PNG (0 or 255)."""
    import imageio.v3 as iio

    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"{path}: a mask must be [H, W], got {mask.shape}")
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, (mask > 0).astype(np.uint8) * 255, extension=".png")
    return Path(path)


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Read a mask PNG as bool ``[H, W]`` (any channel layout; nonzero = foreground)."""
    mask = _read_png(path)
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=-1) if mask.shape[-1] >= 3 else mask[..., 0]
    return mask > (mask.max() / 2 if mask.max() > 0 else 0)


def write_depth(path: str | os.PathLike, depth_m: np.ndarray) -> Path:
    """Write depth ``[H, W]`` metres (0 = no surface) as a uint16 PNG in units of 0.1 mm."""
    import imageio.v3 as iio

    depth = np.asarray(depth_m, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"{path}: a depth map must be [H, W], got {depth.shape}")
    units = np.round(depth / DEPTH_UNIT_M)
    if units.max(initial=0) > np.iinfo(np.uint16).max:
        raise ValueError(f"{path}: depth beyond {np.iinfo(np.uint16).max * DEPTH_UNIT_M:.2f} m")
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, units.astype(np.uint16), extension=".png")
    return Path(path)


def read_depth(path: str | os.PathLike) -> np.ndarray:
    """Read a depth PNG written by :func:`write_depth` as float32 metres ``[H, W]``."""
    depth = _read_png(path)
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ValueError(f"{path}: expected a 16-bit single-channel depth PNG")
    return depth.astype(np.float32) * DEPTH_UNIT_M


def _read_png(path: str | os.PathLike) -> np.ndarray:
    import imageio.v3 as iio

    path = require_file(path)
    try:
        return np.asarray(iio.imread(path))
    except Exception as exc:  # imageio raises many types for corrupt files
        # One line: imageio's "no backend" message lists plugins to install over several.
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "backend" in reason:
            reason = "not a PNG or JPEG file, or a corrupt one"
        raise ValueError(f"{path}: not a readable image ({reason})") from None


def write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """Write arrays to a compressed NPZ atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)
    return Path(path)


def read_npz(path: str | os.PathLike, required: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Read an NPZ into a dict; missing file or keys raise errors naming the file."""
    arrays = read_numpy(path)
    if not isinstance(arrays, dict):
        raise ValueError(f"{path}: a .npy array, not an .npz archive")
    missing = [key for key in required if key not in arrays]
    if missing:
        raise ValueError(f"{path}: missing array(s) {', '.join(missing)}")
    return arrays


def read_split(root: str | os.PathLike) -> dict[str, list[str]]:
    """Read ``split.json`` of a dataset: subject ids per split (train, val, test)."""
    path = Path(root) / "split.json"
    split = read_json(path)
    if not isinstance(split, Mapping) or not all(
        isinstance(split.get(key), list) for key in ("train", "val", "test")
    ):
        raise ValueError(f"{path}: expected an object with lists 'train', 'val' and 'test'")
    return {key: [str(s) for s in split[key]] for key in ("train", "val", "test")}


def list_frames(root: str | os.PathLike, subjects: Sequence[str]) -> list[FramePaths]:
    """All frame folders of the given subjects, sorted (subject, frame)."""
    root = Path(root)
    frames = []
    for subject in subjects:
        folder = root / subject
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: subject folder listed in split.json is missing")
        frames.extend(FramePaths(p) for p in sorted(folder.glob("f*")) if p.is_dir())
    return frames
