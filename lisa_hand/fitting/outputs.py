"""What a fit writes: ``params.json``, ``mesh.ply`` and ``metrics.json``, all or nothing.

Shared by the fitting commands (``lisa fit-points`` and ``lisa fit-images``):

* :func:`check_output_folder` fails before a long fit when ``--out`` cannot be written;
* :func:`read_ground_truth` reads a ``--gt`` mesh or point set (errors name the file) and
  :func:`ground_truth_metrics` gives the paper's four distances (V2V and V2S, both ways, mm);
* :func:`write_fit_outputs` writes the files into a hidden folder beside ``out_dir`` and moves
  them in only once all exist, so that a failure leaves nothing half-written.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.meshing import Mesh
from ..skeleton.params import HandParams

__all__ = [
    "GroundTruth",
    "check_output_folder",
    "read_ground_truth",
    "ground_truth_metrics",
    "json_safe",
    "write_fit_outputs",
]

_MM_TO_M = 1e-3


@dataclass
class GroundTruth:
    """A ground-truth surface for the metrics.

    vertices: [V, 3] float64 metres. faces: [F, 3] int64, or None for a point set.
    unit: the unit the file was read in ("m" or "mm"). note: a sentence when the unit was
    guessed as millimetres, else None. path: the file.
    """

    vertices: np.ndarray
    faces: np.ndarray | None
    unit: str
    note: str | None
    path: Path


def check_output_folder(out: str | os.PathLike) -> Path:
    """Fail before a (long) fit when ``out`` cannot become a writable folder.

    Raises NotADirectoryError when ``out`` is a file and PermissionError when its nearest
    existing ancestor is not a writable folder. Creates nothing.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: --out must be a folder, and this is a file")
    existing = out
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(f"{out}: cannot write here ({existing} is not a writable folder)")
    return out


def read_ground_truth(path: str | os.PathLike, units: str = "auto") -> GroundTruth:
    """Read a ground-truth mesh or point set (:func:`lisa_hand.metrics.load_mesh`) in metres.

    units: "m", "mm" or "auto" (:func:`lisa_hand.metrics.detect_length_unit`: over 2 units
    across is millimetres). With "m", a file that looks like millimetres is an error.
    """
    from ..metrics import detect_length_unit, load_mesh

    if units not in ("auto", "m", "mm"):
        raise ValueError(f"units must be 'auto', 'm' or 'mm', got {units!r}")
    path = Path(path)
    data = load_mesh(path)
    detected = detect_length_unit(data.vertices)
    unit = detected if units == "auto" else units
    if units == "m" and detected == "mm":
        raise ValueError(f"{path}: the ground truth looks like millimetres (over 2 units "
                         "across); pass --units mm or convert it")
    note = None
    if unit == "mm" and units == "auto":
        note = f"{path}: ground truth over 2 units across, read as millimetres"
    scale = _MM_TO_M if unit == "mm" else 1.0
    return GroundTruth(vertices=np.asarray(data.vertices, dtype=np.float64) * scale,
                       faces=data.faces, unit=unit, note=note, path=path)


def prepare_fit(
    out_dir: str | os.PathLike, gt_path: str | os.PathLike | None, units: str,
    model_path: str | os.PathLike | None, device: str, log,
) -> tuple[GroundTruth | None, Any]:
    """What both fit commands check before fitting, in this order so that bad input fails
    before the slow part: the ground truth (``gt_path``, its unit note logged), the output
    folder, then the model (:func:`lisa_hand.trained.load_trained` on ``device``).
    -> (the ground truth or None, the :class:`~lisa_hand.trained.TrainedModel`)."""
    from ..model.trained import load_trained
    from ..utils.device import resolve_device

    truth = None
    if gt_path is not None:
        truth = read_ground_truth(gt_path, units)
        if truth.note is not None:
            log(truth.note)
    check_output_folder(out_dir)
    return truth, load_trained(model_path, resolve_device(device))


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) replaced by None, recursively (JSON has
    no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


def ground_truth_metrics(mesh: Mesh, truth: GroundTruth) -> dict[str, float | None]:
    """V2V and V2S distances (mm) between a fitted mesh and the ground truth, both ways
    (:func:`lisa_hand.metrics.mesh_distances`; None where undefined: V2S towards points)."""
    from ..metrics import mesh_distances

    distances = mesh_distances(mesh.vertices, mesh.faces, truth.vertices, truth.faces)
    return json_safe(distances.to_dict())


def write_fit_outputs(
    out_dir: str | os.PathLike,
    params: HandParams,
    mesh: Mesh,
    metrics: dict[str, Any] | None = None,
) -> list[Path]:
    """Write ``params.json``, ``mesh.ply`` and (when ``metrics`` is given) ``metrics.json`` into
    ``out_dir`` (created), all or nothing.

    The files go into a hidden staging folder beside ``out_dir`` first and are moved in once
    all exist; files of an earlier run with other names are left alone.
    -> the written paths, in that order.
    """
    from ..data.meshio import save_mesh
    from ..skeleton.params import write_params
    from ..utils.io import write_json

    out_dir = check_output_folder(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        files = [write_params(staging / "params.json", params),
                 save_mesh(staging / "mesh.ply", mesh)]
        if metrics is not None:
            files.append(write_json(staging / "metrics.json", json_safe(metrics)))
        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        for file in files:
            target = out_dir / file.name
            os.replace(file, target)
            written.append(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return written
