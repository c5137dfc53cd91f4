"""Where a hand ends at the wrist: the cutting plane of the fits, the written meshes and the
metrics.

A scan can stop anywhere around the wrist or run on into the forearm; LISA's surface (like the
open hand model it learnt from) ends in a short forearm stub, about 2.5 cm beyond the wrist joint.
So what lies beyond the wrist is compared nowhere: the plane through the posed wrist joint,
moved ``offset`` metres towards the forearm (default :data:`WRIST_CLIP_M`), normal along the
hand's forearm-to-fingers axis (the wrist bone's rest direction, turned by the global
orientation), keeps the hand and drops the rest
(:class:`lisa_hand.geometry.planes.Plane`, :func:`lisa_hand.geometry.planes.clip_mesh`).

The rest pose has the fingers along -x (MANO's right hand, :mod:`lisa_hand.handmodel.shape`), so
a right hand's forearm runs along ``R0 @ +x`` and a left hand's (mirrored) along ``R0 @ -x``,
``R0`` the global rotation.
"""

from __future__ import annotations

import numpy as np

from ..geometry.planes import Plane
from .kinematics import check_side, forward_kinematics
from .params import HandParams

__all__ = ["WRIST_CLIP_M", "wrist_plane"]

WRIST_CLIP_M = 0.01
"""Default distance (metres) of the cut beyond the wrist joint, towards the forearm: inside the
stub of LISA's surface (about 2.5 cm) and of rigged hand meshes cut at the wrist (about 2 cm),
past the wrist joint's own uncertainty between rigs (MANO, OpenXR and the open hand model put it
within about 1 cm of each other)."""


def wrist_plane(params: HandParams, offset: float = WRIST_CLIP_M) -> Plane:
    """The wrist cut of a hand (see the module docstring).

    params: the hand (its pose [48] radians, translation [3] and rest_joints [16, 3] metres,
    side). offset: metres beyond the wrist joint, towards the forearm (negative: into the palm).
    -> the :class:`Plane` whose kept side (its normal) is the hand's.
    """
    if not np.isfinite(offset):
        raise ValueError(f"the wrist offset must be finite (metres), got {offset!r}")
    sign = 1.0 if check_side(params.side) == "right" else -1.0
    pose = params.pose.detach().double().reshape(1, -1).cpu()
    rest = params.rest_joints.detach().double().cpu()
    translation = params.translation.detach().double().reshape(1, 3).cpu()
    frame = forward_kinematics(pose, rest, translation).bone_frames[0, 0]
    forearm = sign * frame[:3, 0]
    point = frame[:3, 3] + float(offset) * forearm
    return Plane(point.numpy(), (-forearm).numpy())

