"""Forward kinematics on MANO's tree, linear blend skinning, and left/right mirroring."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..geometry.rotations import axis_angle_to_matrix, matrix_to_quaternion
from ..geometry.transforms import make_transform
from .tree import NUM_JOINTS, PARENTS, POSE_DIM

__all__ = [
    "Kinematics",
    "forward_kinematics",
    "linear_blend_skinning",
    "dual_quaternion_skinning",
    "check_pose",
    "mirror_pose",
    "mirror_points",
    "check_side",
]


@dataclass
class Kinematics:
    """Result of :func:`forward_kinematics` (world frame, metres).

    joints: [B, 16, 3] posed joint positions.
    transforms: [B, 16, 4, 4] rest-to-posed bone transforms ``A_j``: a rest-pose point rigidly
        attached to bone ``j`` lands at ``A_j x``. These are LBS's transforms; LISA unposes a
        query point into bone ``j``'s rest frame with ``A_j^-1``.
    bone_frames: [B, 16, 4, 4] world-from-bone frames: origin at the posed joint, axes the rest
        axes carried along by the chain of rotations. ``A_j = bone_frames_j @ [I | -J_rest_j]``.
    rotmats: [B, 16, 3, 3] the relative (parent-frame) joint rotations.
    """

    joints: torch.Tensor
    transforms: torch.Tensor
    bone_frames: torch.Tensor
    rotmats: torch.Tensor


def check_pose(pose: torch.Tensor, name: str = "pose") -> torch.Tensor:
    """Validate a pose and return it as ``[B, 16, 3]``.

    pose: [B, 48] or [B, 16, 3] axis-angle, radians.
    """
    if not isinstance(pose, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(pose).__name__}")
    if not pose.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor (radians), got dtype {pose.dtype}")
    if pose.dim() == 2 and pose.shape[-1] == POSE_DIM:
        pose = pose.reshape(pose.shape[0], NUM_JOINTS, 3)
    if pose.dim() != 3 or pose.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(
            f"{name} must have shape [B, {POSE_DIM}] or [B, {NUM_JOINTS}, 3] (axis-angle: 3 global "
            f"+ 45 finger values), got {tuple(pose.shape)}"
        )
    if not torch.isfinite(pose).all():
        raise ValueError(f"{name} contains NaN or inf values")
    return pose


def forward_kinematics(
    pose: torch.Tensor,
    rest_joints: torch.Tensor,
    translation: torch.Tensor | None = None,
) -> Kinematics:
    """Pose MANO's kinematic tree.

    The first joint's rotation is the global orientation about the wrist; every other rotation is
    relative to its parent. Differentiable in pose, rest joints and translation.

    pose: [B, 48] or [B, 16, 3] axis-angle radians.
    rest_joints: [16, 3] or [B, 16, 3] joint positions in the rest (zero) pose, metres.
    translation: [B, 3] metres, added after the rotations (MANO's ``transl``); None for zero.
    """
    pose = check_pose(pose)
    batch = pose.shape[0]
    if not isinstance(rest_joints, torch.Tensor):
        raise TypeError(f"rest_joints must be a torch.Tensor, got {type(rest_joints).__name__}")
    if rest_joints.shape[-2:] != (NUM_JOINTS, 3) or rest_joints.dim() not in (2, 3):
        raise ValueError(
            f"rest_joints must be [16, 3] or [B, 16, 3], got {tuple(rest_joints.shape)}"
        )
    if rest_joints.dim() == 3 and rest_joints.shape[0] not in (1, batch):
        raise ValueError(
            f"rest_joints has batch size {rest_joints.shape[0]} but pose has {batch} "
            "(pass [16, 3], [1, 16, 3] or [B, 16, 3])"
        )
    rest_joints = rest_joints.to(pose.dtype).expand(batch, NUM_JOINTS, 3)
    rotmats = axis_angle_to_matrix(pose)  # [B, 16, 3, 3]

    parents = torch.as_tensor(PARENTS[1:], device=pose.device)
    offsets = torch.cat([rest_joints[:, :1], rest_joints[:, 1:] - rest_joints[:, parents]], dim=1)
    local = make_transform(rotmats, offsets)  # [B, 16, 4, 4]
    # The tree is shallow (depth 4): chain per joint in order, parents always come first.
    frames = [local[:, 0]]
    for j in range(1, NUM_JOINTS):
        frames.append(frames[PARENTS[j]] @ local[:, j])
    bone_frames = torch.stack(frames, dim=1)
    if translation is not None:
        if not isinstance(translation, torch.Tensor):
            raise TypeError(
                f"translation must be a torch.Tensor or None, got {type(translation).__name__}"
            )
        if translation.shape != (batch, 3):
            raise ValueError(
                f"translation must be [B, 3] with B={batch}, got {tuple(translation.shape)}"
            )
        if not torch.isfinite(translation).all():
            raise ValueError("translation contains NaN or inf values")
        shift = torch.zeros_like(bone_frames)
        shift[..., :3, 3] = translation[:, None].to(pose.dtype)
        bone_frames = bone_frames + shift
    joints = bone_frames[..., :3, 3]
    rot_world = bone_frames[..., :3, :3]
    transl_lbs = joints - (rot_world @ rest_joints[..., None])[..., 0]
    transforms = make_transform(rot_world, transl_lbs)
    return Kinematics(
        joints=joints, transforms=transforms, bone_frames=bone_frames, rotmats=rotmats
    )


def linear_blend_skinning(
    points_rest: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor
) -> torch.Tensor:
    """Linear blend skinning ``v = sum_j w_j A_j v_rest`` (paper Eq. 2).

    points_rest: [B, V, 3] or [V, 3] rest-pose points, metres.
    weights: [V, J] or [B, V, J], rows summing to 1.
    transforms: [B, J, 4, 4] rest-to-posed bone transforms (:attr:`Kinematics.transforms`).
    -> [B, V, 3] posed points.
    """
    if transforms.dim() != 4 or transforms.shape[-2:] != (4, 4):
        raise ValueError(f"transforms must be [B, J, 4, 4], got {tuple(transforms.shape)}")
    if points_rest.dim() not in (2, 3) or points_rest.shape[-1] != 3:
        raise ValueError(f"points_rest must be [V, 3] or [B, V, 3], got {tuple(points_rest.shape)}")
    if weights.dim() not in (2, 3):
        raise ValueError(f"weights must be [V, J] or [B, V, J], got {tuple(weights.shape)}")
    batch = transforms.shape[0]
    for name, value in (("points_rest", points_rest), ("weights", weights)):
        if value.dim() == 3 and value.shape[0] not in (1, batch):
            raise ValueError(
                f"{name} has batch size {value.shape[0]} but transforms has {batch}: "
                f"{name} {tuple(value.shape)}, transforms {tuple(transforms.shape)}"
            )
    points_rest = points_rest.expand(batch, *points_rest.shape[-2:])
    if weights.shape[-1] != transforms.shape[1] or weights.shape[-2] != points_rest.shape[1]:
        raise ValueError(
            f"weights {tuple(weights.shape)} do not match points {tuple(points_rest.shape)} and "
            f"transforms {tuple(transforms.shape)}"
        )
    weights = weights.expand(batch, *weights.shape[-2:])
    blended = torch.einsum("bvj,bjrc->bvrc", weights.to(transforms.dtype), transforms[..., :3, :])
    return (blended[..., :3] @ points_rest.to(transforms.dtype)[..., None])[..., 0] + blended[
        ..., 3
    ]


def _quaternion_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of quaternions ``(w, x, y, z)``: [..., 4] x [..., 4] -> [..., 4]."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], -1)


def dual_quaternion_skinning(
    points_rest: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor
) -> torch.Tensor:
    """Dual quaternion skinning (Kavan et al. 2008): the bones' rigid transforms blended as unit
    dual quaternions, so that a blend is itself rigid.

    Linear blend skinning averages matrices, which shrinks the skin where bones rotate apart
    (volume lost at a flexed knuckle, the "candy wrapper" of a twisted joint); a blended unit dual
    quaternion is a rotation and a translation, so the skin keeps its thickness. Each vertex's
    quaternions are first put on the hemisphere of its most weighted bone's.

    points_rest: [V, 3] rest points, metres. weights: [V, J], rows summing to 1.
    transforms: [J, 4, 4] rest-to-posed rigid bone transforms. -> [V, 3] posed points.
    """
    if transforms.dim() != 3 or transforms.shape[-2:] != (4, 4):
        raise ValueError(f"transforms must be [J, 4, 4], got {tuple(transforms.shape)}")
    if points_rest.dim() != 2 or points_rest.shape[-1] != 3:
        raise ValueError(f"points_rest must be [V, 3], got {tuple(points_rest.shape)}")
    if weights.shape != (points_rest.shape[0], transforms.shape[0]):
        raise ValueError(f"weights {tuple(weights.shape)} do not match points "
                         f"{tuple(points_rest.shape)} and transforms {tuple(transforms.shape)}")
    dtype = transforms.dtype
    real = matrix_to_quaternion(transforms[:, :3, :3])  # [J, 4]
    shift = torch.cat([torch.zeros_like(transforms[:, :1, 3]), transforms[:, :3, 3]], -1)
    dual = 0.5 * _quaternion_product(shift, real)  # [J, 4]
    weights = weights.to(dtype)
    pivot = real[weights.argmax(dim=1)]  # [V, 4]
    signs = torch.where(pivot @ real.T < 0, -1.0, 1.0).to(dtype)  # [V, J]
    signed = weights * signs
    blend_real, blend_dual = signed @ real, signed @ dual  # [V, 4]
    norm = blend_real.norm(dim=-1, keepdim=True)
    blend_real, blend_dual = blend_real / norm, blend_dual / norm
    w, vec = blend_real[:, :1], blend_real[:, 1:]
    dual_w, dual_vec = blend_dual[:, :1], blend_dual[:, 1:]
    points = points_rest.to(dtype)
    rotated = points + 2.0 * torch.cross(vec, torch.cross(vec, points, dim=-1) + w * points,
                                         dim=-1)
    translation = 2.0 * (w * dual_vec - dual_w * vec + torch.cross(vec, dual_vec, dim=-1))
    return rotated + translation


_SIDES = ("right", "left")


def check_side(side: str) -> str:
    """Validate a hand side name ('right' or 'left')."""
    if side not in _SIDES:
        raise ValueError(f"unknown hand side {side!r}: expected 'right' or 'left'")
    return side


def mirror_points(points: torch.Tensor) -> torch.Tensor:
    """Mirror points through the x = 0 plane (right hand <-> left hand, as MANO's left model).

    points: [..., 3] -> [..., 3]
    """
    return points * points.new_tensor([-1.0, 1.0, 1.0])


def mirror_pose(pose: torch.Tensor) -> torch.Tensor:
    """Mirror axis-angle rotations through the x = 0 plane: ``(x, y, z) -> (x, -y, -z)``.

    With mirrored rest joints, ``FK(mirror_pose(p))`` is the mirror of ``FK(p)``.
    pose: [..., 48] or [..., 16, 3] -> same shape
    """
    shape = pose.shape
    if pose.dim() == 0 or shape[-1] % 3 != 0:
        raise ValueError(
            f"pose must be [..., 3k] axis-angle values (e.g. [..., 48] or [..., 16, 3]), got "
            f"{tuple(shape)}"
        )
    flipped = pose.reshape(*shape[:-1], -1, 3) * pose.new_tensor([1.0, -1.0, -1.0])
    return flipped.reshape(shape)
