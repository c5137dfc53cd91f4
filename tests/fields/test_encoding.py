"""Positional encoding: layout and values."""

from __future__ import annotations

import math

import torch

from lisa_hand.fields import encoding_dim, positional_encoding


def test_layout_and_values():
    x = torch.tensor([[0.5, -1.0, 2.0]], dtype=torch.float64)
    out = positional_encoding(x, 2)
    assert out.shape == (1, encoding_dim(2)) == (1, 15)
    expected = [0.5, -1.0, 2.0]
    for k in range(2):
        f = 2.0**k
        expected += [math.sin(f * v) for v in (0.5, -1.0, 2.0)]
        expected += [math.cos(f * v) for v in (0.5, -1.0, 2.0)]
    torch.testing.assert_close(out[0], torch.tensor(expected, dtype=torch.float64))


def test_zero_frequencies_is_identity_and_batch_dims_kept():
    x = torch.randn(2, 5, 16, 3)
    assert positional_encoding(x, 0) is x
    assert positional_encoding(x, 3).shape == (2, 5, 16, 21)
