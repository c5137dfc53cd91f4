"""Inverse kinematics (keypoints -> pose, rest skeleton, translation) against forward kinematics
of the MANO-like template: random shapes and poses, right and left, fixed and fitted skeletons."""

from __future__ import annotations

import pytest
import torch

from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.handmodel.template import load_template
from lisa_hand.skeleton import forward_kinematics, mirror_points, mirror_pose
from lisa_hand.skeleton.inverse_kinematics import (
    inverse_kinematics,
    mean_skeleton,
    skeleton_keypoints,
    split_keypoints,
)
from lisa_hand.skeleton.tree import joints_to_keypoints

F64 = torch.float64
MM = 1e-3


@pytest.fixture(scope="module")
def template():
    return load_template().to(dtype=F64)


@pytest.fixture(scope="module")
def reference(template):
    """The template's rest keypoints (mean shape, zero pose)."""
    zero = torch.zeros(1, 48, dtype=F64)
    return template(zero, torch.zeros(1, template.num_betas, dtype=F64)).keypoints[0]


@pytest.fixture(scope="module")
def hands(template):
    g = torch.Generator().manual_seed(0)
    pose = sample_pose(g, 64, global_orient=True).to(F64)
    betas = 0.8 * torch.randn(64, template.num_betas, generator=g, dtype=F64)
    translation = 0.1 * torch.randn(64, 3, generator=g, dtype=F64)
    return pose, betas, translation, template(pose, betas, translation)


def test_fitted_skeleton_reproduces_keypoints(hands, reference):
    _, _, _, posed = hands
    result = inverse_kinematics(posed.keypoints, reference)
    assert float(result.max_error.max()) < 1e-9 * MM  # round-off, far below the 1 mm asked
    # Forward kinematics of the result gives the template's joints, and the tips too.
    joints = forward_kinematics(result.pose, result.rest_joints, result.translation).joints
    assert float((joints - posed.joints).abs().max()) < 1e-12
    again = skeleton_keypoints(result.pose, result.rest_joints, result.rest_fingertips,
                               result.translation)
    assert float((again - posed.keypoints).abs().max()) < 1e-12
    assert torch.equal(again, result.keypoints)


def test_rest_skeleton_is_the_reference_shape_with_observed_lengths(hands, reference):
    _, _, _, posed = hands
    result = inverse_kinematics(posed.keypoints, reference)
    observed_joints, _ = split_keypoints(posed.keypoints)
    # Bone lengths of the rest skeleton are the observed ones.
    for joint, parent in ((2, 1), (3, 2), (5, 4), (14, 13)):
        rest = (result.rest_joints[:, joint] - result.rest_joints[:, parent]).norm(dim=-1)
        seen = (observed_joints[:, joint] - observed_joints[:, parent]).norm(dim=-1)
        assert torch.allclose(rest, seen, atol=1e-12)
    # Bone directions are the reference's; the rest wrist is the reference wrist.
    ref_joints, _ = split_keypoints(reference)
    direction = result.rest_joints[:, 3] - result.rest_joints[:, 2]
    expected = ref_joints[3] - ref_joints[2]
    cosine = (direction * expected).sum(-1) / direction.norm(dim=-1) / expected.norm()
    assert float((1 - cosine).abs().max()) < 1e-12
    assert torch.allclose(result.rest_joints[:, 0], ref_joints[0].expand(64, 3), atol=1e-15)


def test_reference_keypoints_give_the_zero_pose(reference):
    result = inverse_kinematics(reference, reference)
    assert float(result.pose.abs().max()) < 1e-7
    assert float(result.translation.abs().max()) < 1e-15
    assert float(result.max_error) < 1e-12


def test_true_skeleton_kept_fixed_recovers_joints_and_pose(template, hands):
    pose, betas, translation, posed = hands
    # One subject: its own rest keypoints as the (fixed) skeleton.
    rest = template(torch.zeros(1, 48, dtype=F64), betas[:1]).keypoints[0]
    result = inverse_kinematics(posed.keypoints[:1], rest, fit_skeleton=False)
    # The template's fingertips are skinned vertices, not rigid with the distal bone: they move
    # by a fraction of a millimetre; the joints are exact.
    assert float(result.max_error) < 1.0 * MM
    joints = forward_kinematics(result.pose, rest_joints=split_keypoints(rest)[0],
                                translation=result.translation).joints
    assert float((joints - posed.joints[:1]).abs().max()) < 1e-12
    # Finger rotations: close to the true ones (the twist about a bone is a choice of the IK).
    assert float((result.pose[:, :3] - pose[:1, :3]).abs().max()) < 1e-9


