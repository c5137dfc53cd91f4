"""Mesh distances of the LISA paper (Table 1): vertex-to-vertex (V2V) and vertex-to-surface
(V2S), both directions, in millimetres.

``lisa metrics RECON GT`` prints :func:`compare_mesh_files` for two meshes (or point sets): each
file is read with :func:`load_mesh` and brought to metres by the hand-size rule of
:func:`lisa_hand.data.units.decide_length_unit`. Pure functions otherwise: numpy arrays or torch
tensors in, Python numbers out, computed in float64 on the CPU.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..data.units import UNIT_CHOICES, decide_length_unit
from ..utils.arrays import as_numpy
from ..utils.io import read_numpy, require_file

__all__ = [
    "MeshData",
    "MeshDistances",
    "MeshComparison",
    "mesh_distances",
    "surface_roughness",
    "load_mesh",
    "compare_mesh_files",
    "MAX_POINT_SET",
]

MAX_POINT_SET = 1_000_000
"""A point set (a file without faces) with more points is compared through this many of them,
drawn at random with a fixed seed (:func:`compare_mesh_files` says so): enough for a hand's
distances to a fraction of a millimetre, and the nearest-neighbour trees stay small."""

_MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")
_POINT_SUFFIXES = (".npy", ".npz", ".xyz")


@dataclass(frozen=True)
class MeshData:
    """A triangle mesh, or a point set when ``faces`` is None (as read by :func:`load_mesh`)."""

    vertices: np.ndarray
    """[V, 3] float64 vertex positions (the file's units)."""
    faces: np.ndarray | None
    """[F, 3] int64 triangle vertex indices, or None for a point set."""
    colors: np.ndarray | None = None
    """[V, 3] uint8 per-vertex colours of a mesh read through trimesh (vertex colours, or its
    texture sampled at each vertex), or None (none, or one colour for a whole mesh)."""


@dataclass(frozen=True)
class MeshDistances:
    """The four distances of the LISA paper's Table 1, in ``unit_scale`` units (mm by default).

    A field is NaN where it is undefined: the vertex-to-surface distance towards a point set.
    """

    v2v_recon_to_scan_mm: float
    """Mean distance from each reconstruction vertex to the nearest scan vertex."""
    v2s_recon_to_scan_mm: float
    """Mean distance from each reconstruction vertex to the scan surface (NaN: scan is points)."""
    v2v_scan_to_recon_mm: float
    """Mean distance from each scan vertex to the nearest reconstruction vertex."""
    v2s_scan_to_recon_mm: float
    """Mean distance from each scan vertex to the reconstruction surface."""

    def to_dict(self) -> dict[str, float]:
        """``{field name: value}`` with exactly the four field names as keys."""
        return asdict(self)


def _check_vertices(vertices: Any, name: str) -> np.ndarray:
    array = as_numpy(vertices, name).astype(np.float64, copy=False)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"{name} must have shape [V, 3] with V > 0, got {list(array.shape)}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} has non-finite entries")
    return np.ascontiguousarray(array)


def _check_faces(faces: Any, name: str, num_vertices: int) -> np.ndarray | None:
    if faces is None:
        return None
    array = as_numpy(faces, name)
    if array.size == 0:
        return None
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must have shape [F, 3], got {list(array.shape)}")
    if not np.issubdtype(array.dtype, np.integer):
        raise TypeError(f"{name} must hold integer vertex indices, got dtype {array.dtype}")
    if array.min() < 0 or array.max() >= num_vertices:
        raise ValueError(f"{name} indexes vertices outside [0, {num_vertices}): "
                         f"min {array.min()}, max {array.max()}")
    return np.ascontiguousarray(array, dtype=np.int64)


def _mean_distance_to_surface(points: np.ndarray, vertices: np.ndarray,
                              faces: np.ndarray) -> float:
    import point_cloud_utils as pcu

    distances, _, _ = pcu.closest_points_on_mesh(points, vertices, faces)
    return float(np.mean(distances))


