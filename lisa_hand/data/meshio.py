"""Triangle mesh files: PLY (with colours and skinning weights), OBJ and GLB.

PLY is written by hand with numpy as binary little endian: vertex ``x y z`` float, optional
``red green blue`` uchar, optional skinning weights as float properties ``w0 .. w{J-1}``, and
``vertex_indices`` as a ``list uchar int``. The reader handles binary (either byte order) and
ASCII PLY with scalar vertex properties and triangle faces, which covers what MeshLab, Blender,
trimesh and Open3D write for triangle meshes. OBJ carries vertex colours as ``v x y z r g b``
(floats in [0, 1]); GLB goes through trimesh (vertex colours as ``COLOR_0``). Neither stores
skinning weights: saving a mesh with weights to them warns and drops the weights.

The vertex tables alone, as stored (float64, no faces needed: point clouds saved as PLY or OBJ),
come from :func:`read_ply_vertices` and :func:`read_obj_vertices` (with an OBJ's ``vn`` normals);
:mod:`lisa_hand.data.pointio` reads point-cloud files through them.

Every write is atomic (:func:`lisa_hand.utils.io.atomic_path`): an exception leaves the previous
file, or none, never a partial one.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.meshing import Mesh, colors_to_uint8
from ..utils.io import atomic_path, require_file

__all__ = ["save_mesh", "load_mesh", "read_ply_vertices", "read_obj_vertices", "ObjVertices",
           "MESH_SUFFIXES"]

MESH_SUFFIXES = (".ply", ".obj", ".glb")
"""File extensions that :func:`save_mesh` and :func:`load_mesh` understand."""

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_WEIGHT_NAME = re.compile(r"^w(\d+)$")


def save_mesh(path: str | os.PathLike, mesh: Mesh) -> Path:
    """Write ``mesh`` to ``path`` (.ply, .obj or .glb, chosen by the extension); returns the path.

    PLY keeps vertices, faces, colours and skinning weights; OBJ and GLB keep vertices, faces
    and colours (weights are dropped with a warning). Parent folders are created.
    """
    path = Path(path)
    if not isinstance(mesh, Mesh):
        raise TypeError("mesh must be a lisa_hand.geometry.meshing.Mesh, got "
                        f"{type(mesh).__name__}")
    suffix = _suffix(path)
    if mesh.skin_weights is not None and suffix != ".ply":
        warnings.warn(
            f"{path}: {suffix} files cannot store skinning weights; they are dropped (use .ply)",
            stacklevel=2,
        )
    writer = {".ply": _write_ply, ".obj": _write_obj, ".glb": _write_glb}[suffix]
    with atomic_path(path) as tmp:
        writer(tmp, mesh)
    return path


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a .ply, .obj or .glb triangle mesh, with the colours and weights the file holds.

    PLY: vertex colours (``red green blue``) and skinning weights (``w0 .. w{J-1}``) when
    present. OBJ: colours when every ``v`` line has them (``v x y z r g b``, floats in [0, 1],
    or 0-255 if any exceeds 1); polygons are fan-triangulated. GLB: all meshes of the scene
    concatenated, vertex colours when present.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder and ValueError
    naming the file for an unknown extension or a corrupt file (a PLY whose faces have no
    vertices says so).
    """
    path = Path(path)
    suffix = _suffix(path)
    require_file(path)
    reader = {".ply": _read_ply, ".obj": _read_obj, ".glb": _read_glb}[suffix]
    try:
        return reader(path)
    except (ValueError, TypeError, IndexError, KeyError, UnicodeDecodeError, EOFError) as exc:
        message = str(exc)
        if message.startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a valid {suffix[1:].upper()} mesh ({message})") from None


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(
            f"{path}: unknown mesh file extension {path.suffix!r}; use one of "
            f"{', '.join(MESH_SUFFIXES)}"
        )
    return suffix


# ----------------------------------------------------------------------------------------------
# PLY


