"""MANO's kinematic tree and the 21-keypoint (OpenPose / MediaPipe) hand order.

MANO orders its 16 joints as the wrist, then the index, middle, pinky, ring and thumb chains of
three joints each (proximal to distal). Keypoint order (OpenPose and MediaPipe agree):

====  ==========  =============  ====  ==========  =============
kp    name        MANO joint     kp    name        MANO joint
====  ==========  =============  ====  ==========  =============
0     wrist       0              11    middle_dip  6
1     thumb_cmc   13             12    middle_tip  tip (middle)
2     thumb_mcp   14             13    ring_mcp    10
3     thumb_ip    15             14    ring_pip    11
4     thumb_tip   tip (thumb)    15    ring_dip    12
5     index_mcp   1              16    ring_tip    tip (ring)
6     index_pip   2              17    pinky_mcp   7
7     index_dip   3              18    pinky_pip   8
8     index_tip   tip (index)    19    pinky_dip   9
9     middle_mcp  4              20    pinky_tip   tip (pinky)
10    middle_pip  5
====  ==========  =============  ====  ==========  =============

Fingertips are not MANO joints; they come from the surface (MANO vertices, see
:data:`MANO_FINGERTIP_VERTEX_IDS`) or, for the open hand model, from the end of each distal bone.
Fingertip order everywhere in this package: thumb, index, middle, ring, pinky.
"""

from __future__ import annotations

import torch

__all__ = [
    "NUM_JOINTS",
    "NUM_KEYPOINTS",
    "POSE_DIM",
    "JOINT_NAMES",
    "PARENTS",
    "FINGER_NAMES",
    "FINGER_JOINTS",
    "KEYPOINT_NAMES",
    "KEYPOINT_SOURCES",
    "KEYPOINT_PARENTS",
    "MANO_FINGERTIP_VERTEX_IDS",
    "AVERAGE_REST_JOINTS",
    "joints_to_keypoints",
]

NUM_JOINTS = 16
NUM_KEYPOINTS = 21
POSE_DIM = 3 * NUM_JOINTS  # 48: global orientation (3) + 15 finger joints (45)

JOINT_NAMES = (
    "wrist",
    "index1", "index2", "index3",
    "middle1", "middle2", "middle3",
    "pinky1", "pinky2", "pinky3",
    "ring1", "ring2", "ring3",
    "thumb1", "thumb2", "thumb3",
)  # fmt: skip

PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)

FINGER_NAMES = ("thumb", "index", "middle", "ring", "pinky")
# MANO joint indices of each finger's chain (proximal -> distal), in FINGER_NAMES order.
FINGER_JOINTS = {
    "thumb": (13, 14, 15),
    "index": (1, 2, 3),
    "middle": (4, 5, 6),
    "ring": (10, 11, 12),
    "pinky": (7, 8, 9),
}

KEYPOINT_NAMES = (
    "wrist",
    "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)  # fmt: skip

# For each keypoint, the index into cat([joints (16), fingertips (5)]): MANO joint j -> j,
# fingertip f (thumb, index, middle, ring, pinky) -> 16 + f.
KEYPOINT_SOURCES = (
    0,
    13, 14, 15, 16,
    1, 2, 3, 17,
    4, 5, 6, 18,
    10, 11, 12, 19,
    7, 8, 9, 20,
)  # fmt: skip

KEYPOINT_PARENTS = (
    -1,
    0, 1, 2, 3,
    0, 5, 6, 7,
    0, 9, 10, 11,
    0, 13, 14, 15,
    0, 17, 18, 19,
)  # fmt: skip
"""Each keypoint's parent along the hand (-1: the wrist): keypoint ``k`` > 0 and
``KEYPOINT_PARENTS[k]`` are the ends of one of the 20 bones of the 21-keypoint skeleton."""

# Vertex indices of MANO's fingertips (thumb, index, middle, ring, pinky), as used by smplx.
MANO_FINGERTIP_VERTEX_IDS = (744, 320, 443, 554, 671)

AVERAGE_REST_JOINTS = (
    (0.0, 0.0, 0.0),
    (-0.0895, -0.0015, 0.021), (-0.1315, -0.0015, 0.0248), (-0.1555, -0.0015, 0.027),
    (-0.0925, 0.0, -0.002), (-0.1378, 0.0, -0.0013), (-0.1646, 0.0, -0.0009),
    (-0.0775, -0.005, -0.039), (-0.1099, -0.005, -0.0446), (-0.1298, -0.005, -0.048),
    (-0.0885, -0.002, -0.0215), (-0.1312, -0.002, -0.0245), (-0.1575, -0.002, -0.0263),
    (-0.026, -0.012, 0.02), (-0.0546, -0.0238, 0.0451), (-0.0793, -0.0285, 0.0606),
)  # fmt: skip
"""A fixed rest skeleton of an average adult right hand: [16, 3] metres in :data:`JOINT_NAMES`
order (wrist, index 1-3, middle 1-3, pinky 1-3, ring 1-3, thumb 1-3), in MANO's rest convention
(fingers along -x, palm facing -y, thumb on +z). A plausible skeleton that needs no template or
trained model: for a model made from scratch, for tests and for the benchmarks' hand
(``torch.tensor(AVERAGE_REST_JOINTS)`` -> [16, 3] float32)."""


def joints_to_keypoints(joints: torch.Tensor, fingertips: torch.Tensor) -> torch.Tensor:
    """Reorder MANO joints plus fingertips into the 21 OpenPose/MediaPipe keypoints.

    joints: [..., 16, 3], fingertips: [..., 5, 3] (thumb, index, middle, ring, pinky)
    -> [..., 21, 3]
    """
    if joints.shape[-2] != NUM_JOINTS or fingertips.shape[-2] != 5:
        raise ValueError(
            f"expected joints [..., 16, 3] and fingertips [..., 5, 3], got "
            f"{tuple(joints.shape)} and {tuple(fingertips.shape)}"
        )
    stacked = torch.cat([joints, fingertips], dim=-2)
    index = torch.as_tensor(KEYPOINT_SOURCES, device=joints.device)
    return stacked.index_select(-2, index)
