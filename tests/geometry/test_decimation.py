"""Decimation of a mesh for pictures (:mod:`lisa_hand.geometry.decimation`)."""

from __future__ import annotations

import numpy as np
import pytest


def test_decimate_mesh_keeps_the_shape_and_the_attributes(monkeypatch):
    import point_cloud_utils as pcu
    import trimesh

    from lisa_hand.geometry.decimation import decimate_mesh
    from lisa_hand.geometry.meshing import Mesh

    sphere = trimesh.creation.icosphere(subdivisions=4)  # 5120 faces, radius 1
    colours = np.round(np.abs(sphere.vertices) * 255).astype(np.uint8)
    weights = np.abs(sphere.vertices) / np.abs(sphere.vertices).sum(1, keepdims=True)
    mesh = Mesh(vertices=sphere.vertices, faces=sphere.faces, colors=colours,
                skin_weights=weights)
    small = decimate_mesh(mesh, 1000)
    assert 900 <= len(small.faces) <= 1000
    radius = np.linalg.norm(small.vertices, axis=1)
    assert np.abs(radius - 1.0).max() < 0.05  # still the sphere
    # each vertex keeps the attributes of the vertex it came from, a neighbour of its place
    expected = np.abs(small.vertices) * 255
    assert np.abs(small.colors.astype(float) - expected).max() < 0.1 * 255
    assert np.allclose(small.skin_weights.sum(1), 1.0, atol=1e-6)
    assert decimate_mesh(mesh, 6000) is mesh  # small enough already

    def failing(*args, **kwargs):
        raise ValueError("decimate_triangle_mesh produced an empty mesh")

    monkeypatch.setattr(pcu, "decimate_triangle_mesh", failing)
    assert decimate_mesh(mesh, 1000) is mesh  # edge collapses that fail: the mesh as it is
    with pytest.raises(ValueError, match="max_faces"):
        decimate_mesh(mesh, 2)
