"""LISA's training and fitting losses (paper Section 4.2), as pure functions on tensors.

Each returns a scalar mean over its samples, so that the weights (lambda) of the total loss
(paper Eq. 14) do not depend on batch sizes.
"""

from __future__ import annotations

import torch

__all__ = [
    "color_loss",
    "eikonal_loss",
    "skinning_loss",
    "latent_loss",
    "surface_loss",
    "normal_loss",
    "robust_surface_loss",
]


def color_loss(rgb_pred: torch.Tensor, rgb_true: torch.Tensor) -> torch.Tensor:
    """L_col = ||c_k - c^_k||_1 (Eq. 10), averaged over rays.

    rgb_pred, rgb_true: [R, 3] in [0, 1]
    """
    return (rgb_pred - rgb_true).abs().sum(-1).mean()


def eikonal_loss(sdf_grad: torch.Tensor) -> torch.Tensor:
    """L_Eik = (||grad_x G(x)||_2 - 1)^2 (Eq. 11), averaged over points.

    sdf_grad: [..., 3] spatial gradient of the SDF at surface and uniform points
    """
    return ((sdf_grad.norm(dim=-1) - 1.0) ** 2).mean()


def skinning_loss(weights_pred: torch.Tensor, weights_true: torch.Tensor) -> torch.Tensor:
    """L_w = ||w - w^||_1 (Eq. 12) against pseudo-ground-truth skinning weights.

    weights_pred, weights_true: [..., J]
    """
    return (weights_pred - weights_true).abs().sum(-1).mean()


def latent_loss(*latents: torch.Tensor) -> torch.Tensor:
    """L_reg = ||beta+||_2 + ||gamma||_2 (Eq. 13), averaged over the batch.

    latents: each [B, D]
    """
    return sum(code.norm(dim=-1).mean() for code in latents)


def surface_loss(sdf_on_surface: torch.Tensor) -> torch.Tensor:
    """L_surf = ||G(x_surf)||_1 (Eq. 16): scan points lie on the zero level set.

    sdf_on_surface: [...] metres
    """
    return sdf_on_surface.abs().mean()


def normal_loss(sdf_grad: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """L_N = ||grad_x G(x_surf) - N(x_surf)||_1 (Eq. 17).

    sdf_grad, normals: [..., 3] (normals unit length, pointing out of the hand)
    """
    return (sdf_grad - normals).abs().sum(-1).mean()


def robust_surface_loss(sdf_on_surface: torch.Tensor, scale: float) -> torch.Tensor:
    """Geman-McClure robust version of :func:`surface_loss` for noisy scans with outliers.

    Behaves like ``|s|^2 / scale^2`` near zero and saturates at 1 far away, so an outlier
    contributes a bounded amount. ``scale`` in metres (about the noise level).
    """
    squared = (sdf_on_surface / scale) ** 2
    return (squared / (squared + 1.0)).mean()
