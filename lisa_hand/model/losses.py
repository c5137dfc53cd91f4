"""LISA's training and fitting losses (paper Section 4.2), as pure functions on tensors.

Each returns a scalar mean over its samples, so that the weights (lambda) of the total loss
(paper Eq. 17) do not depend on batch sizes.
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


def _check_same_shape(
    pred: torch.Tensor, true: torch.Tensor, names: tuple[str, str], last_dim: int | None = None
) -> None:
    """Refuse pairs that would silently broadcast (e.g. [R, 3] against [R, 1, 3])."""
    for name, value in zip(names, (pred, true), strict=True):
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if pred.shape != true.shape or (last_dim is not None and pred.shape[-1:] != (last_dim,)):
        expected = "the same shape" if last_dim is None else f"[..., {last_dim}]"
        raise ValueError(
            f"{names[0]} and {names[1]} must both have shape {expected}, got "
            f"{list(pred.shape)} and {list(true.shape)}"
        )


def color_loss(rgb_pred: torch.Tensor, rgb_true: torch.Tensor) -> torch.Tensor:
    """L_col = ||c_k - c^_k||_1 (Eq. 13), averaged over rays.

    rgb_pred, rgb_true: [R, 3] in [0, 1]
    """
    _check_same_shape(rgb_pred, rgb_true, ("rgb_pred", "rgb_true"))
    return (rgb_pred - rgb_true).abs().sum(-1).mean()


def eikonal_loss(sdf_grad: torch.Tensor) -> torch.Tensor:
    """L_Eik = (||grad_x G(x)||_2 - 1)^2 (Eq. 14), averaged over points.

    sdf_grad: [..., 3] spatial gradient of the SDF at surface and uniform points
    """
    return ((sdf_grad.norm(dim=-1) - 1.0) ** 2).mean()


def skinning_loss(weights_pred: torch.Tensor, weights_true: torch.Tensor) -> torch.Tensor:
    """L_w = ||w - w^||_1 (Eq. 15) against pseudo-ground-truth skinning weights.

    weights_pred, weights_true: [..., J]
    """
    _check_same_shape(weights_pred, weights_true, ("weights_pred", "weights_true"))
    return (weights_pred - weights_true).abs().sum(-1).mean()


def latent_loss(*latents: torch.Tensor) -> torch.Tensor:
    """L_reg = ||beta+||_2 + ||gamma||_2 (Eq. 16), averaged over the batch.

    latents: each [B, D]
    """
    return sum(code.norm(dim=-1).mean() for code in latents)


def surface_loss(sdf_on_surface: torch.Tensor) -> torch.Tensor:
    """L_surf = ||G(x_surf)||_1 (Eq. 19): scan points lie on the zero level set.

    sdf_on_surface: [...] metres
    """
    return sdf_on_surface.abs().mean()


def normal_loss(sdf_grad: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """L_N = ||grad_x G(x_surf) - N(x_surf)||_1 (Eq. 20).

    sdf_grad, normals: [..., 3] (normals unit length, pointing out of the hand)
    """
    _check_same_shape(sdf_grad, normals, ("sdf_grad", "normals"), last_dim=3)
    return (sdf_grad - normals).abs().sum(-1).mean()


def robust_surface_loss(sdf_on_surface: torch.Tensor, scale: float) -> torch.Tensor:
    """Geman-McClure robust version of :func:`surface_loss` for noisy scans with outliers.

    Behaves like ``|s|^2 / scale^2`` near zero and saturates at 1 far away, so an outlier
    contributes a bounded amount. ``scale`` in metres (about the noise level).
    """
    squared = (sdf_on_surface / scale) ** 2
    return (squared / (squared + 1.0)).mean()
