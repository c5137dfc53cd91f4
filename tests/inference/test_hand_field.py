"""One hand bound to a trained model (lisa_hand.inference.hand_field): callbacks, calibration,
mirrored left hands, bad codes, geometry-only models."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from lisa_hand import inference
from lisa_hand.skeleton import mirror_points
from lisa_hand.skeleton.params import HandParams

from .helpers import BIAS, GAIN, PADDING, REST, geometry_only_model, hand_params


def test_callbacks_follow_the_field_protocol_with_calibrated_colours(model):
    params = hand_params(model)
    hand = inference.hand_field(model, params)
    assert isinstance(hand, inference.HandField) and hand.params is params and not hand.mirrored
    points = params.translation + 0.03 * torch.randn(50, 3, generator=torch.Generator()
                                                      .manual_seed(0))
    directions = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    with torch.no_grad():
        sdf = hand.sdf_fn()(points)
        field_sdf, rgb = hand.field_fn()(points, directions)
        colors, weights = hand.attributes(points)
        raw = model.field.field(hand.frame, points[None])
    assert sdf.shape == (50,) and rgb.shape == (50, 3) and weights.shape == (50, 16)
    torch.testing.assert_close(field_sdf, sdf)
    torch.testing.assert_close(sdf, raw.sdf[0])
    # rgb * gain + bias, per point (clamped to [0, 1] for the mesh's vertex colours).
    expected = raw.rgb[0] * torch.tensor(GAIN) + torch.tensor(BIAS)
    torch.testing.assert_close(rgb, expected)
    torch.testing.assert_close(colors, expected.clamp(0.0, 1.0))
    torch.testing.assert_close(weights, raw.weights[0])
    assert hand.attributes(points, colors=False, skin_weights=False) == (None, None)


def test_left_hand_is_evaluated_at_mirrored_points(model):
    right = inference.hand_field(model, hand_params(model))
    left = inference.hand_field(model, hand_params(model, side="left"))
    assert left.mirrored
    points = hand_params(model).translation + 0.03 * torch.randn(
        40, 3, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        torch.testing.assert_close(left.sdf_fn()(mirror_points(points)), right.sdf_fn()(points))


def test_bad_inputs(model):
    wrong = hand_params(model)
    wrong.shape_code = torch.zeros(5)
    with pytest.raises(ValueError, match="shape_code has 5 entries"):
        inference.hand_field(model, wrong)
    with pytest.raises(ValueError, match="hand.json: shape_code has 5 entries"):
        inference.check_params(model, wrong, source="hand.json")
    with pytest.raises(TypeError, match="model must be a TrainedModel"):
        inference.hand_field(model.field, hand_params(model))
    with pytest.raises(TypeError, match="params must be a HandParams"):
        inference.hand_field(model, {"pose": None})


def test_resolve_model_path(tmp_path, model):
    params = hand_params(model)
    assert inference.resolve_model_path(params, None, None) is None  # "default": shipped one
    assert inference.resolve_model_path(params, None, "given.pt") == Path("given.pt")
    (tmp_path / "m.pt").write_bytes(b"")
    params.model = "m.pt"
    assert inference.resolve_model_path(params, tmp_path / "params.json", None) == (
        tmp_path / "m.pt")


def test_geometry_only_model_is_grey():
    prior = geometry_only_model()
    params = HandParams(pose=torch.zeros(48), translation=torch.zeros(3), rest_joints=REST,
                        shape_code=torch.zeros(8))
    mesh = inference.mesh_hand(prior, params, 24, inference.MeshConfig(padding=PADDING))
    grey = round(inference.GEOMETRY_ONLY_GREY * 255)
    assert np.abs(mesh.colors.astype(int) - grey).max() <= 1
    assert mesh.skin_weights.shape == (mesh.num_vertices, 16)
    scene = inference.prepare_render(prior, params)
    output = scene.render(inference.orbit_views(scene, 1, 24, 24)[0])
    expected = inference.GEOMETRY_ONLY_GREY * output.opacity[..., None].expand(-1, -1, 3)
    torch.testing.assert_close(output.rgb[output.mask], expected[output.mask], atol=1e-5, rtol=0)
