"""The numbers a photo fit writes of itself (lisa_hand.fitting.photo.artefacts)."""

from __future__ import annotations

import math

import numpy as np

from lisa_hand.fitting.photo.artefacts import agreement


def test_agreement_is_iou_and_psnr_of_a_known_render():
    """A square "hand" rendered half a square off the mask and 0.1 too bright where both are
    the hand: IoU 1/3 (two squares of area A overlapping in A/2), PSNR -10 log10(0.1^2) = 20 dB,
    with the photo's 0.5 read as the uint8 level 128; the render's colour is divided back out of
    its alpha."""
    photo = np.full((40, 40, 3), 0.2, np.float32)
    mask = np.zeros((40, 40), bool)
    mask[10:30, 10:30] = True
    photo[mask] = 0.5
    alpha = np.zeros((40, 40), np.float32)
    alpha[10:30, 20:40] = 0.8  # partly covered pixels still count (alpha > 0.5)
    rgb = np.zeros((40, 40, 3), np.float32)
    rgb[alpha > 0] = 0.6 * 0.8  # colour 0.6 times alpha
    iou, psnr = agreement(photo, mask, rgb, alpha)
    assert math.isclose(iou, 1.0 / 3.0, rel_tol=1e-9)
    assert math.isclose(psnr, -10.0 * math.log10((0.6 - 128 / 255) ** 2), abs_tol=1e-5)


def test_agreement_resizes_the_photo_to_the_render_and_without_overlap_has_no_psnr():
    photo = np.full((80, 80, 3), 0.5, np.float32)
    mask = np.zeros((80, 80), bool)
    mask[:40] = True
    alpha = np.zeros((20, 20), np.float32)
    alpha[:10] = 1.0
    rgb = alpha[..., None] * np.full(3, 0.5, np.float32)
    iou, psnr = agreement(photo, mask, rgb, alpha)
    assert iou == 1.0 and psnr > 50.0  # the same half, the same colour (up to uint8)
    iou, psnr = agreement(photo, ~mask, rgb, alpha)
    assert iou == 0.0 and math.isnan(psnr)
