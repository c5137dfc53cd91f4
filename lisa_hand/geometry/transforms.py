"""Rigid transforms as 4x4 homogeneous matrices."""

from __future__ import annotations

import torch

__all__ = ["make_transform", "invert_rigid", "apply_transform", "transform_vectors"]


def make_transform(rotmats: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """Stack a rotation and a translation into ``[[R, t], [0, 1]]``.

    rotmats: [..., 3, 3], translations: [..., 3] -> [..., 4, 4]
    """
    top = torch.cat([rotmats, translations[..., :, None]], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def invert_rigid(transforms: torch.Tensor) -> torch.Tensor:
    """Inverse of a rigid transform, ``[[R^T, -R^T t], [0, 1]]`` (exact, no general inverse).

    transforms: [..., 4, 4] -> [..., 4, 4]
    """
    rot_t = transforms[..., :3, :3].transpose(-1, -2)
    trans = -(rot_t @ transforms[..., :3, 3:4])[..., 0]
    return make_transform(rot_t, trans)


def apply_transform(transforms: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply ``T`` to points: ``R x + t``.

    transforms: [..., 4, 4], points: [..., N, 3] -> [..., N, 3] (batch dims broadcast)
    """
    return points @ transforms[..., :3, :3].transpose(-1, -2) + transforms[..., None, :3, 3]


def transform_vectors(transforms: torch.Tensor, vectors: torch.Tensor) -> torch.Tensor:
    """Apply only the rotation of ``T`` (directions, normals).

    transforms: [..., 4, 4], vectors: [..., N, 3] -> [..., N, 3]
    """
    return vectors @ transforms[..., :3, :3].transpose(-1, -2)
