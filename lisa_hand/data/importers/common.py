"""What every importer shares: frame records, skipped-frame accounting, and the writer of the
package's dataset layout (:mod:`lisa_hand.data.layout`) from those records.

An importer turns a dataset's own files into :class:`FrameRecord` s (one hand at one instant:
its 21 3D keypoints in the world frame in metres and OpenPose order, the calibrated views that
show it and the original image files, optionally MANO parameters) and gives them to
:func:`write_dataset`, which

* groups the records by subject (a person and a hand side),
* gives each subject one rest skeleton (``template_rest_joints``): ``J(beta)`` of the user's MANO
  at the subject's median betas when the records carry MANO parameters and a MANO model is
  given, else the median skeleton of inverse kinematics on the template's rest pose
  (:func:`lisa_hand.skeleton.inverse_kinematics.mean_skeleton`),
* gives each frame its pose on that skeleton: MANO's full pose (MANO's tree is ours, so the pose
  carries over as it is), else inverse kinematics of the keypoints with the skeleton fixed,
* writes ``params.json``, ``cameras.json``, ``keypoints.json`` (the keypoints projected into each
  view), ``sources.json`` (the original images and masks, referred to, not copied), then every
  ``subject.json``, ``split.json`` and last ``dataset.json`` (a folder without it is
  unfinished).

Bad input of one frame (:class:`SkipFrame`) skips that frame with one line and a count
(:class:`ImportReport`); nothing half-written is left for it. The checks every importer shares:
a path a data file names stays inside its dataset folder (:func:`dataset_path`), a hand is the
size of a hand (:func:`check_hand_size`), and a view sees the hand from in front at a plausible
distance (:func:`check_view`).
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera, save_cameras
from ...skeleton.inverse_kinematics import inverse_kinematics, mean_skeleton, split_keypoints
from ...skeleton.kinematics import mirror_points, mirror_pose
from ...skeleton.mano import ManoLayer
from ...utils.io import write_json
from ..keypoints import write_keypoints
from ..layout import FORMAT_NAME, FORMAT_VERSION, SOURCES_FILE, FramePaths, prepare_dataset_folder
from ..units import POSSIBLE_DIAGONAL_M, bounding_diagonal

__all__ = [
    "IMPORT_FORMAT_VERSION",
    "SkipFrame",
    "FrameRecord",
    "ManoParams",
    "ImportReport",
    "prepare_output",
    "template_reference",
    "write_dataset",
    "ExtraFiles",
    "subject_folder",
    "MAX_CAMERA_DISTANCE_M",
    "dataset_path",
    "check_hand_size",
    "check_view",
]

IMPORT_FORMAT_VERSION = 1
"""Version of what the importers write (bumped when the files for the same input change)."""
_MAX_MESSAGES = 20  # skipped-frame lines kept in the report (all are counted)
_IK_CHUNK = 4096  # frames per inverse-kinematics batch
_IK_REFINE = 20  # L-BFGS iterations of the pose on the subject's fixed skeleton
MAX_CAMERA_DISTANCE_M = 50.0
"""Farthest a camera that shows a hand may be from it (a capture dome is about 1 m across;
a campos in the wrong unit or a garbage value puts the camera kilometres away)."""


class SkipFrame(ValueError):
    """One frame (or view) of the input cannot be imported: the message names the file and
    the problem; ``reason`` is the short name it is counted under."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass
class ManoParams:
    """MANO parameters of one hand in smplx's convention (see :mod:`.mano_params`).

    global_orient: [3] axis-angle radians. hand_pose: [45] axis-angle radians (not PCA), before
    the mean hand is added. betas: [10]. transl: [3] metres. flat_hand_mean: whether the
    dataset's MANO layer has the mean hand removed (False: the file's ``hands_mean`` is added).
    """

    global_orient: np.ndarray
    hand_pose: np.ndarray
    betas: np.ndarray
    transl: np.ndarray
    flat_hand_mean: bool = False


