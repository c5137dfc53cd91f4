"""Connected pieces of a triangle mesh, and the specks among them.

Marching cubes leaves specks: closed or open pieces a voxel or two across where a learned field
dips below zero away from the hand (between a fist's fingertips and its palm, along the ragged end
of a forearm stub the training scans never showed). They carry no shape, but a mesh file with 3
to 29 pieces is not the one hand a user asked for, and tools that count pieces (watertightness
checks, 3D printing, physics) refuse it. :func:`drop_specks` removes the pieces smaller than a
fraction of the surface (:data:`MIN_PIECE_FRACTION`, the same threshold under which the image
fit's geometry guard does not count a piece), keeping real floaters, which the guard then counts.

Two triangles belong to one piece when they share a vertex; vertices at the same position (to
1e-9 m) are merged first, so a mesh written with duplicated vertices has the same pieces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MIN_PIECE_FRACTION", "Specks", "piece_labels", "surface_pieces", "drop_specks"]

MIN_PIECE_FRACTION = 1e-3
"""Pieces with less than this fraction of the surface's area are specks (0.1 %: for a 400 cm^2
hand, 0.4 cm^2, about the smallest closed blob a 64^3 grid around the hand resolves; a 0.6 cm^2
floater on a real photo is not a speck, the 0.004-0.16 cm^2 ones of marching cubes are)."""


@dataclass(frozen=True)
class Specks:
    """What :func:`drop_specks` removed: ``count`` pieces, ``area_m2`` metres^2 in all."""

    count: int
    area_m2: float

    def note(self, name: str = "the mesh") -> str | None:
        """One line for a log or a report ("mesh.ply: 2 specks ... removed"); None when
        nothing was removed."""
        if self.count == 0:
            return None
        return (f"{name}: {self.count} speck(s) below {100 * MIN_PIECE_FRACTION:g} % of the "
                f"surface removed ({1e4 * self.area_m2:.3g} cm^2 in all)")

    def to_dict(self) -> dict[str, float]:
        """JSON-ready (``metrics.json``, ``params.json`` extras)."""
        return {"count": self.count, "area_cm2": 1e4 * self.area_m2}


def _mesh_arrays(mesh: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3] float64, faces [F, 3] int64) of a mesh with ``vertices`` and ``faces``."""
    try:
        vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except (AttributeError, TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a mesh with vertices [V, 3] and faces [F, 3] "
                        f"({exc})") from None
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"{name}: face indices outside [0, {len(vertices)})")
    return vertices, faces


def _triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[F] areas (metres^2) of the triangles."""
    corners = vertices[faces]  # [F, 3, 3]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return 0.5 * np.linalg.norm(cross, axis=-1)


def piece_labels(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The connected piece of each triangle (see the module docstring).

    vertices: [V, 3] metres; faces: [F, 3] int64 (at least one).
    -> (labels [F] int64 in [0, P), areas [P] metres^2 of each label's triangles).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, welded = np.unique(np.round(vertices / 1e-9).astype(np.int64), axis=0,
                          return_inverse=True)
    merged = welded.reshape(-1)[faces]
    num_vertices = int(merged.max()) + 1
    rows = merged[:, [0, 1, 2]].reshape(-1)
    cols = merged[:, [1, 2, 0]].reshape(-1)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_vertices, num_vertices))
    _, vertex_labels = connected_components(graph, directed=False)
    _, labels = np.unique(vertex_labels[merged[:, 0]], return_inverse=True)
    labels = labels.reshape(-1).astype(np.int64)
    return labels, np.bincount(labels, weights=_triangle_areas(vertices, faces))


def surface_pieces(mesh: Any, name: str = "mesh") -> tuple[np.ndarray, float]:
    """Areas of a mesh's connected pieces, largest first, and its total area.

    mesh: anything with ``vertices`` [V, 3] metres and ``faces`` [F, 3]
    (:class:`lisa_hand.geometry.meshing.Mesh`, a trimesh). name: how errors call the mesh.
    -> (areas [P] metres^2 of every piece, specks included, sorted descending; total area
    metres^2); (empty, 0.0) for a mesh without faces.
    """
    vertices, faces = _mesh_arrays(mesh, name)
    if len(faces) == 0:
        return np.zeros(0), 0.0
    _, areas = piece_labels(vertices, faces)
    total = float(areas.sum())
    return np.sort(areas[areas > 0])[::-1], total


def drop_specks(mesh: Any, min_fraction: float = MIN_PIECE_FRACTION) -> tuple[Any, Specks]:
    """``mesh`` without its pieces smaller than ``min_fraction`` of its area (the largest piece
    is always kept), and what was removed.

    mesh: a :class:`lisa_hand.geometry.meshing.Mesh` (vertices [V, 3] metres, faces [F, 3],
    optional colours [V, 3] and skinning weights [V, J], carried for the vertices kept);
    min_fraction: in [0, 1); 0 removes nothing.
    -> (the same mesh object when nothing is removed, else a new one with its unused vertices
    dropped, faces renumbered in their order; :class:`Specks`).
    """
    from .meshing import Mesh

    if not 0.0 <= min_fraction < 1.0:
        raise ValueError(f"min_fraction must be in [0, 1), got {min_fraction!r}")
    vertices, faces = _mesh_arrays(mesh, "mesh")
    if len(faces) == 0 or min_fraction == 0.0:
        return mesh, Specks(0, 0.0)
    labels, areas = piece_labels(vertices, faces)
    kept_pieces = areas >= min_fraction * areas.sum()
    kept_pieces[np.argmax(areas)] = True
    if kept_pieces.all():
        return mesh, Specks(0, 0.0)
    kept_faces = faces[kept_pieces[labels]]
    used, compact = np.unique(kept_faces, return_inverse=True)

    def rows(values):
        return None if values is None else np.asarray(values)[used]

    cleaned = Mesh(vertices=np.asarray(mesh.vertices)[used],
                   faces=compact.reshape(kept_faces.shape).astype(np.int64),
                   colors=rows(getattr(mesh, "colors", None)),
                   skin_weights=rows(getattr(mesh, "skin_weights", None)))
    return cleaned, Specks(int((~kept_pieces).sum()), float(areas[~kept_pieces].sum()))
