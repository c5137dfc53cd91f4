"""Masked softmax, NASA selection and blending."""

from __future__ import annotations

import torch

from lisa_hand.fields import blend, masked_softmax, nasa_selection


def test_masked_softmax_by_hand():
    logits = torch.tensor([[1.0, 2.0, 3.0], [5.0, 0.0, 1.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    active = torch.tensor([[True, False, True], [False, True, False], [False, False, False]])
    fallback = torch.tensor([0, 0, 2])
    weights = masked_softmax(logits, active, fallback)
    e1, e3 = torch.exp(torch.tensor(1.0)), torch.exp(torch.tensor(3.0))
    expected = torch.tensor(
        [[e1 / (e1 + e3), 0.0, e3 / (e1 + e3)], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )
    torch.testing.assert_close(weights, expected)


def test_single_active_bone_is_exact_one_hot_without_gradient():
    logits = torch.tensor([[0.3, -2.0, 7.0]], requires_grad=True)
    weights = masked_softmax(logits, torch.tensor([[False, True, False]]), torch.tensor([0]))
    assert torch.equal(weights.detach(), torch.tensor([[0.0, 1.0, 0.0]]))
    (weights * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert torch.equal(logits.grad, torch.zeros_like(logits))


def test_nasa_selection_and_blend():
    sdf = torch.tensor([[0.3, -0.1, -0.2], [0.5, 0.1, 0.2]])
    active = torch.tensor([[True, True, False], [False, False, False]])
    choice = nasa_selection(sdf, active, torch.tensor([0, 2]))
    assert choice.tolist() == [1, 2]
    weights = torch.nn.functional.one_hot(choice, 3).float()
    torch.testing.assert_close(blend(weights, sdf), torch.tensor([-0.1, 0.2]))
    colors = torch.arange(18.0).reshape(2, 3, 3)
    torch.testing.assert_close(blend(weights, colors), torch.stack([colors[0, 1], colors[1, 2]]))
