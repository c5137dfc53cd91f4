"""Auto-decoder latent tables."""

from __future__ import annotations

import pytest
import torch

from lisa_hand.fields import LatentTable


def test_initial_codes_are_small_spherical_gaussian():
    torch.manual_seed(0)
    table = LatentTable(400, 128, init_std=0.01)
    codes = table.weight.detach()
    assert abs(codes.mean().item()) < 2e-4
    assert abs(codes.std().item() - 0.01) < 2e-4
    # Spherical: per-dimension variances agree.
    assert codes.var(dim=0).std() / codes.var(dim=0).mean() < 0.15


def test_lookup_prior_and_gradients():
    table = LatentTable(4, 3)
    with torch.no_grad():
        table.weight.copy_(
            torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0, 0, 2.0]])
        )
    codes = table(torch.tensor([0, 1, 0]))
    assert codes.shape == (3, 3)
    assert table.prior_loss(torch.tensor([0, 1])).item() == pytest.approx(3.0)
    assert table.prior_loss().item() == pytest.approx((5 + 1 + 1 + 2) / 4)
    torch.testing.assert_close(table.mean_code(), torch.tensor([1.0, 1.0, 0.75]))
    table.prior_loss(torch.tensor([0])).backward()
    torch.testing.assert_close(table.weight.grad[0], torch.tensor([0.6, 0.8, 0.0]))
    assert table.weight.grad[1:].abs().sum() == 0


def test_validation():
    table = LatentTable(4, 3)
    with pytest.raises(ValueError, match="\\[0, 4\\)"):
        table(torch.tensor([4]))
    with pytest.raises(TypeError, match="integer"):
        table(torch.tensor([0.0]))
    with pytest.raises(ValueError, match="num_codes"):
        LatentTable(0, 3)
