"""Meshes of a hand (lisa_hand.inference.mesh): coarse to fine, colours, weights, re-posing."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from lisa_hand import inference
from lisa_hand.metrics import mesh_distances
from lisa_hand.skeleton import forward_kinematics

from .helpers import BIAS, GAIN, PADDING, REST, hand_params


def test_mesh_is_dense_evaluation_with_calibrated_colours_and_weights(model, right_mesh):
    params = hand_params(model)
    dense = inference.mesh_hand_with_stats(
        model, params, 40, inference.MeshConfig(padding=PADDING, coarse_to_fine=False,
                                                colors=False, skin_weights=False))
    fast = right_mesh
    assert fast.extraction.num_evaluations < 0.5 * dense.extraction.num_evaluations
    distances = mesh_distances(fast.mesh.vertices, fast.mesh.faces, dense.mesh.vertices,
                               dense.mesh.faces)
    assert distances.v2s_recon_to_scan_mm < 0.05 and distances.v2s_scan_to_recon_mm < 0.05
    # Independent evaluation of the field at the vertices: colours are gain * rgb + bias.
    mesh = fast.mesh
    state = model.field.prepare(**params.batch())
    with torch.no_grad():
        out = model.field.field(state, torch.from_numpy(mesh.vertices)[None])
    expected = (out.rgb[0] * torch.tensor(GAIN) + torch.tensor(BIAS))
    expected = np.rint(expected.clamp(0, 1).numpy() * 255)
    assert np.abs(mesh.colors.astype(float) - expected).max() <= 1
    assert mesh.skin_weights.shape == (mesh.num_vertices, 16)
    np.testing.assert_allclose(mesh.skin_weights, out.weights[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(mesh.skin_weights.sum(1), 1.0, atol=1e-5)
    # On the surface: the SDF at the vertices is ~0 (linear interpolation error; a few vertices
    # sit where the untrained blob meets the edge of a bone region, a jump of the field).
    assert np.quantile(out.sdf.abs().numpy(), 0.9) < 0.1 * fast.voxel_size


def test_left_hand_is_the_mirror_image(model, right_mesh):
    left = inference.mesh_hand(model, hand_params(model, side="left"), 40,
                               inference.MeshConfig(padding=PADDING, colors=False,
                                                    skin_weights=False))
    mirrored = right_mesh.mesh.vertices * np.array([-1.0, 1.0, 1.0], dtype=np.float32)
    assert left.num_vertices == right_mesh.mesh.num_vertices
    assert cKDTree(mirrored).query(left.vertices)[0].max() < 1e-6
    # Outward normals on both: the signed volume is positive.
    for mesh in (left, right_mesh.mesh):
        v = mesh.vertices.astype(np.float64)[mesh.faces]
        volume = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
        assert volume > 1e-5  # m^3: a blob of a hand holds some 100 cm^3


def test_repose_mesh_by_skinning(model, right_mesh):
    params = hand_params(model)
    mesh = right_mesh.mesh
    same = inference.repose_mesh(mesh, params, params.pose)
    np.testing.assert_allclose(same.vertices, mesh.vertices, atol=1e-6)
    new_pose = params.pose.clone()
    new_pose[3:] = 0.4
    moved = inference.repose_mesh(mesh, params, new_pose, torch.tensor([0.0, 0.0, 0.5]))
    assert moved.num_vertices == mesh.num_vertices and np.array_equal(moved.faces, mesh.faces)
    back = inference.repose_mesh(moved, params.with_pose(new_pose, torch.tensor([0.0, 0.0, 0.5])),
                                 params.pose, params.translation)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-5)
    # A vertex owned by one bone moves rigidly with it: A_j(new) A_j(old)^-1 v.
    owned = np.flatnonzero(mesh.skin_weights.max(axis=1) > 1 - 1e-6)
    assert owned.size > 10
    bone = mesh.skin_weights[owned].argmax(axis=1)
    old = forward_kinematics(params.pose[None].double(), REST[None].double(),
                             params.translation[None].double()).transforms[0]
    new = forward_kinematics(new_pose[None].double(), REST[None].double(),
                             torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64)).transforms[0]
    relative = (new @ torch.linalg.inv(old))[torch.from_numpy(bone)]
    v = torch.from_numpy(mesh.vertices[owned]).double()
    expected = (relative[:, :3, :3] @ v[..., None])[..., 0] + relative[:, :3, 3]
    np.testing.assert_allclose(moved.vertices[owned], expected.numpy(), atol=2e-6)


def test_bad_inputs(model, right_mesh):
    params = hand_params(model)
    with pytest.raises(ValueError, match="resolution must be >= 8"):
        inference.mesh_hand(model, params, 4)
    with pytest.raises(TypeError, match="resolution must be an int"):
        inference.check_resolution(32.0)
    assert inference.check_resolution(np.int64(16)) == 16
    with pytest.raises(ValueError, match="chunk_size must be a positive int"):
        inference.MeshConfig(chunk_size=0)
    with pytest.raises(ValueError, match="lipschitz must be >= 1"):
        inference.MeshConfig(lipschitz=0.5)
    bare = inference.mesh_hand_with_stats(
        model, params, 16, inference.MeshConfig(padding=PADDING, skin_weights=False)).mesh
    with pytest.raises(ValueError, match="skinning weights"):
        inference.repose_mesh(bare, params, params.pose)
    with pytest.raises(ValueError, match=r"pose must have shape \[48\]"):
        inference.repose_mesh(right_mesh.mesh, params, torch.zeros(45))
