"""``lisa import interhand2.6m``: InterHand2.6M (Moon et al., ECCV 2020) in the package's layout.

What it reads, under ``ROOT`` (the layout of the dataset's release)::

    annotations/{split}/InterHand2.6M_{split}_data.json        COCO-style: "images" (id,
        file_name, width, height, capture, subject, seq_name, camera, frame_idx) and
        "annotations" (image_id, joint_valid [42], hand_type, ...)
    annotations/{split}/InterHand2.6M_{split}_camera.json      {capture: {"campos": {cam: [3]
        mm}, "camrot": {cam: [3, 3]}, "focal": {cam: [2] px}, "princpt": {cam: [2] px}}}
    annotations/{split}/InterHand2.6M_{split}_joint_3d.json    {capture: {frame_idx:
        {"world_coord": [42, 3] mm, "joint_valid": [42], "hand_type", "hand_type_valid"}}}
    annotations/{split}/InterHand2.6M_{split}_MANO_NeuralAnnot.json   optional: {capture:
        {frame_idx: {"right": {"pose", "shape", "trans"} or null, "left": ...}}}
    images/{split}/Capture*/SEQ/cam*/image*.jpg

Conventions it converts: the camera maps world to camera as ``x_cam = camrot (x_world -
campos)`` in millimetres, pixels ``(u, v) = focal * x_cam[:2] / x_cam[2] + princpt`` with
integer pixel centres; the 42 joints are right hand 0-20 then left hand 21-41, each hand per
finger from tip to base (thumb, index, middle, ring, pinky) with the wrist last. The package
keeps metres, OpenPose order and pixel centres at +0.5 (so ``K``'s principal point is
``princpt + 0.5``).

One frame of the package = one hand at one ``(capture, frame_idx)`` with every selected camera
that has its image (multi-view, as LISA trains). Subjects are the dataset's ``subject`` (else
the capture) and hand side; an interacting frame gives one frame per selected hand. Images are
referred to (``sources.json``), never copied.

Bad entries are skipped with one line naming the file and the entry: an image entry with a
missing or malformed field or a ``file_name`` that leaves ``images/{split}`` (absolute, or with
``..``), a view whose ``camrot`` is not a rotation, whose camera is far from the hand (a
``campos`` in the wrong unit) or behind it, a hand that is not hand-sized. An annotation file
that is not the expected JSON object stops the import before anything is written.
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera
from ...utils.io import read_json
from .common import (
    FrameRecord,
    ImportReport,
    SkipFrame,
    check_hand_size,
    check_view,
    dataset_path,
    prepare_output,
    write_dataset,
)
from .mano_params import interhand_mano, load_mano_layers
from .skinning import pseudo_scan_writer

__all__ = ["INTERHAND_TO_OPENPOSE", "InterHandConfig", "import_interhand",
           "interhand_records", "interhand_camera"]

# For each OpenPose keypoint, its index among one hand's 21 InterHand2.6M joints (thumb4..1,
# index4..1, middle4..1, ring4..1, pinky4..1, wrist; 4 = tip, 1 = the finger's root).
INTERHAND_TO_OPENPOSE = (20, 3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12, 19, 18, 17, 16)
_HAND_OFFSET = {"right": 0, "left": 21}
_SPLITS = ("train", "val", "test")
_CAMROT_TOL = 1e-3  # max |R R^T - I| of a camrot rounded in the file (then re-orthonormalised)
_IMAGE_KEYS = ("id", "file_name", "width", "height", "capture", "seq_name", "camera",
               "frame_idx")


@dataclass(frozen=True)
class InterHandConfig:
    """What ``lisa import interhand2.6m`` reads."""

    root: str
    """The dataset folder (holds ``annotations/`` and ``images/``)."""
    split: str = "train"
    """The dataset's split: train, val or test (also the split the subjects go into)."""
    captures: tuple[int, ...] = ()
    """Capture numbers to import (``0`` for Capture0); empty: all."""
    sequences: tuple[str, ...] = ()
    """Sequence names or shell patterns (``ROM*``); empty: all."""
    cameras: tuple[str, ...] = ()
    """Camera ids (``400002``, or ``cam400002``); empty: all."""
    hand: str = "both"
    """Which hands: right, left, or both (an interacting frame then gives two frames)."""
    every: int = 1
    """Keep every Nth annotated frame of each sequence."""
    max_frames: int = 0
    """Stop after this many frames (0: no limit)."""
    masks: str | None = None
    """Folder of hand masks mirroring ``images/{split}`` (same relative paths, .png or .jpg)."""
    mano: str | None = None
    """Folder of the user's MANO_RIGHT.pkl / MANO_LEFT.pkl: poses from the dataset's MANO fits."""
    skinning_points: int = 2000
    """Points of the posed MANO (or template) per frame in scan.npz, with their skinning
    weights: the pseudo ground truth of ``lisa train``'s L_w (0: no scan.npz)."""

    def __post_init__(self) -> None:
        if self.skinning_points < 0:
            raise ValueError(f"skinning_points must be >= 0, got {self.skinning_points}")
        if self.split not in _SPLITS:
            raise ValueError(f"split must be one of {', '.join(_SPLITS)}, got {self.split!r}")
        if self.hand not in ("right", "left", "both"):
            raise ValueError(f"hand must be right, left or both, got {self.hand!r}")
        if isinstance(self.every, bool) or not isinstance(self.every, int) or self.every < 1:
            raise ValueError(f"every must be an integer >= 1, got {self.every!r}")
        if self.max_frames < 0:
            raise ValueError(f"max_frames must be >= 0, got {self.max_frames}")


