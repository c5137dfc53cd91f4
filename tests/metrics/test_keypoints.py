"""MPJPE and PA-MPJPE against closed forms and an independent float64 Procrustes."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial import procrustes
from scipy.spatial.transform import Rotation

from lisa_hand.metrics import mpjpe, pa_mpjpe, procrustes_align


def _hand_like(seed: int = 0, num: int = 21) -> np.ndarray:
    """[num, 3] metres: points spread over about 10 cm around (0, 0, 0.5)."""
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.04, size=(num, 3)) + np.array([0.0, 0.0, 0.5])


def _similarity(points: np.ndarray, seed: int, scale: float, offset) -> np.ndarray:
    rotation = Rotation.random(random_state=seed).as_matrix()
    return scale * points @ rotation.T + np.asarray(offset)


def test_mpjpe_known_offsets():
    true = _hand_like()
    # A pure translation is removed by the root alignment.
    assert mpjpe(true + np.array([0.3, -0.1, 0.2]), true) == pytest.approx(0.0, abs=1e-9)
    # Every keypoint but the root moved by 3 mm along x (20 of 21): mean 20 * 3 / 21 mm.
    moved = true.copy()
    moved[1:, 0] += 0.003
    assert mpjpe(moved, true) == pytest.approx(20 * 3.0 / 21, rel=1e-9)
    # Aligned on another root, the first keypoint is 3 mm off and the others coincide.
    assert mpjpe(moved, true, root=5) == pytest.approx(3.0 / 21, rel=1e-9)
    # A 3-4-5 offset of one keypoint: 5 mm over 21 keypoints.
    moved = true.copy()
    moved[7] += np.array([0.003, 0.004, 0.0])
    assert mpjpe(moved, true) == pytest.approx(5.0 / 21, rel=1e-9)


def test_mpjpe_scaled_about_root():
    # pred = root + 1.1 (true - root): each keypoint is 0.1 |true_k - root| off.
    true = _hand_like(1)
    pred = true[0] + 1.1 * (true - true[0])
    expected = 0.1 * np.linalg.norm(true - true[0], axis=1).mean() * 1000.0
    assert mpjpe(pred, true) == pytest.approx(expected, rel=1e-9)
    assert pa_mpjpe(pred, true) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pa_mpjpe_is_zero_for_a_similarity(seed):
    true = _hand_like(seed)
    pred = _similarity(true, seed + 10, scale=0.7 + 0.2 * seed, offset=[0.1, -0.2, 0.4])
    assert pa_mpjpe(pred, true) == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(procrustes_align(pred, true), true, atol=1e-12)
    # ... while the rotation stays in the root-aligned error.
    assert mpjpe(pred, true) > 10.0


def test_pa_mpjpe_excludes_reflections():
    # A mirror image is not a similarity: the alignment must not undo it.
    true = _hand_like(3)
    mirrored = true * np.array([-1.0, 1.0, 1.0])
    assert pa_mpjpe(mirrored, true) > 5.0
    # Points in the plane z = 0, mirrored in x: a half turn about the y axis is a proper
    # rotation that gives the same points, so the error is 0 there.
    flat = _hand_like(4) * np.array([1.0, 1.0, 0.0])
    assert pa_mpjpe(flat * np.array([-1.0, 1.0, 1.0]), flat) == pytest.approx(0.0, abs=1e-6)


def _umeyama_reference(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """A second implementation: rotation from the quaternion eigenproblem (Horn 1987), then the
    least-squares scale and translation; float64."""
    pred_c, true_c = pred - pred.mean(0), true - true.mean(0)
    m = pred_c.T @ true_c  # sum_k x_k y_k^T
    sxx, sxy, sxz = m[0]
    syx, syy, syz = m[1]
    szx, szy, szz = m[2]
    n = np.array([
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ])
    _, vectors = np.linalg.eigh(n)
    w, x, y, z = vectors[:, -1]
    rotation = Rotation.from_quat([x, y, z, w]).as_matrix()
    rotated = pred_c @ rotation.T
    scale = float((rotated * true_c).sum() / np.square(pred_c).sum())
    return scale * rotated + true.mean(0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pa_mpjpe_matches_independent_implementations(seed):
    rng = np.random.default_rng(100 + seed)
    true = _hand_like(seed)
    pred = _similarity(true, seed, 1.2, [0.02, 0.0, -0.1]) + rng.normal(scale=0.004,
                                                                        size=true.shape)
    aligned = procrustes_align(pred, true)
    reference = _umeyama_reference(pred, true)
    np.testing.assert_allclose(aligned, reference, atol=1e-10)
    expected = np.linalg.norm(reference - true, axis=1).mean() * 1000.0
    assert pa_mpjpe(pred, true) == pytest.approx(expected, rel=1e-9)
    # scipy's procrustes standardises both sets (unit Frobenius norm); its disparity is the
    # residual sum of squares of true's standardised copy: |true - aligned|^2 / |true_c|^2.
    _, _, disparity = procrustes(true, pred)
    true_centred = true - true.mean(0)
    residual = np.square(aligned - true).sum() / np.square(true_centred).sum()
    assert residual == pytest.approx(disparity, rel=1e-7)
    # Noise of 4 mm std per axis leaves a few mm, less than the unaligned error.
    assert 1.0 < pa_mpjpe(pred, true) < mpjpe(pred, true)


def test_torch_inputs_and_float32():
    true = _hand_like(5)
    pred = true + np.array([0.0, 0.002, 0.0])
    pred[0] -= np.array([0.0, 0.002, 0.0])  # only the root stays put: 20 keypoints 2 mm off
    value = mpjpe(torch.from_numpy(pred).float(), torch.from_numpy(true))
    assert value == pytest.approx(20 * 2.0 / 21, rel=1e-5)
    assert math.isfinite(pa_mpjpe(torch.from_numpy(pred), true))


@pytest.mark.parametrize(
    ("pred", "true", "message"),
    [
        (np.zeros((21, 2)), np.zeros((21, 2)), r"pred must have shape \[K, 3\]"),
        (np.zeros((21, 3)), np.zeros((20, 3)), "same shape"),
        (np.full((21, 3), np.nan), np.zeros((21, 3)), "pred holds non-finite"),
        (np.zeros((21, 3)), np.zeros((21, 3)), "all lie on one point"),
        (np.eye(2, 3), np.eye(2, 3), "K >= 3"),
    ],
)
def test_bad_inputs(pred, true, message):
    with pytest.raises(ValueError, match=message):
        pa_mpjpe(pred, true)


def test_bad_root():
    true = _hand_like()
    with pytest.raises(ValueError, match=r"root must be in \[0, 21\)"):
        mpjpe(true, true, root=21)
    with pytest.raises(TypeError, match="root must be an int"):
        mpjpe(true, true, root=1.0)


def test_mrrpe_by_hand():
    """Roots (wrists) 0 and 0.1 m apart in x: fitted offsets (0.1, 0.02, 0) against true
    (0.09, 0, 0.01) differ by (0.01, 0.02, -0.01) m, 24.495 mm; moving both fitted hands alike
    changes nothing; other keypoints do not count."""
    from lisa_hand.metrics.keypoints import mrrpe

    rng = np.random.default_rng(0)
    true_right = rng.normal(size=(21, 3)) * 0.05
    true_left = rng.normal(size=(21, 3)) * 0.05
    true_right[0], true_left[0] = [0.0, 0.0, 0.5], [0.09, 0.0, 0.51]
    pred_right, pred_left = true_right.copy(), true_left.copy()
    pred_left[0] = [0.1, 0.02, 0.5]
    expected = 1000.0 * math.sqrt(0.01 ** 2 + 0.02 ** 2 + 0.01 ** 2)
    assert mrrpe(pred_right, pred_left, true_right, true_left) == pytest.approx(expected,
                                                                                rel=1e-12)
    shift = np.array([0.3, -0.1, 0.2])
    assert mrrpe(pred_right + shift, pred_left + shift, true_right, true_left) == pytest.approx(
        expected, rel=1e-9)
    pred_left[1:] += 0.05  # not the root
    assert mrrpe(pred_right, pred_left, true_right, true_left) == pytest.approx(expected,
                                                                                rel=1e-12)
    assert mrrpe(true_right, true_left, true_right, true_left) == 0.0
    with pytest.raises(ValueError, match="root"):
        mrrpe(pred_right, pred_left, true_right, true_left, root=21)
