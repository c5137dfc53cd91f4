"""The figures of a video fit (lisa_hand.fitting.video.quality) against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.fitting.video.quality import (
    acceleration_error_mm,
    agreement_px,
    jitter_mm,
    nan_mean,
)

RNG = np.random.default_rng(3)
HAND = RNG.uniform(-0.08, 0.08, size=(21, 3))  # metres


def straight_line(frames: int = 9) -> np.ndarray:
    """[N, 21, 3]: a rigid hand moving at constant velocity (1 cm a frame)."""
    return HAND[None] + np.arange(frames)[:, None, None] * np.array([0.01, -0.004, 0.002])


def test_constant_velocity_has_no_jitter():
    np.testing.assert_allclose(jitter_mm(straight_line()), 0.0, atol=1e-9)
    assert jitter_mm(straight_line()).shape == (7,)


def test_jitter_of_an_alternating_offset_on_one_keypoint():
    """Keypoint 5 offset by +e, -e, +e ... mm along x: its second difference is 4 e (e.g.
    -e - 2 e - e), the other 20 keypoints' (wrist-relative, rigid) 0: the mean is 4 e / 21."""
    error_mm = 1.5
    points = straight_line(8)
    points[:, 5, 0] += 1e-3 * error_mm * (-1.0) ** np.arange(8)
    np.testing.assert_allclose(jitter_mm(points), 4.0 * error_mm / 21.0, rtol=1e-9)


def test_jitter_is_wrist_relative_and_nan_where_a_frame_has_no_hand():
    points = straight_line(6)
    points[2] += np.array([0.0, 0.0, 0.05])  # the whole hand jumps in depth: not the fingers
    np.testing.assert_allclose(jitter_mm(points), 0.0, atol=1e-9)
    points[4] = np.nan
    jitter = jitter_mm(points)
    np.testing.assert_array_equal(np.isnan(jitter), [False, False, True, True])  # triples 2, 3
    assert nan_mean(jitter) == pytest.approx(0.0, abs=1e-9)
    assert len(jitter_mm(points[:2])) == 0


def test_agreement_is_the_mean_keypoint_distance_where_detected():
    fitted = RNG.uniform(0.0, 300.0, size=(4, 21, 2))
    detected_2d = fitted.copy()
    detected_2d[0] += np.array([3.0, 4.0])  # 5 px each keypoint
    detected_2d[1, :7] += np.array([0.0, 6.0])  # 6 px on a third of them: 2 px mean
    agreement = agreement_px(fitted, detected_2d, np.array([True, True, True, False]))
    np.testing.assert_allclose(agreement[:3], [5.0, 2.0, 0.0], atol=1e-9)
    assert np.isnan(agreement[3])
    assert nan_mean(agreement) == pytest.approx(7.0 / 3.0)


def test_acceleration_error():
    true = straight_line(7)
    np.testing.assert_allclose(acceleration_error_mm(true, true), 0.0, atol=1e-12)
    fitted = true.copy()
    fitted[3, 10] += np.array([0.0, 0.003, 0.004])  # keypoint 10 off by 5 mm in frame 3 only
    # The second differences of rows (1, 2, 3), (2, 3, 4), (3, 4, 5) see it as 1, -2, 1 x 5 mm.
    np.testing.assert_allclose(acceleration_error_mm(fitted, true),
                               [0.0, 5.0 / 21, 10.0 / 21, 5.0 / 21, 0.0], rtol=1e-9, atol=1e-12)
    # A rigid offset of the whole hand in one frame is no acceleration of the hand's own shape.
    moved = true.copy()
    moved[3] += 0.02
    np.testing.assert_allclose(acceleration_error_mm(moved, true), 0.0, atol=1e-9)
    assert len(acceleration_error_mm(true[:2], true[:2])) == 0


def test_shapes_are_checked():
    with pytest.raises(ValueError, match=r"\[N, 21, 3\]"):
        jitter_mm(np.zeros((5, 20, 3)))
    with pytest.raises(ValueError, match=r"\[N, 21, 3\]"):
        jitter_mm(np.zeros((21, 3)))
    with pytest.raises(ValueError, match="shapes differ"):
        acceleration_error_mm(np.zeros((5, 21, 3)), np.zeros((6, 21, 3)))
    with pytest.raises(ValueError, match=r"\[N, 21, 3\]"):
        acceleration_error_mm(np.zeros((5, 21, 2)), np.zeros((5, 21, 2)))


def test_nan_mean():
    assert nan_mean(np.array([1.0, np.nan, 3.0, np.inf])) == 2.0
    assert np.isnan(nan_mean(np.array([np.nan]))) and np.isnan(nan_mean(np.zeros(0)))
