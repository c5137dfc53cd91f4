"""Forward kinematics, LBS and mirroring against hand-computed and explicit references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lisa_hand.geometry import apply_transform, axis_angle_to_matrix, make_transform
from lisa_hand.skeleton import (
    PARENTS,
    check_pose,
    check_side,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
    mirror_pose,
)

F64 = torch.float64


def _straight_hand(dtype=F64) -> torch.Tensor:
    """Rest joints: each finger a straight chain along +x (metres), the thumb off to the side."""
    joints = torch.zeros(16, 3, dtype=dtype)
    for base, z in ((1, 0.02), (4, 0.0), (7, -0.04), (10, -0.02)):
        for level, x in enumerate((0.10, 0.14, 0.17)):
            joints[base + level] = torch.tensor([x, 0.0, z], dtype=dtype)
    joints[13:] = torch.tensor([[0.03, 0.0, 0.04], [0.06, 0.0, 0.06], [0.08, 0.0, 0.07]])
    return joints


def _random_case(batch: int = 3, seed: int = 0, dtype=F64):
    rng = np.random.default_rng(seed)
    pose = torch.as_tensor(rng.uniform(-0.8, 0.8, (batch, 48)), dtype=dtype)
    rest = _straight_hand(dtype) + torch.as_tensor(rng.normal(0, 0.005, (16, 3)), dtype=dtype)
    translation = torch.as_tensor(rng.uniform(-0.1, 0.1, (batch, 3)), dtype=dtype)
    return pose, rest, translation


def _fk_reference(pose: np.ndarray, rest: np.ndarray, translation: np.ndarray):
    """Explicit per-joint loop with scipy rotations: (joints [16, 3], A [16, 4, 4])."""
    rotmats = Rotation.from_rotvec(pose.reshape(16, 3)).as_matrix()
    world = [None] * 16
    for j in range(16):
        local = np.eye(4)
        local[:3, :3] = rotmats[j]
        local[:3, 3] = rest[j] if j == 0 else rest[j] - rest[PARENTS[j]]
        world[j] = local if j == 0 else world[PARENTS[j]] @ local
    joints = np.stack([frame[:3, 3] for frame in world]) + translation
    transforms = np.stack([np.eye(4)] * 16)
    for j in range(16):
        transforms[j, :3, :3] = world[j][:3, :3]
        transforms[j, :3, 3] = joints[j] - world[j][:3, :3] @ rest[j]
    return joints, transforms


def test_zero_pose_gives_rest_pose_and_identity_transforms():
    rest = _straight_hand()
    kin = forward_kinematics(torch.zeros(2, 48, dtype=F64), rest)
    assert kin.joints.shape == (2, 16, 3)
    torch.testing.assert_close(kin.joints, rest.expand(2, 16, 3), atol=0, rtol=0)
    eye = torch.eye(4, dtype=F64).expand(2, 16, 4, 4)
    torch.testing.assert_close(kin.transforms, eye, atol=0, rtol=0)
    expected_frames = make_transform(torch.eye(3, dtype=F64).expand(16, 3, 3), rest)
    torch.testing.assert_close(kin.bone_frames, expected_frames.expand(2, 16, 4, 4))


def test_finger_bent_by_hand_computed_angles():
    # Index chain: joints 1, 2, 3 at x = 0.10, 0.14, 0.17 (z = 0.02). Bend joint 1 by +90 deg about
    # z: its children swing from +x to +y. Then joint 2 by +90 deg about y: the last bone, along +x
    # in joint 2's frame, turns to -z there, and joint 1's z-rotation leaves -z unchanged.
    rest = _straight_hand()
    pose = torch.zeros(1, 16, 3, dtype=F64)
    pose[0, 1] = torch.tensor([0.0, 0.0, math.pi / 2])
    kin = forward_kinematics(pose, rest)
    torch.testing.assert_close(kin.joints[0, 2], torch.tensor([0.10, 0.04, 0.02], dtype=F64))
    torch.testing.assert_close(kin.joints[0, 3], torch.tensor([0.10, 0.07, 0.02], dtype=F64))
    pose[0, 2] = torch.tensor([0.0, math.pi / 2, 0.0])
    kin = forward_kinematics(pose, rest)
    torch.testing.assert_close(kin.joints[0, 1], rest[1])
    torch.testing.assert_close(kin.joints[0, 2], torch.tensor([0.10, 0.04, 0.02], dtype=F64))
    torch.testing.assert_close(kin.joints[0, 3], torch.tensor([0.10, 0.04, -0.01], dtype=F64))
    others = [j for j in range(16) if j not in (2, 3)]
    torch.testing.assert_close(kin.joints[0, others], rest[others])


def test_global_orientation_rotates_about_the_wrist():
    rest = _straight_hand() + torch.tensor([0.01, 0.02, 0.03], dtype=F64)
    pose = torch.zeros(1, 48, dtype=F64)
    pose[0, :3] = torch.tensor([0.0, math.pi, 0.0])  # 180 deg about y: (x, y, z) -> (-x, y, -z)
    kin = forward_kinematics(pose, rest)
    relative = rest - rest[0]
    expected = rest[0] + relative * torch.tensor([-1.0, 1.0, -1.0], dtype=F64)
    torch.testing.assert_close(kin.joints[0], expected)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fk_matches_explicit_loop_reference(dtype):
    pose, rest, translation = _random_case(dtype=dtype)
    kin = forward_kinematics(pose, rest, translation)
    assert kin.joints.dtype == kin.transforms.dtype == dtype
    tol = 1e-12 if dtype == F64 else 1e-5
    for b in range(pose.shape[0]):
        joints, transforms = _fk_reference(
            pose[b].double().numpy(), rest.double().numpy(), translation[b].double().numpy()
        )
        np.testing.assert_allclose(kin.joints[b].double().numpy(), joints, atol=tol)
        np.testing.assert_allclose(kin.transforms[b].double().numpy(), transforms, atol=tol)


def test_transforms_map_rest_joints_and_agree_with_bone_frames():
    pose, rest, translation = _random_case(seed=1)
    kin = forward_kinematics(pose, rest, translation)
    moved = apply_transform(kin.transforms, rest[None, :, None, :].expand(3, 16, 1, 3))[:, :, 0]
    torch.testing.assert_close(moved, kin.joints)
    # A_j = bone_frames_j @ [I | -J_rest_j]
    unshift = make_transform(torch.eye(3, dtype=F64).expand(16, 3, 3), -rest)
    torch.testing.assert_close(kin.transforms, kin.bone_frames @ unshift)
    torch.testing.assert_close(kin.bone_frames[..., :3, 3], kin.joints)
    # The frame's rotation is the chain product of relative rotations.
    rotmats = axis_angle_to_matrix(pose.reshape(3, 16, 3))
    torch.testing.assert_close(kin.rotmats, rotmats)
    chain = rotmats[:, 13] @ rotmats[:, 14] @ rotmats[:, 15]
    torch.testing.assert_close(kin.bone_frames[:, 15, :3, :3], rotmats[:, 0] @ chain)


def test_translation_shifts_everything():
    pose, rest, translation = _random_case(seed=2)
    plain = forward_kinematics(pose, rest)
    moved = forward_kinematics(pose, rest, translation)
    torch.testing.assert_close(moved.joints, plain.joints + translation[:, None])
    torch.testing.assert_close(
        moved.transforms[..., :3, 3], plain.transforms[..., :3, 3] + translation[:, None]
    )
    torch.testing.assert_close(moved.transforms[..., :3, :3], plain.transforms[..., :3, :3])


def test_batched_rest_joints_and_pose_as_joint_triplets():
    pose, rest, _ = _random_case(batch=2, seed=3)
    rest_batch = torch.stack([rest, rest * 1.1])
    kin = forward_kinematics(pose.reshape(2, 16, 3), rest_batch)
    torch.testing.assert_close(kin.joints[1], forward_kinematics(pose[1:], rest * 1.1).joints[0])


def test_fk_gradcheck():
    pose, rest, translation = _random_case(batch=1, seed=4)
    inputs = (
        pose.requires_grad_(True),
        rest.requires_grad_(True),
        translation.requires_grad_(True),
    )

    def posed_joints(pose, rest, translation):
        kin = forward_kinematics(pose, rest, translation)
        return kin.joints, kin.transforms[..., :3, :]

    assert torch.autograd.gradcheck(posed_joints, inputs, eps=1e-7, atol=1e-7)


def test_fk_gradient_finite_at_zero_pose():
    pose = torch.zeros(1, 48, dtype=torch.float32, requires_grad=True)
    forward_kinematics(pose, _straight_hand(torch.float32)).joints.square().sum().backward()
    assert torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_fk_and_lbs_on_cuda_match_cpu():
    pose, rest, translation = _random_case(dtype=torch.float32)
    weights = torch.softmax(torch.randn(50, 16, generator=torch.Generator().manual_seed(0)), -1)
    points = torch.randn(50, 3, generator=torch.Generator().manual_seed(1)) * 0.05
    cpu = forward_kinematics(pose, rest, translation)
    gpu = forward_kinematics(pose.cuda(), rest.cuda(), translation.cuda())
    assert gpu.joints.is_cuda
    torch.testing.assert_close(gpu.joints.cpu(), cpu.joints, atol=1e-5, rtol=0)
    skinned = linear_blend_skinning(points.cuda(), weights.cuda(), gpu.transforms)
    expected = linear_blend_skinning(points, weights, cpu.transforms)
    torch.testing.assert_close(skinned.cpu(), expected, atol=1e-5, rtol=0)


# --------------------------------------------------------------------------------------------------
# LBS


def _random_weights(num_points: int, seed: int) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    weights = rng.uniform(size=(num_points, 16)) ** 4
    return torch.as_tensor(weights / weights.sum(-1, keepdims=True))


def test_lbs_is_identity_at_rest():
    points = torch.as_tensor(np.random.default_rng(5).normal(0, 0.05, (2, 40, 3)))
    kin = forward_kinematics(torch.zeros(2, 48, dtype=F64), _straight_hand())
    skinned = linear_blend_skinning(points, _random_weights(40, 5), kin.transforms)
    torch.testing.assert_close(skinned, points, atol=1e-15, rtol=0)


def test_lbs_with_one_hot_weights_is_the_bone_transform():
    pose, rest, translation = _random_case(seed=6)
    kin = forward_kinematics(pose, rest, translation)
    points = torch.as_tensor(np.random.default_rng(6).normal(0, 0.05, (16, 3)))
    bones = torch.arange(16)  # point i rides bone i
    weights = torch.nn.functional.one_hot(bones, 16).to(F64)
    skinned = linear_blend_skinning(points, weights, kin.transforms)
    expected = apply_transform(kin.transforms, points[None, :, None, :].expand(3, 16, 1, 3))[
        :, :, 0
    ]
    torch.testing.assert_close(skinned, expected)


def test_lbs_matches_explicit_sum_over_bones():
    pose, rest, translation = _random_case(seed=7)
    kin = forward_kinematics(pose, rest, translation)
    points = np.random.default_rng(7).normal(0, 0.05, (3, 30, 3))
    weights = _random_weights(30, 7)
    skinned = linear_blend_skinning(torch.as_tensor(points), weights, kin.transforms)
    transforms, w = kin.transforms.numpy(), weights.numpy()
    expected = np.zeros_like(points)
    for b in range(3):
        for v in range(30):
            blended = sum(w[v, j] * transforms[b, j] for j in range(16))
            expected[b, v] = blended[:3, :3] @ points[b, v] + blended[:3, 3]
    np.testing.assert_allclose(skinned.numpy(), expected, atol=1e-14)


def test_lbs_shape_mismatch_raises():
    kin = forward_kinematics(torch.zeros(1, 48), _straight_hand(torch.float32))
    with pytest.raises(ValueError, match=r"weights \(10, 15\) do not match points \(1, 10, 3\)"):
        linear_blend_skinning(torch.zeros(10, 3), torch.zeros(10, 15), kin.transforms)
    weights = torch.full((10, 16), 1.0 / 16)
    with pytest.raises(
        ValueError, match=r"points_rest must be \[V, 3\] or \[B, V, 3\], got \(10, 2\)"
    ):
        linear_blend_skinning(torch.zeros(10, 2), weights, kin.transforms)
    with pytest.raises(ValueError, match=r"transforms must be \[B, J, 4, 4\], got \(16, 4, 4\)"):
        linear_blend_skinning(torch.zeros(10, 3), weights, kin.transforms[0])
    with pytest.raises(ValueError, match=r"weights must be \[V, J\] or \[B, V, J\], got \(160,\)"):
        linear_blend_skinning(torch.zeros(10, 3), weights.reshape(-1), kin.transforms)
    with pytest.raises(ValueError, match="points_rest has batch size 3 but transforms has 1"):
        linear_blend_skinning(torch.zeros(3, 10, 3), weights, kin.transforms)


def test_lbs_broadcasts_single_batch_points_and_weights():
    pose, rest, translation = _random_case(batch=3, seed=9)
    kin = forward_kinematics(pose, rest, translation)
    gen = torch.Generator().manual_seed(9)
    weights = torch.softmax(torch.randn(7, 16, generator=gen, dtype=F64), dim=-1)
    points = torch.randn(7, 3, generator=gen, dtype=F64)
    expected = linear_blend_skinning(points, weights, kin.transforms)
    got = linear_blend_skinning(points[None], weights[None], kin.transforms)
    assert got.shape == (3, 7, 3)
    torch.testing.assert_close(got, expected, atol=0, rtol=0)


# --------------------------------------------------------------------------------------------------
# Mirroring, validation


def test_mirrored_pose_on_mirrored_skeleton_is_the_mirror_image():
    pose, rest, translation = _random_case(seed=8)
    kin = forward_kinematics(pose, rest, translation)
    mirrored = forward_kinematics(
        mirror_pose(pose), mirror_points(rest), mirror_points(translation)
    )
    torch.testing.assert_close(mirrored.joints, mirror_points(kin.joints))
    points = torch.as_tensor(np.random.default_rng(8).normal(0, 0.05, (25, 3)))
    weights = _random_weights(25, 8)
    torch.testing.assert_close(
        linear_blend_skinning(mirror_points(points), weights, mirrored.transforms),
        mirror_points(linear_blend_skinning(points, weights, kin.transforms)),
    )


def test_mirror_pose_conjugates_rotations():
    pose = torch.as_tensor(np.random.default_rng(9).uniform(-2, 2, (4, 48)))
    mirror = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=F64))
    rotmats = axis_angle_to_matrix(pose.reshape(4, 16, 3))
    mirrored = axis_angle_to_matrix(mirror_pose(pose).reshape(4, 16, 3))
    torch.testing.assert_close(mirrored, mirror @ rotmats @ mirror)
    assert mirror_pose(pose.reshape(4, 16, 3)).shape == (4, 16, 3)
    torch.testing.assert_close(mirror_pose(mirror_pose(pose)), pose)
    with pytest.raises(ValueError, match=r"pose must be \[\.\.\., 3k\].*got \(2, 47\)"):
        mirror_pose(torch.zeros(2, 47))


def test_check_pose_accepts_both_layouts_and_rejects_bad_input():
    assert check_pose(torch.zeros(2, 48)).shape == (2, 16, 3)
    assert check_pose(torch.zeros(2, 16, 3)).shape == (2, 16, 3)
    with pytest.raises(ValueError, match=r"pose must have shape \[B, 48\].*got \(2, 47\)"):
        check_pose(torch.zeros(2, 47))
    bad = torch.zeros(1, 48)
    bad[0, 5] = float("nan")
    with pytest.raises(ValueError, match="pose contains NaN or inf"):
        forward_kinematics(bad, _straight_hand(torch.float32))
    with pytest.raises(TypeError, match="pose must be a torch.Tensor, got ndarray"):
        check_pose(np.zeros((1, 48)))
    with pytest.raises(TypeError, match=r"pose must be a floating-point tensor.*torch\.int64"):
        forward_kinematics(torch.zeros(1, 48, dtype=torch.long), _straight_hand())


def test_fk_rejects_bad_rest_joints_and_translation():
    pose = torch.zeros(2, 48)
    with pytest.raises(
        ValueError, match=r"rest_joints must be \[16, 3\] or \[B, 16, 3\], got \(15, 3\)"
    ):
        forward_kinematics(pose, torch.zeros(15, 3))
    with pytest.raises(TypeError, match="rest_joints must be a torch.Tensor, got ndarray"):
        forward_kinematics(pose, np.zeros((16, 3)))
    with pytest.raises(ValueError, match="rest_joints has batch size 3 but pose has 2"):
        forward_kinematics(pose, torch.zeros(3, 16, 3))
    with pytest.raises(TypeError, match="translation must be a torch.Tensor or None, got ndarray"):
        forward_kinematics(pose, torch.zeros(16, 3), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"translation must be \[B, 3\] with B=2, got \(3,\)"):
        forward_kinematics(pose, torch.zeros(16, 3), torch.zeros(3))
    with pytest.raises(ValueError, match="translation contains NaN or inf"):
        forward_kinematics(pose, torch.zeros(16, 3), torch.full((2, 3), float("inf")))


def test_check_side():
    assert check_side("right") == "right" and check_side("left") == "left"
    for bad in ("Right", "middle", ""):
        with pytest.raises(ValueError, match=r"unknown hand side .*expected 'right' or 'left'"):
            check_side(bad)
