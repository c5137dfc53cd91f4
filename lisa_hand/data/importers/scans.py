"""``lisa import scans``: a folder of hand scans for the geometric prior (``lisa train-prior``).

What it reads::

    DIR/PERSON/NAME.ply|.obj|.glb     a scan mesh (faces) or a point cloud (a PLY without faces,
                                      normals ``nx ny nz`` used when present); one subfolder per
                                      person (files directly in DIR: one person each)
    DIR/PERSON/NAME.mano.json         optional: {"pose": [48], "shape": [10], "trans": [3]}
                                      (smplx's MANO, flat_hand_mean=False, metres) and
                                      optionally "side"
    DIR/PERSON/NAME.keypoints3d.json  optional: {"keypoints": [21, 3] OpenPose order, in the
                                      scan's units, "side": "right"|"left"}

Per scan, ``scan.npz``: ``points`` / ``normals`` (uniform surface samples of a mesh; the cloud's
points), ``template_weights`` (skinning pseudo ground truth, :mod:`.skinning`: the weights of the
nearest vertex of the posed user's MANO when ``--mano`` and MANO parameters are given, else of
the posed MANO-like template), ``sdf_points`` / ``sdf`` (exact distances to a mesh; for a cloud,
points offset along the normals by at most 2 mm with the offset as distance, an approximation).
A scan without MANO parameters or 3D keypoints gets its keypoints from ``keypoints_fn`` when
one is given (``lisa import scans`` passes the point-cloud fit of ``lisa fit-points``,
:func:`lisa_hand.fitting.points.fit.fit_points`, and its fitted 21 keypoints: the pose search
lives in ``lisa_hand.fitting``, above this layer); without one it is skipped and counted. Such a
scan's side is ``config.side``.

A scan's keypoints must lie on it: within :data:`KEYPOINT_MAX_DISTANCE_M` of its nearest
point, read in the scan's units. Keypoints that lie on it only in the unit their own size says
(millimetre keypoints beside a mesh in metres) are converted with a note; keypoints that lie on
it in no unit (another scan's, or shifted) are skipped with their line.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...skeleton.kinematics import check_side
from ...skeleton.mano import ManoLayer
from ...utils.io import read_json
from ..layout import FramePaths, write_npz
from ..meshio import MESH_SUFFIXES, load_mesh, read_ply_vertices
from ..units import (
    LENGTH_UNITS,
    POSSIBLE_DIAGONAL_M,
    UNIT_NAMES,
    bounding_diagonal,
    decide_length_unit,
    detect_length_unit,
)
from .common import FrameRecord, ImportReport, SkipFrame, prepare_output, write_dataset
from .mano_params import interhand_mano, load_mano_layers
from .skinning import skinning_pseudo_ground_truth

__all__ = ["ScanImportConfig", "KeypointsFn", "import_scans", "scan_records",
           "KEYPOINT_MAX_DISTANCE_M"]

_CLOUD_SDF_SIGMA_M = 0.002
KEYPOINT_MAX_DISTANCE_M = 0.05
"""Farthest a scan's keypoint may lie from the scan's nearest point (or vertex): joints are
inside the hand, at most about 2 cm under its skin, plus the gaps of a partial scan."""


@dataclass(frozen=True)
class ScanImportConfig:
    """What ``lisa import scans`` reads."""

    root: str
    """The folder of scans (one subfolder per person)."""
    units: str = "auto"
    """Length unit of the scan files: m, cm, mm, or auto (from the size)."""
    num_points: int = 20000
    """Surface points per scan in scan.npz."""
    num_sdf_samples: int = 20000
    """Near-surface SDF samples per scan."""
    split: str = "train"
    """The split the subjects go into."""
    mano: str | None = None
    """Folder of the user's MANO models (pose and skinning pseudo ground truth from MANO)."""
    seed: int = 0
    """Seed of the surface and SDF sampling."""
    side: str = "right"
    """The side of scans whose files do not say it (no keypoints or MANO file)."""


KeypointsFn = Callable[[np.ndarray, "np.ndarray | None", str], np.ndarray]
"""(points [N, 3] metres, normals [N, 3] or None, side) -> the scan's 21 keypoints [21, 3]
metres (OpenPose order): the pose search of scans without annotations."""


def _scan_files(root: Path) -> list[tuple[str, Path]]:
    """(person, scan file) of every scan under ``root``, sorted."""
    found = []
    for path in sorted(root.rglob("*")):
        if path.suffix.lower() in MESH_SUFFIXES and path.is_file():
            person = path.parent.name if path.parent != root else path.stem
            found.append((person, path))
    return found