def _annotation_path(root: Path, split: str, name: str) -> Path:
    return root / "annotations" / split / f"InterHand2.6M_{split}_{name}.json"


def _read_required(root: Path, split: str, name: str) -> Any:
    path = _annotation_path(root, split, name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing InterHand2.6M annotation file (expected "
                                f"annotations/{split}/InterHand2.6M_{split}_{name}.json under "
                                f"{root})")
    return _object(read_json(path), path)


def _object(value: Any, path: Path) -> dict:
    """An annotation file's content, which must be a JSON object (ValueError naming it)."""
    if not isinstance(value, dict):
        raise ValueError(f"{path}: expected a JSON object (keyed by capture), got a "
                         f"{type(value).__name__}")
    return value


def _lookup(mapping: Any, *keys: str) -> Any:
    """``mapping[k0][k1]...``, or None where a level is missing or not an object."""
    for key in keys:
        if not isinstance(mapping, dict):
            return None
        mapping = mapping.get(key)
    return mapping


def _integer(value: Any) -> int:
    """An integer field of a JSON entry (an int, an integral float or a decimal string)."""
    if isinstance(value, bool):
        raise ValueError("a boolean is not an integer")
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, (int, str)):
        return int(value)
    raise ValueError(f"{value!r} is not an integer")


def _image_entry(image: Any, index: int, config: InterHandConfig, data_file: Path
                 ) -> dict[str, Any]:
    """Entry ``index`` of the data file's ``images``, checked: the integer fields, the camera,
    and the image path inside ``images/{split}``; SkipFrame naming the entry otherwise."""
    where = f"{data_file}: images[{index}]"
    if not isinstance(image, dict):
        raise SkipFrame(f"{where}: not an object", "bad image entry")
    missing = [key for key in _IMAGE_KEYS if key not in image]
    if missing:
        raise SkipFrame(f"{where}: no {', '.join(missing)}", "bad image entry")
    try:
        entry = {key: _integer(image[key]) for key in
                 ("id", "capture", "frame_idx", "width", "height")}
    except ValueError:
        raise SkipFrame(f"{where}: id, capture, frame_idx, width and height must be integers",
                        "bad image entry") from None
    subject = image.get("subject", f"Capture{entry['capture']}")
    for key, value in (("camera", image["camera"]), ("seq_name", image["seq_name"]),
                       ("subject", subject)):
        if isinstance(value, bool) or not isinstance(value, (str, int)):
            raise SkipFrame(f"{where}: {key} must be a string or an integer", "bad image entry")
    where = f"{where} (id {entry['id']})"
    images = Path(config.root) / "images" / config.split
    entry.update(camera=str(image["camera"]), seq_name=str(image["seq_name"]), subject=subject,
                 file_name=image["file_name"], where=where,
                 path=dataset_path(images, image["file_name"], where))
    return entry


