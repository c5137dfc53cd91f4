"""First-hit ray casting against a triangle mesh (lisa_hand.render.raycast), checked against a
sphere's closed-form hits and trimesh's normals."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.render.raycast import MeshRayCaster, check_mesh, vertex_normals

RADIUS = 0.1


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64)


def test_vertex_normals_match_trimesh_and_the_sphere(sphere):
    vertices, faces = sphere
    normals = vertex_normals(vertices, faces)
    np.testing.assert_allclose(normals, vertices / RADIUS, atol=3e-3)
    capsule = trimesh.creation.capsule(height=0.1, radius=0.03)  # faces of very different shapes
    np.testing.assert_allclose(vertex_normals(capsule.vertices, capsule.faces),
                               capsule.vertex_normals, atol=1e-5)


def test_first_hits_on_a_sphere(sphere):
    """Rays from 0.5 m along -z towards the sphere: hits at the closed-form distance on the near
    side, misses beyond the radius; barycentrics sum to 1 on hits; torch inputs are taken."""
    caster = MeshRayCaster(*(torch.from_numpy(array) for array in sphere))
    offsets = np.array([0.0, 0.05, 0.09, 0.11, 0.2])
    origins = np.stack([offsets, np.zeros(5), np.full(5, -0.5)], axis=1)
    directions = np.tile([0.0, 0.0, 1.0], (5, 1))
    hits = caster.intersect(torch.from_numpy(origins), directions)
    np.testing.assert_array_equal(hits.hit, [True, True, True, False, False])
    expected = 0.5 - np.sqrt(RADIUS**2 - offsets[:3] ** 2)
    np.testing.assert_allclose(hits.distances[:3], expected, atol=2e-3)
    assert np.isinf(hits.distances[3:]).all() and (hits.face_ids[3:] == -1).all()
    np.testing.assert_allclose(hits.barycentrics[:3].sum(1), 1.0, atol=1e-5)
    assert (caster.face_normals[hits.face_ids[:3], 2] < 0).all()  # the near side faces the rays
    # A near bound past the front surface finds the back one.
    back = caster.intersect(origins[:1], directions[:1], near=0.5)
    np.testing.assert_allclose(back.distances, [0.5 + RADIUS], atol=2e-3)
    assert caster.intersect(np.zeros((0, 3)), np.zeros((0, 3))).hit.shape == (0,)


def test_invalid_meshes_and_rays(sphere):
    vertices, faces = sphere
    with pytest.raises(ValueError, match="vertices"):
        check_mesh(vertices[:, :2], faces)
    with pytest.raises(ValueError, match="faces index vertices"):
        check_mesh(vertices, faces + len(vertices))
    with pytest.raises(TypeError, match="faces must hold integer"):
        check_mesh(vertices, faces.astype(np.float32))
    with pytest.raises(ValueError, match="origins must have shape"):
        MeshRayCaster(vertices, faces).intersect(np.zeros((1, 2)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="directions must have the shape"):
        MeshRayCaster(vertices, faces).intersect(np.zeros((2, 3)), np.zeros((1, 3)))
