"""Bone geometry in the rest pose: unposing, bone centres, and the capsule regions of the bones.

Each bone ``j`` owns a region in its rest frame: the points within a radius of its segments.
The wrist (palm) bone has five segments, from the wrist to the base of each finger; every finger
bone has one, from its joint to its child joint, or, for the last bone of a finger, from its joint
along the direction of the previous segment (the fingertip is not a joint). Regions are what
makes bone culling part of the model's definition (see :mod:`lisa_hand.model`).
"""

from __future__ import annotations

import torch

from ..skeleton import NUM_JOINTS, PARENTS

__all__ = [
    "CHILDREN",
    "LEAF_BONES",
    "PALM_CHILDREN",
    "SEGMENT_BONES",
    "NUM_SEGMENTS",
    "unpose_points",
    "bone_segments",
    "bone_centres",
    "bone_axes",
    "capsule_distance",
    "segment_distances",
]

CHILDREN = tuple(tuple(c for c in range(NUM_JOINTS) if PARENTS[c] == j) for j in range(NUM_JOINTS))
"""Children of each joint in MANO's tree."""
PALM_CHILDREN = CHILDREN[0]  # (1, 4, 7, 10, 13): the base joint of each finger
LEAF_BONES = tuple(j for j in range(NUM_JOINTS) if not CHILDREN[j])  # (3, 6, 9, 12, 15)
SEGMENT_BONES = (0,) * len(PALM_CHILDREN) + tuple(range(1, NUM_JOINTS))
"""Owner bone of each region segment: five palm segments, then one per finger bone."""
NUM_SEGMENTS = len(SEGMENT_BONES)  # 20