@dataclass
class FrameRecord:
    """One hand at one instant, as an importer reads it.

    subject: the person (any hashable, e.g. ``("Capture0", 3)``); frames of one subject and side
        share a skeleton. side: 'right' or 'left'.
    keypoints: [21, 3] world metres, OpenPose order (:data:`lisa_hand.skeleton.KEYPOINT_NAMES`).
    cameras: the views, world-to-camera, metres, pixel centres at +0.5 (package convention).
    images: {camera name: original image file}; masks: {camera name: mask file} (may be empty).
    visible: {camera name: [21] bool}: which keypoints the dataset marks valid, or None (all).
    mano: MANO parameters, or None. vertices: [778, 3] metres (the dataset's MANO mesh) or None.
    source: what the frame is in the dataset (written to ``params.json`` as ``"source"``).
    """

    subject: Any
    side: str
    keypoints: np.ndarray
    cameras: list[Camera]
    images: dict[str, Path]
    masks: dict[str, Path] = field(default_factory=dict)
    visible: dict[str, np.ndarray] | None = None
    mano: ManoParams | None = None
    vertices: np.ndarray | None = None
    source: dict[str, Any] = field(default_factory=dict)


@dataclass
class ImportReport:
    """What an import did: counts, skipped frames by reason, the first skip messages."""

    root: Path
    dataset: str
    num_subjects: int = 0
    num_frames: int = 0
    num_views: int = 0
    skipped: Counter = field(default_factory=Counter)
    messages: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    pose_source: Counter = field(default_factory=Counter)
    ik_error_mm: list[float] = field(default_factory=list)
    seconds: float = 0.0

    def skip(self, exc: SkipFrame) -> None:
        """Count a skipped frame (or view) and keep its line (the first ones)."""
        self.skipped[exc.reason] += 1
        if len(self.messages) < _MAX_MESSAGES:
            self.messages.append(str(exc))

    def note(self, message: str) -> None:
        """Keep one line about what the import changed in the input (e.g. a unit converted)."""
        if message not in self.notes and len(self.notes) < _MAX_MESSAGES:
            self.notes.append(message)

    def to_dict(self) -> dict[str, Any]:
        errors = np.asarray(self.ik_error_mm or [np.nan])
        return {
            "dataset": self.dataset, "num_subjects": self.num_subjects,
            "num_frames": self.num_frames, "num_views": self.num_views,
            "skipped": dict(self.skipped), "skip_messages": self.messages,
            "notes": self.notes,
            "pose_source": dict(self.pose_source),
            "ik_error_mm_mean": None if np.isnan(errors).all() else float(np.nanmean(errors)),
            "ik_error_mm_max": None if np.isnan(errors).all() else float(np.nanmax(errors)),
            "seconds": round(self.seconds, 3),
        }

    def describe(self) -> str:
        """A few lines for the command line."""
        lines = [f"imported {self.dataset}: {self.num_frames} frames ({self.num_views} views) of "
                 f"{self.num_subjects} subjects into {self.root} in {self.seconds:.1f} s"]
        info = self.to_dict()
        lines.extend(f"  note: {message}" for message in self.notes[:5])
        if info["ik_error_mm_max"] is not None:
            lines.append(f"  inverse kinematics: keypoints reproduced within "
                         f"{info['ik_error_mm_mean']:.3f} mm on average, "
                         f"{info['ik_error_mm_max']:.3f} mm at most")
        if self.skipped:
            counts = ", ".join(f"{n} {reason}" for reason, n in sorted(self.skipped.items()))
            lines.append(f"  skipped: {counts}")
            lines.extend(f"  skipped: {message}" for message in self.messages[:5])
        return "\n".join(lines)


def prepare_output(out: Path, overwrite: bool) -> Path:
    """Create ``out``; it must be empty unless ``overwrite`` (which removes a previous
    dataset's subject folders and dataset files only):
    :func:`lisa_hand.data.layout.prepare_dataset_folder`."""
    return prepare_dataset_folder(out, overwrite)


def template_reference() -> torch.Tensor:
    """[21, 3] float64 metres: the shipped template's rest keypoints (mean shape, zero pose, a
    right hand in MANO's axes): the reference of the inverse kinematics."""
    from ...handmodel.template import load_template

    template = load_template().to(dtype=torch.float64)
    zero = torch.zeros(1, 48, dtype=torch.float64)
    return template(zero, torch.zeros(1, template.num_betas, dtype=torch.float64)).keypoints[0]


