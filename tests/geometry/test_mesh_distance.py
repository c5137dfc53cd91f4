"""Signed distances to a closed mesh against the closed form of a box."""

from __future__ import annotations

import numpy as np
import trimesh

from lisa_hand.geometry.mesh_distance import mesh_distance


def _box_sdf(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(points) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0)


def test_box_distances_match_the_closed_form():
    half = np.array([0.03, 0.01, 0.02])
    box = trimesh.creation.box(extents=2 * half)
    points = np.random.default_rng(0).uniform(-0.06, 0.06, (2000, 3))
    where = mesh_distance(points, box.vertices, box.faces)
    np.testing.assert_allclose(where.sdf, _box_sdf(points, half), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(points - where.closest, axis=1), np.abs(where.sdf),
                               atol=1e-12)
    # Per-vertex values are interpolated at the closest points: the positions themselves.
    np.testing.assert_allclose(where.interpolate(box.faces, box.vertices), where.closest,
                               atol=1e-12)
    # One point alone is answered as among others.
    alone = mesh_distance(points[:1], box.vertices, box.faces)
    np.testing.assert_allclose(alone.sdf, where.sdf[:1], atol=1e-12)
