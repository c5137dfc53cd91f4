"""SDF primitives against brute-force references, and the smooth union's algebra."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.handmodel.primitives import (
    gaussian,
    round_cone_sdf,
    rounded_polygon_sdf,
    smooth_union,
    smoothstep,
)

F64 = torch.float64


def _cone_reference(along, radial, length, r0, r1):
    """Distance to the union of the spheres (h, r(h)) along the axis, sampled finely (outside)."""
    h = torch.linspace(0.0, length, 20001, dtype=F64)
    radius = r0 + (r1 - r0) * h / length
    dist = torch.sqrt((along[:, None] - h) ** 2 + radial[:, None] ** 2) - radius
    return dist.amin(1)


@pytest.mark.parametrize("r0, r1", [(0.01, 0.006), (0.006, 0.009), (0.008, 0.008)])
def test_round_cone_matches_sphere_family_outside(r0, r1):
    generator = torch.Generator().manual_seed(0)
    length = 0.03
    along = torch.rand(400, generator=generator, dtype=F64) * 0.07 - 0.02
    radial = torch.rand(400, generator=generator, dtype=F64) * 0.03
    value = round_cone_sdf(
        along[:, None], (radial**2)[:, None], torch.tensor([length], dtype=F64),
        torch.tensor([r0], dtype=F64), torch.tensor([r1], dtype=F64),
    )[:, 0]  # fmt: skip
    reference = _cone_reference(along, radial, length, r0, r1)
    outside = reference > 0
    assert outside.sum() > 200
    # The union of the spheres equals the hull outside; sampling h finely bounds the error.
    assert torch.allclose(value[outside], reference[outside], atol=2e-7)
    # Inside, the exact distance is at most as deep as the deepest sphere.
    assert torch.all(value[~outside] <= 1e-12)


def test_round_cone_gradient_is_unit():
    along = torch.tensor([[-0.01], [0.015], [0.04], [0.02]], dtype=F64, requires_grad=True)
    radial = torch.tensor([[0.02], [0.012], [0.003], [0.001]], dtype=F64, requires_grad=True)
    value = round_cone_sdf(
        along, radial**2, torch.tensor([0.03], dtype=F64), torch.tensor([0.01], dtype=F64),
        torch.tensor([0.006], dtype=F64),
    )  # fmt: skip
    grad_a, grad_r = torch.autograd.grad(value.sum(), (along, radial))
    assert torch.allclose(torch.hypot(grad_a, grad_r), torch.ones_like(grad_a), atol=1e-9)


def test_rounded_polygon_against_dense_polygon_samples():
    square = torch.tensor([[0.0, 0.0], [0.02, 0.0], [0.02, 0.01], [0.0, 0.01]], dtype=F64)
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(300, 3, generator=generator, dtype=F64) * 0.06 - torch.tensor(
        [0.02, 0.025, 0.02], dtype=F64
    )
    value = rounded_polygon_sdf(points, square, 0.004)
    # Reference: distance to a dense sampling of the (filled) rectangle, minus the radius.
    grid = torch.stack(
        torch.meshgrid(torch.linspace(0, 0.02, 201, dtype=F64),
                       torch.linspace(0, 0.01, 101, dtype=F64), indexing="ij"), -1,
    ).reshape(-1, 2)  # fmt: skip
    planar = torch.cdist(points[:, :2], grid) ** 2
    reference = torch.sqrt(planar.amin(1) + points[:, 2] ** 2) - 0.004
    assert torch.allclose(value, reference, atol=1e-4 * 0.75)  # grid spacing 1e-4 m


def test_smooth_union_bounds_and_weights_are_its_gradient():
    generator = torch.Generator().manual_seed(2)
    distances = (torch.rand(50, 6, generator=generator, dtype=F64) * 0.01).requires_grad_(True)
    blend = 0.0015
    value, weights = smooth_union(distances, blend)
    minimum = distances.amin(1)
    assert torch.all(value <= minimum + 1e-15)
    assert torch.all(value >= minimum - blend * math.log(6) - 1e-15)
    assert torch.allclose(weights.sum(1), torch.ones(50, dtype=F64))
    (grad,) = torch.autograd.grad(value.sum(), distances)
    assert torch.allclose(grad, weights, atol=1e-12)
    # Far apart distances: the union is the minimum.
    far, _ = smooth_union(torch.tensor([[0.0, 1.0]], dtype=F64), blend)
    assert far.item() == pytest.approx(0.0, abs=1e-12)


def test_smoothstep_and_gaussian_values():
    x = torch.tensor([-1.0, 0.0, 0.25, 0.5, 1.0, 2.0], dtype=F64)
    expected = torch.tensor([0.0, 0.0, 0.15625, 0.5, 1.0, 1.0], dtype=F64)
    assert torch.allclose(smoothstep(0.0, 1.0, x), expected)
    assert torch.allclose(smoothstep(1.0, 0.0, x), 1.0 - expected)
    z = torch.tensor([0.0, 1.0, 2.5, 30.0], dtype=F64)
    assert torch.allclose(gaussian(z), torch.exp(-0.5 * z * z), atol=1e-15)
    assert np.isfinite(gaussian(torch.tensor([1e6])).item())
