"""MANO's kinematic tree and the 21-keypoint order."""

from __future__ import annotations

import re

import pytest
import torch

from lisa_hand.skeleton import (
    FINGER_JOINTS,
    FINGER_NAMES,
    JOINT_NAMES,
    KEYPOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    joints_to_keypoints,
    tree,
)

# Keypoint level names per finger, proximal -> distal, matching MANO levels 1, 2, 3.
_LEVELS = {"thumb": ("cmc", "mcp", "ip"), "other": ("mcp", "pip", "dip")}


def _expected_source(keypoint_name: str) -> tuple[str, str]:
    """('joint', MANO joint name) or ('tip', finger) for a keypoint, from its name alone."""
    if keypoint_name == "wrist":
        return ("joint", "wrist")
    finger, level = keypoint_name.split("_")
    if level == "tip":
        return ("tip", finger)
    levels = _LEVELS["thumb" if finger == "thumb" else "other"]
    return ("joint", f"{finger}{levels.index(level) + 1}")


def test_parents_come_first_and_chains_follow_the_names():
    assert len(JOINT_NAMES) == len(PARENTS) == NUM_JOINTS == 16
    assert PARENTS[0] == -1
    assert all(0 <= PARENTS[j] < j for j in range(1, NUM_JOINTS))
    assert FINGER_NAMES == ("thumb", "index", "middle", "ring", "pinky")
    chains = [joint for finger in FINGER_NAMES for joint in FINGER_JOINTS[finger]]
    assert sorted(chains) == list(range(1, 16))
    for finger in FINGER_NAMES:
        first, second, third = FINGER_JOINTS[finger]
        assert (PARENTS[first], PARENTS[second], PARENTS[third]) == (0, first, second)
        assert [JOINT_NAMES[j] for j in (first, second, third)] == [
            f"{finger}{level}" for level in (1, 2, 3)
        ]


def test_mano_joint_order_as_documented():
    # wrist, then index, middle, pinky, ring, thumb chains.
    assert [JOINT_NAMES[j][:-1] for j in (1, 4, 7, 10, 13)] == [
        "index",
        "middle",
        "pinky",
        "ring",
        "thumb",
    ]


def test_joints_to_keypoints_follows_the_keypoint_names():
    # Joint j carries the value j, fingertip f the value 100 + f: each output says its source.
    joints = torch.arange(16, dtype=torch.float64)[:, None].expand(16, 3)
    tips = 100.0 + torch.arange(5, dtype=torch.float64)[:, None].expand(5, 3)
    keypoints = joints_to_keypoints(joints, tips)
    assert keypoints.shape == (21, 3) and len(KEYPOINT_NAMES) == 21
    for index, name in enumerate(KEYPOINT_NAMES):
        kind, source = _expected_source(name)
        value = int(keypoints[index, 0])
        if kind == "joint":
            assert value < 100 and JOINT_NAMES[value] == source, (index, name)
        else:
            assert value == 100 + FINGER_NAMES.index(source), (index, name)


def test_joints_to_keypoints_matches_the_docstring_table():
    # Each table line holds one or two "kp  name  source" cells; source is a joint or "tip (f)".
    cell = re.compile(r"(\d+)\s+([a-z_]+)\s+(?:(\d+)|tip \((\w+)\))")
    table = {}
    for line in tree.__doc__.splitlines():
        for kp, name, joint, tip_finger in cell.findall(line):
            table[int(kp)] = (name, joint, tip_finger)
    assert sorted(table) == list(range(21))
    joints = torch.arange(16, dtype=torch.float32)[None, :, None].expand(2, 16, 3)
    tips = 100.0 + torch.arange(5, dtype=torch.float32)[None, :, None].expand(2, 5, 3)
    keypoints = joints_to_keypoints(joints, tips)
    for index, (name, joint, tip_finger) in table.items():
        assert KEYPOINT_NAMES[index] == name
        expected = 100 + FINGER_NAMES.index(tip_finger) if tip_finger else int(joint)
        assert keypoints[:, index].eq(expected).all(), (index, name)


def test_joints_to_keypoints_batch_dims_and_errors():
    joints = torch.randn(2, 3, 16, 3, generator=torch.Generator().manual_seed(0))
    tips = torch.randn(2, 3, 5, 3, generator=torch.Generator().manual_seed(1))
    keypoints = joints_to_keypoints(joints, tips)
    assert keypoints.shape == (2, 3, 21, 3)
    assert torch.equal(keypoints[..., 0, :], joints[..., 0, :])
    assert torch.equal(keypoints[..., 4, :], tips[..., 0, :])
    with pytest.raises(ValueError, match=r"expected joints \[\.\.\., 16, 3\] and fingertips"):
        joints_to_keypoints(joints[..., :15, :], tips)
    with pytest.raises(ValueError, match=r"fingertips \[\.\.\., 5, 3\]"):
        joints_to_keypoints(joints, tips[..., :4, :])
