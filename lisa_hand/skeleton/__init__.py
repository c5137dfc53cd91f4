"""MANO-compatible skeleton: kinematic tree, forward kinematics, LBS, keypoints, MANO .pkl."""

from .kinematics import (
    Kinematics,
    check_pose,
    check_side,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
    mirror_pose,
)
from .tree import (
    FINGER_JOINTS,
    FINGER_NAMES,
    JOINT_NAMES,
    KEYPOINT_NAMES,
    KEYPOINT_SOURCES,
    MANO_FINGERTIP_VERTEX_IDS,
    NUM_JOINTS,
    NUM_KEYPOINTS,
    PARENTS,
    POSE_DIM,
    joints_to_keypoints,
)

__all__ = [
    "Kinematics",
    "check_pose",
    "check_side",
    "forward_kinematics",
    "linear_blend_skinning",
    "mirror_points",
    "mirror_pose",
    "FINGER_JOINTS",
    "FINGER_NAMES",
    "JOINT_NAMES",
    "KEYPOINT_NAMES",
    "KEYPOINT_SOURCES",
    "MANO_FINGERTIP_VERTEX_IDS",
    "NUM_JOINTS",
    "NUM_KEYPOINTS",
    "PARENTS",
    "POSE_DIM",
    "joints_to_keypoints",
]
