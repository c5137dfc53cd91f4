import numpy as np
import pytest
import torch
from scipy.stats import laplace

from lisa_hand.render import LaplaceDensity, laplace_cdf, volsdf_density


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("beta", [1e-4, 1e-2, 0.5])
def test_laplace_cdf_matches_scipy_including_extremes(dtype, beta):
    ratios = np.concatenate([-np.logspace(4, -3, 40), [0.0], np.logspace(-3, 4, 40), [-1e30, 1e30]])
    x = ratios * beta
    expected = laplace.cdf(x, loc=0.0, scale=beta)
    got = laplace_cdf(torch.tensor(x, dtype=dtype), beta)
    assert got.dtype == dtype
    assert torch.isfinite(got).all()
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    np.testing.assert_allclose(got.double().numpy(), expected, rtol=tol, atol=tol)
    # Relative accuracy of the left tail (where a naive 1 - 0.5 exp(.) is fine but 0.5 exp(.)
    # must not be computed as 1 - something).
    tail = x < 0
    np.testing.assert_allclose(
        got.double().numpy()[tail & (expected > 1e-30)],
        expected[tail & (expected > 1e-30)],
        rtol=1e-5 if dtype == torch.float32 else 1e-12,
    )


def test_laplace_cdf_gradients_are_finite_and_exact():
    beta = torch.tensor(1e-3, dtype=torch.float64, requires_grad=True)
    x = torch.tensor([-1e6, -1.0, -1e-3, 0.0, 1e-3, 1.0, 1e6], dtype=torch.float64)
    x.requires_grad_(True)
    cdf = laplace_cdf(x, beta)
    grad_x, grad_beta = torch.autograd.grad(cdf.sum(), (x, beta))
    assert torch.isfinite(grad_x).all() and torch.isfinite(grad_beta)
    expected = laplace.pdf(x.detach().numpy(), scale=1e-3)
    np.testing.assert_allclose(grad_x.numpy(), expected, rtol=1e-12, atol=1e-300)
    assert grad_x[3].item() == pytest.approx(1.0 / (2.0 * 1e-3))  # density at x = 0
    # d/dbeta Psi(x) = -x / beta * pdf(x)
    expected_beta = float((-x.detach().numpy() / 1e-3 * expected).sum())
    assert grad_beta.item() == pytest.approx(expected_beta, rel=1e-10)


def test_laplace_cdf_gradcheck_float64():
    x = torch.linspace(-0.03, 0.03, 13, dtype=torch.float64).requires_grad_(True)
    beta = torch.tensor(0.01, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: laplace_cdf(a, b), (x, beta))


def test_volsdf_density_formula():
    sdf = torch.tensor([-1.0, -0.01, 0.0, 0.01, 1.0], dtype=torch.float64)
    beta = 0.01
    expected = (1.0 / beta) * laplace.cdf(-sdf.numpy(), scale=beta)
    np.testing.assert_allclose(volsdf_density(sdf, beta).numpy(), expected, rtol=1e-13)
    np.testing.assert_allclose(
        volsdf_density(sdf, beta, alpha=3.0).numpy(), 3.0 * beta * expected, rtol=1e-13
    )
    # Deep inside: alpha; on the surface: alpha / 2; far outside: 0 (not NaN).
    assert volsdf_density(torch.tensor([-1e9, 0.0, 1e9]), 1e-4).tolist() == pytest.approx(
        [1e4, 5e3, 0.0], rel=1e-6
    )


def test_laplace_density_module():
    module = LaplaceDensity(beta_init=0.02, beta_min=1e-4)
    assert module.beta.item() == pytest.approx(0.02, rel=1e-6)
    assert module.alpha.item() == pytest.approx(50.0, rel=1e-6)
    sdf = torch.tensor([-0.05, 0.0, 0.03])
    np.testing.assert_allclose(
        module(sdf).detach().numpy(), 50.0 * laplace.cdf(-sdf.numpy(), scale=0.02), rtol=1e-5
    )
    # beta stays above beta_min however negative the raw parameter gets.
    with torch.no_grad():
        module.beta_raw.fill_(-200.0)
    assert module.beta.item() == pytest.approx(1e-4, rel=1e-6)
    assert torch.isfinite(module(torch.tensor([-1.0, 1.0]))).all()
    # Gradient reaches the raw parameter.
    module = LaplaceDensity(beta_init=0.02, beta_min=1e-4)
    module(torch.tensor([0.01, -0.01])).sum().backward()
    assert module.beta_raw.grad is not None and module.beta_raw.grad.abs().item() > 0
    # float64 inputs stay float64.
    assert module(torch.zeros(2, dtype=torch.float64)).dtype == torch.float64


def test_laplace_density_validation():
    with pytest.raises(ValueError, match="beta_init"):
        LaplaceDensity(beta_init=1e-5, beta_min=1e-4)
    with pytest.raises(ValueError, match="beta_min"):
        LaplaceDensity(beta_init=0.1, beta_min=-1.0)
    with pytest.raises(ValueError, match="beta"):
        laplace_cdf(torch.zeros(2), 0.0)
    with pytest.raises(TypeError, match="sdf"):
        volsdf_density([0.0], 0.1)
