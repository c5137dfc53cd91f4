"""Views of a hand (lisa_hand.inference.render): calibration, framing, cameras, file names."""

from __future__ import annotations

import pytest
import torch

from lisa_hand import inference
from lisa_hand.geometry.cameras import Camera
from lisa_hand.render.image import ImageRenderConfig

from .helpers import BIAS, GAIN, hand_params, tiny_model


def test_render_calibration_and_framing(model):
    params = hand_params(model)
    plain = tiny_model()
    config = ImageRenderConfig(beta=0.002, lipschitz=1.5, normals="autograd")
    scene = inference.prepare_render(model, params, config)
    cameras = inference.orbit_views(scene, 2, 40, 32)
    assert [c.name for c in cameras] == ["orbit000", "orbit001"]
    calibrated = scene.render(cameras[0])
    raw = inference.render_hand(plain, params, cameras[:1], config)[0]
    mask = calibrated.mask
    border = torch.cat([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    assert mask[10:22, 16:22].all() and not border.any()  # the palm, in the middle
    rows = torch.nonzero(mask.any(dim=1))[:, 0]
    assert 0.5 < (rows.max() - rows.min() + 1) / 32 < 0.95  # framed: fingers up, margins left
    assert torch.equal(calibrated.rgb[0, 0], torch.zeros(3))  # black background
    # Calibration is affine per sample: rgb = gain * raw + bias * opacity (black background);
    # up to faint pixels whose samples all fall under the renderer's colour weight threshold
    # and get no colour at all: there the bias term is missing, |bias| * opacity <= 0.05 * 0.06
    # (32 samples a ray, each under 1e-2).
    gain, bias = torch.tensor(GAIN), torch.tensor(BIAS)
    expected = raw.rgb * gain + bias * raw.opacity[..., None]
    faint = (calibrated.rgb - expected).abs().amax(dim=-1) > 1e-5
    assert not faint.any() or float(raw.opacity[faint].max()) < 0.06
    torch.testing.assert_close(calibrated.rgb, expected, atol=3e-3, rtol=0)
    torch.testing.assert_close(calibrated.rgb[mask], expected[mask], atol=1e-5, rtol=0)
    normals = calibrated.normals[mask]
    torch.testing.assert_close(normals.norm(dim=-1), torch.ones(normals.shape[0]))
    # The first camera faces the palm: the palm normal points at the camera.
    _, palm = scene.hand_axes()
    to_camera = cameras[0].center.double() - scene.framing_sphere()[0]
    assert float(palm @ to_camera) > 0.8 * float(to_camera.norm())
    with pytest.raises(ValueError, match="cameras must not be empty"):
        inference.render_hand(model, params, [], config)


def test_scale_camera_by_hand():
    K = torch.tensor([[100.0, 0.0, 20.0], [0.0, 90.0, 16.0], [0.0, 0.0, 1.0]])
    camera = Camera(K=K, R=torch.eye(3), t=torch.tensor([0.0, 0.0, 1.0]), width=40, height=32,
                    name="c")
    half = inference.scale_camera(camera, 20, 8)
    expected = torch.tensor([[50.0, 0.0, 10.0], [0.0, 22.5, 4.0], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(half.K, expected)
    assert (half.width, half.height, half.name) == (20, 8, "c")
    torch.testing.assert_close(half.R, camera.R)
    torch.testing.assert_close(half.t, camera.t)
    assert inference.scale_camera(camera, 40, 32) is camera
    with pytest.raises(ValueError, match="width must be a positive int"):
        inference.scale_camera(camera, 0, 8)


def test_file_stems_are_safe_and_unique():
    assert inference.file_stem(["cam 1", None, "cam 1", "../x"]) == [
        "cam_1", "view001", "cam_1_002", "x"]
