"""A cutting plane: which points lie on its kept side, and a mesh cut along it.

The wrist cut of the fits and the metrics (:func:`lisa_hand.skeleton.wrist.wrist_plane`) is one:
a scan may stop anywhere at the wrist or run on into the forearm, LISA's surface ends in a short
stub, so everything beyond the plane is left out of the fit, the written mesh and the distances
alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Plane", "clip_mesh"]


@dataclass(frozen=True)
class Plane:
    """The plane through ``point`` [3] (metres) with unit ``normal`` [3], pointing to the side
    that is kept (for the wrist: towards the fingers)."""

    point: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        point = np.asarray(self.point, np.float64).reshape(-1)
        normal = np.asarray(self.normal, np.float64).reshape(-1)
        if point.shape != (3,) or normal.shape != (3,):
            raise ValueError(f"a plane needs a point [3] and a normal [3], got "
                             f"{point.shape} and {normal.shape}")
        length = float(np.linalg.norm(normal))
        if not (np.isfinite(point).all() and np.isfinite(length) and length > 1e-12):
            raise ValueError("a plane needs a finite point and a finite, non-zero normal")
        object.__setattr__(self, "point", point)
        object.__setattr__(self, "normal", normal / length)

    def signed_distance(self, points) -> np.ndarray:
        """points: [N, 3] metres -> [N] metres, positive on the kept side."""
        return (np.asarray(points, np.float64) - self.point) @ self.normal

    def keeps(self, points, margin: float = 0.0) -> np.ndarray:
        """[N] bool: the points on the kept side, or within ``margin`` metres beyond it."""
        return self.signed_distance(points) >= -float(margin)

    def shifted(self, distance: float) -> Plane:
        """The parallel plane moved ``distance`` metres along the normal (negative: beyond)."""
        return Plane(self.point + float(distance) * self.normal, self.normal)

    def to_dict(self) -> dict:
        return {"point": self.point.tolist(), "normal": self.normal.tolist()}


def clip_mesh(vertices, faces, plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """The part of a triangle mesh on the plane's kept side, cut exactly along the plane
    (``trimesh.intersections.slice_faces_plane``; left open where it is cut, as a scan that
    stops there; the cut's new vertices are shared by the faces on both sides of an edge).

    vertices: [V, 3] metres; faces: [F, 3] -> (vertices [V', 3] float64, faces [F', 3] int64);
    empty arrays when nothing is kept. Vertices that no kept face uses are dropped.
    """
    import trimesh
    from trimesh.intersections import slice_faces_plane

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if faces.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    distance = plane.signed_distance(vertices)
    if (distance >= 0).all():
        return vertices, faces
    if (distance < 0).all():
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    new_vertices, new_faces = slice_faces_plane(vertices, faces, plane.normal, plane.point)[:2]
    # Merge the cut's duplicated vertices (each cut edge's point is made once per face).
    cut = trimesh.Trimesh(new_vertices, new_faces, process=False)
    cut.merge_vertices(digits_vertex=12)
    cut.remove_unreferenced_vertices()
    return np.asarray(cut.vertices, np.float64), np.asarray(cut.faces, np.int64)
