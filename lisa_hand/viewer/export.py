"""What the viewer's Export panel writes: the hand on screen as ``params.json`` (readable by
:func:`lisa_hand.skeleton.params.read_params`, so every other command takes it), its mesh as
``mesh.ply`` (colours and skinning weights), ``view.json`` (the viewer's settings and state,
the resolved config of the export), and a browser screenshot (``screenshot.png``).

The panel writes only inside the viewer's export folder (``lisa view --export-dir``): its Folder
box names one folder in it (:func:`export_folder`), never a path elsewhere."""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..data.meshio import save_mesh
from ..inference.mesh import MeshConfig, mesh_hand
from ..model.trained import TrainedModel
from ..skeleton.params import HandParams, write_params
from ..utils.io import atomic_path, check_output_file, write_json
from .config import ViewerConfig
from .state import ViewState

__all__ = ["EXPORT_FILES", "export_folder", "export_hand", "write_screenshot"]

EXPORT_FILES = ("params.json", "mesh.ply", "view.json")


_MAX_NAME = 100
_FORBIDDEN_CHARS = frozenset('/\\:*?"<>|')


def export_folder(root: str | os.PathLike, name: str) -> Path:
    """The folder of the Export panel: ``root`` itself for an empty ``name`` (or "."), else
    the folder ``name`` in it. Nothing is created.

    name: one folder name, at most 100 characters, none of ``/ \\ : * ? " < > |`` nor a
    control character, not ".." (so no absolute path, no way up, no subfolder); surrounding
    spaces are dropped. A name whose folder is a link out of ``root`` is refused too.
    Raises ValueError naming the problem.
    """
    if not isinstance(name, str):
        raise ValueError(f"the folder must be a name, got {type(name).__name__}")
    name = name.strip()
    root = Path(root).resolve()
    if name in ("", "."):
        return root
    if name == ".." or len(name) > _MAX_NAME or any(
            char in _FORBIDDEN_CHARS or not char.isprintable() for char in name):
        raise ValueError(f"the folder must be one name inside {root} (no '/', '\\', ':', "
                         f"'..', at most {_MAX_NAME} characters)")
    folder = root / name
    if folder.resolve().parent != root:
        raise ValueError(f"{folder} leads out of {root}")
    return folder


def _check_folder(folder: Path) -> Path:
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    if not os.access(folder, os.W_OK):
        raise PermissionError(f"{folder}: cannot write here")
    return folder


def export_hand(folder: str | os.PathLike, model: TrainedModel, params: HandParams,
                state: ViewState, config: ViewerConfig) -> list[Path]:
    """Write the hand into ``folder`` (created): params.json, mesh.ply (marching cubes at
    ``config.export_resolution``), view.json. Every file is written atomically, the mesh
    (the slow part) first. -> the paths written"""
    folder = _check_folder(Path(folder))
    for name in EXPORT_FILES:
        check_output_file(folder / name)
    mesh = mesh_hand(model, params, config.export_resolution,
                     MeshConfig(padding=config.remesh.padding))
    paths = [save_mesh(folder / "mesh.ply", mesh), write_params(folder / "params.json", params)]
    view = {"config": config.to_dict(), "state": asdict(state), "model": model.source,
            "mesh": {"resolution": config.export_resolution, "vertices": mesh.num_vertices,
                     "faces": mesh.num_faces}}
    paths.append(write_json(folder / "view.json", view))
    return paths


def write_screenshot(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an [H, W, 3|4] uint8 image as PNG (atomic). -> path"""
    import imageio.v3 as iio

    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        raise ValueError(f"a screenshot must be [H, W, 3|4] uint8, got {image.shape} "
                         f"{image.dtype}")
    path = Path(path)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, image, extension=".png")
    return path