def interhand_camera(params: dict[str, Any], camera: str, width: int, height: int,
                     where: str) -> Camera:
    """The package camera (metres, pixel centres at +0.5) of camera ``camera`` of a capture's
    entry of ``_camera.json``; :class:`SkipFrame` naming ``where`` when it is missing or bad."""
    try:
        campos = np.asarray(params["campos"][camera], np.float64).reshape(3) * 1e-3
        camrot = np.asarray(params["camrot"][camera], np.float64).reshape(3, 3)
        focal = np.asarray(params["focal"][camera], np.float64).reshape(2)
        princpt = np.asarray(params["princpt"][camera], np.float64).reshape(2)
    except (KeyError, TypeError, ValueError):
        raise SkipFrame(f"{where}: camera {camera} has no complete campos/camrot/focal/princpt",
                        "missing camera") from None
    if not (np.isfinite(camrot).all() and np.isfinite(campos).all()):
        raise SkipFrame(f"{where}: camera {camera} has non-finite values", "bad camera")
    error, det = np.abs(camrot @ camrot.T - np.eye(3)).max(), np.linalg.det(camrot)
    if error > _CAMROT_TOL or det <= 0:
        raise SkipFrame(f"{where}: camera {camera}: camrot is not a rotation (max |R R^T - I| "
                        f"= {error:.3g}, det {det:.3g})", "bad camera")
    if error > 1e-12:  # re-orthonormalise values rounded in the file
        u, _, vt = np.linalg.svd(camrot)
        camrot = u @ vt
    K = np.array([[focal[0], 0.0, princpt[0] + 0.5], [0.0, focal[1], princpt[1] + 0.5],
                  [0.0, 0.0, 1.0]])
    try:
        return Camera(K=torch.from_numpy(K), R=torch.from_numpy(camrot),
                      t=torch.from_numpy(-camrot @ campos), width=int(width),
                      height=int(height), name=f"cam{camera}")
    except (TypeError, ValueError) as exc:
        raise SkipFrame(f"{where}: camera {camera}: {exc}", "bad camera") from None


def _hand_keypoints(world_mm: np.ndarray, valid: np.ndarray, side: str, where: str
                    ) -> np.ndarray:
    """[21, 3] metres, OpenPose order, of one hand of the 42 joints; SkipFrame when invalid."""
    offset = _HAND_OFFSET[side]
    index = [offset + i for i in INTERHAND_TO_OPENPOSE]
    joints = world_mm[index] * 1e-3
    bad = [i for i in range(21) if not valid[index[i]] or not np.isfinite(joints[i]).all()]
    if bad:
        raise SkipFrame(f"{where}: {side} hand has {len(bad)} invalid joint(s) (joint_valid 0)",
                        "invalid joints")
    check_hand_size(joints, f"{where}: {side} hand")
    return joints


def _selected_groups(config: InterHandConfig, data: dict[str, Any], data_file: Path,
                     report: ImportReport) -> dict[tuple[int, str, int], list[dict[str, Any]]]:
    """Checked image entries (:func:`_image_entry`; bad ones skipped in ``report``) grouped by
    (capture, sequence, frame_idx), filtered and subsampled."""
    cameras = {c.removeprefix("cam") for c in config.cameras}
    groups: dict[tuple[int, str, int], list[dict[str, Any]]] = {}
    for index, raw in enumerate(data["images"]):
        try:
            image = _image_entry(raw, index, config, data_file)
        except SkipFrame as exc:
            report.skip(exc)
            continue
        capture, seq = image["capture"], image["seq_name"]
        if config.captures and capture not in config.captures:
            continue
        if config.sequences and not any(fnmatch.fnmatch(seq, p) for p in config.sequences):
            continue
        if cameras and image["camera"] not in cameras:
            continue
        groups.setdefault((capture, seq, image["frame_idx"]), []).append(image)
    by_sequence: dict[tuple[int, str], list[int]] = {}
    for capture, seq, frame in groups:
        by_sequence.setdefault((capture, seq), []).append(frame)
    kept = {(c, s, f) for (c, s), frames in by_sequence.items()
            for f in sorted(frames)[::config.every]}
    return {key: groups[key] for key in sorted(groups) if key in kept}