def _write_ply(path: Path, mesh: Mesh) -> None:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if mesh.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    num_weights = 0 if mesh.skin_weights is None else mesh.skin_weights.shape[1]
    fields += [(f"w{j}", "<f4") for j in range(num_weights)]
    vertices = np.empty(mesh.num_vertices, dtype=fields)
    for axis, name in enumerate("xyz"):
        vertices[name] = mesh.vertices[:, axis]
    if mesh.colors is not None:
        for channel, name in enumerate(("red", "green", "blue")):
            vertices[name] = mesh.colors[:, channel]
    for j in range(num_weights):
        vertices[f"w{j}"] = mesh.skin_weights[:, j]
    if mesh.num_vertices > np.iinfo(np.int32).max:
        raise ValueError(f"{path}: too many vertices for PLY int indices ({mesh.num_vertices})")
    faces = np.empty(mesh.num_faces, dtype=[("count", "u1"), ("indices", "<i4", (3,))])
    faces["count"] = 3
    faces["indices"] = mesh.faces

    header = ["ply", "format binary_little_endian 1.0", "comment written by lisa_hand"]
    header.append(f"element vertex {mesh.num_vertices}")
    type_names = {"<f4": "float", "u1": "uchar"}
    header += [f"property {type_names[kind]} {name}" for name, kind in fields]
    header += [f"element face {mesh.num_faces}", "property list uchar int vertex_indices"]
    header.append("end_header")
    with open(path, "wb") as handle:
        handle.write(("\n".join(header) + "\n").encode("ascii"))
        handle.write(vertices.tobytes())
        handle.write(faces.tobytes())


