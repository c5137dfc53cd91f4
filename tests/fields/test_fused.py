"""Fused inference of stacked-MLP chunks: the polynomial Softplus, the compiled chain against the
eager one, no recompilation per group size, the eager path under autograd, the fallback."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import lisa_hand.fields.fused as fused
from lisa_hand.fields import StackedMLP
from lisa_hand.fields.fused import fast_softplus, fused_inference, fused_stats
from tests.fields.helpers import perturb_


@pytest.fixture
def clean_state():
    """Each test starts with the path off, nothing failed, counters at zero; restored after."""
    saved = dict(fused._STATE)
    fused._STATE.update(enabled=False, disabled_reason=None, compile_seconds=0.0,
                        compilations=0, fused_calls=0, eager_calls=0)  # fmt: skip
    yield
    fused._STATE.clear()
    fused._STATE.update(saved)


def make_mlp(activation: str, out_dim: int) -> StackedMLP:
    torch.manual_seed(0)
    mlp = StackedMLP(3, 5, 4, 32, 3, out_dim, activation=activation)
    perturb_(mlp, 1, std=0.3)
    return mlp


@pytest.mark.parametrize("beta", [100.0, 1.0])
def test_fast_softplus_matches_softplus(beta):
    scale = 1.0 / beta
    values = torch.cat([
        torch.linspace(-50.0, 50.0, 20001) * scale,  # |beta x| up to 50
        torch.tensor([0.0, -1e-30, 1e-30, -200.0, 200.0, -1e4, 1e4]),
    ])  # fmt: skip
    expected = F.softplus(values.double(), beta=beta)
    error = (fast_softplus(values, beta).double() - expected).abs()
    # float32 F.softplus itself is within 1.6e-8 at beta 100; the polynomials add < 1e-8.
    assert error.max() < 3e-8 * (100.0 / beta)
    # Relative accuracy where the result is tiny but a normal float32 (below -87: 2^-126 floor).
    tiny = (values < -30.0 * scale) & (values > -80.0 * scale)
    relative = error[tiny] / expected[tiny].clamp_min(1e-300)
    assert relative.max() < 1e-5
    with pytest.raises(ValueError, match="float32"):
        fast_softplus(values.double(), beta)


def _compiled_or_skip(mlp, rows, sizes, bias, **options):
    with torch.no_grad(), fused_inference(True):
        out = mlp.forward_grouped(rows, sizes, bias, **options)
    reason = fused_stats()["disabled_reason"]
    if reason is not None:
        pytest.skip(f"torch.compile unavailable here: {reason}")
    return out


@pytest.mark.parametrize("activation, out_dim", [("softplus", 1), ("relu", 2)])
def test_compiled_chain_equals_eager_without_recompiling(clean_state, activation, out_dim):
    mlp = make_mlp(activation, out_dim)
    gen = torch.Generator().manual_seed(1)
    bias = mlp.condition(torch.randn(1, 3, 4, generator=gen), 1)[0]
    rows = torch.randn(300, 5, generator=gen)
    sizes = [100, 0, 200]  # chunks of 64: full ones, a 36- and an 8-row rest (eager)
    with torch.no_grad():
        eager = mlp.forward_grouped(rows, sizes, bias, chunk_rows=64)
    out = _compiled_or_skip(mlp, rows, sizes, bias, chunk_rows=64)
    stats = fused_stats()
    assert stats["fused_calls"] == 4 + 1 and stats["eager_calls"] == 1  # 64 64 36 | ... 8
    assert stats["compilations"] >= 1 and stats["compile_seconds"] > 0
    torch.testing.assert_close(out, eager, rtol=0, atol=2e-6)
    # New group sizes and chunk lengths: the same compiled graph (rows are dynamic).
    sizes = [17, 250, 33]
    with torch.no_grad():
        eager = mlp.forward_grouped(rows, sizes, bias, chunk_rows=50)
    out = _compiled_or_skip(mlp, rows, sizes, bias, chunk_rows=50)
    assert fused_stats()["compilations"] == stats["compilations"]
    torch.testing.assert_close(out, eager, rtol=0, atol=2e-6)


def test_autograd_runs_eagerly(clean_state):
    mlp = make_mlp("softplus", 1)
    rows = torch.randn(80, 5, requires_grad=True)
    bias = mlp.condition(torch.randn(1, 3, 4), 1)[0]
    with fused_inference(True):
        out = mlp.forward_grouped(rows, [30, 30, 20], bias)
    assert fused_stats()["fused_calls"] == 0
    expected = mlp.forward_grouped(rows, [30, 30, 20], bias)
    assert torch.equal(out, expected)
    (grad,) = torch.autograd.grad(out.sum(), rows, create_graph=True)
    grad.square().sum().backward()  # double backward (Eikonal) still works
    assert mlp.hidden_weights[0].grad is not None


def test_compile_failure_falls_back_once(clean_state, monkeypatch):
    mlp = make_mlp("softplus", 1)
    rows = torch.randn(80, 5)
    bias = mlp.condition(torch.randn(1, 3, 4), 1)[0]

    def broken(key):
        raise RuntimeError("no C++ compiler\nmore detail")

    monkeypatch.setattr(fused, "_compiled_chain", broken)
    with torch.no_grad(), fused_inference(True):
        with pytest.warns(RuntimeWarning, match="no C..? compiler"):
            out = mlp.forward_grouped(rows, [30, 30, 20], bias)
        assert not fused.fused_inference_enabled()
        again = mlp.forward_grouped(rows, [30, 30, 20], bias)  # no second warning, eager
        expected = mlp.forward_grouped(rows, [30, 30, 20], bias, low_precision=False)
    assert fused_stats()["disabled_reason"] == "RuntimeError: no C++ compiler"
    assert torch.equal(out, expected) and torch.equal(again, expected)


def test_switch_and_context_restore(clean_state):
    assert not fused.fused_inference_enabled()
    with fused_inference(True):
        assert fused.fused_inference_enabled()
        with fused_inference(False):
            assert not fused.fused_inference_enabled()
        assert fused.fused_inference_enabled()
    assert not fused.fused_inference_enabled()
