"""``lisa import freihand``: FreiHAND (Zimmermann et al., ICCV 2019) in the package's layout.

What it reads, under ``ROOT`` (the dataset's release)::

    {set}_K.json        [N] intrinsics [3, 3] px (integer pixel centres)
    {set}_xyz.json      [N] keypoints [21, 3] metres, camera frame, OpenPose order
    {set}_mano.json     optional: [N] [[61]]: pose [48] (the mean hand is added to it),
                        shape [10], root uv [2] and scale [1] of a weak-perspective model
    {set}_verts.json    optional: [N] MANO vertices [778, 3] metres, camera frame
    {set}/rgb/%08d.jpg  224x224 RGB; the training set holds 4 versions of each sample: image
                        ``i + k * N`` (k = 0 green screen, 1-3 other backgrounds)
    {set}/mask/%08d.jpg hand masks of the N samples (shared by the versions)

``set`` is ``training`` or ``evaluation`` (whose annotations came with the later release).
The world frame is the camera's (R = I, t = 0); ``K``'s principal point moves by +0.5 to the
package's pixel centres. Every sample is its own subject (FreiHAND has no subject ids); its
versions are frames of that subject. FreiHAND shows right hands only. Images are referred to.

Units: a ``{set}_xyz.json`` (or ``_verts.json``) whose hands are the size of a hand in
centimetres or millimetres (:func:`lisa_hand.data.units.decide_length_unit` on the median
sample) is converted to metres with a note; one that is a hand in no unit is refused. A sample
whose keypoints are not hand-sized, lie behind the camera or whose ``K`` is singular is skipped
with its line.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ...geometry.cameras import Camera
from ...utils.io import read_json, write_json
from ..layout import FramePaths, write_npz
from ..units import UNIT_NAMES, bounding_diagonal, decide_length_unit
from .common import (
    ExtraFiles,
    FrameRecord,
    ImportReport,
    SkipFrame,
    check_hand_size,
    check_view,
    prepare_output,
    write_dataset,
)
from .mano_params import freihand_mano, load_mano_layers
from .skinning import pseudo_scan_writer

__all__ = ["FreiHandConfig", "import_freihand", "freihand_records", "freihand_camera"]

_SETS = ("training", "evaluation")


@dataclass(frozen=True)
class FreiHandConfig:
    """What ``lisa import freihand`` reads."""

    root: str
    """The dataset folder (holds ``training_K.json``, ``training/rgb``, ...)."""
    set: str = "training"
    """training or evaluation."""
    versions: tuple[int, ...] = (0,)
    """Training-image versions (0 green screen, 1-3 composited backgrounds)."""
    every: int = 1
    """Keep every Nth sample."""
    max_frames: int = 0
    """Stop after this many samples (0: no limit)."""
    vertices: bool = False
    """Also read ``{set}_verts.json`` (large for training) into ``mano_mesh.npz`` per frame."""
    mano: str | None = None
    """Folder of the user's MANO_RIGHT.pkl: poses from ``{set}_mano.json``."""
    split: str = "test"
    """The split (train, val, test) the subjects go into."""
    skinning_points: int = 2000
    """Points of the posed MANO (or template) per frame in scan.npz, with their skinning
    weights (pseudo ground truth of L_w; 0: no scan.npz)."""

    def __post_init__(self) -> None:
        if self.set not in _SETS:
            raise ValueError(f"set must be training or evaluation, got {self.set!r}")
        if not self.versions or any(v not in (0, 1, 2, 3) for v in self.versions):
            raise ValueError(f"versions must be among 0, 1, 2, 3, got {self.versions!r}")
        if self.every < 1 or self.max_frames < 0 or self.skinning_points < 0:
            raise ValueError("every must be >= 1, max_frames and skinning_points >= 0")
        if self.split not in ("train", "val", "test"):
            raise ValueError(f"split must be train, val or test, got {self.split!r}")


def _list(root: Path, set_name: str, key: str, required: bool):
    path = root / f"{set_name}_{key}.json"
    if not path.is_file():
        if required:
            raise FileNotFoundError(f"{path}: missing FreiHAND annotation file")
        return None
    values = read_json(path)
    if not isinstance(values, list):
        raise ValueError(f"{path}: expected a JSON list (one entry per sample)")
    return values


