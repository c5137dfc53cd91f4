"""Point-cloud files: points and optional normals, as stored (:func:`read_points`).

Formats (normals are optional everywhere):

* ``.ply``: the vertex element's ``x y z`` and, when present, ``nx ny nz`` (ASCII or binary;
  :func:`lisa_hand.data.meshio.read_ply_vertices`); faces and other properties are ignored (a
  mesh's vertices are its points).
* ``.obj``: the ``v`` lines (first three numbers); the ``vn`` lines are the normals when there
  is one per vertex (point-cloud exports), else they are ignored
  (:func:`lisa_hand.data.meshio.read_obj_vertices`).
* ``.xyz``: text, one point a line, ``x y z`` or ``x y z nx ny nz``; ``#`` starts a comment.
* ``.npy``: an ``[N, 3]`` or ``[N, 6]`` (points, normals) array.
* ``.npz``: ``points`` (or ``vertices``) ``[N, 3]`` and optional ``normals`` ``[N, 3]`` (the
  ``scan.npz`` files of ``lisa synth``).

PLY and OBJ are parsed once in the package, by :mod:`lisa_hand.data.meshio`. Errors are one line
naming the file (:func:`named_read_errors`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..utils.io import read_numpy, require_file
from .meshio import read_obj_vertices, read_ply_vertices

__all__ = ["POINT_FILE_SUFFIXES", "read_points", "named_read_errors"]

POINT_FILE_SUFFIXES = (".ply", ".obj", ".xyz", ".npy", ".npz")
"""File extensions :func:`read_points` understands."""

_READ_ERRORS = (OSError, EOFError, ValueError, TypeError, IndexError, KeyError,
                UnicodeDecodeError)


@contextmanager
def named_read_errors(path: Path) -> Iterator[None]:
    """Inside the block, what reading ``path`` raises (a parser's ValueError, an OSError, a
    numpy error) becomes one ValueError line naming the file: the message itself when it starts
    with the path, else ``PATH: cannot read this SUFFIX file (Type: message)``."""
    try:
        yield
    except _READ_ERRORS as exc:
        message = str(exc)
        if message.startswith(str(path)):
            raise ValueError(message) from None
        raise ValueError(f"{path}: cannot read this {path.suffix[1:].upper()} file "
                         f"({type(exc).__name__}: {message})") from None


def read_points(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point file as stored (see the module docstring for the formats).

    -> (points [N, 3] in the file's units, normals [N, 3] or None); N may be 0 and values are
    not checked beyond their shape (NaN stays NaN). Raises FileNotFoundError for a missing
    file, IsADirectoryError for a folder and ValueError naming the file for an unknown
    extension or a corrupt file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in POINT_FILE_SUFFIXES:
        raise ValueError(f"{path}: unsupported point file type {path.suffix!r} (expected one of "
                         f"{', '.join(POINT_FILE_SUFFIXES)})")
    require_file(path)
    reader = {".ply": _read_ply, ".obj": _read_obj, ".xyz": _read_xyz, ".npy": _read_npy,
              ".npz": _read_npz}[suffix]
    with named_read_errors(path):
        return reader(path)


def _columns(array: np.ndarray, path: Path, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """[N, 3] points or [N, 6] points and normals from one array."""
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] not in (3, 6):
        raise ValueError(f"{path}: {what} must have shape [N, 3] or [N, 6] (points, normals), "
                         f"got {list(array.shape)}")
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{path}: {what} must be real numbers, got dtype {array.dtype}")
    return array[:, :3], (array[:, 3:6] if array.shape[1] == 6 else None)


def _read_npy(path: Path):
    array = read_numpy(path)
    if isinstance(array, dict):
        raise ValueError(f"{path}: an .npz archive, not a .npy array: name it .npz")
    return _columns(array, path, "the array")


def _read_xyz(path: Path):
    table = np.loadtxt(path, ndmin=2, comments="#")
    if table.size == 0:
        return np.zeros((0, 3)), None
    return _columns(table, path, "the table")


def _read_npz(path: Path):
    archive = read_numpy(path)
    if not isinstance(archive, dict):
        raise ValueError(f"{path}: a .npy array, not an .npz archive: name it .npy")
    key = next((k for k in ("points", "vertices") if k in archive), None)
    if key is None:
        raise ValueError(f"{path}: expected an array named 'points' or 'vertices', found "
                         f"{list(archive)}")
    points = archive[key]
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: '{key}' must have shape [N, 3], got {list(points.shape)}")
    return points, archive.get("normals")


def _read_obj(path: Path):
    table = read_obj_vertices(path)
    return table.positions, table.normals


def _read_ply(path: Path):
    vertex = read_ply_vertices(path)  # the vertex element only: faces and others are skipped
    columns = vertex.dtype.names
    points = np.stack([vertex[axis] for axis in "xyz"], axis=1)
    normals = None
    if all(name in columns for name in ("nx", "ny", "nz")):
        normals = np.stack([vertex[name] for name in ("nx", "ny", "nz")], axis=1)
    return points, normals
