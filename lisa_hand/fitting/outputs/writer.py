"""The one writer of a fit's files: :func:`write_fit` writes a list of :class:`Artefact` as the
output folder, all or nothing (:func:`lisa_hand.fitting.outputs.folder.write_folder`).

An artefact is a file's name inside the folder and how to write it. The files every fit writes
have constructors here (:func:`params_artefact`, :func:`mesh_artefact`, :func:`json_artefact`,
:func:`image_artefact`, :func:`mask_artefact`, :func:`text_artefact`,
:func:`model_artefact`); a fitter's own files (the photo fit's cameras, overlays and report,
:mod:`lisa_hand.fitting.photo.artefacts`) are artefacts built by the fitter. The files of a point
or image fit are :func:`fit_artefacts` (:func:`write_fit_outputs` writes them).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...geometry.meshing import Mesh
from ...skeleton.params import HandParams
from .folder import Allowed, write_folder
from .records import json_safe, keypoints_3d_record

__all__ = [
    "Artefact",
    "params_artefact",
    "mesh_artefact",
    "json_artefact",
    "image_artefact",
    "mask_artefact",
    "text_artefact",
    "model_artefact",
    "write_fit",
    "fit_artefacts",
    "write_fit_outputs",
]


@dataclass(frozen=True)
class Artefact:
    """One file of a fit's output folder.

    name: its path inside the folder, ``/``-separated (``"params.json"``,
    ``"hand0/photo1/mask.png"``). write: called with the file's path in the staging folder (its
    folder created) -> the path written (or the paths, for a writer of several files).
    """

    name: str
    write: Callable[[Path], Path | Sequence[Path]]


def params_artefact(params: HandParams, name: str = "params.json") -> Artefact:
    """The hand's parameters (:func:`lisa_hand.skeleton.params.write_params`)."""

    def write(path: Path) -> Path:
        from ...skeleton.params import write_params

        return write_params(path, params)

    return Artefact(name, write)


def mesh_artefact(mesh: Mesh, name: str = "mesh.ply") -> Artefact:
    """A mesh (:func:`lisa_hand.data.meshio.save_mesh`: PLY with colours and skinning
    weights)."""

    def write(path: Path) -> Path:
        from ...data.meshio import save_mesh

        return save_mesh(path, mesh)

    return Artefact(name, write)


def json_artefact(name: str, record: Any) -> Artefact:
    """A JSON file of ``record``, every NaN or inf written as null (:func:`json_safe`)."""

    def write(path: Path) -> Path:
        from ...utils.io import write_json

        return write_json(path, json_safe(record))

    return Artefact(name, write)


def image_artefact(name: str, image: np.ndarray) -> Artefact:
    """An RGB picture [H, W, 3] (:func:`lisa_hand.data.layout.write_image`)."""

    def write(path: Path) -> Path:
        from ...data.layout import write_image

        return write_image(path, image)

    return Artefact(name, write)


def mask_artefact(name: str, mask: np.ndarray) -> Artefact:
    """A mask [H, W] bool, white where true (:func:`lisa_hand.data.layout.write_mask`)."""

    def write(path: Path) -> Path:
        from ...data.layout import write_mask

        return write_mask(path, mask)

    return Artefact(name, write)


def text_artefact(name: str, text: str) -> Artefact:
    """A UTF-8 text file (an HTML report)."""

    def write(path: Path) -> Path:
        path.write_text(text, encoding="utf-8")
        return path

    return Artefact(name, write)


def model_artefact(model: Any, name: str = "model.pt") -> Artefact:
    """A :class:`~lisa_hand.model.trained.TrainedModel` in full precision
    (:func:`lisa_hand.model.trained.export_trained`)."""

    def write(path: Path) -> Path:
        from ...model.trained import export_trained

        return export_trained(model, path)[0]

    return Artefact(name, write)


def write_fit(out_dir: str | os.PathLike, artefacts: Sequence[Artefact],
              allowed: Allowed | None = None, described: str | None = None) -> list[Path]:
    """Write ``artefacts`` as the folder ``out_dir`` (created), all or nothing: staged beside it
    and swapped in once every file exists; the folder then holds these files and nothing else
    (:func:`lisa_hand.fitting.outputs.folder.write_folder`). allowed, described: what a
    previous fit of this kind leaves in ``out_dir`` (default: the files of
    :data:`~lisa_hand.fitting.outputs.folder.FIT_FILES`); anything else there is refused.
    -> the written paths (under ``out_dir``), in the artefacts' order.
    """
    artefacts = list(artefacts)
    names = [artefact.name for artefact in artefacts]
    if not artefacts or len(set(names)) != len(names):
        raise ValueError(f"a fit writes one or more files of distinct names, got {names}")

    def write(staging: Path) -> list[Path]:
        files: list[Path] = []
        for artefact in artefacts:
            path = staging / artefact.name
            path.parent.mkdir(parents=True, exist_ok=True)
            written = artefact.write(path)
            files += [written] if isinstance(written, (str, os.PathLike)) else list(written)
        return files

    return write_folder(out_dir, write, allowed, described)


def fit_artefacts(
    params: HandParams,
    mesh: Mesh,
    metrics: dict[str, Any] | None = None,
    keypoints: dict[str, Any] | None = None,
    model: Any = None,
    preview: np.ndarray | None = None,
) -> list[Artefact]:
    """The files of a point or image fit: ``params.json``, ``mesh.ply``, ``keypoints.json`` and,
    when given, ``metrics.json``, ``model.pt`` and ``preview.png``, in that order.

    keypoints: what ``keypoints.json`` holds (default:
    :func:`~lisa_hand.fitting.outputs.records.keypoints_3d_record`, the fitted hand's 3D
    keypoints in the world frame). model: a refined
    :class:`~lisa_hand.model.trained.TrainedModel`, or None. preview: an RGB picture
    [H, W, 3] uint8, or None.
    """
    record = keypoints_3d_record(params) if keypoints is None else keypoints
    artefacts = [params_artefact(params), mesh_artefact(mesh),
                 json_artefact("keypoints.json", record)]
    if metrics is not None:
        artefacts.append(json_artefact("metrics.json", metrics))
    if model is not None:
        artefacts.append(model_artefact(model))
    if preview is not None:
        artefacts.append(image_artefact("preview.png", preview))
    return artefacts


def write_fit_outputs(
    out_dir: str | os.PathLike,
    params: HandParams,
    mesh: Mesh,
    metrics: dict[str, Any] | None = None,
    keypoints: dict[str, Any] | None = None,
    model: Any = None,
    preview: np.ndarray | None = None,
) -> list[Path]:
    """Write a point or image fit's files (:func:`fit_artefacts`) as the folder ``out_dir``, all
    or nothing (:func:`write_fit`): ``out_dir`` must be new, empty or hold only
    :data:`~lisa_hand.fitting.outputs.folder.FIT_FILES`, and afterwards holds this fit's files
    and nothing else (a previous fit's ``metrics.json`` does not survive).
    -> the written paths, in :func:`fit_artefacts`' order.
    """
    return write_fit(out_dir, fit_artefacts(params, mesh, metrics, keypoints, model, preview))