def _frame_views(config: InterHandConfig, images: list[dict[str, Any]], camera_params: Any,
                 annotations: dict[int, dict], side: str, keypoints: np.ndarray,
                 report: ImportReport
                 ) -> tuple[list[Camera], dict[str, Path], dict[str, Path], dict]:
    """The views of one hand at one instant: cameras, image and mask files, valid keypoints;
    a view that cannot be used is skipped with its line in ``report``."""
    root = Path(config.root)
    camera_file = _annotation_path(root, config.split, "camera")
    cameras, files, masks, visible = [], {}, {}, {}
    for image in sorted(images, key=lambda entry: entry["camera"]):
        path = image["path"]
        try:
            if not path.is_file():
                raise SkipFrame(f"{path}: image of an annotated frame is missing",
                                "missing image")
            where = f"{camera_file}: Capture{image['capture']}"
            camera = interhand_camera(camera_params, image["camera"], image["width"],
                                      image["height"], where)
            check_view(camera, keypoints, where)
            if config.masks is not None:
                relative = path.relative_to(root / "images" / config.split)
                candidates = [Path(config.masks) / relative.with_suffix(s) for s in
                              (".png", ".jpg")]
                found = [c for c in candidates if c.is_file()]
                if not found:
                    raise SkipFrame(f"{candidates[0]}: mask of an annotated image is missing",
                                    "missing mask")
                masks[camera.name] = found[0]
            annotation = annotations.get(image["id"])
            if annotation is not None and "joint_valid" in annotation:
                try:
                    valid = np.asarray(annotation["joint_valid"], np.float64).reshape(42)
                except (TypeError, ValueError):
                    raise SkipFrame(f"{image['where']}: its annotation's joint_valid must be 42 "
                                    "numbers", "bad annotation") from None
                offset = _HAND_OFFSET[side]
                visible[camera.name] = valid[[offset + i for i in INTERHAND_TO_OPENPOSE]] > 0
        except SkipFrame as exc:
            report.skip(exc)
            continue
        cameras.append(camera)
        files[camera.name] = path
    return cameras, files, masks, visible


def _annotations(data: dict[str, Any], data_file: Path, report: ImportReport
                 ) -> dict[int, dict]:
    """The data file's ``annotations`` by ``image_id``; malformed entries skipped and named."""
    entries = data.get("annotations", [])
    if not isinstance(entries, list):
        raise ValueError(f"{data_file}: 'annotations' must be a list")
    annotations = {}
    for index, entry in enumerate(entries):
        try:
            annotations[_integer(entry["image_id"])] = entry
        except (KeyError, TypeError, ValueError):
            report.skip(SkipFrame(f"{data_file}: annotations[{index}]: an object with an "
                                  "integer image_id needed", "bad annotation"))
    return annotations


