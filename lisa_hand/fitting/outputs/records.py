"""What a fit's JSON files hold beyond the hand's parameters: the fitted hand's 3D keypoints
(:func:`hand_keypoints_3d`, ``keypoints.json``: :func:`keypoints_3d_record`) and JSON without
NaN (:func:`json_safe`).

``keypoints.json`` of ``lisa fit-points`` and ``lisa fit-images`` (one JSON object):
``"names"`` [21] the keypoint names in OpenPose order (:data:`lisa_hand.skeleton.KEYPOINT_NAMES`),
``"keypoints_3d"`` [21, 3] metres, ``"frame"`` ``"world"`` (the input's frame: the point cloud's,
or that of ``cameras.json``), ``"units"`` ``"m"``, ``"side"``, and ``"note"``, a sentence saying
so. (It is not the 2D ``keypoints.json`` of a frame folder, :mod:`lisa_hand.data.keypoints`,
which has ``"views"``.) Every fit writes the 3D keypoints so that nobody has to rebuild them from
the pose.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams

__all__ = ["json_safe", "hand_keypoints_3d", "keypoints_3d_record"]


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) replaced by None, recursively (JSON has
    no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


def hand_keypoints_3d(params: HandParams, template: Any = None) -> np.ndarray:
    """The fitted hand's 21 keypoints in 3D (OpenPose order), in the frame of its pose.

    The 16 joints are the forward kinematics of ``params.rest_joints`` (LISA's skeleton) in
    ``params.pose`` and ``params.translation``; the five fingertips are the mesh template's
    fingertip vertices (shaped by ``params.betas``, zeros when None), moved with their distal
    joint onto this skeleton and skinned with the template's weights. For a hand fitted on the
    template's skeleton (``rest_joints == template.rest_joints(betas)``, the image fit) these
    are exactly the keypoints the fit projected. A left hand's are the mirror image of those
    of its mirrored right hand (as meshing and rendering treat it).

    template: the mesh template (default: :func:`lisa_hand.handmodel.template.load_template`).
    -> [21, 3] float64 metres.
    """
    from ...skeleton import (
        FINGER_JOINTS,
        FINGER_NAMES,
        forward_kinematics,
        joints_to_keypoints,
        linear_blend_skinning,
        mirror_points,
    )
    from ..sides import mirror_hand

    if template is None:
        from ...handmodel.template import load_template

        template = load_template()
    template = template.to(device=torch.device("cpu"), dtype=torch.float64)
    hand = mirror_hand(params) if params.side == "left" else params
    betas = torch.zeros(int(template.num_betas), dtype=torch.float64)
    if hand.betas is not None and hand.betas.numel() == betas.numel():
        betas = hand.betas.double()
    tip_ids = list(template.fingertip_ids)
    distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
    rest_joints = hand.rest_joints.double()
    template_joints = template.rest_joints(betas[None])[0]
    tips_rest = (template.rest_vertices(betas[None])[0][tip_ids]
                 + rest_joints[distal] - template_joints[distal])
    kinematics = forward_kinematics(hand.pose.double()[None], rest_joints[None],
                                    hand.translation.double()[None])
    tips = linear_blend_skinning(tips_rest[None], template.weights[tip_ids],
                                 kinematics.transforms)[0]
    keypoints = joints_to_keypoints(kinematics.joints[0], tips)
    if params.side == "left":
        keypoints = mirror_points(keypoints)
    return keypoints.numpy()


def keypoints_3d_record(params: HandParams, frame: str = "world",
                        note: str | None = None) -> dict[str, Any]:
    """What ``keypoints.json`` of ``lisa fit-points`` / ``lisa fit-images`` holds (see the module
    docstring): the names, :func:`hand_keypoints_3d` [21, 3] metres, the frame, units, side
    and a note (default: a sentence naming the frame)."""
    from ...skeleton import KEYPOINT_NAMES

    if note is None:
        note = ("keypoints_3d: the fitted hand's 21 keypoints (OpenPose order, metres) in the "
                "world frame of the input: the point cloud's, or that of cameras.json")
    return {"names": list(KEYPOINT_NAMES), "side": params.side, "frame": frame, "units": "m",
            "keypoints_3d": hand_keypoints_3d(params).tolist(), "note": note}
