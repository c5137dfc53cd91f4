"""Rotations: axis-angle <-> matrix, exact and differentiable at zero angle."""

from __future__ import annotations

import torch

__all__ = ["axis_angle_to_matrix", "matrix_to_axis_angle", "matrix_to_quaternion", "skew"]

# Below this squared angle the Taylor series (to theta^4) is exact to machine precision for
# float64 (error ~ theta^6 / 5040) and float32 alike; above it the closed form is well conditioned.
_SMALL_ANGLE_SQ = 1e-6


def skew(vectors: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices ``[v]_x`` with ``[v]_x u = v x u``.

    vectors: [..., 3] -> [..., 3, 3]
    """
    x, y, z = vectors.unbind(-1)
    zero = torch.zeros_like(x)
    rows = (
        torch.stack([zero, -z, y], dim=-1),
        torch.stack([z, zero, -x], dim=-1),
        torch.stack([-y, x, zero], dim=-1),
    )
    return torch.stack(rows, dim=-2)


def axis_angle_to_matrix(axis_angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula, batched: ``R = I + a [k]_x + b [k]_x^2``, ``k`` the unnormalised axis.

    ``a = sin(theta)/theta`` and ``b = (1 - cos theta)/theta^2`` switch to their Taylor series near
    zero, so both the value and the gradient are exact at zero angle (no NaN from ``|k|``).

    axis_angle: [..., 3] radians (direction = axis, norm = angle) -> [..., 3, 3]
    """
    if axis_angle.shape[-1] != 3:
        raise ValueError(f"axis_angle must have shape [..., 3], got {tuple(axis_angle.shape)}")
    theta_sq = (axis_angle * axis_angle).sum(-1, keepdim=True)
    small = theta_sq < _SMALL_ANGLE_SQ
    # The closed form runs on a safe angle so that its (unused) gradient is finite where small.
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    theta = safe_sq.sqrt()
    half_sin = torch.sin(0.5 * theta)
    sinc = torch.where(small, 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0, torch.sin(theta) / theta)
    cosc = torch.where(
        small, 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0, 2.0 * half_sin * half_sin / safe_sq
    )
    k = skew(axis_angle)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + sinc[..., None] * k + cosc[..., None] * (k @ k)


def matrix_to_axis_angle(rotmats: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`axis_angle_to_matrix` via quaternions (robust near 0 and pi).

    rotmats: [..., 3, 3] -> [..., 3] radians, angle in [0, pi]
    """
    quat = matrix_to_quaternion(rotmats)
    w, xyz = quat[..., 0], quat[..., 1:]
    sin_half = xyz.norm(dim=-1)
    angle = 2.0 * torch.atan2(sin_half, w)
    # angle / sin(angle/2) -> 2 as the angle -> 0
    scale = torch.where(
        sin_half > 1e-8, angle / sin_half.clamp_min(1e-12), 2.0 / w.clamp_min(1e-12)
    )
    return xyz * scale[..., None]


def matrix_to_quaternion(rotmats: torch.Tensor) -> torch.Tensor:
    """Unit quaternions ``(w, x, y, z)`` of rotation matrices, ``w >= 0``.

    rotmats: [..., 3, 3] -> [..., 4]
    """
    if rotmats.shape[-2:] != (3, 3):
        raise ValueError(f"rotmats must have shape [..., 3, 3], got {tuple(rotmats.shape)}")
    m00, m01, m02 = rotmats[..., 0, 0], rotmats[..., 0, 1], rotmats[..., 0, 2]
    m10, m11, m12 = rotmats[..., 1, 0], rotmats[..., 1, 1], rotmats[..., 1, 2]
    m20, m21, m22 = rotmats[..., 2, 0], rotmats[..., 2, 1], rotmats[..., 2, 2]
    # Four candidate quaternions (w, x, y, z), each scaled by 4 times one of its components and so
    # well conditioned where that component is large; pick the one with the largest.
    diag = torch.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    cands = torch.stack(
        [
            torch.stack([diag[..., 0], m21 - m12, m02 - m20, m10 - m01], -1),
            torch.stack([m21 - m12, diag[..., 1], m01 + m10, m02 + m20], -1),
            torch.stack([m02 - m20, m01 + m10, diag[..., 2], m12 + m21], -1),
            torch.stack([m10 - m01, m02 + m20, m12 + m21, diag[..., 3]], -1),
        ],
        dim=-2,
    )
    best = diag.argmax(-1)
    quat = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    quat = quat / quat.norm(dim=-1, keepdim=True)
    return torch.where(quat[..., :1] < 0, -quat, quat)