def test_mean_skeleton_of_noisy_frames_reproduces_within_a_millimetre(template, reference):
    g = torch.Generator().manual_seed(5)
    pose = sample_pose(g, 20, global_orient=True).to(F64)
    betas = torch.randn(1, template.num_betas, generator=g, dtype=F64).expand(20, -1)
    keypoints = template(pose, betas).keypoints
    noisy = keypoints + 0.2 * MM * torch.randn(keypoints.shape, generator=g, dtype=F64)
    skeleton = mean_skeleton(noisy, reference)
    result = inverse_kinematics(noisy, skeleton, fit_skeleton=False)
    assert float(result.error.max()) < 1.0 * MM
    # Against the noiseless keypoints, better still than the noise of the observations.
    assert float((result.keypoints - keypoints).norm(dim=-1).mean()) < 0.5 * MM
    # Refining the pose on the fixed skeleton brings the keypoints closer still.
    refined = inverse_kinematics(noisy, skeleton, fit_skeleton=False, refine=20)
    assert float(refined.error.mean()) < float(result.error.mean())
    assert float((refined.keypoints - keypoints).norm(dim=-1).mean()) < float(
        (result.keypoints - keypoints).norm(dim=-1).mean())


def test_left_hand_is_the_mirror_of_the_right(hands, reference):
    _, _, _, posed = hands
    right = inverse_kinematics(posed.keypoints, reference)
    left = inverse_kinematics(mirror_points(posed.keypoints), reference, side="left")
    assert float(left.max_error.max()) < 1e-9 * MM
    assert torch.allclose(left.pose, mirror_pose(right.pose), atol=1e-12)
    assert torch.allclose(left.rest_joints, mirror_points(right.rest_joints), atol=1e-15)


def test_single_hand_and_float32(hands, reference):
    _, _, _, posed = hands
    result = inverse_kinematics(posed.keypoints[0].float(), reference.float())
    assert result.pose.shape == (48,) and result.pose.dtype == torch.float32
    assert result.rest_joints.shape == (16, 3) and result.translation.shape == (3,)
    assert float(result.max_error) < 1e-3 * MM


def test_fingers_flex_as_hinges(template, reference):
    """Fingers bent at PIP and DIP only (about the template's flexion axis): the IK puts the
    bends back on one axis per finger instead of rolling the finger."""
    pose = torch.zeros(1, 16, 3, dtype=F64)
    pose[0, 2] = torch.tensor([0.0, 0.0, 0.9])  # index PIP about the z axis (across the finger)
    pose[0, 3] = torch.tensor([0.0, 0.0, 0.6])
    keypoints = template(pose.reshape(1, 48), torch.zeros(1, template.num_betas,
                                                          dtype=F64)).keypoints
    result = inverse_kinematics(keypoints, reference, fit_skeleton=False)
    assert float(result.max_error) < 1.0 * MM
    index_pip = result.pose[0, 6:9]
    axis = index_pip / index_pip.norm()
    assert float(axis[2].abs()) > 0.99  # bends about z, like the input
    assert abs(float(index_pip.norm()) - 0.9) < 0.05


def test_bad_keypoints_are_refused(reference):
    with pytest.raises(ValueError, match=r"\[\.\.\., 21, 3\]"):
        inverse_kinematics(torch.zeros(20, 3, dtype=F64), reference)
    bad = reference.clone()
    bad[3, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        inverse_kinematics(bad, reference)
    coincident = reference.clone()
    coincident[6] = coincident[5]
    with pytest.raises(ValueError, match="index bone has zero length"):
        inverse_kinematics(coincident, reference)
    with pytest.raises(ValueError, match="side"):
        inverse_kinematics(reference, reference, side="middle")


def test_split_keypoints_inverts_joints_to_keypoints(hands):
    _, _, _, posed = hands
    joints, tips = split_keypoints(posed.keypoints)
    assert torch.equal(joints_to_keypoints(joints, tips), posed.keypoints)