def unpose_points(transforms: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Unpose world points into every bone's rest frame, ``x_j = R_j^-1 (x - t_j)`` (Sec. 4.1).

    transforms: [B, J, 4, 4] rest-to-posed bone transforms ``A_j = [R_j | t_j]``
        (:attr:`lisa_hand.skeleton.Kinematics.transforms`).
    points: [B, N, 3] world points, metres.
    -> [B, N, J, 3] rest-frame points, metres (a rest point ``y`` attached to bone ``j`` and posed
    to ``A_j y`` unposes back to ``y`` in slot ``j``).
    """
    rot = transforms[..., :3, :3]  # [B, J, 3, 3]
    shifted = points[:, :, None, :] - transforms[:, None, :, :3, 3]  # [B, N, J, 3]
    return torch.einsum("bjck,bnjc->bnjk", rot, shifted)  # R^T (x - t)


def bone_segments(
    rest_joints: torch.Tensor, tip_extension: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Start and end of the region segments (owners in :data:`SEGMENT_BONES`), rest frame.

    rest_joints: [B, 16, 3] metres.
    tip_extension: length of each finger's last segment as a fraction of the previous segment.
    -> (start [B, 20, 3], end [B, 20, 3]) metres.
    """
    palm_children = list(PALM_CHILDREN)
    finger_bones = list(range(1, NUM_JOINTS))
    # Each finger bone's end: its child joint, or the extrapolated tip for the last bone.
    end_index = [CHILDREN[j][0] if CHILDREN[j] else j for j in finger_bones]
    finger_start = rest_joints[:, finger_bones]
    finger_end = rest_joints[:, end_index]
    leaf = torch.tensor([not CHILDREN[j] for j in finger_bones], device=rest_joints.device)
    parents = [PARENTS[j] for j in finger_bones]
    tip = finger_start + tip_extension * (finger_start - rest_joints[:, parents])
    finger_end = torch.where(leaf[:, None], tip, finger_end)
    palm_start = rest_joints[:, :1].expand(-1, len(palm_children), 3)
    start = torch.cat([palm_start, finger_start], dim=1)
    end = torch.cat([rest_joints[:, palm_children], finger_end], dim=1)
    return start, end


def bone_centres(rest_joints: torch.Tensor, tip_extension: float) -> torch.Tensor:
    """Centre of each bone in the rest frame: the midpoint of a finger bone's segment; for the
    wrist bone, the mean of the wrist and the five finger bases (the palm's centre).

    rest_joints: [B, 16, 3] metres -> [B, 16, 3] metres
    """
    start, end = bone_segments(rest_joints, tip_extension)
    num_palm = len(PALM_CHILDREN)
    palm = torch.cat([rest_joints[:, :1], end[:, :num_palm]], dim=1).mean(dim=1, keepdim=True)
    return torch.cat([palm, 0.5 * (start[:, num_palm:] + end[:, num_palm:])], dim=1)


def bone_axes(rest_joints: torch.Tensor, tip_extension: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Main axis and length of each bone in the rest frame (wrist bone: wrist to middle base).

    rest_joints: [B, 16, 3] metres -> (unit axes [B, 16, 3], lengths [B, 16] metres)
    """
    start, end = bone_segments(rest_joints, tip_extension)
    num_palm = len(PALM_CHILDREN)
    middle = PALM_CHILDREN.index(4)
    palm_vec = end[:, middle : middle + 1] - start[:, middle : middle + 1]
    vectors = torch.cat([palm_vec, end[:, num_palm:] - start[:, num_palm:]], dim=1)
    lengths = vectors.norm(dim=-1)
    return vectors / lengths.clamp_min(1e-9)[..., None], lengths


def capsule_distance(
    points: torch.Tensor, start: torch.Tensor, direction: torch.Tensor, length: torch.Tensor
) -> torch.Tensor:
    """Distance from points to segments ``start + t direction``, ``0 <= t <= length``.

    points: [..., S, 3]; start, direction (unit): [..., S, 3] (broadcast); length: [..., S]
    -> [..., S] in the units of the inputs. The gradient is finite everywhere (zero on the segment).
    """
    rel = points - start
    along = (rel * direction).sum(-1).clamp(min=0.0)
    along = torch.minimum(along, length)
    offset = rel - along[..., None] * direction
    return (offset * offset).sum(-1).clamp_min(1e-24).sqrt()


def segment_distances(
    points: torch.Tensor, start: torch.Tensor, direction: torch.Tensor, length: torch.Tensor
) -> torch.Tensor:
    """Distances from every point to every segment, as one batched product (no [B, N, S, 3]).

    Expands ``|x - p - t d|^2 = |x - p|^2 - t (2 (x - p).d - t)`` with ``t = clamp((x - p).d, 0,
    L)``; ``x.p`` and ``x.d`` for all segments come from one [B, N, 3] @ [B, 3, 2S] product.
    Express points and starts relative to a nearby origin (e.g. the wrist): the expansion
    loses about ``eps |x|^2 / d`` to cancellation at distance ``d`` (float32, within 0.3 m of
    the origin: ~1e-8 m at 2 cm, the regions' boundaries) and ``sqrt(eps) |x|`` on the segment
    itself (float32: ~0.05 mm, deep inside the hand, where only the region test uses it).

    points: [B, N, 3]; start, direction (unit): [B, S, 3]; length: [B, S] -> [B, N, S]
    (same units; finite gradient everywhere).
    """
    products = torch.bmm(points, torch.cat([start, direction], dim=1).transpose(1, 2))
    num_segments = start.shape[1]
    x_dot_p, x_dot_d = products[..., :num_segments], products[..., num_segments:]
    p_dot_d = (start * direction).sum(-1)[:, None]
    along = x_dot_d - p_dot_d  # (x - p).d
    rel_sq = (points * points).sum(-1, keepdim=True) - 2.0 * x_dot_p
    rel_sq = rel_sq + (start * start).sum(-1)[:, None]
    clamped = torch.minimum(along.clamp(min=0.0), length[:, None])
    dist_sq = rel_sq - clamped * (2.0 * along - clamped)
    return dist_sq.clamp_min(1e-24).sqrt()
