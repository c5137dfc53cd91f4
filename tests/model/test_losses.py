import pytest
import torch

from lisa_hand.model.losses import (
    color_loss,
    eikonal_loss,
    latent_loss,
    normal_loss,
    robust_surface_loss,
    skinning_loss,
    surface_loss,
)


def test_eikonal_is_zero_on_exact_sdf_gradient():
    points = torch.randn(100, 3, dtype=torch.float64, requires_grad=True)
    sdf = points.norm(dim=-1) - 0.5  # exact sphere SDF
    (grad,) = torch.autograd.grad(sdf.sum(), points)
    assert eikonal_loss(grad).item() < 1e-20
    assert abs(eikonal_loss(2.0 * grad).item() - 1.0) < 1e-12


def test_losses_against_hand_values():
    pred = torch.tensor([[0.5, 0.5, 0.5], [0.0, 1.0, 0.0]])
    true = torch.tensor([[0.5, 0.25, 0.5], [0.0, 1.0, 1.0]])
    assert torch.isclose(color_loss(pred, true), torch.tensor((0.25 + 1.0) / 2))
    assert torch.isclose(skinning_loss(pred, true), torch.tensor((0.25 + 1.0) / 2))
    codes = torch.tensor([[3.0, 4.0], [0.0, 0.0]])
    assert torch.isclose(latent_loss(codes, codes), torch.tensor(2.5 + 2.5))
    assert torch.isclose(surface_loss(torch.tensor([-0.1, 0.3])), torch.tensor(0.2))
    normals = torch.tensor([[0.0, 0.0, 1.0]])
    assert torch.isclose(normal_loss(torch.tensor([[0.0, 0.1, 0.9]]), normals), torch.tensor(0.2))


def test_robust_surface_loss_bounds_outliers():
    inliers = torch.full((99,), 1e-4)
    with_outlier = torch.cat([inliers, torch.tensor([10.0])])
    robust = robust_surface_loss(with_outlier, scale=1e-3)
    assert robust.item() < 0.02  # one outlier adds at most 1/100
    assert surface_loss(with_outlier).item() > 0.09  # L1 is dominated by it


def test_paired_losses_refuse_shapes_that_would_broadcast():
    rays = torch.zeros(4, 3)
    with pytest.raises(ValueError, match=r"rgb_pred and rgb_true .* \[4, 3\] and \[4, 1, 3\]"):
        color_loss(rays, rays[:, None])
    with pytest.raises(ValueError, match="weights_pred and weights_true"):
        skinning_loss(torch.zeros(2, 5, 16), torch.zeros(5, 16))
    with pytest.raises(ValueError, match=r"sdf_grad and normals .* \[\.\.\., 3\]"):
        normal_loss(torch.zeros(4, 2), torch.zeros(4, 2))
    with pytest.raises(TypeError, match="rgb_true must be a torch.Tensor"):
        color_loss(rays, rays.numpy())
