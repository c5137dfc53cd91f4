"""Bone geometry: segments, centres, distances, unposing."""

from __future__ import annotations

import torch

from lisa_hand.fields import (
    SEGMENT_BONES,
    bone_axes,
    bone_centres,
    bone_segments,
    capsule_distance,
    segment_distances,
    unpose_points,
)
from lisa_hand.skeleton import forward_kinematics
from tests.fields.helpers import rest_joints


def test_segments_and_centres():
    rest = rest_joints()[None]
    start, end = bone_segments(rest, tip_extension=0.5)
    assert start.shape == end.shape == (1, 20, 3)
    assert SEGMENT_BONES[:5] == (0,) * 5 and SEGMENT_BONES[5:] == tuple(range(1, 16))
    torch.testing.assert_close(end[0, :5], rest[0, [1, 4, 7, 10, 13]])  # palm fans out
    torch.testing.assert_close(end[0, 5], rest[0, 2])  # index1 -> index2
    tip = rest[0, 3] + 0.5 * (rest[0, 3] - rest[0, 2])  # index3 -> extrapolated tip
    torch.testing.assert_close(end[0, 7], tip)
    centres = bone_centres(rest, 0.5)
    torch.testing.assert_close(centres[0, 3], 0.5 * (rest[0, 3] + tip))
    torch.testing.assert_close(centres[0, 0], rest[0, [0, 1, 4, 7, 10, 13]].mean(0))
    axes, lengths = bone_axes(rest, 0.5)
    torch.testing.assert_close(axes.norm(dim=-1), torch.ones(1, 16, dtype=torch.float64))
    torch.testing.assert_close(lengths[0, 1], (rest[0, 2] - rest[0, 1]).norm())


def test_capsule_distance_by_hand():
    start = torch.tensor([0.0, 0.0, 0.0])
    direction = torch.tensor([1.0, 0.0, 0.0])
    length = torch.tensor(2.0)
    points = torch.tensor([[1.0, 3.0, 4.0], [-3.0, 4.0, 0.0], [5.0, 0.0, 0.0]])
    distance = capsule_distance(points, start, direction, length.expand(3))
    torch.testing.assert_close(distance, torch.tensor([5.0, 5.0, 3.0]))


def test_segment_distances_matches_direct_formula_and_has_finite_gradient():
    gen = torch.Generator().manual_seed(0)
    start = 0.05 * torch.randn(2, 7, 3, generator=gen, dtype=torch.float64)
    vec = 0.03 * torch.randn(2, 7, 3, generator=gen, dtype=torch.float64)
    length = vec.norm(dim=-1)
    direction = vec / length[..., None]
    points = 0.08 * torch.randn(2, 50, 3, generator=gen, dtype=torch.float64)
    points[0, 0] = start[0, 3] + 0.4 * vec[0, 3]  # exactly on a segment
    points.requires_grad_(True)
    fast = segment_distances(points, start, direction, length)
    direct = capsule_distance(
        points[:, :, None], start[:, None], direction[:, None], length[:, None]
    )
    # Cancellation: about eps |x|^2 / d away from the segment, sqrt(eps) |x| on it.
    torch.testing.assert_close(fast[:, 1:], direct[:, 1:], rtol=0, atol=1e-12)
    torch.testing.assert_close(fast[:, :1], direct[:, :1], rtol=0, atol=1e-8)
    (grad,) = torch.autograd.grad(fast.sum(), points)
    assert torch.isfinite(grad).all()


def test_unpose_points_inverts_the_bone_transforms():
    gen = torch.Generator().manual_seed(1)
    rest = rest_joints()[None].expand(2, -1, -1)
    pose = 0.4 * torch.randn(2, 48, generator=gen, dtype=torch.float64)
    kin = forward_kinematics(pose, rest, torch.randn(2, 3, generator=gen, dtype=torch.float64))
    points = torch.randn(2, 6, 3, generator=gen, dtype=torch.float64)
    unposed = unpose_points(kin.transforms, points)
    assert unposed.shape == (2, 6, 16, 3)
    rot, trans = kin.transforms[:, 9, :3, :3], kin.transforms[:, 9, :3, 3]
    torch.testing.assert_close(unposed[:, :, 9] @ rot.transpose(-1, -2) + trans[:, None], points)