def subject_folder(index: int, count: int = 1000) -> str:
    """Subject folder name ``index`` of ``count``: ``s000``, ... (wider when count > 1000)."""
    return f"s{index:0{max(3, len(str(count - 1)))}d}"


def dataset_path(base: Path, relative: Any, where: str) -> Path:
    """``base / relative`` for a path that a data file names (``file_name``).

    A data file may only name files inside its dataset folder: a path that is not a non-empty
    string, is absolute (``/etc/passwd``, ``C:\\x``) or has a ``..`` part is a
    :class:`SkipFrame` naming ``where`` (the file and entry). The check is on the path as
    written: symbolic links the user made inside the folder are followed as usual.
    """
    if not isinstance(relative, str) or not relative.strip():
        raise SkipFrame(f"{where}: file_name must be a non-empty relative path, got "
                        f"{relative!r}", "bad path")
    posix = PurePosixPath(relative.replace("\\", "/"))
    if (posix.is_absolute() or ".." in posix.parts or PureWindowsPath(relative).drive
            or relative.startswith("~")):
        raise SkipFrame(f"{where}: file_name {relative!r} leaves the dataset folder {base} "
                        "(absolute, or with '..'): refused", "bad path")
    return base / posix


def check_hand_size(keypoints_m: np.ndarray, where: str) -> None:
    """SkipFrame naming ``where`` unless the 21 keypoints [21, 3] metres span a possible hand
    (bounding-box diagonal within :data:`lisa_hand.data.units.POSSIBLE_DIAGONAL_M`)."""
    diagonal = bounding_diagonal(keypoints_m)
    low, high = POSSIBLE_DIAGONAL_M
    if not low <= diagonal <= high:
        raise SkipFrame(f"{where}: the hand's keypoints span {diagonal:.4g} m, not a hand "
                        f"({low:g}-{high:g} m; wrong unit?)", "invalid joints")


def check_view(camera: Camera, keypoints_m: np.ndarray, where: str) -> None:
    """SkipFrame naming ``where`` and the camera unless every keypoint [21, 3] (world, metres)
    is in front of ``camera`` and the camera is at most :data:`MAX_CAMERA_DISTANCE_M` from
    the hand."""
    points = torch.as_tensor(keypoints_m, dtype=torch.float64)
    camera = camera.to(dtype=torch.float64)
    depth = points @ camera.R[2] + camera.t[2]
    behind = int((depth <= 0).sum())
    if behind:
        raise SkipFrame(f"{where}: camera {camera.name}: {behind} of 21 keypoints are behind "
                        "the camera (depth <= 0)", "bad camera")
    centre = -camera.R.T @ camera.t
    distance = float(torch.linalg.norm(points.mean(0) - centre))
    if not distance <= MAX_CAMERA_DISTANCE_M:
        raise SkipFrame(f"{where}: camera {camera.name} is {distance:.4g} m from the hand "
                        f"(at most {MAX_CAMERA_DISTANCE_M:g} m is plausible; wrong unit?)",
                        "bad camera")


def _right_handed(points: np.ndarray, side: str) -> torch.Tensor:
    tensor = torch.as_tensor(points, dtype=torch.float64)
    return mirror_points(tensor) if side == "left" else tensor


def _mano_hands(records: Sequence[FrameRecord], layer: ManoLayer) -> dict[str, torch.Tensor]:
    """Posed MANO of records (all with MANO params, one side) -> full pose, rest joints,
    joints, vertices (metres, float64)."""
    def stack(name: str) -> torch.Tensor:
        return torch.as_tensor(np.stack([getattr(r.mano, name) for r in records]),
                               dtype=layer.dtype)

    if layer.flat_hand_mean or layer.use_pca:
        raise ValueError("the MANO layer of an import must have use_pca=False and "
                         "flat_hand_mean=False")
    hand_pose = stack("hand_pose")
    flat = torch.tensor([r.mano.flat_hand_mean for r in records])[:, None]
    # The layer adds the file's mean hand: take it off the poses that exclude it already.
    hand_pose = torch.where(flat, hand_pose - layer.hand_mean, hand_pose)
    output = layer(hand_pose=hand_pose, global_orient=stack("global_orient"),
                   betas=stack("betas"), transl=stack("transl"))
    return {"full_pose": output.full_pose, "rest_joints": output.rest_joints,
            "joints": output.joints, "vertices": output.vertices, "betas": stack("betas")}


