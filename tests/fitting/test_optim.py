"""The fitters' one optimiser and schedule (``lisa_hand.fitting.optim``): checked against Adam
written out in float64 with the cosine factors, and pruning rows checked against optimising
every row to the end (the rows of a separable energy do not interact)."""

from __future__ import annotations

import math

import pytest
import torch

from lisa_hand.fitting.optim import adam, cosine_factor, keep_rows, lr_schedule


def test_the_cosine_falls_from_one_to_the_final_fraction():
    assert cosine_factor(0, 11, 0.1) == 1.0
    assert cosine_factor(10, 11, 0.1) == pytest.approx(0.1)
    assert cosine_factor(5, 11, 0.1) == pytest.approx(0.55)
    assert cosine_factor(3, 1, 0.1) == 1.0
    assert cosine_factor(20, 11, 0.1) == pytest.approx(0.1)  # past the end: the floor


def _reference_adam(x0: torch.Tensor, target: torch.Tensor, lr: float, steps: int, total: int,
                    start: int, final: float) -> torch.Tensor:
    """Adam (betas 0.9, 0.999, eps 1e-8) on ``sum (x - target)^2``, written out in float64."""
    x = x0.double().clone()
    m, v = torch.zeros_like(x), torch.zeros_like(x)
    for t in range(1, steps + 1):
        g = 2 * (x - target.double())
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
        rate = lr * cosine_factor(start + t - 1, total, final)
        x = x - rate * (m / (1 - 0.9**t)) / ((v / (1 - 0.999**t)).sqrt() + 1e-8)
    return x


def test_adam_under_the_schedule_matches_adam_written_out():
    target = torch.tensor([[0.3, -1.0, 2.0]], dtype=torch.float64)
    x = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    optimizer = adam([(x, 0.05)])
    schedule = lr_schedule(optimizer, 40, 0.2, start=10)  # the last 30 of a 40-step stage
    for _ in range(30):
        optimizer.zero_grad()
        (x - target).square().sum().backward()
        optimizer.step()
        schedule.step()
    expected = _reference_adam(torch.zeros(1, 3), target, 0.05, 30, 40, 10, 0.2)
    assert torch.allclose(x.detach(), expected, atol=1e-12, rtol=0)
    assert not math.isclose(float(x.detach()[0, 0]), 0.3, abs_tol=1e-3)  # not simply converged


def _run(rows: torch.Tensor, target: torch.Tensor, steps: int, prune_at: int | None,
         keep: torch.Tensor | None) -> torch.Tensor:
    a = rows.clone().requires_grad_(True)
    b = (rows * 2).clone().requires_grad_(True)
    optimizer = adam([(a, 0.1), (b, 0.02)])
    schedule = lr_schedule(optimizer, steps, 0.1)
    for step in range(steps):
        if step == prune_at:
            a = a.detach()[keep].requires_grad_(True)
            b = b.detach()[keep].requires_grad_(True)
            keep_rows(optimizer, keep, [a, b])
        optimizer.zero_grad()
        goal = target if step < (prune_at or steps) else target[keep]
        ((a - goal).square().sum() + (b * a.detach() - goal).square().sum()).backward()
        optimizer.step()
        schedule.step()
    return torch.cat([a.detach(), b.detach()], -1)


def test_pruned_rows_go_on_as_if_never_pruned():
    rows = torch.linspace(-1, 1, 12, dtype=torch.float64).reshape(4, 3)
    target = torch.linspace(0.5, -0.5, 12, dtype=torch.float64).reshape(4, 3)
    keep = torch.tensor([3, 1])
    pruned = _run(rows, target, 25, 10, keep)
    whole = _run(rows, target, 25, None, None)[keep]
    assert torch.allclose(pruned, whole, atol=1e-12, rtol=0)


def test_keep_rows_needs_one_tensor_per_group():
    x = torch.zeros(2, 3, requires_grad=True)
    optimizer = adam([(x, 0.1)])
    with pytest.raises(ValueError, match="one tensor per parameter group"):
        keep_rows(optimizer, torch.tensor([0]), [])
