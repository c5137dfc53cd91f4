"""Dual quaternion skinning: LBS for one bone, and no candy wrapper at a twisted joint."""

from __future__ import annotations

import math

import torch

from lisa_hand.skeleton.kinematics import (
    dual_quaternion_skinning,
    forward_kinematics,
    linear_blend_skinning,
)

F64 = torch.float64


def test_one_bone_per_point_is_rigid_as_lbs():
    generator = torch.Generator().manual_seed(0)
    pose = torch.randn(1, 48, generator=generator, dtype=F64)
    joints = torch.randn(16, 3, generator=generator, dtype=F64) * 0.05
    transforms = forward_kinematics(pose, joints, torch.randn(1, 3, dtype=F64)).transforms
    points = torch.randn(50, 3, generator=generator, dtype=F64) * 0.05
    owner = torch.randint(0, 16, (50,), generator=generator)
    weights = torch.nn.functional.one_hot(owner, 16).to(F64)
    expected = linear_blend_skinning(points, weights, transforms)[0]
    torch.testing.assert_close(dual_quaternion_skinning(points, weights, transforms[0]), expected)


def test_a_half_blended_twist_keeps_the_radius():
    # Bone 1 twists by 150 degrees about the x axis; points weighted half and half. LBS pulls
    # them toward the axis by cos(75 deg); dual quaternions rotate them by 75 degrees.
    angle = math.radians(150.0)
    twist = torch.eye(4, dtype=F64).repeat(2, 1, 1)
    twist[1, 1:3, 1:3] = torch.tensor([[math.cos(angle), -math.sin(angle)],
                                       [math.sin(angle), math.cos(angle)]], dtype=F64)
    points = torch.tensor([[0.01, 0.02, 0.0], [-0.03, 0.0, 0.02]], dtype=F64)
    weights = torch.full((2, 2), 0.5, dtype=F64)
    radius = points[:, 1:].norm(dim=1)
    dqs = dual_quaternion_skinning(points, weights, twist)
    lbs = linear_blend_skinning(points, weights, twist[None])[0]
    torch.testing.assert_close(dqs[:, 1:].norm(dim=1), radius)
    torch.testing.assert_close(dqs[:, 0], points[:, 0])
    torch.testing.assert_close(lbs[:, 1:].norm(dim=1), radius * math.cos(angle / 2))
    # The blended rotation is the half twist.
    half = torch.tensor([[1.0, 0, 0], [0, math.cos(angle / 2), -math.sin(angle / 2)],
                         [0, math.sin(angle / 2), math.cos(angle / 2)]], dtype=F64)
    torch.testing.assert_close(dqs, points @ half.T)