def _subject_poses(records: list[FrameRecord], side: str, reference: torch.Tensor,
                   mano: ManoLayer | None, report: ImportReport
                   ) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """One subject's skeleton ``[16, 3]`` and per frame ``{pose, translation, ...}``."""
    if mano is not None and all(r.mano is not None for r in records):
        hands = _mano_hands(records, mano)
        betas = hands["betas"].median(dim=0).values[None]
        rest = mano(betas=betas).rest_joints[0].double()
        wrist = hands["joints"][:, 0].double()
        frames = []
        for i in range(len(records)):
            frames.append({"pose": hands["full_pose"][i].double().numpy(),
                           "translation": (wrist[i] - rest[0]).numpy(),
                           "pose_source": "mano",
                           "mano_betas": hands["betas"][i].double().numpy()})
            report.pose_source["mano"] += 1
        return rest.numpy(), frames
    keypoints = torch.stack([_right_handed(r.keypoints, side) for r in records])
    skeleton = mean_skeleton(keypoints, reference)
    chunks = [inverse_kinematics(keypoints[start:start + _IK_CHUNK], skeleton,
                                 fit_skeleton=False, refine=_IK_REFINE)
              for start in range(0, len(records), _IK_CHUNK)]
    poses = torch.cat([chunk.pose for chunk in chunks])
    translations = torch.cat([chunk.translation for chunk in chunks])
    max_errors = torch.cat([chunk.max_error for chunk in chunks])
    rest_joints, rest_tips = split_keypoints(skeleton)
    frames = []
    for i in range(len(records)):
        pose = poses[i]
        translation = translations[i]
        if side == "left":
            pose, translation = mirror_pose(pose), mirror_points(translation)
        error = float(max_errors[i]) * 1e3
        report.ik_error_mm.append(error)
        report.pose_source["inverse_kinematics"] += 1
        frames.append({"pose": pose.numpy(), "translation": translation.numpy(),
                       "pose_source": "inverse_kinematics", "ik_error_mm": error})
    rest = mirror_points(rest_joints) if side == "left" else rest_joints
    tips = mirror_points(rest_tips) if side == "left" else rest_tips
    frames[0]["rest_fingertips"] = tips.numpy()
    return rest.numpy(), frames


def _view_keypoints(record: FrameRecord) -> dict[str, dict[str, np.ndarray]]:
    """The keypoints projected into every view: pixels, visible (valid, in front, in image)."""
    views = {}
    points = torch.as_tensor(record.keypoints, dtype=torch.float64)
    for camera in record.cameras:
        pixels, depth = camera.to(dtype=torch.float64).project(points)
        pixels, depth = pixels.numpy(), depth.numpy()
        in_image = ((depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width)
                    & (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height))
        valid = np.ones(21, bool) if record.visible is None else np.asarray(
            record.visible.get(camera.name, np.ones(21, bool)), bool)
        views[camera.name] = {"keypoints": np.where(np.isfinite(pixels), pixels, 0.0),
                              "visible": valid & in_image, "in_image": in_image, "depth": depth}
    return views


def _relative(path: Path, start: Path) -> str:
    """``path`` relative to ``start`` when both are on one drive, else absolute."""
    try:
        return os.path.relpath(Path(path).resolve(), start.resolve())
    except ValueError:
        return str(Path(path).resolve())


ExtraFiles = Callable[[FramePaths, FrameRecord, dict[str, Any], np.ndarray], None]
"""``extra_files(paths, record, frame, rest_joints)``: more files for a frame folder; ``frame``
holds its ``pose`` [48] and ``translation`` [3], ``rest_joints`` [16, 3] is its subject's."""


