"""A detected hand cut by the photo's border: its keypoints outside the photo are not visible
(left to the fit's prior) and said in one line; a hand mostly outside is not fitted."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from lisa_hand.data.detect import DetectedHand
from lisa_hand.fitting.photo.inputs import detected_hand


def _hand(keypoints: np.ndarray) -> DetectedHand:
    low, high = keypoints.min(0), keypoints.max(0)
    return DetectedHand(keypoints=keypoints, score=0.9, side="right",
                        box=(float(low[0]), float(low[1]), float(high[0]), float(high[1])),
                        side_votes=(2, 0))


def test_keypoints_outside_the_photo_are_not_visible():
    photo = SimpleNamespace(image=np.zeros((100, 200, 3), np.float32), path=Path("p.jpg"))
    rng = np.random.default_rng(0)
    keypoints = rng.uniform([20, 20], [180, 80], size=(21, 2))
    keypoints[[4, 8, 12]] = [[205.0, 50.0], [230.0, 40.0], [199.0, 101.0]]  # past the border
    lines = []
    hand = detected_hand(photo, _hand(keypoints), 0.0, lines.append)
    assert hand is not None and hand.visible.sum() == 18
    assert not hand.visible[[4, 8, 12]].any()
    # the hidden ones stand in at their nearest visible ancestor (inside the photo)
    np.testing.assert_allclose(hand.keypoints[4], keypoints[3])
    np.testing.assert_allclose(hand.keypoints[hand.visible], keypoints[hand.visible])
    assert len(lines) == 1 and "cut by the photo's border" in lines[0] and "3 keypoint" in lines[0]
    # all inside: as detected, nothing said
    inside = keypoints.copy()
    inside[[4, 8, 12]] = [[150.0, 50.0], [160.0, 40.0], [170.0, 60.0]]
    lines.clear()
    whole = detected_hand(photo, _hand(inside), 0.0, lines.append)
    assert whole.visible.all() and not lines
    np.testing.assert_allclose(whole.keypoints, inside)


def test_a_hand_mostly_outside_is_not_fitted():
    photo = SimpleNamespace(image=np.zeros((100, 200, 3), np.float32), path=Path("p.jpg"))
    keypoints = np.random.default_rng(1).uniform([210, 20], [300, 80], size=(21, 2))
    keypoints[:5, 0] = 190.0  # five inside
    lines = []
    assert detected_hand(photo, _hand(keypoints), 0.0, lines.append) is None
    assert len(lines) == 1 and "not fitted" in lines[0] and "5 of 21" in lines[0]