def _split_ply(path: Path, data: bytes) -> tuple[int, str, list]:
    """A PLY file's bytes -> (offset of its body, format, elements of its header)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements = _parse_ply_header(path, header)
    return body_start, fmt, elements


def _check_ply_vertices(path: Path, elements: list, need_vertices: bool) -> None:
    """A clear error for a PLY without vertices: no vertex element, or ``element vertex 0``
    with faces that then index nothing (with ``need_vertices``, any empty vertex element)."""
    counts = {name: count for name, count, _ in elements}
    faces = counts.get("face", 0)
    if "vertex" not in counts:
        if faces:
            raise ValueError(f"{path}: the PLY has {faces} face(s) but no vertex element (a "
                             "mesh needs 'element vertex N' with x y z before its faces)")
        raise ValueError(f"{path}: PLY has no vertex element")
    if counts["vertex"] == 0 and (faces or need_vertices):
        also = (f" but {faces} face(s), which index vertices the file does not hold" if faces
                else "")
        raise ValueError(f"{path}: the PLY has no vertices (element vertex 0){also}")


def read_ply_vertices(path: str | os.PathLike) -> np.ndarray:
    """The vertex element of a PLY file (ASCII or binary) as a structured array.

    -> [V] with one field per scalar vertex property, as stored (``x y z``, and ``nx ny nz``,
    ``red green blue`` ... when present), V > 0. What follows the vertex element (faces, custom
    elements) is not read. Raises FileNotFoundError, IsADirectoryError, or ValueError naming the
    file (not a PLY, no vertices, truncated, no ``x y z``).
    """
    path = require_file(path)
    data = path.read_bytes()
    body_start, fmt, elements = _split_ply(path, data)
    _check_ply_vertices(path, elements, need_vertices=True)
    names = [name for name, _, _ in elements]
    elements = elements[: names.index("vertex") + 1]
    if fmt == "ascii":
        tables = _read_ply_ascii(path, data[body_start:], elements)
    else:
        order = "<" if "little" in fmt else ">"
        needed = body_start + sum(
            count * np.dtype([(p[0], order + p[1]) for p in props]).itemsize
            for _, count, props in elements if all(p[2] is None for p in props))
        if len(data) < needed:
            raise ValueError(f"{path}: PLY file is truncated ({len(data)} of at least {needed} "
                             "bytes)")
        tables = _read_ply_binary(path, data, body_start, elements, order)
    vertex = tables["vertex"]
    missing = [axis for axis in "xyz" if axis not in vertex.dtype.names]
    if missing:
        raise ValueError(f"{path}: PLY vertex element lacks properties {missing}")
    return vertex


def _read_ply(path: Path) -> Mesh:
    data = path.read_bytes()
    body_start, fmt, elements = _split_ply(path, data)
    _check_ply_vertices(path, elements, need_vertices=False)
    if fmt == "ascii":
        tables = _read_ply_ascii(path, data[body_start:], elements)
    else:
        tables = _read_ply_binary(path, data, body_start, elements, "<" if "little" in fmt else ">")
    if "vertex" not in tables:
        raise ValueError(f"{path}: PLY has no vertex element")
    vertex = tables["vertex"]
    names = vertex.dtype.names
    missing = [axis for axis in "xyz" if axis not in names]
    if missing:
        raise ValueError(f"{path}: PLY vertex element lacks properties {missing}")
    vertices = np.stack([vertex[axis] for axis in "xyz"], axis=1).astype(np.float32)

    colors = None
    if all(name in names for name in ("red", "green", "blue")):
        colors = np.stack([vertex[name] for name in ("red", "green", "blue")], axis=1)
        if colors.dtype.kind == "f":
            colors = colors_to_uint8(colors)
        colors = colors.astype(np.uint8)
    weight_ids = sorted(int(m.group(1)) for m in map(_WEIGHT_NAME.match, names) if m)
    skin_weights = None
    if weight_ids:
        if weight_ids != list(range(len(weight_ids))):
            raise ValueError(
                f"{path}: skinning weight properties are not w0..w{{J-1}}: {weight_ids}"
            )
        skin_weights = np.stack([vertex[f"w{j}"] for j in weight_ids], axis=1).astype(np.float32)
    faces = tables.get("face", np.zeros((0, 3), dtype=np.int64))
    return Mesh(vertices=vertices, faces=faces, colors=colors, skin_weights=skin_weights)


def _parse_ply_header(path: Path, header: list[str]):
    fmt = None
    elements: list[tuple[str, int, list]] = []
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in (
                "ascii", "binary_little_endian", "binary_big_endian"
            ):
                raise ValueError(f"{path}: unknown PLY format line {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"{path}: bad PLY element line {line!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise ValueError(f"{path}: PLY property before any element: {line!r}")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise ValueError(f"{path}: unknown PLY list types in {line!r}")
                elements[-1][2].append((words[4], _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]], None))
            else:
                raise ValueError(f"{path}: unknown PLY property line {line!r}")
        else:
            raise ValueError(f"{path}: unknown PLY header line {line!r}")
    if fmt is None:
        raise ValueError(f"{path}: PLY header has no format line")
    return fmt, elements


def _read_ply_binary(path: Path, data: bytes, offset: int, elements, order: str) -> dict:
    tables = {}
    for name, count, properties in elements:
        lists = [prop for prop in properties if prop[2] is not None]
        if not lists:
            dtype = np.dtype([(prop[0], order + prop[1]) for prop in properties])
            table = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            offset += count * dtype.itemsize
            if name == "vertex":
                tables["vertex"] = table
            continue
        if name != "face" or len(properties) != 1:
            if name in ("vertex", "face"):
                raise ValueError(f"{path}: unsupported PLY {name} layout with list properties")
            break  # an extra element with lists: we cannot size it, and need nothing after it
        _, count_type, item_type = properties[0]
        # Triangles only: read as fixed-size records, then check every count is 3.
        dtype = np.dtype([("count", order + count_type), ("indices", order + item_type, (3,))])
        table = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        if count and not np.all(table["count"] == 3):
            raise ValueError(f"{path}: only triangle faces are supported in binary PLY")
        tables["face"] = table["indices"].astype(np.int64)
        offset += count * dtype.itemsize
    return tables


def _read_ply_ascii(path: Path, body: bytes, elements) -> dict:
    lines = body.decode("ascii").splitlines()
    tables = {}
    row = 0
    for name, count, properties in elements:
        block = lines[row : row + count]
        if len(block) < count:
            raise ValueError(f"{path}: PLY ends after {len(block)} of {count} {name} lines")
        row += count
        if name == "vertex":
            if any(prop[2] is not None for prop in properties):
                raise ValueError(f"{path}: unsupported PLY vertex list properties")
            values = np.array([line.split()[: len(properties)] for line in block], dtype=np.float64)
            if count == 0:
                values = values.reshape(0, len(properties))
            if values.shape != (count, len(properties)):
                raise ValueError(f"{path}: PLY vertex lines do not have {len(properties)} values")
            table = np.empty(count, dtype=[(prop[0], prop[1]) for prop in properties])
            for column, prop in enumerate(properties):
                table[prop[0]] = values[:, column]
            tables["vertex"] = table
        elif name == "face":
            triangles = []
            for line in block:
                numbers = [int(word) for word in line.split()]
                if not numbers or len(numbers) != numbers[0] + 1 or numbers[0] < 3:
                    raise ValueError(f"{path}: bad PLY face line {line!r}")
                triangles += [(numbers[1], numbers[k], numbers[k + 1])
                              for k in range(2, numbers[0])]
            tables["face"] = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    return tables


# ----------------------------------------------------------------------------------------------
# OBJ


def _write_obj(path: Path, mesh: Mesh) -> None:
    with open(path, "w", encoding="ascii") as handle:
        handle.write(f"# written by lisa_hand: {mesh.num_vertices} vertices, "
                     f"{mesh.num_faces} faces\n")
        if mesh.colors is not None:
            table = np.concatenate([mesh.vertices, mesh.colors / 255.0], axis=1)
            np.savetxt(handle, table, fmt="v %.9g %.9g %.9g %.6f %.6f %.6f")
        else:
            np.savetxt(handle, mesh.vertices, fmt="v %.9g %.9g %.9g")
        np.savetxt(handle, mesh.faces + 1, fmt="f %d %d %d")


@dataclass
class ObjVertices:
    """The vertices of an OBJ file as stored (:func:`read_obj_vertices`). V vertices."""

    positions: np.ndarray
    """[V, 3] float64, the first three numbers of each ``v`` line (V may be 0)."""
    colors: np.ndarray | None
    """[V, 3] float64 as stored (``v x y z r g b``: floats in [0, 1], or 0-255), when every
    ``v`` line has six numbers; else None."""
    normals: np.ndarray | None
    """[V, 3] float64, the ``vn`` lines when there is one per vertex (point-cloud exports; a
    mesh's ``vn`` lines belong to its face corners); else None."""


def read_obj_vertices(path: str | os.PathLike) -> ObjVertices:
    """The ``v`` (and ``vn``) lines of an OBJ file, faces not needed (a point cloud saved as OBJ
    is read as well). Raises FileNotFoundError, IsADirectoryError, or ValueError naming the file
    (a ``v`` line with fewer than 3 numbers, text where a number belongs)."""
    path = require_file(path)
    try:
        return _obj_vertices(path, path.read_text(encoding="utf-8").splitlines(), normals=True)
    except (ValueError, UnicodeDecodeError) as exc:
        message = str(exc)
        if message.startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a valid OBJ file ({message})") from None


def _obj_vertices(path: Path, lines: list[str], normals: bool = False) -> ObjVertices:
    """The ``v`` lines (and with ``normals`` the ``vn`` lines) of an OBJ file's ``lines``."""
    vertex_rows = [line.split()[1:] for line in lines if line.startswith("v ")]
    widths = {len(row) for row in vertex_rows}
    if vertex_rows and min(widths) < 3:
        raise ValueError(f"{path}: OBJ vertex line with fewer than 3 coordinates")
    width = 6 if widths == {6} else 3
    if not vertex_rows:
        table = np.zeros((0, 3))
    elif len(widths) == 1:
        table = np.array([word for row in vertex_rows for word in row], dtype=np.float64)
        table = table.reshape(len(vertex_rows), -1)[:, :width]
    else:
        table = np.array([row[:width] for row in vertex_rows], dtype=np.float64)
    normal_rows = [line.split()[1:4] for line in lines if normals and line.startswith("vn ")]
    per_vertex = (normal_rows and len(normal_rows) == len(vertex_rows)
                  and all(len(row) == 3 for row in normal_rows))
    return ObjVertices(positions=table[:, :3], colors=table[:, 3:6] if width == 6 else None,
                       normals=np.array(normal_rows, dtype=np.float64) if per_vertex else None)


def _read_obj(path: Path) -> Mesh:
    lines = path.read_text(encoding="utf-8").splitlines()
    table = _obj_vertices(path, lines)
    if len(table.positions) == 0:
        raise ValueError(f"{path}: OBJ has no vertices")
    colors = None
    if table.colors is not None:
        rgb = table.colors
        colors = rgb.round().astype(np.uint8) if rgb.max() > 1.0 else colors_to_uint8(rgb)
    return Mesh(
        vertices=table.positions.astype(np.float32),
        faces=_obj_faces(path, lines, len(table.positions)),
        colors=colors,
    )


def _obj_faces(path: Path, lines: list[str], num_vertices: int) -> np.ndarray:
    """Faces as [F, 3] zero-based indices: polygons fanned, ``i/t/n`` and negative indices."""
    face_lines = [line for line in lines if line.startswith("f ")]
    if not face_lines:
        return np.zeros((0, 3), dtype=np.int64)
    rows = [line.split()[1:] for line in face_lines]
    if all(len(row) == 3 for row in rows) and not any("/" in line for line in face_lines):
        faces = np.array([word for row in rows for word in row], dtype=np.int64).reshape(-1, 3)
        if faces.min() > 0:  # the common case: positive, vertex-only, triangles
            return faces - 1
    triangles = []
    vertices_so_far = 0
    for line in lines:  # relative (negative) indices count the vertices read so far
        if line.startswith("v "):
            vertices_so_far += 1
        elif line.startswith("f "):
            words = line.split()[1:]
            if len(words) < 3:
                raise ValueError(f"{path}: face with fewer than 3 vertices: {line!r}")
            corners = []
            for word in words:
                index = int(word.split("/", 1)[0])
                corners.append(index - 1 if index > 0 else vertices_so_far + index)
            triangles += [(corners[0], corners[k], corners[k + 1])
                          for k in range(1, len(corners) - 1)]
    return np.array(triangles, dtype=np.int64).reshape(-1, 3)


# ----------------------------------------------------------------------------------------------
# GLB


def _write_glb(path: Path, mesh: Mesh) -> None:
    import trimesh

    tri = trimesh.Trimesh(
        vertices=mesh.vertices, faces=mesh.faces, vertex_colors=mesh.colors, process=False
    )
    path.write_bytes(tri.export(file_type="glb"))


def _read_glb(path: Path) -> Mesh:
    import trimesh

    try:
        tri = trimesh.load(path, file_type="glb", force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for a bad file
        raise ValueError(f"{path}: not a valid GLB mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(tri, trimesh.Trimesh) or len(tri.vertices) == 0:
        raise ValueError(f"{path}: GLB holds no triangle mesh")
    colors = None
    if tri.visual.kind == "vertex":
        colors = np.asarray(tri.visual.vertex_colors)[:, :3].astype(np.uint8)
    return Mesh(
        vertices=np.asarray(tri.vertices, dtype=np.float32),
        faces=np.asarray(tri.faces, dtype=np.int64),
        colors=colors,
    )
