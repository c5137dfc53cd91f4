"""Image metrics: PSNR, SSIM and LPIPS against closed forms and their availability."""

import math

import numpy as np
import pytest
import torch

from lisa_hand.metrics import (
    image_metrics,
    lpips_distance,
    lpips_unavailable_reason,
    psnr,
    ssim,
)


def _images(seed: int = 0, size: tuple[int, int] = (24, 32)) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.2, 0.8, size=(*size, 3))


def test_psnr_closed_form_and_mask():
    target = _images()
    offset = 0.05
    # MSE = offset^2 -> PSNR = -20 log10(offset) = 26.0206 dB.
    assert psnr(target + offset, target) == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert psnr(target + offset, target, max_value=2.0) == pytest.approx(
        20.0 * math.log10(2.0 / offset), rel=1e-9)
    assert psnr(target, target) == math.inf
    # A larger error outside the mask is ignored inside it.
    pred = target + offset
    mask = np.zeros(target.shape[:2], dtype=bool)
    mask[4:12, 5:20] = True
    pred[~mask] += 0.2
    assert psnr(pred, target, mask=mask) == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert psnr(pred, target) < psnr(pred, target, mask=mask) - 5.0


def test_psnr_uint8_and_torch_inputs():
    target = (np.arange(24 * 32 * 3) % 200).reshape(24, 32, 3).astype(np.uint8)
    pred = target + np.uint8(10)
    expected = -20.0 * math.log10(10.0 / 255.0)
    assert psnr(pred, target) == pytest.approx(expected, rel=1e-9)
    assert psnr(torch.from_numpy(pred / 255.0), target) == pytest.approx(expected, rel=1e-9)


def test_ssim_identical_constant_and_mask():
    image = _images()
    assert ssim(image, image) == pytest.approx(1.0, abs=1e-12)
    # Constant images a and b: the contrast/structure terms are C2 / C2 = 1 and the luminance
    # term is (2ab + C1) / (a^2 + b^2 + C1) with C1 = (0.01 L)^2.
    a, b, c1 = 0.3, 0.5, 0.01**2
    expected = (2 * a * b + c1) / (a * a + b * b + c1)
    flat_a, flat_b = np.full((20, 20, 3), a), np.full((20, 20, 3), b)
    assert ssim(flat_a, flat_b) == pytest.approx(expected, rel=1e-9)
    assert ssim(flat_a, flat_b, mask=np.ones((20, 20), bool)) == pytest.approx(expected, rel=1e-9)
    # Change only pixels farther than the window's half-width (5) from the mask: masked SSIM
    # stays exactly 1, the whole-image SSIM drops.
    noisy = image.copy()
    noisy[:, 20:] = _images(seed=3)[:, 20:]
    mask = np.zeros(image.shape[:2], dtype=bool)
    mask[:, :14] = True
    assert ssim(noisy, image, mask=mask) == pytest.approx(1.0, abs=1e-12)
    assert ssim(noisy, image) < 0.9


def test_image_shape_errors():
    with pytest.raises(ValueError, match=r"pred \[24, 32, 3\] and target \[24, 31, 3\]"):
        psnr(_images(), _images()[:, :31])
    with pytest.raises(ValueError, match=r"pred \[24, 32, 3\] and target \[20, 32, 3\]"):
        ssim(_images(), _images()[:20])
    with pytest.raises(ValueError, match=r"mask must have shape \[H, W\] = \[24, 32\]"):
        psnr(_images(), _images(), mask=np.ones((24, 30), bool))
    with pytest.raises(ValueError, match="mask is empty"):
        psnr(_images(), _images(), mask=np.zeros((24, 32), bool))
    with pytest.raises(ValueError, match=r"pred must have shape \[H, W, 3\]"):
        psnr(np.zeros((4, 4, 5)), np.zeros((4, 4, 5)))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))


def test_lpips_reports_availability():
    reason = lpips_unavailable_reason()
    image = _images()
    value = lpips_distance(image, image)
    if reason:
        assert value is None
        assert "\n" not in reason and reason.startswith("LPIPS unavailable")
    else:
        assert value == pytest.approx(0.0, abs=1e-6)
        assert lpips_distance(image, _images(seed=5)) > 0.01
    assert "unknown LPIPS network" in lpips_unavailable_reason(net="resnet")


def test_image_metrics_combines_psnr_ssim_and_lpips():
    target = _images()
    offset = 0.05
    mask = np.zeros(target.shape[:2], dtype=bool)
    mask[4:12, 5:20] = True
    pred = target + offset
    pred[~mask] += 0.2
    result = image_metrics(pred, target, mask)
    assert result.psnr_db == pytest.approx(psnr(pred, target), rel=1e-12)
    assert result.psnr_mask_db == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert result.ssim == pytest.approx(ssim(pred, target), rel=1e-12)
    assert result.ssim_mask == pytest.approx(ssim(pred, target, mask=mask), rel=1e-12)
    reason = lpips_unavailable_reason()
    if reason:  # no weights: NaN and the one-line reason, never a download
        assert math.isnan(result.lpips) and result.lpips_message == reason
        assert result.to_dict()["lpips"] is None
    else:
        assert result.lpips > 0.0 and result.lpips_message == ""
    unmasked = image_metrics(pred, target)
    assert math.isnan(unmasked.psnr_mask_db) and math.isnan(unmasked.ssim_mask)
    assert list(unmasked.to_dict()) == ["psnr_db", "ssim", "psnr_mask_db", "ssim_mask", "lpips"]
    with pytest.raises(ValueError, match="mask must have shape"):
        image_metrics(pred, target, mask[:, :10])
