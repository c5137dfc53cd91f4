"""Inverse kinematics on MANO's tree: 21 3D keypoints -> pose, rest skeleton and translation.

:func:`inverse_kinematics` is the inverse of :func:`skeleton_keypoints` (forward kinematics of
the 16 joints plus the five fingertips carried rigidly by their distal bones). It is analytic
(no optimisation) and works in three steps, for a right hand (a left one is mirrored in and
out, see ``side``):

1. **Global orientation** ``R_0``: the rotation that best aligns the reference's palm (wrist to
   the five finger roots, joints 1, 4, 7, 10, 13) with the observed palm (Kabsch).
2. **Rest skeleton** (``fit_skeleton=True``): the observed palm turned back by ``R_0^T`` and
   placed at the reference wrist; every finger bone in the reference's rest direction with the
   observed length. Posing it reproduces the 21 keypoints to round-off. With
   ``fit_skeleton=False`` the reference itself is the skeleton (a subject's fixed skeleton, see
   :func:`mean_skeleton`): the pose then points every bone along the observed one and the
   residual comes from the differences in palm shape and bone lengths.
3. **Finger rotations**: walking each chain from the root, the world rotation of joint ``j`` is
   the parent's followed by the smallest rotation taking the bone's rest direction (under the
   parent) onto the observed one; its twist about the bone, which keypoints cannot see, is
   chosen so that the next joint bends about the reference's flexion axis (the axis across the
   finger, perpendicular to the palm normal) whenever that next joint is bent by more than
   about a degree, so that fingers flex as hinges instead of rolling. The relative rotation
   ``R_parent^T R_j`` is the pose.

``translation`` is the observed wrist minus the rest wrist (MANO's ``transl``: the wrist is
posed at ``rest_joints[0] + translation``).

Units are those of the input (metres everywhere in this package); axis-angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from .kinematics import check_side, forward_kinematics, mirror_points, mirror_pose
from .tree import (
    FINGER_JOINTS,
    FINGER_NAMES,
    KEYPOINT_SOURCES,
    NUM_JOINTS,
    NUM_KEYPOINTS,
    PARENTS,
)

__all__ = [
    "IKResult",
    "inverse_kinematics",
    "skeleton_keypoints",
    "split_keypoints",
    "mean_skeleton",
]

# Keypoint index of each MANO joint (16) and of each fingertip (thumb, index, middle, ring,
# pinky), from KEYPOINT_SOURCES.
_JOINT_KEYPOINT = tuple(KEYPOINT_SOURCES.index(j) for j in range(NUM_JOINTS))
_TIP_KEYPOINT = tuple(KEYPOINT_SOURCES.index(NUM_JOINTS + f) for f in range(5))
_PALM_JOINTS = (1, 4, 7, 10, 13)  # the children of the wrist: rigid with the global rotation
_MIN_BEND = 0.02  # radians (about 1 degree): below, the next joint's bend says nothing of twist


@dataclass
class IKResult:
    """Result of :func:`inverse_kinematics` (B hands, units of the input: metres).

    pose: [B, 48] axis-angle radians, MANO order (global rotation, then 15 finger joints).
    rest_joints: [B, 16, 3] the rest skeleton the pose applies to.
    rest_fingertips: [B, 5, 3] rest fingertips (thumb, index, middle, ring, pinky), each carried
        by its finger's distal bone (:func:`skeleton_keypoints`).
    translation: [B, 3], added after the rotations.
    keypoints: [B, 21, 3] the keypoints the result poses to (OpenPose order).
    error: [B] mean distance of ``keypoints`` to the input keypoints.
    max_error: [B] largest such distance.
    """

    pose: torch.Tensor
    rest_joints: torch.Tensor
    rest_fingertips: torch.Tensor
    translation: torch.Tensor
    keypoints: torch.Tensor
    error: torch.Tensor
    max_error: torch.Tensor


def split_keypoints(keypoints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The 21 keypoints as MANO joints and fingertips (inverse of ``joints_to_keypoints``).

    keypoints: [..., 21, 3] -> (joints [..., 16, 3], fingertips [..., 5, 3])
    """
    _check_keypoints(keypoints, "keypoints")
    joints = keypoints[..., list(_JOINT_KEYPOINT), :]
    tips = keypoints[..., list(_TIP_KEYPOINT), :]
    return joints, tips


