"""First-hit ray casting against a triangle mesh (Embree, through point-cloud-utils).

:class:`MeshRayCaster` builds the acceleration structure once and casts rays at millions per
second; :func:`vertex_normals` gives the smooth (angle-weighted) normals the ground-truth
renderer (:func:`lisa_hand.data.images.render_views`) interpolates at the hits, and the scan
simulator (:mod:`lisa_hand.data.scans`) uses the caster to test visibility. Arrays are numpy
(float32 points, int32 faces inside; torch tensors are taken too); nothing here is
differentiable. It renders meshes, not fields: unlike the rest of :mod:`lisa_hand.render`, it is
not re-exported by the package (point-cloud-utils is imported on first use).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..utils.arrays import as_numpy

__all__ = ["RayHits", "MeshRayCaster", "check_mesh", "vertex_normals"]


@dataclass(eq=False)
class RayHits:
    """First hits of rays on a mesh. R rays."""

    hit: np.ndarray
    """[R] bool."""
    face_ids: np.ndarray
    """[R] int64 index of the face hit, -1 on a miss."""
    barycentrics: np.ndarray
    """[R, 3] float32 weights of the face's three vertices (0 on a miss)."""
    distances: np.ndarray
    """[R] float32 ray parameter of the hit (metres for unit directions), inf on a miss."""


def check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Validate a triangle mesh (vertices [V, 3] metres, faces [F, 3] vertex indices; numpy or
    torch); -> (float32 [V, 3], int32 [F, 3]) C-contiguous arrays."""
    vertices = as_numpy(vertices, "vertices")
    faces = as_numpy(faces, "faces")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise ValueError(f"vertices must have shape [V, 3] with V > 0, got {list(vertices.shape)}")
    if not np.issubdtype(vertices.dtype, np.floating) or not np.isfinite(vertices).all():
        raise ValueError(f"vertices must be finite floats, got dtype {vertices.dtype}")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise ValueError(f"faces must have shape [F, 3] with F > 0, got {list(faces.shape)}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise TypeError(f"faces must hold integer vertex indices, got dtype {faces.dtype}")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise ValueError(f"faces index vertices in [{faces.min()}, {faces.max()}], outside "
                         f"[0, {vertices.shape[0] - 1}]")
    return (np.ascontiguousarray(vertices, dtype=np.float32),
            np.ascontiguousarray(faces, dtype=np.int32))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted vertex normals (unit; zero for unused vertices).

    Each face adds its unit normal times its corner angle at the vertex (Thuermer and Wuethrich
    1998): closer to the true normal of a smooth surface than area weighting when the faces
    around a vertex differ in shape.

    vertices: [V, 3] metres; faces: [F, 3] counter-clockwise seen from outside.
    -> [V, 3] float32, pointing outwards.
    """
    vertices, faces = check_mesh(vertices, faces)
    corners = vertices.astype(np.float64)[faces]  # [F, 3, 3]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normals /= np.maximum(np.linalg.norm(face_normals, axis=1, keepdims=True), 1e-300)
    # Corner k's angle between the edges to the next and the previous corner.
    to_next = np.roll(corners, -1, axis=1) - corners
    to_prev = np.roll(corners, 1, axis=1) - corners
    to_next /= np.maximum(np.linalg.norm(to_next, axis=2, keepdims=True), 1e-300)
    to_prev /= np.maximum(np.linalg.norm(to_prev, axis=2, keepdims=True), 1e-300)
    angles = np.arccos(np.clip((to_next * to_prev).sum(-1), -1.0, 1.0))  # [F, 3]
    weighted = angles[:, :, None] * face_normals[:, None, :]  # [F, 3, 3]
    flat_ids = faces.reshape(-1)
    normals = np.stack([np.bincount(flat_ids, weights=weighted[:, :, axis].reshape(-1),
                                    minlength=vertices.shape[0]) for axis in range(3)], axis=1)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0, length, 1.0)).astype(np.float32)


class MeshRayCaster:
    """First-hit ray casting against one triangle mesh (Embree, via point-cloud-utils).

    The acceleration structure is built once, on construction (tens of milliseconds for 200k
    faces); :meth:`intersect` then runs at millions of rays per second on a few cores.

    vertices: [V, 3] metres; faces: [F, 3] vertex indices, counter-clockwise seen from outside
    (numpy or torch). Computation is float32.
    """

    def __init__(self, vertices, faces) -> None:
        import point_cloud_utils as pcu

        self.vertices, self.faces = check_mesh(vertices, faces)
        self._intersector = pcu.RayMeshIntersector(self.vertices, self.faces)
        self._vertex_normals: np.ndarray | None = None
        self._face_normals: np.ndarray | None = None

    @property
    def vertex_normals(self) -> np.ndarray:
        """[V, 3] float32 unit angle-weighted vertex normals (computed once)."""
        if self._vertex_normals is None:
            self._vertex_normals = vertex_normals(self.vertices, self.faces)
        return self._vertex_normals

    @property
    def face_normals(self) -> np.ndarray:
        """[F, 3] float32 unit face normals (right-hand rule on the face's vertex order)."""
        if self._face_normals is None:
            corners = self.vertices[self.faces]
            normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            self._face_normals = (normals / np.where(length > 0, length, 1.0)).astype(np.float32)
        return self._face_normals

    def intersect(self, origins, directions, near: float = 0.0,
                  far: float = math.inf) -> RayHits:
        """First hit of each ray ``origin + s direction`` with ``near <= s <= far``.

        origins: [R, 3] metres; directions: [R, 3] (unit for ``s`` in metres).
        """
        origins = np.ascontiguousarray(as_numpy(origins, "origins"), dtype=np.float32)
        directions = np.ascontiguousarray(as_numpy(directions, "directions"), dtype=np.float32)
        if origins.ndim != 2 or origins.shape[1] != 3:
            raise ValueError(f"origins must have shape [R, 3], got {list(origins.shape)}")
        if directions.shape != origins.shape:
            raise ValueError(f"directions must have the shape of origins {list(origins.shape)}, "
                             f"got {list(directions.shape)}")
        if origins.shape[0] == 0:
            return RayHits(hit=np.zeros(0, bool), face_ids=np.zeros(0, np.int64),
                           barycentrics=np.zeros((0, 3), np.float32),
                           distances=np.zeros(0, np.float32))
        face_ids, barycentrics, distances = self._intersector.intersect_rays(
            origins, directions, float(near), float(far))
        # point-cloud-utils squeezes the results of a single ray: shape them back.
        face_ids = np.asarray(face_ids, dtype=np.int64).reshape(-1)
        hit = face_ids >= 0
        distances = np.asarray(distances, np.float32).reshape(-1)
        distances = np.where(hit, distances, np.float32(np.inf))
        barycentrics = np.asarray(barycentrics, np.float32).reshape(-1, 3)
        barycentrics = np.where(hit[:, None], barycentrics, 0.0)
        return RayHits(hit=hit, face_ids=face_ids, barycentrics=barycentrics.astype(np.float32),
                       distances=distances.astype(np.float32))