def _write_frame(folder: Path, record: FrameRecord, frame: dict[str, Any], rest: np.ndarray,
                 extra_files: ExtraFiles | None) -> None:
    """The files of one frame (``dataset.json`` of the dataset is what marks completion)."""
    paths = FramePaths(folder)
    folder.mkdir(parents=True, exist_ok=True)
    joints, _ = split_keypoints(torch.as_tensor(record.keypoints))
    params = {
        "pose": frame["pose"].tolist(), "translation": frame["translation"].tolist(),
        "joints": joints.tolist(), "keypoints": np.asarray(record.keypoints).tolist(),
        "side": record.side, "pose_name": None, "pose_source": frame["pose_source"],
        "source": record.source,
    }
    for key in ("ik_error_mm",):
        if key in frame:
            params[key] = frame[key]
    if "mano_betas" in frame:
        params["mano_betas"] = frame["mano_betas"].tolist()
    if record.mano is not None:
        params["mano"] = {name: np.asarray(getattr(record.mano, name)).tolist() for name in
                          ("global_orient", "hand_pose", "betas", "transl")}
        params["mano"]["flat_hand_mean"] = record.mano.flat_hand_mean
    save_cameras(paths.cameras, record.cameras)
    write_keypoints(paths.keypoints, _view_keypoints(record))
    write_json(folder / SOURCES_FILE, {
        "images": {name: _relative(p, folder) for name, p in record.images.items()},
        "masks": {name: _relative(p, folder) for name, p in record.masks.items()},
    })
    if extra_files is not None:
        extra_files(paths, record, frame, rest)
    write_json(paths.params, params)


def write_dataset(
    out: Path,
    records: Iterable[FrameRecord],
    report: ImportReport,
    *,
    split: str,
    config: dict[str, Any],
    mano_layers: dict[str, ManoLayer] | None = None,
    extra_files: ExtraFiles | None = None,
    progress: bool = True,
) -> ImportReport:
    """Write ``records`` in the package's layout into ``out`` (already prepared, see
    :func:`prepare_output`); see the module docstring.

    split: the split ('train', 'val' or 'test') every subject goes into.
    config: the importer's resolved settings (written to ``dataset.json``).
    mano_layers: {'right': ManoLayer, 'left': ...} of the user's MANO, float64, or None.
    extra_files: called per frame to write more files into its folder (e.g. ``scan.npz``),
        see :data:`ExtraFiles`.
    """
    from tqdm.auto import tqdm

    start = time.perf_counter()
    groups: dict[tuple[Any, str], list[FrameRecord]] = {}
    for record in records:
        groups.setdefault((record.subject, record.side), []).append(record)
    if not groups:
        first = f"; the first: {report.messages[0]}" if report.messages else ""
        raise ValueError(f"{report.dataset}: no frame could be imported "
                         f"({', '.join(f'{n} {r}' for r, n in report.skipped.items()) or 'none'}"
                         f" skipped); nothing written{first}")
    reference = template_reference()
    subject_ids = []
    bar = tqdm(total=sum(len(v) for v in groups.values()), desc="import", unit="frame",
               disable=not progress, dynamic_ncols=True)
    for index, ((subject, side), subject_records) in enumerate(groups.items()):
        name = subject_folder(index, len(groups))
        layer = None if mano_layers is None else mano_layers.get(side)
        rest, frames = _subject_poses(subject_records, side, reference, layer, report)
        width = max(3, len(str(len(subject_records) - 1)))
        for number, (record, frame) in enumerate(zip(subject_records, frames, strict=True)):
            _write_frame(out / name / f"f{number:0{width}d}", record, frame, rest, extra_files)
            report.num_views += len(record.cameras)
            bar.update(1)
        subject_json = {"id": name, "side": side, "template_rest_joints": rest.tolist(),
                        "source": _jsonable(subject), "num_frames": len(subject_records),
                        "skeleton": frames[0]["pose_source"]}
        if "rest_fingertips" in frames[0]:
            subject_json["template_rest_fingertips"] = frames[0]["rest_fingertips"].tolist()
        write_json(out / name / "subject.json", subject_json)
        subject_ids.append(name)
        report.num_frames += len(subject_records)
    bar.close()
    report.num_subjects = len(subject_ids)
    splits = {key: (sorted(subject_ids) if key == split else []) for key in
              ("train", "val", "test")}
    write_json(out / "split.json", splits)
    report.seconds += time.perf_counter() - start
    write_json(out / "import_report.json", report.to_dict())
    write_json(out / "dataset.json", {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "generator": report.dataset,
        "importer_version": IMPORT_FORMAT_VERSION, "config": config,
        "num_subjects": report.num_subjects, "num_frames": report.num_frames,
        "num_views": report.num_views, "split_counts": {k: len(v) for k, v in splits.items()},
    })
    return report


def _jsonable(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