def skeleton_keypoints(
    pose: torch.Tensor,
    rest_joints: torch.Tensor,
    rest_fingertips: torch.Tensor,
    translation: torch.Tensor | None = None,
) -> torch.Tensor:
    """The 21 keypoints of a posed skeleton: the joints of :func:`forward_kinematics` and the
    fingertips moved rigidly with their distal bones (joints 15, 3, 6, 12, 9).

    pose: [B, 48] radians. rest_joints: [16, 3] or [B, 16, 3]. rest_fingertips: [5, 3] or
    [B, 5, 3] (thumb, index, middle, ring, pinky). translation: [B, 3] or None.
    -> [B, 21, 3] (OpenPose order), units of the input.
    """
    kinematics = forward_kinematics(pose, rest_joints, translation)
    batch = kinematics.joints.shape[0]
    tips = rest_fingertips.to(kinematics.joints.dtype).expand(batch, 5, 3)
    distal = [FINGER_JOINTS[name][-1] for name in FINGER_NAMES]
    transforms = kinematics.transforms[:, distal]  # [B, 5, 4, 4]
    posed_tips = (transforms[..., :3, :3] @ tips[..., None])[..., 0] + transforms[..., :3, 3]
    stacked = torch.cat([kinematics.joints, posed_tips], dim=1)
    return stacked[:, list(KEYPOINT_SOURCES)]


def _check_keypoints(keypoints: torch.Tensor, name: str) -> None:
    if not isinstance(keypoints, torch.Tensor) or not keypoints.is_floating_point():
        raise TypeError(f"{name} must be a floating-point torch.Tensor")
    if keypoints.dim() < 2 or keypoints.shape[-2:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"{name} must have shape [..., 21, 3] (OpenPose order), got "
                         f"{tuple(keypoints.shape)}")
    if not torch.isfinite(keypoints).all():
        raise ValueError(f"{name} contains NaN or inf values")