def _read_geometry(path: Path, units: str) -> dict[str, Any]:
    """Vertices (metres), faces (or None) and normals (or None) of a scan file."""
    try:
        mesh = load_mesh(path)
        vertices = np.asarray(mesh.vertices, np.float64)
        faces = np.asarray(mesh.faces, np.int64) if len(mesh.faces) else None
    except ValueError:
        if path.suffix.lower() != ".ply":
            raise
        vertices, faces = None, None
    normals = None
    if faces is None and path.suffix.lower() == ".ply":
        table = read_ply_vertices(path)
        vertices = np.stack([table[k] for k in ("x", "y", "z")], -1).astype(np.float64)
        if all(k in table.dtype.names for k in ("nx", "ny", "nz")):
            normals = np.stack([table[k] for k in ("nx", "ny", "nz")], -1).astype(np.float64)
            normals /= np.linalg.norm(normals, axis=1, keepdims=True).clip(1e-12)
    unit = decide_length_unit(vertices, units, name=str(path), what="the scan")
    return {"vertices": vertices * unit.metres_per_unit, "faces": faces, "normals": normals,
            "scale": unit.metres_per_unit}


def _searched_keypoints(geometry: dict[str, Any], side: str, keypoints_fn: KeypointsFn,
                        seed: int) -> np.ndarray:
    """The keypoints ``keypoints_fn`` finds on a scan (a mesh: 20,000 surface samples)."""
    from ..scans import sample_surface

    points, normals = geometry["vertices"], geometry["normals"]
    if geometry["faces"] is not None:
        samples = sample_surface(points, geometry["faces"], 20000, seed)
        points, normals = samples.points, samples.normals
    keypoints = np.asarray(keypoints_fn(points, normals, side), np.float64)
    if keypoints.shape != (21, 3) or not np.isfinite(keypoints).all():
        raise ValueError(f"the pose search gave keypoints of shape {keypoints.shape}")
    return keypoints


def _read_object(path: Path) -> dict[str, Any]:
    data = read_json(path)
    if not isinstance(data, dict):
        raise SkipFrame(f"{path}: expected a JSON object, got a {type(data).__name__}",
                        "bad input")
    return data


def _scan_keypoints(data: dict[str, Any], geometry: dict[str, Any], path: Path,
                    scan: Path, report: ImportReport) -> np.ndarray:
    """The 21 keypoints [21, 3] metres of a ``NAME.keypoints3d.json`` (``path``) of ``scan``:
    in the scan's units, else in the unit their own size says when that puts them on the scan
    (with a note); SkipFrame naming the file when they are malformed or lie off the scan."""
    if "keypoints" not in data:
        raise SkipFrame(f"{path}: no 'keypoints'", "bad input")
    try:
        keypoints = np.asarray(data["keypoints"], np.float64).reshape(21, 3)
    except (TypeError, ValueError):
        raise SkipFrame(f"{path}: 'keypoints' must be 21 [x, y, z]", "bad input") from None
    if not np.isfinite(keypoints).all():
        raise SkipFrame(f"{path}: 'keypoints' has non-finite values", "bad input")
    from scipy.spatial import cKDTree

    tree = cKDTree(geometry["vertices"])
    scales = [geometry["scale"]]
    own = detect_length_unit(keypoints)
    if own is not None and LENGTH_UNITS[own] != geometry["scale"]:
        scales.append(LENGTH_UNITS[own])
    low, high = POSSIBLE_DIAGONAL_M
    distances = []
    for scale in scales:
        scaled = keypoints * scale
        distance = float(tree.query(scaled)[0].max())
        distances.append(distance)
        if distance <= KEYPOINT_MAX_DISTANCE_M and low <= bounding_diagonal(scaled) <= high:
            if scale != geometry["scale"]:
                report.note(f"{path}: the keypoints are in {UNIT_NAMES[own]}, not in the "
                            f"scan's units (the keypoints3d.json convention): converted")
            return scaled
    raise SkipFrame(f"{path}: the keypoints lie up to {distances[0] * 100:.3g} cm from the scan "
                    f"{scan.name} (in its units; at most {KEYPOINT_MAX_DISTANCE_M * 100:g} cm): "
                    "they are not this scan's", "keypoints off the scan")


