"""Mixing two fitted hands (lisa_hand.inference.blend): swaps, interpolation, refusals."""

from __future__ import annotations

import pytest
import torch

from lisa_hand import inference

from .helpers import REST, hand_params


def test_blend_swaps_and_interpolates(model):
    a, b = hand_params(model, 0), hand_params(model, 1)
    b = b.with_pose(torch.zeros(48), torch.zeros(3))
    b.rest_joints = REST * 1.1
    same = inference.blend_params(a, b, shape=0.0, color=0.0)
    assert torch.equal(same.shape_code, a.shape_code) and torch.equal(same.color_code, a.color_code)
    assert torch.equal(same.rest_joints, a.rest_joints)
    swapped = inference.blend_params(a, b, shape=0.0, color=1.0)
    assert torch.equal(swapped.color_code, b.color_code)
    assert torch.equal(swapped.shape_code, a.shape_code) and torch.equal(swapped.pose, a.pose)
    half = inference.blend_params(a, b, shape=0.5, color=0.25)
    torch.testing.assert_close(half.shape_code, 0.5 * (a.shape_code + b.shape_code))
    torch.testing.assert_close(half.rest_joints, REST * 1.05)
    torch.testing.assert_close(half.color_code, 0.75 * a.color_code + 0.25 * b.color_code)
    assert half.extra["blend"] == {"shape": 0.5, "color": 0.25}
    # A left B lends its skeleton mirrored to a right A.
    left_b = hand_params(model, 1, side="left")
    torch.testing.assert_close(inference.blend_params(a, left_b, shape=1.0).rest_joints, REST)
    with pytest.raises(ValueError, match="shape must be in"):
        inference.blend_params(a, b, shape=1.5)
    with pytest.raises(TypeError, match="color must be a number"):
        inference.blend_params(a, b, color=True)
    other = hand_params(model, 1)
    other.model = "other.pt"
    with pytest.raises(ValueError, match="different models"):
        inference.blend_params(a, other, color=1.0)
    no_color = hand_params(model, 1)
    no_color.color_code = None
    with pytest.raises(ValueError, match="hand B has none"):
        inference.blend_params(a, no_color, color=0.5)