def _file_scale(values: list, path: Path, what: str, report: ImportReport) -> float:
    """Metres per unit of a file of per-sample points ([N] of [P, 3]): 1 for FreiHAND's
    metres; a file whose median sample is a hand in cm or mm is converted, with a note in
    ``report``; ValueError (naming the file) when it is a hand in no unit."""
    samples = []
    for value in values:
        try:
            array = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            continue
        if array.ndim == 2 and array.shape[1] == 3 and len(array) and np.isfinite(array).all():
            samples.append(array)
    if not samples:
        return 1.0  # every sample is skipped with its own line
    diagonals = [bounding_diagonal(sample) for sample in samples]
    median = samples[int(np.argsort(diagonals)[len(diagonals) // 2])]
    unit = decide_length_unit(median, "auto", name=str(path), what=f"the median sample's {what}")
    if unit.unit != "m":
        report.note(f"{path}: the {what} are in {UNIT_NAMES[unit.unit]}, not metres (the median "
                    f"hand is {unit.diagonal:.4g} units across): converted to metres")
    return unit.metres_per_unit


def freihand_camera(K: object, width: int, height: int, name: str, where: str) -> Camera:
    """The package camera of a FreiHAND ``K`` (camera frame = world, pixel centres +0.5);
    SkipFrame naming ``where`` for a K that is not [3, 3], not finite or singular."""
    try:
        K = np.asarray(K, np.float64).reshape(3, 3).copy()
    except (TypeError, ValueError):
        raise SkipFrame(f"{where}: K must be [3, 3] numbers", "bad camera") from None
    scale = float(np.abs(K[:2, :2]).max()) ** 2 if np.isfinite(K).all() else 0.0
    if not abs(np.linalg.det(K)) > 1e-9 * scale or scale == 0.0:
        raise SkipFrame(f"{where}: K is singular or not finite: {K.tolist()}", "bad camera")
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    try:
        return Camera(K=torch.from_numpy(K), R=torch.eye(3, dtype=torch.float64),
                      t=torch.zeros(3, dtype=torch.float64), width=width, height=height,
                      name=name)
    except (TypeError, ValueError) as exc:
        raise SkipFrame(f"{where}: bad K ({exc})", "bad camera") from None


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.size
    except OSError as exc:
        raise SkipFrame(f"{path}: not a readable image ({exc})", "bad image") from None


def freihand_records(config: FreiHandConfig, report: ImportReport, mano_layer=None
                     ) -> Iterator[FrameRecord]:
    """The frame records of a FreiHAND set (see the module docstring)."""
    root, name = Path(config.root), config.set
    intrinsics = _list(root, name, "K", True)
    xyz = _list(root, name, "xyz", True)
    mano = _list(root, name, "mano", False) if mano_layer is not None else None
    verts = _list(root, name, "verts", False) if config.vertices else None
    count_n = len(xyz)
    if len(intrinsics) != count_n:
        raise ValueError(f"{root / (name + '_K.json')}: {len(intrinsics)} entries but "
                         f"{name}_xyz.json has {count_n}")
    xyz_scale = _file_scale(xyz, root / f"{name}_xyz.json", "keypoints", report)
    verts_scale = (1.0 if verts is None else
                   _file_scale(verts, root / f"{name}_verts.json", "vertices", report))
    count = 0
    for index in range(0, count_n, config.every):
        where = f"{root / (name + '_xyz.json')}: sample {index}"
        try:
            keypoints = np.asarray(xyz[index], np.float64) * xyz_scale
            if keypoints.shape != (21, 3) or not np.isfinite(keypoints).all():
                raise SkipFrame(f"{where}: keypoints must be 21 finite [x, y, z]",
                                "invalid joints")
            check_hand_size(keypoints, where)
            params = None
            if mano is not None and index < len(mano):
                params = freihand_mano(mano[index], keypoints[0], mano_layer,
                                       f"{root / (name + '_mano.json')}: sample {index}")
            vertices = None
            if verts is not None and index < len(verts):
                vertices = np.asarray(verts[index], np.float64).reshape(-1, 3) * verts_scale
        except (SkipFrame, TypeError, ValueError) as exc:
            report.skip(exc if isinstance(exc, SkipFrame) else SkipFrame(f"{where}: {exc}",
                                                                          "bad annotation"))
            continue
        versions = config.versions if name == "training" else (0,)
        for version in versions:
            image = root / name / "rgb" / f"{index + version * count_n:08d}.jpg"
            mask = root / name / "mask" / f"{index:08d}.jpg"
            try:
                if not image.is_file():
                    raise SkipFrame(f"{image}: image of an annotated sample is missing",
                                    "missing image")
                width, height = _image_size(image)
                camera = freihand_camera(intrinsics[index], width, height, "cam0", where)
                check_view(camera, keypoints, where)
            except SkipFrame as exc:
                report.skip(exc)
                continue
            yield FrameRecord(
                subject=("FreiHAND", name, index), side="right", keypoints=keypoints,
                cameras=[camera], images={"cam0": image},
                masks={"cam0": mask} if mask.is_file() else {}, mano=params,
                vertices=vertices,
                source={"dataset": "FreiHAND", "set": name, "sample": index,
                        "version": version})
            count += 1
            if config.max_frames and count >= config.max_frames:
                return


def _frame_files(config: FreiHandConfig, layers) -> ExtraFiles:
    """``mano_mesh.npz`` (the dataset's MANO vertices, when read) and the pseudo scan."""
    scan = pseudo_scan_writer(config.skinning_points, layers) if config.skinning_points else None

    def write(paths: FramePaths, record: FrameRecord, frame: dict, rest: np.ndarray) -> None:
        if record.vertices is not None:
            write_npz(paths.root / "mano_mesh.npz", vertices=record.vertices.astype(np.float64))
        if scan is not None:
            scan(paths, record, frame, rest)

    return write


def import_freihand(config: FreiHandConfig, out: str | os.PathLike, *, overwrite: bool = False,
                    progress: bool = True) -> ImportReport:
    """Import a FreiHAND set into ``out`` (see the module docstring) -> :class:`ImportReport`."""
    root = Path(config.root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such FreiHAND folder")
    for key in ("K", "xyz"):
        path = root / f"{config.set}_{key}.json"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing FreiHAND annotation file")
    if Path(out).is_dir() and any(Path(out).iterdir()) and not overwrite:
        prepare_output(Path(out), overwrite)  # raises before reading the dataset
    layers = load_mano_layers(config.mano)
    if layers is not None and "right" not in layers:
        raise FileNotFoundError(f"{config.mano}: FreiHAND needs MANO_RIGHT.pkl")
    layer = None if layers is None else layers["right"]
    report = ImportReport(root=Path(out), dataset="FreiHAND")
    records = list(freihand_records(config, report, layer))
    out = prepare_output(Path(out), overwrite)
    report = write_dataset(out, records, report, split=config.split, config=asdict(config),
                           mano_layers=layers, extra_files=_frame_files(config, layers),
                           progress=progress)
    write_json(out / "import_report.json", report.to_dict())
    return report