def interhand_records(config: InterHandConfig, report: ImportReport, mano_sides: set[str]
                      ) -> Iterator[FrameRecord]:
    """The frame records of an InterHand2.6M split (see the module docstring); skipped frames
    are counted in ``report``. ``mano_sides``: the sides with a MANO model (MANO params read)."""
    root = Path(config.root)
    data_file = _annotation_path(root, config.split, "data")
    data = _read_required(root, config.split, "data")
    cameras_json = _read_required(root, config.split, "camera")
    joints_json = _read_required(root, config.split, "joint_3d")
    mano_path = _annotation_path(root, config.split, "MANO_NeuralAnnot")
    mano_json = (_object(read_json(mano_path), mano_path) if mano_sides and mano_path.is_file()
                 else {})
    if not isinstance(data.get("images"), list):
        raise ValueError(f"{data_file}: expected a COCO-style object with 'images' (a list) and "
                         "'annotations'")
    annotations = _annotations(data, data_file, report)
    joints_file = _annotation_path(root, config.split, "joint_3d")
    count = 0
    for (capture, seq, frame_idx), images in _selected_groups(config, data, data_file,
                                                               report).items():
        where = f"{joints_file}: Capture{capture} frame {frame_idx}"
        entry = _lookup(joints_json, str(capture), str(frame_idx))
        try:
            if entry is None:
                raise SkipFrame(f"{where}: no 3D joint annotation for this frame",
                                "missing annotation")
            world = np.asarray(entry["world_coord"], np.float64).reshape(42, 3)
            valid = np.asarray(entry["joint_valid"], np.float64).reshape(42) > 0
        except SkipFrame as exc:
            report.skip(exc)
            continue
        except (KeyError, TypeError, ValueError):
            report.skip(SkipFrame(f"{where}: world_coord [42, 3] and joint_valid [42] needed",
                                  "missing annotation"))
            continue
        fallback = annotations.get(images[0]["id"])
        hand_type = str(entry.get("hand_type", fallback.get("hand_type", "interacting")
                                  if isinstance(fallback, dict) else "interacting"))
        if hand_type == "interacting":
            sides = ["right", "left"]
        elif hand_type in _HAND_OFFSET:
            sides = [hand_type]
        else:  # no usable hand_type: the hands that have valid joints
            sides = [s for s, o in _HAND_OFFSET.items() if valid[o:o + 21].any()]
        for side in [s for s in sides if config.hand in (s, "both")]:
            try:
                keypoints = _hand_keypoints(world, valid, side, where)
                cams, files, masks, visible = _frame_views(
                    config, images, cameras_json.get(str(capture)), annotations, side,
                    keypoints, report)
                if not cams:
                    raise SkipFrame(f"{where}: no view of this frame could be read", "no view")
                mano = None
                if side in mano_sides:
                    mano_entry = _lookup(mano_json, str(capture), str(frame_idx))
                    if isinstance(mano_entry, dict) and mano_entry.get(side) is not None:
                        mano = interhand_mano(mano_entry[side], f"{mano_path}: Capture{capture} "
                                              f"frame {frame_idx} {side}")
            except SkipFrame as exc:
                report.skip(exc)
                continue
            subject = images[0]["subject"]
            yield FrameRecord(
                subject=("InterHand2.6M", subject), side=side, keypoints=keypoints,
                cameras=cams, images=files, masks=masks, visible=visible, mano=mano,
                source={"dataset": "InterHand2.6M", "split": config.split, "capture": capture,
                        "seq_name": seq, "frame_idx": frame_idx, "hand_type": hand_type})
            count += 1
            if config.max_frames and count >= config.max_frames:
                return


def import_interhand(config: InterHandConfig, out: str | os.PathLike, *, overwrite: bool = False,
                     progress: bool = True) -> ImportReport:
    """Import InterHand2.6M into ``out`` (see the module docstring) -> :class:`ImportReport`.

    Raises FileNotFoundError for a missing annotation file, FileExistsError for a non-empty
    ``out`` (unless ``overwrite``), ValueError when no frame could be imported.
    """
    root = Path(config.root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such InterHand2.6M folder")
    for name in ("data", "camera", "joint_3d"):  # fail before writing anything
        path = _annotation_path(root, config.split, name)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing InterHand2.6M annotation file")
    if Path(out).is_dir() and any(Path(out).iterdir()) and not overwrite:
        prepare_output(Path(out), overwrite)  # raises: fail before reading the dataset
    layers = load_mano_layers(config.mano, fix_left_shapedirs=True)  # as InterHand's code
    report = ImportReport(root=Path(out), dataset="InterHand2.6M")
    records = list(interhand_records(config, report, set(layers or {})))
    out = prepare_output(Path(out), overwrite)
    hook = (pseudo_scan_writer(config.skinning_points, layers) if config.skinning_points
            else None)
    return write_dataset(out, records, report, split=config.split, config=asdict(config),
                         mano_layers=layers, extra_files=hook, progress=progress)
