"""Stacked per-bone MLPs: per-frame conditioning, dense vs grouped evaluation, initialisation."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from lisa_hand.fields import StackedMLP, geometric_init_, positional_encoding, soft_min_init_
from tests.fields.helpers import perturb_


def concat_mlp(mlp: StackedMLP, group: int, points: torch.Tensor, cond: torch.Tensor):
    """Reference: group ``group`` as a plain MLP on concat(point, cond), full first weight."""
    weight = torch.cat([mlp.point_weight[group], mlp.cond_weight[group]], dim=0)
    x = torch.cat([points, cond.expand(points.shape[0], -1)], dim=-1)
    h = F.softplus(x @ weight + mlp.first_bias[group], beta=mlp.beta)
    for w, b in zip(mlp.hidden_weights, mlp.hidden_biases, strict=True):
        h = F.softplus(h @ w[group] + b[group], beta=mlp.beta)
    return h @ mlp.out_weight[group] + mlp.out_bias[group]


@pytest.fixture
def mlp() -> StackedMLP:
    torch.manual_seed(0)
    module = StackedMLP(3, 5, 4, 8, 3, 2).double()
    perturb_(module, 1, std=0.3)
    return module


def test_per_frame_conditioning_equals_concatenation(mlp):
    gen = torch.Generator().manual_seed(2)
    points = torch.randn(2, 7, 3, 5, generator=gen, dtype=torch.float64)
    cond = torch.randn(2, 3, 4, generator=gen, dtype=torch.float64)
    bias = mlp.condition(cond, batch_size=2)
    assert bias.shape == (2, 3, 8)
    dense = mlp.forward_dense(points, bias)
    assert dense.shape == (2, 7, 3, 2)
    for b in range(2):
        for g in range(3):
            expected = concat_mlp(mlp, g, points[b, :, g], cond[b, g])
            torch.testing.assert_close(dense[b, :, g], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("chunk_rows", [2, 4096])
def test_grouped_equals_dense(mlp, chunk_rows):
    gen = torch.Generator().manual_seed(3)
    sizes = [4, 0, 6]
    rows = torch.randn(sum(sizes), 5, generator=gen, dtype=torch.float64)
    cond = torch.randn(2, 3, 4, generator=gen, dtype=torch.float64)
    bias = mlp.condition(cond, 2)
    group = torch.repeat_interleave(torch.arange(3), torch.tensor(sizes))
    frame = torch.tensor([0, 1, 1, 0, 1, 0, 0, 1, 1, 0])
    # One bias per group (a single frame) and one per row (several frames).
    out = mlp.forward_grouped(rows, sizes, bias[0], chunk_rows=chunk_rows)
    per_row = mlp.forward_grouped(
        rows, sizes, bias[frame, group], bias_per_row=True, chunk_rows=chunk_rows
    )
    for i in range(rows.shape[0]):
        g = int(group[i])
        expected = concat_mlp(mlp, g, rows[i : i + 1], cond[0, g])[0]
        torch.testing.assert_close(out[i], expected, rtol=0, atol=1e-12)
        expected = concat_mlp(mlp, g, rows[i : i + 1], cond[int(frame[i]), g])[0]
        torch.testing.assert_close(per_row[i], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("bias_kind", ["group", "per_frame", "per_row"])
def test_padded_equals_the_loop_with_first_and_second_derivatives(mlp, bias_kind):
    # The GPU's padded path (one batched product a layer) is the loop's function, its gradient
    # and its gradient's gradient (Eikonal training) included; float64, to rounding.
    gen = torch.Generator().manual_seed(5)
    frame_sizes = [[3, 1], [0, 0], [2, 4]]  # group 1 empty; groups sorted by frame
    sizes = [sum(group) for group in frame_sizes]
    rows = torch.randn(sum(sizes), 5, generator=gen, dtype=torch.float64, requires_grad=True)
    cond = torch.randn(2, 3, 4, generator=gen, dtype=torch.float64)
    bias = mlp.condition(cond, 2)
    if bias_kind == "group":
        args, kwargs = (sizes, bias[0]), {}
    elif bias_kind == "per_frame":
        args, kwargs = (frame_sizes, bias), {}
    else:
        group = torch.repeat_interleave(torch.arange(3), torch.tensor(sizes))
        frame = torch.tensor([0, 0, 0, 1, 0, 0, 1, 1, 1, 1])
        args, kwargs = (sizes, bias[frame, group]), {"bias_per_row": True}
    outputs = {}
    for padded in (False, True):
        out = mlp.forward_grouped(rows, *args, padded=padded, **kwargs)
        (grad,) = torch.autograd.grad(out.square().sum(), rows, create_graph=True)
        second = torch.autograd.grad(grad.square().sum(), [rows, mlp.point_weight,
                                                            mlp.out_weight])
        outputs[padded] = (out, grad, *second)
    for loop, padded in zip(outputs[False], outputs[True], strict=True):
        torch.testing.assert_close(padded, loop, rtol=1e-10, atol=1e-12)
    assert outputs[True][2].abs().sum() > 0  # the second derivative is not trivially zero


def test_padded_low_precision_matches_the_loop(mlp):
    mlp = mlp.float()
    rows = torch.randn(50, 5, generator=torch.Generator().manual_seed(6))
    bias = mlp.condition(torch.randn(1, 3, 4), 1)[0]
    loop = mlp.forward_grouped(rows, [20, 20, 10], bias, low_precision=True, padded=False)
    padded = mlp.forward_grouped(rows, [20, 20, 10], bias, low_precision=True, padded=True)
    assert padded.dtype == torch.float32
    torch.testing.assert_close(padded, loop, rtol=0, atol=1e-6 * loop.abs().max().item() + 1e-6)


def test_grouped_low_precision_is_close_and_keeps_dtype(mlp):
    mlp = mlp.float()
    rows = torch.randn(50, 5)
    bias = mlp.condition(torch.randn(1, 3, 4), 1)[0]
    exact = mlp.forward_grouped(rows, [20, 20, 10], bias)
    low = mlp.forward_grouped(rows, [20, 20, 10], bias, low_precision=True)
    assert low.dtype == torch.float32 and not torch.equal(low, exact)
    torch.testing.assert_close(low, exact, rtol=0, atol=0.05 * exact.abs().max().item())


def test_grouped_validation(mlp):
    rows = torch.zeros(5, 5, dtype=torch.float64)
    with pytest.raises(ValueError, match="group_sizes"):
        mlp.forward_grouped(rows, [1, 2], mlp.first_bias)
    with pytest.raises(ValueError, match="first_bias"):
        mlp.forward_grouped(rows, [1, 2, 2], mlp.first_bias[:2])
    with pytest.raises(ValueError, match="cond"):
        mlp.condition(torch.zeros(1, 3, 5, dtype=torch.float64), 1)


def test_geometric_init_is_a_sphere_and_a_spheroid():
    torch.manual_seed(4)
    mlp = StackedMLP(2, 3 * 5, 4, 128, 3, 1).double()
    radii = torch.tensor([0.3, 0.2], dtype=torch.float64)
    axes = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    half = torch.tensor([0.0, 0.6], dtype=torch.float64)
    geometric_init_(mlp, radii, axes=axes, half_lengths=half)
    assert (mlp.point_weight[:, 3:] == 0).all()  # sinusoids start at zero weight

    def sdf(points):  # [M, 3] -> [M, 2]
        encoded = positional_encoding(points.double(), 2)[None, :, None].expand(-1, -1, 2, -1)
        return mlp.forward_dense(encoded, torch.zeros(1, 2, 128).double())[0, :, :, 0]

    gen = torch.Generator().manual_seed(5)
    dirs = torch.randn(200, 3, generator=gen, dtype=torch.float64)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    sphere = sdf(torch.cat([torch.zeros(1, 3).double(), 0.3 * dirs, 0.9 * dirs]))[:, 0]
    assert sphere[0] < -0.1  # inside at the centre
    on_sphere = sphere[1:201]  # about zero on the sphere of radius r (random features: +-20%)
    assert on_sphere.mean().abs() < 0.01 and on_sphere.abs().mean() < 0.06
    outside = sphere[201:] - 0.6  # slope about 1 between r and 3 r
    assert outside.mean().abs() < 0.05 and outside.abs().mean() < 0.2
    # The spheroid reaches a = half + r = 0.8 along its axis (z), r across it.
    along = sdf(torch.tensor([[0.0, 0.0, 0.8], [0.0, 0.0, -0.8], [0.2, 0.0, 0.0]]))[:, 1]
    assert along.abs().max() < 0.06
    assert sdf(torch.tensor([[0.0, 0.0, 0.5]]))[0, 1] < -0.02  # |D x| - r = -0.075


def test_soft_min_init():
    torch.manual_seed(6)
    mlp = StackedMLP(1, 48 + 16, 0, 32, 2, 16).double()
    assert soft_min_init_(mlp, 48, 16, sharpness=20.0, value_max=2.0)
    gen = torch.Generator().manual_seed(7)
    values = 0.5 * torch.randn(10, 16, generator=gen, dtype=torch.float64)
    inputs = torch.cat([torch.randn(10, 48, generator=gen, dtype=torch.float64), values], -1)
    logits = mlp.forward_grouped(inputs, [10], mlp.first_bias)
    torch.testing.assert_close(logits, 20.0 * (2.0 - values), rtol=0, atol=0.05)
    assert not soft_min_init_(StackedMLP(1, 64, 0, 8, 2, 16), 48, 16, 20.0, 2.0)
