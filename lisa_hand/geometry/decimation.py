"""A triangle mesh with fewer faces, for pictures: :func:`decimate_mesh`."""

from __future__ import annotations

import numpy as np

from .meshing import Mesh

__all__ = ["decimate_mesh"]


def decimate_mesh(mesh: Mesh, max_faces: int) -> Mesh:
    """``mesh`` with at most ``max_faces`` faces, by edge collapses (point-cloud-utils'
    ``decimate_triangle_mesh``); each kept vertex keeps the colour and skinning weights of the
    vertex it came from. A mesh already small enough is returned as it is, and so is one the
    edge collapses fail on (they need a manifold mesh; one cut open at the wrist may stop them
    with an empty result). For pictures: a hand's 56k faces drawn in a 200-pixel region are as
    many as its pixels; 5k look the same and ray cast 5x faster."""
    import point_cloud_utils as pcu

    if max_faces < 4:
        raise ValueError(f"max_faces must be at least 4, got {max_faces}")
    if len(mesh.faces) <= max_faces:
        return mesh
    try:
        vertices, faces, origin, _ = pcu.decimate_triangle_mesh(
            mesh.vertices.astype(np.float64), mesh.faces.astype(np.int32), int(max_faces))
    except (ValueError, RuntimeError):
        return mesh
    if len(faces) == 0:
        return mesh
    origin = np.asarray(origin).reshape(-1)
    return Mesh(vertices=vertices, faces=faces,
                colors=None if mesh.colors is None else mesh.colors[origin],
                skin_weights=None if mesh.skin_weights is None else mesh.skin_weights[origin])