def _clipped(vertices: np.ndarray, faces: np.ndarray | None, clip, name: str
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """``vertices``, ``faces`` cut by the plane ``clip`` (faces: cut along it; points: those on
    its kept side); ValueError naming ``name`` when nothing is left."""
    from ..geometry.planes import clip_mesh

    if faces is None:
        vertices = vertices[clip.keeps(vertices)]
    else:
        vertices, faces = clip_mesh(vertices, faces, clip)
    if len(vertices) == 0:
        raise ValueError(f"{name}: nothing is left on the hand's side of the wrist cut")
    return vertices, faces


def mesh_distances(recon_vertices: Any, recon_faces: Any | None, scan_vertices: Any,
                   scan_faces: Any | None = None, unit_scale: float = 1000.0,
                   clip: Any = None) -> MeshDistances:
    """Vertex-to-vertex (V2V) and vertex-to-surface (V2S) distances, both directions.

    As in the LISA paper (Table 1): V2V from A to B is the mean over A's vertices of the distance
    to the nearest VERTEX of B (``scipy.spatial.cKDTree``); V2S from A to B is the mean over A's
    vertices of the distance to B's SURFACE, i.e. the closest point on any triangle
    (``point_cloud_utils.closest_points_on_mesh``). Since a vertex is a point of the surface,
    V2V >= V2S. All vertices count, referenced by a face or not; V2S only sees B's triangles.

    recon_vertices: [V, 3], recon_faces: [F, 3] or None, scan_vertices: [V', 3],
    scan_faces: [F', 3] or None (a scan that is only points). Lengths in metres with the default
    ``unit_scale=1000`` give millimetres; pass ``unit_scale=1`` to keep the inputs' units.

    A scan without faces has no surface, so ``v2s_recon_to_scan_mm`` is NaN (likewise
    ``v2s_scan_to_recon_mm`` for a reconstruction without faces).

    clip: a :class:`lisa_hand.geometry.planes.Plane` (e.g. the fitted hand's wrist cut,
    :func:`lisa_hand.skeleton.wrist.wrist_plane`) or None: both meshes are first cut along it
    (a mesh's triangles exactly along the plane, a point set by keeping its points on the kept
    side), so that a forearm in the scan, or one cut shorter than the reconstruction, counts
    in neither direction.
    """
    recon_v = _check_vertices(recon_vertices, "recon_vertices")
    scan_v = _check_vertices(scan_vertices, "scan_vertices")
    recon_f = _check_faces(recon_faces, "recon_faces", len(recon_v))
    scan_f = _check_faces(scan_faces, "scan_faces", len(scan_v))
    if not unit_scale > 0:
        raise ValueError(f"unit_scale must be positive, got {unit_scale}")
    if clip is not None:
        recon_v, recon_f = _clipped(recon_v, recon_f, clip, "the reconstruction")
        scan_v, scan_f = _clipped(scan_v, scan_f, clip, "the scan")
    from scipy.spatial import cKDTree

    v2v_recon_to_scan = float(np.mean(cKDTree(scan_v).query(recon_v)[0]))
    v2v_scan_to_recon = float(np.mean(cKDTree(recon_v).query(scan_v)[0]))
    v2s_recon_to_scan = (math.nan if scan_f is None
                         else _mean_distance_to_surface(recon_v, scan_v, scan_f))
    v2s_scan_to_recon = (math.nan if recon_f is None
                         else _mean_distance_to_surface(scan_v, recon_v, recon_f))
    return MeshDistances(
        v2v_recon_to_scan_mm=unit_scale * v2v_recon_to_scan,
        v2s_recon_to_scan_mm=unit_scale * v2s_recon_to_scan,
        v2v_scan_to_recon_mm=unit_scale * v2v_scan_to_recon,
        v2s_scan_to_recon_mm=unit_scale * v2s_scan_to_recon,
    )


def surface_roughness(vertices: Any, faces: Any, iterations: int = 30,
                      unit_scale: float = 1000.0) -> float:
    """How bumpy a surface is: the mean distance from the mesh's vertices to a Taubin-smoothed
    copy of it (``trimesh.smoothing.filter_taubin``, lambda 0.5, nu 0.53: smoothing that does
    not shrink the mesh), millimetres with the default ``unit_scale`` for metres.

    Bumps a few edges across (knobbly joints, a lumpy surface, marching cubes' steps) move under
    the filter; a smooth surface barely does. The figure depends on the tessellation: compare
    meshes of about the same edge length (e.g. both from marching cubes at one voxel size).

    vertices: [V, 3]; faces: [F, 3]; iterations: filter passes (30: bumps of up to a few mm on
    a hand meshed at 0.7-1 mm).
    """
    import trimesh

    vertices = _check_vertices(vertices, "vertices")
    faces = _check_faces(faces, "faces", len(vertices))
    if faces is None or len(faces) == 0:
        raise ValueError("surface_roughness needs a mesh with faces")
    mesh = trimesh.Trimesh(vertices.astype(np.float64), faces, process=False)
    smoothed = mesh.copy()
    trimesh.smoothing.filter_taubin(smoothed, lamb=0.5, nu=0.53, iterations=iterations)
    return unit_scale * _mean_distance_to_surface(vertices.astype(np.float64),
                                                  np.asarray(smoothed.vertices), faces)


def _points_from_array(array: np.ndarray, path: Path, what: str) -> np.ndarray:
    if array.ndim != 2 or array.shape[1] < 3 or array.shape[0] == 0:
        raise ValueError(f"{path}: {what} must have shape [N, 3] (extra columns such as normals "
                         f"are ignored), got {list(array.shape)}")
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{path}: {what} must be real numbers, got dtype {array.dtype}")
    return np.ascontiguousarray(array[:, :3], dtype=np.float64)


def _load_point_file(path: Path, suffix: str) -> MeshData:
    """A .npy, .xyz or .npz file (see :func:`load_mesh`)."""
    try:
        if suffix == ".xyz":
            array = np.loadtxt(path, ndmin=2, comments="#")
            return MeshData(_points_from_array(array, path, "the points"), None)
        loaded = read_numpy(path)
        if suffix == ".npy" or not isinstance(loaded, dict):
            if isinstance(loaded, dict):
                raise ValueError(f"{path}: an .npz archive, not a .npy array: name it .npz")
            return MeshData(_points_from_array(loaded, path, "the array"), None)
        key = next((k for k in ("vertices", "points") if k in loaded), None)
        if key is None:
            raise ValueError(f"{path}: expected an array named 'vertices' or 'points', "
                             f"found {list(loaded)}")
        vertices = _points_from_array(loaded[key], path, f"'{key}'")
        faces = loaded.get("faces")
    except (OSError, EOFError, ValueError) as exc:
        message = str(exc)
        raise ValueError(message if message.startswith(str(path))
                         else f"{path}: cannot read ({message})") from None
    return MeshData(vertices, _check_faces(faces, f"{path}: faces", len(vertices)))


def _no_vertices(path: Path, suffix: str) -> ValueError:
    """The error for a mesh file without vertices: for PLY, the reason the header gives (no
    vertex element, or ``element vertex 0`` beside faces)."""
    if suffix == ".ply":
        from ..data.meshio import load_mesh as read_mesh

        read_mesh(path)  # raises the precise reason for a PLY without vertices
    return ValueError(f"{path}: the file holds no vertices")


def _load_trimesh_file(path: Path, suffix: str) -> MeshData:
    """A mesh (or point) file through trimesh (see :func:`load_mesh`)."""
    import trimesh

    try:
        # process=True merges vertices at identical positions (STL and UV seams repeat them), so
        # V2V averages over distinct surface points.
        loaded = trimesh.load(path, process=True)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise ValueError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None
    colors = _vertex_colours([loaded]) if isinstance(loaded, trimesh.Trimesh) else None
    if isinstance(loaded, trimesh.Scene):
        geometries = list(loaded.dump()) if loaded.geometry else []
        meshes = [g for g in geometries if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        clouds = [g for g in geometries if isinstance(g, trimesh.PointCloud)]
        if meshes:
            colors = _vertex_colours(meshes)
            loaded = trimesh.util.concatenate(meshes)
        elif clouds:
            loaded = trimesh.PointCloud(np.concatenate([c.vertices for c in clouds]))
        else:
            raise _no_vertices(path, suffix)
    if isinstance(loaded, trimesh.PointCloud):
        vertices, faces = np.asarray(loaded.vertices, dtype=np.float64), None
    elif isinstance(loaded, trimesh.Trimesh):
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64) if len(loaded.faces) else None
    else:
        raise ValueError(f"{path}: unsupported content ({type(loaded).__name__})")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise _no_vertices(path, suffix)
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: vertices have non-finite entries")
    if colors is not None and len(colors) != len(vertices):
        colors = None
    return MeshData(np.ascontiguousarray(vertices), faces, colors)


def _vertex_colours(meshes: list) -> np.ndarray | None:
    """[V, 3] uint8 colours of trimesh meshes' vertices, in concatenation order, or None when
    one of them has no colour or one colour for all of it (a material's)."""
    parts = []
    for mesh in meshes:
        if mesh.visual is None or mesh.visual.kind is None:
            return None  # no colour at all (trimesh would invent its default grey)
        visual = mesh.visual.to_color() if hasattr(mesh.visual, "to_color") else mesh.visual
        colours = np.asarray(visual.vertex_colors)
        if colours.ndim != 2 or len(colours) != len(mesh.vertices):
            return None
        parts.append(colours[:, :3])
    return np.concatenate(parts).astype(np.uint8)


def load_mesh(path: str | os.PathLike) -> MeshData:
    """Read a mesh (PLY, OBJ, GLB/GLTF, STL, OFF via trimesh) or a point set (.npy, .npz, .xyz).

    Scenes are concatenated into one mesh; a PLY holding only points gives a point set.
    ``.npy``: an [N, 3+] array. ``.npz``: ``vertices`` (or ``points``) [N, 3] and optional
    ``faces`` [F, 3]. ``.xyz``: text, one point a line, the first three columns are x y z.
    Errors name the file (a missing file, a folder, a file without vertices, a corrupt file).
    """
    path = require_file(path)
    suffix = path.suffix.lower()
    if suffix in _POINT_SUFFIXES:
        return _load_point_file(path, suffix)
    if suffix not in _MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported file type '{suffix}' (expected one of "
                         f"{', '.join(_MESH_SUFFIXES + _POINT_SUFFIXES)})")
    return _load_trimesh_file(path, suffix)


@dataclass(frozen=True)
class MeshComparison:
    """Result of :func:`compare_mesh_files`."""

    distances: MeshDistances
    """The four distances in millimetres."""
    recon_unit: str
    """Unit the reconstruction file was read in: "m", "cm" or "mm"."""
    scan_unit: str
    """Unit the scan file was read in: "m", "cm" or "mm"."""
    recon_unit_detected: bool
    """True if ``recon_unit`` was guessed (``units="auto"``)."""
    scan_unit_detected: bool
    """True if ``scan_unit`` was guessed (``units="auto"``)."""
    recon_note: str | None = None
    """What was done to the file's points: the guess of ``recon_unit``, a subsample
    (:data:`MAX_POINT_SET`); None: nothing (read as metres, or in the given unit)."""
    scan_note: str | None = None
    """What was done to the file's points: the guess of ``scan_unit``, a subsample
    (:data:`MAX_POINT_SET`); None: nothing (read as metres, or in the given unit)."""


def compare_mesh_files(recon_path: str | os.PathLike, scan_path: str | os.PathLike,
                       units: str = "auto") -> MeshComparison:
    """Load two files with :func:`load_mesh` and return their distances in millimetres.

    units: "m", "cm", "mm" (both files), or "auto" (each file on its own): see
    :func:`lisa_hand.data.units.decide_length_unit`, whose ValueError (naming the file and the
    ``--units`` that fits) refuses a file whose size is no hand's in that unit.
    """
    if units not in UNIT_CHOICES:
        raise ValueError(f"units must be one of {', '.join(UNIT_CHOICES)}, got {units!r}")
    recon = load_mesh(recon_path)
    scan = load_mesh(scan_path)
    recon, recon_sampled = _capped_point_set(recon)
    scan, scan_sampled = _capped_point_set(scan)
    recon_unit, scan_unit = (
        decide_length_unit(data.vertices, units, name=str(path),
                           what="the mesh" if data.faces is not None else "the point set")
        for data, path in ((recon, recon_path), (scan, scan_path)))
    distances = mesh_distances(recon.vertices * recon_unit.metres_per_unit, recon.faces,
                               scan.vertices * scan_unit.metres_per_unit, scan.faces,
                               unit_scale=1000.0)
    recon_note, scan_note = (
        "; ".join(note for note in (unit.note, sampled) if note) or None
        for unit, sampled in ((recon_unit, recon_sampled), (scan_unit, scan_sampled)))
    return MeshComparison(distances, recon_unit.unit, scan_unit.unit, recon_unit.detected,
                          scan_unit.detected, recon_note, scan_note)


def _capped_point_set(data: MeshData) -> tuple[MeshData, str | None]:
    """``data``, a point set of more than :data:`MAX_POINT_SET` points reduced to that many
    (random, seed 0), and the sentence saying so (None when unchanged)."""
    count = len(data.vertices)
    if data.faces is not None or count <= MAX_POINT_SET:
        return data, None
    keep = np.sort(np.random.default_rng(0).choice(count, MAX_POINT_SET, replace=False))
    sentence = (f"compared through {MAX_POINT_SET} of its {count} points (a random subset; the "
                "distances are over those)")
    return MeshData(data.vertices[keep], None), sentence
