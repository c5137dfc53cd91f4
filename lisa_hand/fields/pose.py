"""Pose conditioning of the MLPs: local per-bone rotation features, or the full pose vector."""

from __future__ import annotations

import torch

from ..skeleton import NUM_JOINTS, PARENTS, POSE_DIM, mano_pose_features
from .bones import CHILDREN

__all__ = ["LOCAL_POSE_DIM", "pose_feature_dim", "local_pose_mask", "pose_features"]

LOCAL_POSE_DIM = 9 * (NUM_JOINTS - 1)  # 135: vec(R_k - I) of the 15 finger joints


def pose_feature_dim(mode: str) -> int:
    """Width of :func:`pose_features` for a conditioning mode ('local': 135, 'full': 48)."""
    if mode == "local":
        return LOCAL_POSE_DIM
    if mode == "full":
        return POSE_DIM
    raise ValueError(f"pose conditioning must be 'local' or 'full', got {mode!r}")


def local_pose_mask(per_bone: bool) -> torch.Tensor:
    """Which finger joints each MLP sees in 'local' mode.

    Bone ``j`` sees the rotations of its own joint, its parent and its children. The global
    orientation (joint 0) moves the whole hand rigidly and never changes its shape in the rest
    frame, so no bone sees it. With ``per_bone=False`` (one MLP) all 15 finger joints are seen.
    -> [G, 15] float (G = 16 bones, or 1)
    """
    if not per_bone:
        return torch.ones(1, NUM_JOINTS - 1)
    mask = torch.zeros(NUM_JOINTS, NUM_JOINTS)
    for bone in range(NUM_JOINTS):
        for joint in (bone, PARENTS[bone], *CHILDREN[bone]):
            if joint >= 0:
                mask[bone, joint] = 1.0
    return mask[:, 1:]


def pose_features(
    pose: torch.Tensor, rotmats: torch.Tensor, mode: str, mask: torch.Tensor
) -> torch.Tensor:
    """Per-MLP pose inputs.

    pose: [B, 48] axis-angle radians; rotmats: [B, 16, 3, 3] relative joint rotations.
    mode: 'local' (masked ``vec(R_k - I)`` over the finger joints, zeros elsewhere) or 'full'
        (the 48-D pose, the same for every MLP).
    mask: [G, 15] from :func:`local_pose_mask` (used in 'local' mode).
    -> [B, G, 135] ('local') or [B, G, 48] ('full')
    """
    groups = mask.shape[0]
    if mode == "full":
        return pose.reshape(pose.shape[0], 1, POSE_DIM).expand(-1, groups, -1)
    if mode != "local":
        raise ValueError(f"pose conditioning must be 'local' or 'full', got {mode!r}")
    features = mano_pose_features(rotmats).reshape(-1, 1, NUM_JOINTS - 1, 9)
    mask = mask.to(dtype=features.dtype, device=features.device)
    return (features * mask[None, :, :, None]).flatten(-2)
