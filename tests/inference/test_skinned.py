"""A fitted hand's mesh posed by skinning (lisa_hand.inference.skinned.SkinnedMesh), on meshes of
the tiny model's right and left hands: the same vertices as
:func:`lisa_hand.inference.mesh.repose_mesh` (a second implementation: it unposes with the
mesh's own pose, not through the zero pose), gradients in the pose and translation against
central finite differences in float64, and ``rows`` picking the same vertices."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand import inference
from lisa_hand.inference.skinned import SkinnedMesh
from lisa_hand.skeleton import mirror_pose

from .helpers import PADDING, hand_params


@pytest.fixture(scope="module", params=["right", "left"])
def hand(request, model):
    """(params, mesh at resolution 32 with skinning weights) of one side."""
    params = hand_params(model, side=request.param)
    mesh = inference.mesh_hand(model, params, 32,
                               inference.MeshConfig(padding=PADDING, colors=False))
    assert mesh.num_vertices > 200 and mesh.skin_weights.shape == (mesh.num_vertices, 16)
    return params, mesh


def new_pose(side: str, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A random pose (0.3 rad a joint, the root turned more) of ``side`` and a translation."""
    generator = torch.Generator().manual_seed(seed)
    pose = 0.3 * torch.randn(48, generator=generator, dtype=torch.float64)
    pose[:3] = torch.tensor([0.9, -0.4, 0.5], dtype=torch.float64)
    translation = torch.tensor([-0.03, 0.05, 0.55], dtype=torch.float64)
    if side == "left":
        pose = mirror_pose(pose)
    return pose, translation


def test_vertices_equal_repose_mesh_in_new_poses(hand):
    params, mesh = hand
    skinned = SkinnedMesh(mesh, params)
    np.testing.assert_array_equal(skinned.rest.faces, mesh.faces)
    for seed in (0, 1):
        pose, translation = new_pose(params.side, seed)
        with torch.no_grad():
            got = skinned.vertices(pose[None], translation[None])[0].numpy()
        reference = inference.repose_mesh(mesh, params, pose, translation).vertices
        assert np.abs(reference - mesh.vertices).max() > 0.02  # the new pose moved it
        np.testing.assert_allclose(got, reference, atol=2e-6)
        posed = skinned.posed(pose.numpy(), translation.numpy())
        np.testing.assert_allclose(posed.vertices, reference, atol=2e-6)
    # Its own pose gives the mesh back.
    with torch.no_grad():
        same = skinned.vertices(params.pose.double()[None], params.translation.double()[None])[0]
    np.testing.assert_allclose(same.numpy(), mesh.vertices, atol=2e-6)


def test_a_batch_of_poses_is_each_pose_alone(hand):
    params, mesh = hand
    skinned = SkinnedMesh(mesh, params)
    poses, translations = zip(*(new_pose(params.side, seed) for seed in (2, 3)), strict=True)
    with torch.no_grad():
        batch = skinned.vertices(torch.stack(poses), torch.stack(translations))
        for index in range(2):
            alone = skinned.vertices(poses[index][None], translations[index][None])[0]
            torch.testing.assert_close(batch[index], alone, rtol=0, atol=1e-12)


def test_rows_select_the_same_vertices(hand):
    params, mesh = hand
    skinned = SkinnedMesh(mesh, params)
    pose, translation = new_pose(params.side, 4)
    rows = torch.randperm(mesh.num_vertices, generator=torch.Generator().manual_seed(5))[:37]
    with torch.no_grad():
        every = skinned.vertices(pose[None], translation[None])
        some = skinned.vertices(pose[None], translation[None], rows)
    assert some.shape == (1, 37, 3)
    torch.testing.assert_close(some, every[:, rows], rtol=0, atol=1e-12)


def test_gradients_match_finite_differences(hand):
    """Central differences of float64 (gradcheck) in all 48 pose values and the translation,
    at a few vertices; the translation's Jacobian is the identity at every vertex (skinning
    weights sum to 1, to float32's precision: they are stored as float32)."""
    params, mesh = hand
    skinned = SkinnedMesh(mesh, params)
    pose, translation = new_pose(params.side, 6)
    rows = torch.randperm(mesh.num_vertices, generator=torch.Generator().manual_seed(7))[:6]

    def posed(pose: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        return skinned.vertices(pose, translation, rows)

    assert torch.autograd.gradcheck(
        posed, (pose[None].clone().requires_grad_(True),
                translation[None].clone().requires_grad_(True)),
        eps=1e-6, atol=1e-7, rtol=1e-5)
    shift = translation[None].clone().requires_grad_(True)
    jacobian = torch.autograd.functional.jacobian(lambda t: posed(pose[None], t), shift)
    identity = torch.eye(3, dtype=torch.float64).expand(6, 3, 3)
    torch.testing.assert_close(jacobian[0, :, :, 0, :], identity, rtol=0, atol=1e-6)
    # The pose does move the vertices (a test of gradients through a constant would pass).
    pose_jacobian = torch.autograd.functional.jacobian(
        lambda p: posed(p, translation[None]), pose[None])
    assert float(pose_jacobian.abs().max()) > 0.01
