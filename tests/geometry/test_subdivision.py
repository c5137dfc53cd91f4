"""Catmull-Clark as a sparse operator, checked on a cube by hand-computed points."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lisa_hand.geometry.subdivision import catmull_clark, quads_to_triangles, subdivide

# A cube [-1, 1]^3, quads counter-clockwise seen from outside.
CUBE_VERTICES = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def test_one_step_of_a_cube_gives_the_hand_computed_points():
    vertices, quads = subdivide(CUBE_VERTICES, CUBE_QUADS)
    assert vertices.shape == (8 + 12 + 6, 3) and quads.shape == (24, 4)
    # A corner (valence 3): (Q + 2R) / 3 with Q = (1/3, 1/3, 1/3), R = (2/3, 2/3, 2/3).
    np.testing.assert_allclose(np.abs(vertices[:8]), 5.0 / 9.0, atol=1e-12)
    # An edge point: the ends and the two face points, a quarter each: (3/4, 3/4, 0) up to signs.
    edge_points = np.sort(np.abs(vertices[8:20]), axis=1)
    np.testing.assert_allclose(edge_points, np.tile([0.0, 0.75, 0.75], (12, 1)), atol=1e-12)
    # Face points: the face centres.
    np.testing.assert_allclose(np.sort(np.abs(vertices[20:]), axis=1),
                               np.tile([0.0, 0.0, 1.0], (6, 1)), atol=1e-12)


def test_the_operator_is_affine_closed_and_outward():
    operator = catmull_clark(CUBE_QUADS, 8, levels=3)
    np.testing.assert_allclose(np.asarray(operator.matrix.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    vertices = operator.apply(CUBE_VERTICES)
    mesh = trimesh.Trimesh(vertices, quads_to_triangles(operator.quads), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    # A rounded cube: between the balls of its nearest and farthest points, inside the cube.
    radius = np.linalg.norm(vertices, axis=1)
    assert np.abs(vertices).max() < 1.0 and radius.min() > 0.5
    assert 4 / 3 * np.pi * radius.min() ** 3 < mesh.volume < 4 / 3 * np.pi * radius.max() ** 3
    # Moving the cube moves every subdivided vertex the same way (translation invariance).
    np.testing.assert_allclose(operator.apply(CUBE_VERTICES + 2.0), vertices + 2.0, atol=1e-12)


def test_an_open_mesh_is_refused():
    with pytest.raises(ValueError, match="closed manifold"):
        catmull_clark(CUBE_QUADS[:-1], 8)