def _normalize(vectors: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    return vectors / vectors.norm(dim=-1, keepdim=True).clamp_min(eps)


def _kabsch(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Rotations [B, 3, 3] minimising ``sum |R source_i - target_i|^2`` (no centring: vectors).

    source: [B, N, 3] or [N, 3]; target: [B, N, 3].
    """
    source = source.expand_as(target)
    covariance = target.transpose(1, 2) @ source  # [B, 3, 3]
    u, _, vh = torch.linalg.svd(covariance)
    sign = torch.sign(torch.linalg.det(u @ vh))
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    fix = torch.diag_embed(torch.stack([torch.ones_like(sign), torch.ones_like(sign), sign], -1))
    return u @ fix @ vh


def _swing(start: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
    """The smallest rotations [B, 3, 3] taking unit vectors ``start`` [B, 3] onto ``end``."""
    cross = torch.cross(start, end, dim=-1)
    sin = cross.norm(dim=-1, keepdim=True)
    cos = (start * end).sum(-1, keepdim=True)
    angle = torch.atan2(sin, cos)
    # Opposite vectors: any axis perpendicular to start (the cross with the least aligned axis).
    basis = torch.eye(3, dtype=start.dtype, device=start.device)
    least = basis[start.abs().argmin(-1)]
    fallback = _normalize(torch.cross(start, least, dim=-1))
    axis = torch.where(sin > 1e-9, cross / sin.clamp_min(1e-300), fallback)
    axis = torch.where((sin <= 1e-9) & (cos > 0), torch.zeros_like(axis), axis)
    return axis_angle_to_matrix(axis * angle)


def _about(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotations [B, 3, 3] by ``angle`` [B] about unit ``axis`` [B, 3]."""
    return axis_angle_to_matrix(axis * angle[:, None])


def mean_skeleton(keypoints: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """One rest skeleton for many observations of the same hand (a subject's frames).

    Each frame's exact rest skeleton (:func:`inverse_kinematics`, ``fit_skeleton=True``) is
    reduced to its palm offsets (in the rest frame) and bone lengths; the result takes their
    per-coordinate median, with the reference's bone directions. Right-hand keypoints (mirror a
    left hand's first).

    keypoints: [F, 21, 3]; reference: [21, 3] rest-pose keypoints. -> [21, 3] rest keypoints.
    """
    fitted = inverse_kinematics(keypoints, reference, fit_skeleton=True)
    rest = torch.cat([fitted.rest_joints, fitted.rest_fingertips], dim=1)[:, list(
        KEYPOINT_SOURCES)]  # [F, 21, 3]
    median = rest.median(dim=0).values
    ref_joints, ref_tips = split_keypoints(reference.to(keypoints.dtype))
    joints, tips = split_keypoints(median)
    out_joints = ref_joints.clone()
    for j in _PALM_JOINTS:
        out_joints[j] = ref_joints[0] + (joints[j] - joints[0])
    out_tips = ref_tips.clone()
    for f, name in enumerate(FINGER_NAMES):
        chain = FINGER_JOINTS[name]
        points = [joints[j] for j in chain] + [tips[f]]
        ref_points = [ref_joints[j] for j in chain] + [ref_tips[f]]
        current = out_joints[chain[0]]
        for level in range(1, 4):
            length = (points[level] - points[level - 1]).norm()
            direction = _normalize(ref_points[level] - ref_points[level - 1])
            current = current + length * direction
            if level < 3:
                out_joints[chain[level]] = current
            else:
                out_tips[f] = current
    return torch.cat([out_joints, out_tips], dim=0)[list(KEYPOINT_SOURCES)]


def inverse_kinematics(
    keypoints: torch.Tensor,
    reference: torch.Tensor,
    *,
    fit_skeleton: bool = True,
    side: str = "right",
    refine: int = 0,
) -> IKResult:
    """Pose (and skeleton) that reproduce observed keypoints (see the module docstring).

    keypoints: [B, 21, 3] or [21, 3] observed keypoints (OpenPose order, e.g. metres).
    reference: [21, 3] rest-pose keypoints of a right hand in MANO's axes (e.g. the template's or
        MANO's zero pose): the bone directions of the rest skeleton, the flexion axes and the
        rest wrist; with ``fit_skeleton=False`` it is the skeleton itself.
    fit_skeleton: True: build the rest skeleton from the observation (bone lengths and palm),
        reproducing the keypoints to round-off. False: keep ``reference`` as the skeleton.
    side: 'right', or 'left' for left-hand keypoints (mirrored through x = 0, solved as a right
        hand and mirrored back: the result is in the left-hand convention of
        :func:`lisa_hand.skeleton.mirror_pose`).
    refine: with ``fit_skeleton=False``, this many L-BFGS iterations on the pose and translation
        (skeleton fixed) from the analytic solution, minimising the squared keypoint distances
        (the analytic pose points every bone along its observation and lets the errors of a
        skeleton that does not quite fit add up along each finger; 0: none).
    Computed in float64; results in the input's dtype. Raises ValueError for bad shapes or
    non-finite values, or for keypoints where a bone has zero length.
    """
    check_side(side)
    _check_keypoints(keypoints, "keypoints")
    _check_keypoints(reference, "reference")
    if reference.dim() != 2:
        raise ValueError(f"reference must be [21, 3], got {tuple(reference.shape)}")
    single = keypoints.dim() == 2
    dtype = keypoints.dtype
    observed = (keypoints[None] if single else keypoints).double()
    if observed.dim() != 3:
        raise ValueError(f"keypoints must be [B, 21, 3] or [21, 3], got {tuple(keypoints.shape)}")
    if side == "left":
        observed = mirror_points(observed)
    result = _solve_right(observed, reference.double().to(observed.device), fit_skeleton)
    if refine > 0 and not fit_skeleton:
        result = _refine(result, observed, int(refine))
    if side == "left":
        result = IKResult(
            pose=mirror_pose(result.pose), rest_joints=mirror_points(result.rest_joints),
            rest_fingertips=mirror_points(result.rest_fingertips),
            translation=mirror_points(result.translation),
            keypoints=mirror_points(result.keypoints), error=result.error,
            max_error=result.max_error)
    fields = {name: getattr(result, name).to(dtype) for name in result.__dataclass_fields__}
    if single:
        fields = {name: value[0] for name, value in fields.items()}
    return IKResult(**fields)


def _solve_right(observed: torch.Tensor, reference: torch.Tensor, fit_skeleton: bool) -> IKResult:
    """:func:`inverse_kinematics` of right-hand keypoints [B, 21, 3], float64."""
    batch = observed.shape[0]
    obs_joints, obs_tips = split_keypoints(observed)
    ref_joints, ref_tips = split_keypoints(reference)
    palm = list(_PALM_JOINTS)
    # 1. global orientation from the palm.
    global_rot = _kabsch(ref_joints[palm] - ref_joints[0], obs_joints[:, palm] - obs_joints[:, :1])
    palm_normal = _normalize(torch.cross(ref_joints[1] - ref_joints[0],
                                         ref_joints[7] - ref_joints[0], dim=-1))

    # 2. rest skeleton.
    rest_joints = ref_joints.expand(batch, NUM_JOINTS, 3).clone()
    rest_tips = ref_tips.expand(batch, 5, 3).clone()
    if fit_skeleton:
        offsets = obs_joints[:, palm] - obs_joints[:, :1]
        rest_joints[:, palm] = ref_joints[0] + (global_rot.transpose(1, 2) @ offsets.transpose(
            1, 2)).transpose(1, 2)
    world_rot = [global_rot] + [None] * (NUM_JOINTS - 1)
    for f, name in enumerate(FINGER_NAMES):
        chain = FINGER_JOINTS[name]
        obs_points = [obs_joints[:, j] for j in chain] + [obs_tips[:, f]]
        ref_points = [ref_joints[j] for j in chain] + [ref_tips[f]]
        obs_bones = [obs_points[k + 1] - obs_points[k] for k in range(3)]
        lengths = [bone.norm(dim=-1) for bone in obs_bones]
        if any(bool((length <= 1e-9).any()) for length in lengths):
            raise ValueError(f"keypoints: a {name} bone has zero length (coincident keypoints)")
        obs_dirs = [bone / length[:, None] for bone, length in zip(obs_bones, lengths,
                                                                   strict=True)]
        rest_dirs = [_normalize(ref_points[k + 1] - ref_points[k]) for k in range(3)]
        if fit_skeleton:
            for k in range(3):
                point = rest_joints[:, chain[k]] + lengths[k][:, None] * rest_dirs[k]
                if k < 2:
                    rest_joints[:, chain[k + 1]] = point
                else:
                    rest_tips[:, f] = point
        flex = [_normalize(torch.cross(rest_dirs[k], palm_normal, dim=-1)) for k in range(3)]
        # 3. rotations along the chain.
        parent_rot = global_rot
        for k, joint in enumerate(chain):
            rot = _swing(parent_rot @ rest_dirs[k], obs_dirs[k]) @ parent_rot
            if k < 2:
                rot = _untwist(rot, obs_dirs[k], rest_dirs[k + 1], obs_dirs[k + 1], flex[k + 1])
            world_rot[joint] = rot
            parent_rot = rot

    rotations = torch.stack(world_rot, dim=1)  # [B, 16, 3, 3] world rotations
    parents = list(PARENTS)
    relative = rotations.clone()
    relative[:, 1:] = rotations[:, parents[1:]].transpose(-1, -2) @ rotations[:, 1:]
    pose = matrix_to_axis_angle(relative).reshape(batch, 3 * NUM_JOINTS)
    translation = obs_joints[:, 0] - rest_joints[:, 0]
    posed = skeleton_keypoints(pose, rest_joints, rest_tips, translation)
    distance = (posed - observed).norm(dim=-1)
    return IKResult(pose=pose, rest_joints=rest_joints, rest_fingertips=rest_tips,
                    translation=translation, keypoints=posed, error=distance.mean(-1),
                    max_error=distance.amax(-1))


def _refine(result: IKResult, observed: torch.Tensor, iterations: int) -> IKResult:
    """L-BFGS on pose and translation (rest skeleton fixed) from ``result``; float64."""
    pose = result.pose.detach().clone().requires_grad_(True)
    translation = result.translation.detach().clone().requires_grad_(True)
    optimizer = torch.optim.LBFGS([pose, translation], lr=1.0, max_iter=iterations,
                                  line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        posed = skeleton_keypoints(pose, result.rest_joints, result.rest_fingertips, translation)
        loss = ((posed - observed) ** 2).sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        posed = skeleton_keypoints(pose, result.rest_joints, result.rest_fingertips, translation)
        distance = (posed - observed).norm(dim=-1)
        if not bool(distance.mean() <= result.error.mean()):  # never worse than the start
            return result
        return IKResult(pose=pose.detach(), rest_joints=result.rest_joints,
                        rest_fingertips=result.rest_fingertips, translation=translation.detach(),
                        keypoints=posed, error=distance.mean(-1), max_error=distance.amax(-1))


def _untwist(rot: torch.Tensor, bone: torch.Tensor, next_rest: torch.Tensor,
             next_bone: torch.Tensor, next_flex: torch.Tensor, iterations: int = 4
             ) -> torch.Tensor:
    """Turn ``rot`` [B, 3, 3] about its observed bone [B, 3] (unit) so that the next joint's
    bend, the smallest rotation taking its rest direction ``next_rest`` [3] (rest frame, carried
    by ``rot``) onto the observed ``next_bone`` [B, 3], is about that joint's rest flexion axis
    ``next_flex`` [3] (either sign, the nearer). A few fixed-point steps (one when the rest
    finger is straight). Rows whose next joint bends by less than ``_MIN_BEND`` keep ``rot``."""
    for _ in range(iterations):
        start = rot @ next_rest
        bend_axis = torch.cross(start, next_bone, dim=-1)
        bend = torch.atan2(bend_axis.norm(dim=-1), (start * next_bone).sum(-1))
        target = bend_axis - (bend_axis * bone).sum(-1, keepdim=True) * bone
        target = _normalize(target)
        current = rot @ next_flex
        current = _normalize(current - (current * bone).sum(-1, keepdim=True) * bone)
        target = torch.where((current * target).sum(-1, keepdim=True) < 0, -target, target)
        angle = torch.atan2((bone * torch.cross(current, target, dim=-1)).sum(-1),
                            (current * target).sum(-1))
        angle = torch.where(bend > _MIN_BEND, angle, torch.zeros_like(angle))
        rot = _about(bone, angle) @ rot
    return rot
