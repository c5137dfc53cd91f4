"""A fit's ground truth (``--gt``): read in the unit of a hand's size (:func:`read_ground_truth`)
and compared with the fitted mesh (:func:`ground_truth_metrics`: the paper's four distances, V2V
and V2S both ways, mm, for ``metrics.json``); and what the point and image fits check before
their work (:func:`prepare_fit`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...data.units import UNIT_CHOICES, decide_length_unit
from ...geometry.meshing import Mesh
from .folder import claim_output_folder
from .records import json_safe

__all__ = ["GroundTruth", "read_ground_truth", "ground_truth_metrics", "prepare_fit"]


@dataclass
class GroundTruth:
    """A ground-truth surface for the metrics.

    vertices: [V, 3] float64 metres. faces: [F, 3] int64, or None for a point set.
    unit: the unit the file was read in ("m", "cm" or "mm"). note: a sentence naming the file
    when the unit was guessed as other than metres, else None. path: the file.
    """

    vertices: np.ndarray
    faces: np.ndarray | None
    unit: str
    note: str | None
    path: Path


def read_ground_truth(path: str | os.PathLike, units: str = "auto") -> GroundTruth:
    """Read a ground-truth mesh or point set (:func:`lisa_hand.metrics.load_mesh`) in metres.

    units: "m", "cm", "mm" or "auto" (:func:`lisa_hand.data.units.decide_length_unit`: the
    unit in which the file is a hand's size; a given unit that makes no hand is an error naming
    the ``--units`` that fits).
    """
    from ...metrics import load_mesh

    if units not in UNIT_CHOICES:
        raise ValueError(f"units must be one of {', '.join(UNIT_CHOICES)}, got {units!r}")
    path = Path(path)
    data = load_mesh(path)
    length = decide_length_unit(data.vertices, units, name=str(path), what="the ground truth")
    note = None if length.note is None else f"{path}: {length.note}"
    vertices = np.asarray(data.vertices, dtype=np.float64)
    if length.unit != "m":
        vertices = vertices * length.metres_per_unit
    return GroundTruth(vertices=vertices, faces=data.faces, unit=length.unit, note=note,
                       path=path)


def prepare_fit(
    out_dir: str | os.PathLike, gt_path: str | os.PathLike | None, units: str,
    model_path: str | os.PathLike | None, device: str, log,
) -> tuple[GroundTruth | None, Any]:
    """What both fit commands check before fitting, in this order so that bad input fails
    before the slow part: the ground truth (``gt_path``, its unit note logged), the output
    folder (then claimed, :func:`~lisa_hand.fitting.outputs.folder.claim_output_folder`: the
    caller frees it, :func:`~lisa_hand.fitting.outputs.folder.releases_output_locks`), then the
    model
    (:func:`lisa_hand.model.trained.load_trained` on ``device``).
    -> (the ground truth or None, the :class:`~lisa_hand.model.trained.TrainedModel`)."""
    from ...model.trained import load_trained
    from ...utils.device import resolve_device

    truth = None
    if gt_path is not None:
        truth = read_ground_truth(gt_path, units)
        if truth.note is not None:
            log(truth.note)
    claim_output_folder(out_dir)
    return truth, load_trained(model_path, resolve_device(device))


def ground_truth_metrics(mesh: Mesh, truth: GroundTruth, clip: Any = None
                         ) -> dict[str, float | None]:
    """V2V and V2S distances (mm) between a fitted mesh and the ground truth, both ways
    (:func:`lisa_hand.metrics.mesh_distances`; None where undefined: V2S towards points).
    clip: the fit's wrist cut (a :class:`lisa_hand.geometry.planes.Plane`) or None: both are
    cut along it first, as the written mesh is."""
    from ...metrics import mesh_distances

    distances = mesh_distances(mesh.vertices, mesh.faces, truth.vertices, truth.faces,
                               clip=clip)
    return json_safe(distances.to_dict())