def scan_records(config: ScanImportConfig, report: ImportReport, mano_sides: set[str],
                 keypoints_fn: KeypointsFn | None = None) -> Iterator[FrameRecord]:
    """The records of a scan folder (geometry is read again when scan.npz is written);
    ``keypoints_fn``: the pose search of scans without annotations (module docstring)."""
    root = Path(config.root)
    for person, path in _scan_files(root):
        stem = path.with_suffix("")
        try:
            mano_file, keypoint_file = Path(f"{stem}.mano.json"), Path(f"{stem}.keypoints3d.json")
            mano, keypoints, side = None, None, check_side(config.side)
            if keypoint_file.is_file():
                data = _read_object(keypoint_file)
                side = check_side(str(data.get("side", side)))
                keypoints = _scan_keypoints(data, _read_geometry(path, config.units),
                                            keypoint_file, path, report)
            if mano_file.is_file() and mano_sides:
                data = _read_object(mano_file)
                side = check_side(str(data.get("side", side)))
                if side in mano_sides:
                    mano = interhand_mano(data, str(mano_file))
            if keypoints is None and mano is None and keypoints_fn is None:
                raise SkipFrame(f"{path}: no {stem.name}.keypoints3d.json (or .mano.json with "
                                "--mano): its pose is unknown", "no pose")
            geometry = _read_geometry(path, config.units)
            if geometry["faces"] is None and geometry["normals"] is None:
                raise SkipFrame(f"{path}: a point cloud needs normals (nx ny nz)", "no normals")
            if keypoints is None and mano is None:
                keypoints = _searched_keypoints(geometry, side, keypoints_fn, config.seed)
        except SkipFrame as exc:
            report.skip(exc)
            continue
        except (KeyError, TypeError, ValueError) as exc:
            report.skip(SkipFrame(f"{path}: {exc}", "bad input"))
            continue
        yield FrameRecord(subject=("scans", person), side=side,
                          keypoints=keypoints if keypoints is not None else np.zeros((21, 3)),
                          cameras=[], images={}, mano=mano,
                          source={"dataset": "scans", "file": str(path), "person": person})


def _scan_writer(config: ScanImportConfig, layers: dict[str, ManoLayer] | None):
    from ..scans import sample_surface, sdf_samples

    def write(paths: FramePaths, record: FrameRecord, frame: dict, rest: np.ndarray) -> None:
        geometry = _read_geometry(Path(record.source["file"]), config.units)
        rng = np.random.default_rng(config.seed)
        if geometry["faces"] is not None:
            surface = sample_surface(geometry["vertices"], geometry["faces"], config.num_points,
                                     rng)
            points, normals = np.asarray(surface.points), np.asarray(surface.normals)
            sdf = sdf_samples((geometry["vertices"], geometry["faces"]), points, normals,
                              config.num_sdf_samples, sigma=(0.0025, 0.01), generator=rng)
            sdf_points, sdf_values = sdf.points, sdf.sdf
        else:
            if geometry["normals"] is None:
                raise ValueError(f"{record.source['file']}: a point cloud needs normals "
                                 "(nx ny nz) for scan.npz")
            keep = rng.permutation(len(geometry["vertices"]))[:config.num_points]
            points, normals = geometry["vertices"][keep], geometry["normals"][keep]
            pick = rng.integers(0, len(points), config.num_sdf_samples)
            offset = rng.uniform(-_CLOUD_SDF_SIGMA_M, _CLOUD_SDF_SIGMA_M, config.num_sdf_samples)
            sdf_points = points[pick] + offset[:, None] * normals[pick]
            sdf_values = offset
        layer = None if layers is None else layers.get(record.side)
        mano = (layer, record.mano) if layer is not None and record.mano is not None else None
        weights = skinning_pseudo_ground_truth(points, frame["pose"], frame["translation"],
                                               rest, record.side, mano)
        write_npz(paths.scan, points=points.astype(np.float32),
                  normals=normals.astype(np.float32),
                  template_weights=weights.astype(np.float32),
                  sdf_points=np.asarray(sdf_points, np.float32),
                  sdf=np.asarray(sdf_values, np.float32))

    return write


def _mano_keypoints(records: list[FrameRecord], layers: dict[str, ManoLayer]) -> None:
    """Records posed by MANO get MANO's keypoints (joints and fingertip vertices)."""
    for record in records:
        if record.mano is None:
            continue
        layer, params = layers[record.side], record.mano
        out = layer(hand_pose=torch.as_tensor(params.hand_pose[None], dtype=layer.dtype),
                    global_orient=torch.as_tensor(params.global_orient[None], dtype=layer.dtype),
                    betas=torch.as_tensor(params.betas[None], dtype=layer.dtype),
                    transl=torch.as_tensor(params.transl[None], dtype=layer.dtype))
        record.keypoints = out.keypoints[0].double().numpy()


def import_scans(config: ScanImportConfig, out: str | os.PathLike, *, overwrite: bool = False,
                 progress: bool = True, keypoints_fn: KeypointsFn | None = None
                 ) -> ImportReport:
    """Import a folder of scans into ``out`` (see the module docstring; ``keypoints_fn``: the
    pose search of scans without keypoints or MANO parameters, None to skip them)."""
    root = Path(config.root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder of scans")
    if Path(out).is_dir() and any(Path(out).iterdir()) and not overwrite:
        prepare_output(Path(out), overwrite)  # raises before reading the scans
    layers = load_mano_layers(config.mano)
    report = ImportReport(root=Path(out), dataset="scans")
    records = list(scan_records(config, report, set(layers or {}), keypoints_fn))
    if layers:
        _mano_keypoints(records, layers)
    out = prepare_output(Path(out), overwrite)
    return write_dataset(out, records, report, split=config.split, config=asdict(config),
                         mano_layers=layers, extra_files=_scan_writer(config, layers),
                         progress=progress)
