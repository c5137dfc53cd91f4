"""The wrist cut (:mod:`lisa_hand.skeleton.wrist`): through the posed wrist joint, ``offset``
metres towards the forearm, normal towards the fingers, for right and left hands."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.handmodel import HandShape, rest_skeleton
from lisa_hand.skeleton import forward_kinematics, mirror_points, mirror_pose
from lisa_hand.skeleton.params import HandParams
from lisa_hand.skeleton.wrist import WRIST_CLIP_M, wrist_plane


def _hand(side: str = "right", turn=(0.3, -1.1, 0.7)) -> HandParams:
    rest = rest_skeleton(HandShape()).joints.float()
    pose = torch.zeros(48)
    pose[:3] = torch.tensor(turn)
    pose[3:] = 0.2  # bent fingers do not move the wrist's cut
    hand = HandParams(pose=pose, translation=torch.tensor([0.05, -0.02, 0.4]), rest_joints=rest,
                      shape_code=torch.zeros(0))
    if side == "left":
        hand = HandParams(pose=mirror_pose(pose), translation=mirror_points(hand.translation),
                          rest_joints=mirror_points(rest), shape_code=torch.zeros(0),
                          side="left")
    return hand


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_cut_passes_offset_beyond_the_wrist_and_keeps_the_fingers(side):
    hand = _hand(side)
    joints = forward_kinematics(hand.pose[None].double(), hand.rest_joints.double(),
                                hand.translation[None].double()).joints[0].numpy()
    plane = wrist_plane(hand, 0.0)
    assert plane.signed_distance(joints[:1])[0] == pytest.approx(0.0, abs=1e-9)
    # The normal runs from the wrist towards the middle knuckle (MANO joint 4), up to the
    # knuckle's small offset from the wrist bone's axis.
    knuckle = joints[4] - joints[0]
    cosine = plane.normal @ knuckle / np.linalg.norm(knuckle)
    assert math.degrees(math.acos(cosine)) < 15.0
    assert plane.keeps(joints[1:]).all()  # every finger joint is on the hand's side
    shifted = wrist_plane(hand)
    assert shifted.signed_distance(joints[:1])[0] == pytest.approx(WRIST_CLIP_M, abs=1e-9)
    np.testing.assert_allclose(shifted.normal, plane.normal, atol=1e-12)


def test_a_left_hand_cut_is_the_mirror_of_the_right_one():
    right, left = wrist_plane(_hand("right")), wrist_plane(_hand("left"))
    flip = np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(left.point, right.point * flip, atol=1e-7)
    np.testing.assert_allclose(left.normal, right.normal * flip, atol=1e-7)


def test_a_bad_offset_is_refused():
    with pytest.raises(ValueError, match="wrist offset"):
        wrist_plane(_hand(), float("nan"))
