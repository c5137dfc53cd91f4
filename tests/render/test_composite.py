import math

import pytest
import torch

from lisa_hand.render import composite, sample_deltas


def test_composite_three_samples_hand_computed():
    t_vals = torch.tensor([[1.0, 2.0, 4.0]], dtype=torch.float64)
    far = torch.tensor([5.0], dtype=torch.float64)
    sigma = torch.tensor([[0.5, 1.0, 2.0]], dtype=torch.float64)
    colors = torch.tensor([[[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]]], dtype=torch.float64)
    background = torch.tensor([0.2, 0.4], dtype=torch.float64)
    # deltas 1, 2, 1 -> optical depths 0.5, 2, 2
    assert sample_deltas(t_vals, far).tolist() == [[1.0, 2.0, 1.0]]
    w0 = 1 - math.exp(-0.5)
    w1 = math.exp(-0.5) * (1 - math.exp(-2.0))
    w2 = math.exp(-2.5) * (1 - math.exp(-2.0))
    out = composite(sigma, colors, t_vals, far, background)
    assert out.weights[0].tolist() == pytest.approx([w0, w1, w2], rel=1e-14)
    opacity = 1 - math.exp(-4.5)
    assert out.opacity.item() == pytest.approx(opacity, rel=1e-14)
    assert w0 + w1 + w2 == pytest.approx(opacity, rel=1e-14)
    expected_rgb = [
        w0 * 1.0 + w2 * 0.5 + (1 - opacity) * 0.2,
        w1 * 1.0 + w2 * 0.5 + (1 - opacity) * 0.4,
    ]
    assert out.rgb[0].tolist() == pytest.approx(expected_rgb, rel=1e-14)
    assert out.depth.item() == pytest.approx((w0 * 1 + w1 * 2 + w2 * 4) / opacity, rel=1e-14)


def test_composite_two_samples_per_ray_background_and_empty_ray():
    t_vals = torch.tensor([[0.0, 1.0], [0.0, 1.0]])
    far = torch.tensor([3.0, 3.0])
    sigma = torch.tensor([[0.0, math.log(2.0) / 2.0], [0.0, 0.0]])  # second: alpha = 1/2
    colors = torch.ones(2, 2, 3)
    background = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    out = composite(sigma, colors, t_vals, far, background)
    torch.testing.assert_close(out.weights, torch.tensor([[0.0, 0.5], [0.0, 0.0]]))
    assert out.rgb.tolist()[0] == pytest.approx([0.5, 0.5, 1.0], abs=1e-6)
    assert out.rgb.tolist()[1] == pytest.approx([1.0, 0.0, 0.0])
    assert out.opacity.tolist() == pytest.approx([0.5, 0.0], abs=1e-7)
    assert out.depth.tolist() == pytest.approx([1.0, 0.0], abs=1e-6)
    # No background means black.
    assert composite(sigma, colors, t_vals, far).rgb[1].tolist() == [0.0, 0.0, 0.0]


def test_composite_matches_closed_form_for_constant_density():
    # Constant density on [near, far]: opacity 1 - exp(-sigma (far - near)) for any sampling.
    t_vals = torch.sort(
        torch.rand(4, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(1)), -1
    ).values
    t_vals[:, 0] = 0.0
    far = torch.full((4,), 1.5, dtype=torch.float64)
    sigma = torch.full_like(t_vals, 2.0)
    out = composite(sigma, torch.zeros(4, 7, 1, dtype=torch.float64), t_vals, far)
    torch.testing.assert_close(
        out.opacity, torch.full((4,), 1 - math.exp(-3.0), dtype=torch.float64)
    )


def test_composite_gradcheck_float64():
    gen = torch.Generator().manual_seed(0)
    t_vals = torch.sort(torch.rand(3, 4, generator=gen, dtype=torch.float64), -1).values
    far = torch.full((3,), 1.2, dtype=torch.float64)
    sigma = torch.rand(3, 4, generator=gen, dtype=torch.float64).mul(3).requires_grad_(True)
    colors = torch.rand(3, 4, 2, generator=gen, dtype=torch.float64).requires_grad_(True)
    background = torch.rand(2, generator=gen, dtype=torch.float64).requires_grad_(True)

    def run(s, c, b):
        out = composite(s, c, t_vals, far, b)
        return out.rgb, out.opacity, out.depth

    assert torch.autograd.gradcheck(run, (sigma, colors, background))


def test_composite_extreme_densities_are_finite():
    t_vals = torch.tensor([[0.0, 1e-3, 2e-3]])
    sigma = torch.tensor([[0.0, 1e30, 1e30]], requires_grad=True)
    out = composite(sigma, torch.ones(1, 3, 3), t_vals, torch.tensor([1.0]), torch.zeros(3))
    out.rgb.sum().backward()
    assert out.opacity.item() == pytest.approx(1.0)
    assert torch.isfinite(sigma.grad).all()


def test_composite_validation():
    with pytest.raises(ValueError, match="densities"):
        composite(torch.zeros(3), torch.zeros(3, 1), torch.zeros(3), torch.zeros(1))
    with pytest.raises(ValueError, match="colors"):
        composite(torch.zeros(2, 3), torch.zeros(2, 4, 3), torch.zeros(2, 3), torch.zeros(2))
    with pytest.raises(ValueError, match="background"):
        composite(
            torch.zeros(2, 3),
            torch.zeros(2, 3, 3),
            torch.zeros(2, 3),
            torch.zeros(2),
            torch.zeros(4),
        )
    with pytest.raises(ValueError, match="far"):
        composite(torch.zeros(2, 3), torch.zeros(2, 3, 3), torch.zeros(2, 3), torch.zeros(3))
