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

__all__ = ["json_safe", "hand_keypoints_3d", "fingertips_at_rest", "posed_keypoints",
           "keypoints_3d_record"]


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
    from ...skeleton import mirror_points
    from ..sides import mirror_hand

    if template is None:
        from ...handmodel.template import load_template

        template = load_template()
    template = template.to(device=torch.device("cpu"), dtype=torch.float64)
    hand = mirror_hand(params) if params.side == "left" else params
    keypoints = posed_keypoints(template, hand.rest_joints.double(), hand.betas,
                                hand.pose.double()[None], hand.translation.double()[None])[0]
    if params.side == "left":
        keypoints = mirror_points(keypoints)
    return keypoints.numpy()


def fingertips_at_rest(template: Any, rest_joints: torch.Tensor, betas: torch.Tensor | None
                       ) -> torch.Tensor:
    """The five fingertips of a RIGHT hand at rest: the mesh template's fingertip vertices
    (shaped by ``betas``, zeros when None) moved with their distal joint onto the skeleton
    ``rest_joints`` [16, 3] metres -> [5, 3] metres (constant through a fit of the pose)."""
    from ...skeleton import FINGER_JOINTS, FINGER_NAMES

    shape = torch.zeros(int(template.num_betas), dtype=rest_joints.dtype,
                        device=rest_joints.device)
    if betas is not None and betas.numel() == shape.numel():
        shape = betas.to(shape)
    distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
    template_joints = template.rest_joints(shape[None])[0]
    return (template.rest_vertices(shape[None])[0][list(template.fingertip_ids)]
            + rest_joints[distal] - template_joints[distal])


def posed_keypoints(template: Any, rest_joints: torch.Tensor, betas: torch.Tensor | None,
                    pose: torch.Tensor, translation: torch.Tensor,
                    tips_rest: torch.Tensor | None = None) -> torch.Tensor:
    """The 21 keypoints of a RIGHT hand in B poses, differentiable (the keypoints of
    :func:`hand_keypoints_3d`, batched for the fitters that move only pose and translation).

    template: the mesh template on the inputs' device and dtype. rest_joints: [16, 3] metres
    (the hand's skeleton). betas: [K] the template's shape coefficients (None: zeros).
    pose: [B, 48] axis-angle radians. translation: [B, 3] metres. tips_rest:
    :func:`fingertips_at_rest` when already computed. -> [B, 21, 3] metres.
    """
    from ...skeleton import forward_kinematics, joints_to_keypoints, linear_blend_skinning

    if tips_rest is None:
        tips_rest = fingertips_at_rest(template, rest_joints, betas)
    count = pose.shape[0]
    kinematics = forward_kinematics(pose, rest_joints.expand(count, -1, -1), translation)
    tips = linear_blend_skinning(tips_rest.expand(count, -1, -1),
                                 template.weights[list(template.fingertip_ids)],
                                 kinematics.transforms)
    return joints_to_keypoints(kinematics.joints, tips)


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
