"""The viewer's state -> HandParams (lisa_hand.viewer.state): pure functions, no viser needed."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from lisa_hand.geometry.rotations import axis_angle_to_matrix
from lisa_hand.handmodel.poses import JOINT_LIMITS, joint_frames, pose_to_angles
from lisa_hand.handmodel.template import load_template
from lisa_hand.skeleton import FINGER_JOINTS, mirror_points
from lisa_hand.viewer.display import posed_joints
from lisa_hand.viewer.state import (
    CodeSpaces,
    NamedHand,
    PoseEdit,
    ViewState,
    finger_angles,
    mean_hand,
    model_hands,
    view_params,
)

CURL_FLEXION = (1.40, 1.75, 1.15)
"""Radians of MCP, PIP, DIP flexion at curl 1 (lisa_hand.handmodel.poses' synergy table)."""


@pytest.fixture(scope="module")
def spaces(model):
    return CodeSpaces.from_model(model)


def _show(state, hands, spaces):
    return view_params(state, hands, spaces)


def test_neutral_state_is_hand_a_exactly(hands, spaces):
    shown = _show(ViewState(hand_a=1, hand_b=0), hands, spaces)
    b = hands[1].params
    for key in ("pose", "translation", "rest_joints", "shape_code", "color_code"):
        assert torch.equal(getattr(shown, key), getattr(b, key)), key
    assert shown.side == b.side and shown.model == b.model


def test_curl_flexes_the_index_joints_by_the_synergy_angles(hands, spaces):
    edit = PoseEdit(named="flat").with_synergy("index_curl", 0.5)
    shown = _show(ViewState(pose=edit), hands, spaces)
    frames = joint_frames(torch.float64)
    for joint, flexion in zip(FINGER_JOINTS["index"], CURL_FLEXION, strict=True):
        axis_angle = shown.pose[3 * joint : 3 * joint + 3].double()
        # A rotation about the joint's flexion axis only, by 0.5 x the curl-1 flexion.
        assert float(axis_angle.norm()) == pytest.approx(0.5 * flexion, abs=1e-5)
        axis = axis_angle / axis_angle.norm()
        assert torch.allclose(axis, frames[joint - 1][:, 0], atol=1e-5)
    others = [j for finger in ("middle", "ring", "pinky", "thumb") for j in FINGER_JOINTS[finger]]
    for joint in others:  # the flat pose elsewhere
        assert float(shown.pose[3 * joint : 3 * joint + 3].norm()) < 1e-6
    assert torch.equal(shown.pose[:3], hands[0].params.pose[:3])  # global rotation kept


def test_limits_clamp_a_large_curl_and_can_be_switched_off(hands, spaces):
    edit = PoseEdit(named="flat").with_synergy("middle_curl", 1.5)
    pip = FINGER_JOINTS["middle"][1]
    clamped = pose_to_angles(_show(ViewState(pose=edit), hands, spaces).pose)
    free = pose_to_angles(_show(ViewState(pose=replace(edit, limits=False)), hands, spaces).pose)
    assert float(clamped[pip - 1, 0]) == pytest.approx(float(JOINT_LIMITS[pip - 1, 0, 1]),
                                                       abs=1e-5)  # 115 degrees
    assert float(free[pip - 1, 0]) == pytest.approx(1.5 * 1.75, abs=1e-5)


def test_a_finger_value_sets_its_angle(hands, spaces):
    state = ViewState(pose=PoseEdit(named="flat"))
    before, _ = finger_angles(state.pose, hands[0].params.pose, "right")
    # The viewer's slider for index1 flexion set to 20 degrees: offset = 20 - before.
    offset = 20.0 - math.degrees(float(before[0, 0]))
    shown = _show(replace(state, pose=state.pose.with_offset(0, offset)), hands, spaces)
    assert math.degrees(float(pose_to_angles(shown.pose)[0, 0])) == pytest.approx(20.0,
                                                                                  abs=1e-4)


def test_rotation_turns_the_posed_skeleton_about_the_wrist(hands, spaces):
    base = _show(ViewState(), hands, spaces)
    turned = _show(ViewState(pose=PoseEdit(rotation_deg=(0.0, 0.0, 90.0))), hands, spaces)
    joints, moved = (torch.from_numpy(posed_joints(p)) for p in (base, turned))
    rz = axis_angle_to_matrix(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    expected = (joints - joints[0]) @ rz.T + joints[0]
    assert torch.allclose(moved, expected, atol=1e-6)


def test_swapping_colour_keeps_the_shape(hands, spaces):
    a, b = hands[0].params, hands[1].params
    shown = _show(ViewState(hand_b=1, shape_t=0.0, color_t=1.0), hands, spaces)
    assert torch.equal(shown.shape_code, a.shape_code)
    assert torch.equal(shown.rest_joints, a.rest_joints)
    assert torch.equal(shown.color_code, b.color_code)
    assert torch.equal(shown.pose, a.pose)


def test_interpolation_reproduces_both_hands_and_halves(hands, spaces):
    a, b = hands[0].params, hands[1].params
    at_b = _show(ViewState(hand_b=1, shape_t=1.0, color_t=1.0, pose_t=1.0), hands, spaces)
    for key in ("shape_code", "color_code", "rest_joints", "pose", "translation"):
        assert torch.equal(getattr(at_b, key), getattr(b, key)), key
    half = _show(ViewState(hand_b=1, shape_t=0.5, color_t=0.5, pose_t=0.5), hands, spaces)
    assert torch.allclose(half.shape_code, 0.5 * (a.shape_code + b.shape_code), atol=1e-7)
    assert torch.allclose(half.rest_joints, 0.5 * (a.rest_joints + b.rest_joints), atol=1e-7)
    assert torch.allclose(half.translation, 0.5 * (a.translation + b.translation), atol=1e-7)
    # Finger joints halfway in anatomical angles.
    angles = pose_to_angles(half.pose.double())
    middle = 0.5 * (pose_to_angles(a.pose.double()) + pose_to_angles(b.pose.double()))
    assert torch.allclose(angles, middle, atol=1e-5)


def test_principal_direction_moves_the_code_by_one_std(model, hands, spaces):
    shown = _show(ViewState(shape_pcs=(1.0,), color_pcs=(0.0, -0.5)), hands, spaces)
    a = hands[0].params
    # The tiny model has two subjects: one direction, the line through their codes.
    direction = model.shape_codes[1] - model.shape_codes[0]
    std = float(direction.norm()) / math.sqrt(2.0)  # two codes: unbiased std along the line
    step = shown.shape_code - a.shape_code
    assert float(step.norm()) == pytest.approx(std, rel=1e-5)
    assert abs(float(step @ direction)) == pytest.approx(float(step.norm() * direction.norm()),
                                                         rel=1e-5)
    assert torch.equal(shown.color_code, a.color_code)  # only one colour direction: -0.5 unused


def test_side_shows_the_mirror_image(hands, spaces):
    right = _show(ViewState(), hands, spaces)
    left = _show(ViewState(side="left"), hands, spaces)
    assert left.side == "left"
    joints = torch.from_numpy(posed_joints(left))
    assert torch.allclose(joints, mirror_points(torch.from_numpy(posed_joints(right))),
                          atol=1e-6)
    assert torch.equal(left.shape_code, right.shape_code)


def test_curl_on_a_left_hand_is_the_mirror_of_the_right_one(hands, spaces):
    edit = PoseEdit(named="relaxed").with_synergy("ring_curl", 0.4)
    right = _show(ViewState(pose=edit), hands, spaces)
    left_hands = [replace(hands[0], params=_show(ViewState(side="left"), hands, spaces))]
    left = _show(ViewState(pose=edit), left_hands, spaces)
    assert torch.allclose(pose_to_angles(left.pose, "left"), pose_to_angles(right.pose),
                          atol=1e-5)


def test_mean_hand_and_subjects(model):
    mean = mean_hand(model)
    template = load_template()
    rest = template.rest_joints(torch.zeros(1, template.num_betas, dtype=template.dtype))[0]
    assert torch.allclose(mean.rest_joints.double(), rest, atol=1e-6)
    assert torch.allclose(mean.shape_code, model.shape_codes.mean(0))
    assert torch.allclose(mean.color_code, model.color_codes.mean(0))
    assert torch.equal(mean.pose, torch.zeros(48))
    named = model_hands(model)
    assert [hand.name for hand in named] == ["mean hand", "subject s0", "subject s1"]
    assert torch.equal(named[2].params.shape_code, model.shape_codes[1])


def test_bad_values_are_refused(hands, spaces):
    with pytest.raises(ValueError, match="shape_t"):
        ViewState(shape_t=1.5)
    with pytest.raises(ValueError, match="unknown pose name"):
        PoseEdit(named="wave")
    with pytest.raises(ValueError, match="hand_b"):
        view_params(ViewState(hand_b=5), hands, spaces)
    with pytest.raises(ValueError, match="synergies"):
        PoseEdit(synergies=(0.0,) * 3)
    assert isinstance(hands[0], NamedHand)
