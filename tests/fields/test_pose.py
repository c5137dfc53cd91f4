"""Pose conditioning features."""

from __future__ import annotations

import torch

from lisa_hand.fields import LOCAL_POSE_DIM, local_pose_mask, pose_feature_dim, pose_features
from lisa_hand.geometry import axis_angle_to_matrix


def test_local_mask_is_own_parent_and_children():
    mask = local_pose_mask(per_bone=True)
    assert mask.shape == (16, 15)
    seen = {bone: {k + 1 for k in range(15) if mask[bone, k]} for bone in range(16)}
    assert seen[0] == {1, 4, 7, 10, 13}  # the global orientation (joint 0) is never seen
    assert seen[2] == {1, 2, 3}
    assert seen[3] == {2, 3}
    assert seen[13] == {13, 14}
    assert local_pose_mask(per_bone=False).shape == (1, 15) and local_pose_mask(False).all()


def test_features_are_masked_rotation_offsets():
    gen = torch.Generator().manual_seed(0)
    pose = torch.randn(2, 48, generator=gen, dtype=torch.float64)
    rotmats = axis_angle_to_matrix(pose.reshape(2, 16, 3))
    features = pose_features(pose, rotmats, "local", local_pose_mask(True))
    assert features.shape == (2, 16, LOCAL_POSE_DIM) == (2, 16, pose_feature_dim("local"))
    blocks = features.reshape(2, 16, 15, 9)
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(blocks[:, 5, 4], (rotmats[:, 5] - eye).reshape(2, 9))  # own joint
    torch.testing.assert_close(blocks[:, 5, 3], (rotmats[:, 4] - eye).reshape(2, 9))  # parent
    assert (blocks[:, 5, 7] == 0).all()  # an unrelated joint
    full = pose_features(pose, rotmats, "full", local_pose_mask(True))
    assert full.shape == (2, 16, 48) == (2, 16, pose_feature_dim("full"))
    torch.testing.assert_close(full[:, 7], pose)


def test_rest_pose_gives_zero_local_features():
    pose = torch.zeros(1, 48)
    rotmats = axis_angle_to_matrix(pose.reshape(1, 16, 3))
    assert (pose_features(pose, rotmats, "local", local_pose_mask(True)) == 0).all()
