"""Catmull-Clark subdivision of a closed polygon mesh, as a sparse linear operator.

Catmull-Clark is linear in the vertex positions, so one subdivision step of a fixed topology is a
sparse matrix ``S`` [V', V]: the subdivided vertices of any morph of the mesh are ``S @ vertices``,
and any per-vertex attribute (skinning weights, morph offsets) is carried the same way. The
matrix is built once per topology (:func:`catmull_clark`) and reused for every subject.

Rules (closed, manifold meshes; Catmull & Clark 1978, as in OpenSubdiv without creases):

- face point: the mean of the face's corners;
- edge point: ``(v0 + v1 + f_a + f_b) / 4`` (the edge's ends and its two faces' points);
- vertex point: ``(Q + 2 R + (n - 3) P) / n`` with ``n >= 2`` the valence, ``Q`` the mean of the
  adjacent face points, ``R`` the mean of the incident edges' midpoints, ``P`` the old position.

Every face of ``k`` corners becomes ``k`` quads ``(v_i, e_i, f, e_{i-1})``, keeping its
orientation. Not differentiable: plain numpy / scipy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["Subdivision", "catmull_clark", "subdivide", "quads_to_triangles"]


@dataclass(frozen=True)
class Subdivision:
    """One or more Catmull-Clark steps of a fixed topology.

    matrix: [V', V] sparse (CSR) float64, rows summing to 1: subdivided = ``matrix @ vertices``.
    quads: [Q', 4] int64 faces of the subdivided mesh (every face a quad), same orientation.
    """

    matrix: sp.csr_matrix
    quads: np.ndarray

    def apply(self, values: np.ndarray) -> np.ndarray:
        """[V, ...] per-vertex values -> [V', ...] (positions, weights, offsets)."""
        values = np.asarray(values)
        flat = values.reshape(values.shape[0], -1)
        return np.asarray(self.matrix @ flat).reshape((self.matrix.shape[0],) + values.shape[1:])


def _edges(faces: Sequence[Sequence[int]]) -> tuple[np.ndarray, dict[tuple[int, int], int]]:
    """Unique undirected edges [E, 2] (sorted ends) and the index of each sorted pair."""
    index: dict[tuple[int, int], int] = {}
    for face in faces:
        for i, a in enumerate(face):
            b = face[(i + 1) % len(face)]
            key = (min(a, b), max(a, b))
            if key not in index:
                index[key] = len(index)
    edges = np.array(list(index), dtype=np.int64).reshape(-1, 2)
    return edges, index


def _step(faces: Sequence[Sequence[int]], num_vertices: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """One Catmull-Clark step: (matrix [V + E + F, V], quads [sum k, 4])."""
    faces = [list(map(int, face)) for face in faces]
    edges, edge_index = _edges(faces)
    num_edges, num_faces = len(edges), len(faces)
    edge_faces: list[list[int]] = [[] for _ in range(num_edges)]
    vertex_faces: list[list[int]] = [[] for _ in range(num_vertices)]
    for f, face in enumerate(faces):
        for i, a in enumerate(face):
            b = face[(i + 1) % len(face)]
            edge_faces[edge_index[(min(a, b), max(a, b))]].append(f)
            vertex_faces[a].append(f)
    if any(len(adjacent) != 2 for adjacent in edge_faces):
        raise ValueError("catmull_clark needs a closed manifold mesh: every edge in two faces")
    vertex_edges: list[list[int]] = [[] for _ in range(num_vertices)]
    for e, (a, b) in enumerate(edges):
        vertex_edges[a].append(e)
        vertex_edges[b].append(e)

    # Face points as rows over the old vertices.
    face_rows = sp.lil_matrix((num_faces, num_vertices))
    for f, face in enumerate(faces):
        for a in face:
            face_rows[f, a] += 1.0 / len(face)
    face_rows = face_rows.tocsr()
    # Edge points: the ends and the two face points, a quarter each.
    ends = sp.csr_matrix((np.full(2 * num_edges, 0.25), (np.repeat(np.arange(num_edges), 2),
                                                          edges.ravel())),
                         shape=(num_edges, num_vertices))
    pairs = np.array(edge_faces)
    edge_rows = ends + 0.25 * (face_rows[pairs[:, 0]] + face_rows[pairs[:, 1]])
    # Vertex points: (Q + 2R + (n - 3)P) / n.
    vertex_rows = sp.lil_matrix((num_vertices, num_vertices))
    q_rows = []
    for v in range(num_vertices):
        valence = len(vertex_edges[v])
        if valence < 2:
            raise ValueError(f"catmull_clark: vertex {v} has {valence} edges (needs >= 2)")
        for e in vertex_edges[v]:  # R: mean of the edge midpoints
            a, b = edges[e]
            vertex_rows[v, a] += 1.0 / valence / valence
            vertex_rows[v, b] += 1.0 / valence / valence
        vertex_rows[v, v] += (valence - 3.0) / valence
        q_rows.append(vertex_faces[v])
    q = sp.lil_matrix((num_vertices, num_faces))
    for v, adjacent in enumerate(q_rows):
        for f in adjacent:
            q[v, f] += 1.0 / len(adjacent) / len(vertex_edges[v])
    vertex_rows = vertex_rows.tocsr() + q.tocsr() @ face_rows
    matrix = sp.vstack([vertex_rows, edge_rows, face_rows]).tocsr()

    quads = []
    for f, face in enumerate(faces):
        k = len(face)
        for i in range(k):
            a, b, prev = face[i], face[(i + 1) % k], face[i - 1]
            e_next = num_vertices + edge_index[(min(a, b), max(a, b))]
            e_prev = num_vertices + edge_index[(min(prev, a), max(prev, a))]
            quads.append((a, e_next, num_vertices + num_edges + f, e_prev))
    return matrix, np.array(quads, dtype=np.int64)


def catmull_clark(faces: Sequence[Sequence[int]], num_vertices: int,
                  levels: int = 1) -> Subdivision:
    """``levels`` Catmull-Clark steps of a closed polygon mesh.

    faces: polygons (lists of >= 3 vertex indices, counter-clockwise from outside).
    num_vertices: V. -> :class:`Subdivision` (its matrix maps the original V vertices).
    """
    if not isinstance(levels, int) or levels < 1:
        raise ValueError(f"levels must be an int >= 1, got {levels!r}")
    matrix = sp.identity(num_vertices, format="csr")
    current: Sequence[Sequence[int]] = faces
    count = num_vertices
    for _ in range(levels):
        step, quads = _step(current, count)
        matrix = (step @ matrix).tocsr()
        current, count = quads, step.shape[0]
    return Subdivision(matrix=matrix, quads=np.asarray(current, dtype=np.int64))


def subdivide(vertices: np.ndarray, faces: Sequence[Sequence[int]],
              levels: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Subdivided ``(vertices [V', 3], quads [Q', 4])`` of a closed polygon mesh."""
    vertices = np.asarray(vertices, dtype=np.float64)
    operator = catmull_clark(faces, len(vertices), levels)
    return operator.apply(vertices), operator.quads


def quads_to_triangles(quads: np.ndarray) -> np.ndarray:
    """[Q, 4] quads -> [2Q, 3] triangles (split along the 0-2 diagonal, orientation kept)."""
    quads = np.asarray(quads, dtype=np.int64)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=0).reshape(-1, 3)
