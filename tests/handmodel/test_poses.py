"""Anatomical angles, joint limits, synergies, named poses and interpolation."""

from __future__ import annotations

import pytest
import torch

from lisa_hand.handmodel import (
    JOINT_LIMITS,
    POSE_NAMES,
    HandShape,
    angles_to_pose,
    clamp_to_limits,
    interpolate_poses,
    named_pose,
    pose_sequence,
    pose_to_angles,
    rest_skeleton,
    sample_pose,
    within_limits,
)
from lisa_hand.skeleton import FINGER_JOINTS, forward_kinematics, mirror_pose

F64 = torch.float64


def _random_angles(seed: int, num: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    low, high = JOINT_LIMITS[..., 0], JOINT_LIMITS[..., 1]
    return low + (high - low) * torch.rand(num, 15, 3, generator=generator, dtype=F64)


def test_angles_pose_round_trip_over_the_limits():
    angles = _random_angles(0, 200)
    pose = angles_to_pose(angles)
    assert pose.shape == (200, 48)
    assert torch.allclose(pose_to_angles(pose), angles, atol=1e-9)
    left = angles_to_pose(angles, side="left")
    assert torch.allclose(left, mirror_pose(pose), atol=1e-12)
    assert torch.allclose(pose_to_angles(left, side="left"), angles, atol=1e-9)


def test_flexion_curls_toward_the_palm_and_abduction_toward_the_thumb():
    skel = rest_skeleton(HandShape())
    index = FINGER_JOINTS["index"]
    angles = torch.zeros(15, 3, dtype=F64)
    angles[index[0] - 1, 0] = 0.5  # MCP flexion
    kin = forward_kinematics(angles_to_pose(angles)[None], skel.joints)
    moved = kin.joints[0, index[1]] - skel.joints[index[1]]
    assert moved[1] < -0.01  # toward the palm (-y)
    angles = torch.zeros(15, 3, dtype=F64)
    angles[index[0] - 1, 1] = 0.3  # MCP abduction
    kin = forward_kinematics(angles_to_pose(angles)[None], skel.joints)
    assert (kin.joints[0, index[1]] - skel.joints[index[1]])[2] > 0.005  # toward the thumb (+z)


def test_sampled_poses_respect_limits_and_are_seeded():
    poses = sample_pose(torch.Generator().manual_seed(3), num=300)
    assert poses.shape == (300, 48) and poses.dtype == torch.float32
    assert within_limits(poses.double(), tolerance=1e-4).all()
    again = sample_pose(torch.Generator().manual_seed(3), num=300)
    assert torch.equal(poses, again)
    other = sample_pose(torch.Generator().manual_seed(4), num=300)
    assert not torch.equal(poses, other)
    # Natural variety: some fists, some open hands.
    flexion = pose_to_angles(poses.double())[..., 0].mean(-1)
    assert flexion.min() < 0.15 and flexion.max() > 0.8
    rotated = sample_pose(torch.Generator().manual_seed(3), num=5, global_orient=True)
    assert rotated[:, :3].norm(dim=1).min() > 0.0
    left = sample_pose(torch.Generator().manual_seed(3), num=20, side="left")
    assert within_limits(left.double(), side="left").all()


def test_named_poses_are_within_limits_and_distinct():
    poses = {name: named_pose(name) for name in POSE_NAMES}
    assert set(poses) >= {"flat", "relaxed", "fist", "point", "pinch", "ok"}
    for pose in poses.values():
        assert pose.shape == (48,)
        assert within_limits(pose.double()).item()
    assert torch.count_nonzero(poses["flat"]) == 0
    angles = {name: pose_to_angles(p.double()) for name, p in poses.items()}
    assert angles["fist"][..., 0].mean() > angles["relaxed"][..., 0].mean() > 0.1
    index = FINGER_JOINTS["index"][1] - 1
    middle = FINGER_JOINTS["middle"][1] - 1
    assert angles["point"][index, 0] < 0.1 < 1.0 < angles["point"][middle, 0]


def test_pinch_brings_thumb_and_index_tips_together():
    skel = rest_skeleton(HandShape())
    for name in ("pinch", "ok"):
        kin = forward_kinematics(named_pose(name, dtype=F64)[None], skel.joints)
        tips = []
        for bone, tip in ((15, skel.fingertips[0]), (3, skel.fingertips[1])):
            transform = kin.transforms[0, bone]
            tips.append(transform[:3, :3] @ tip + transform[:3, 3])
        assert (tips[0] - tips[1]).norm() < 0.03  # fingertip apexes, pads touching


def test_unknown_pose_name_lists_the_known_names():
    with pytest.raises(ValueError, match="known names are flat, relaxed, fist"):
        named_pose("thumbs_up")
    with pytest.raises(ValueError, match="side"):
        named_pose("fist", side="middle")


def test_clamp_to_limits():
    # Many joints beyond their limits, but |abduction| < 90 degrees (unique decomposition).
    angles = _random_angles(5, 50) * 1.25
    pose = angles_to_pose(angles, global_orient=torch.full((50, 3), 0.3, dtype=F64))
    assert not within_limits(pose).all()
    clamped = clamp_to_limits(pose)
    assert within_limits(clamped).all()
    assert torch.equal(clamped[:, :3], pose[:, :3])
    assert torch.allclose(clamp_to_limits(clamped), clamped, atol=1e-9)
    expected = torch.maximum(torch.minimum(angles, JOINT_LIMITS[..., 1]), JOINT_LIMITS[..., 0])
    assert torch.allclose(pose_to_angles(clamped), expected, atol=1e-9)


def test_interpolation_keeps_ends_and_limits():
    start = named_pose("flat", dtype=F64)
    end = named_pose("fist", dtype=F64).clone()
    end[:3] = torch.tensor([0.0, 0.0, 1.2], dtype=F64)
    poses = interpolate_poses(start, end, 9)
    assert poses.shape == (9, 48)
    assert torch.allclose(poses[0], start, atol=1e-9)
    assert torch.allclose(poses[-1], end, atol=1e-9)
    assert within_limits(poses).all()
    assert torch.allclose(poses[4, :3], torch.tensor([0.0, 0.0, 0.6], dtype=F64), atol=1e-9)
    sequence = pose_sequence([start, end, named_pose("point", dtype=F64)], 4)
    assert sequence.shape == (9, 48)
    with pytest.raises(ValueError, match="num"):
        interpolate_poses(start, end, 1)
    with pytest.raises(ValueError, match="start"):
        interpolate_poses(start[:10], end, 3)


def test_bad_pose_inputs():
    with pytest.raises(ValueError, match="pose"):
        pose_to_angles(torch.zeros(47))
    with pytest.raises(TypeError, match="angles"):
        angles_to_pose([[0.0] * 3] * 15)
    with pytest.raises(ValueError, match="noise"):
        sample_pose(torch.Generator(), noise=-1.0)
