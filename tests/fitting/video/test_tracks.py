"""Hands followed through a clip (lisa_hand.fitting.video.tracks): detections made by hand,
frame by frame, joined into tracks; bridged dropouts checked against the linear interpolation
computed here."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.data.detect import DetectedHand
from lisa_hand.fitting.video.tracks import HandTrack, build_tracks, hand_size_px

SHAPE = np.random.default_rng(0).uniform(0.0, 1.0, size=(21, 2))
SHAPE[0], SHAPE[1] = (0.0, 0.0), (1.0, 1.0)  # the keypoints' box is the unit square


def hand(x: float, y: float, side: str = "right", score: float = 0.9,
         size: float = 100.0) -> DetectedHand:
    """A detected hand: :data:`SHAPE` scaled to ``size`` pixels, its box's corner at (x, y)."""
    keypoints = np.asarray((x, y)) + size * SHAPE
    low, high = keypoints.min(0), keypoints.max(0)
    return DetectedHand(keypoints=keypoints, score=score, side=side,
                        box=(float(low[0]), float(low[1]), float(high[0]), float(high[1])))


def test_hand_size_is_the_keypoint_box_diagonal():
    assert hand_size_px(np.array([[10.0, 20.0], [40.0, 60.0], [25.0, 30.0]])) == 50.0
    assert hand_size_px(hand(3.0, 4.0, size=100.0).keypoints) == pytest.approx(100 * 2 ** 0.5)


def test_the_detectors_3d_landmarks_follow_their_track():
    """A track holds each detection's 3D landmarks in its frame, NaN where it was not
    detected (a bridged dropout) or the detector gave none."""
    from dataclasses import replace

    shape = np.random.default_rng(1).normal(0.0, 0.05, size=(21, 3))
    frames = [[replace(hand(100.0 + 5.0 * row, 100.0), landmarks_3d=shape + row)]
              for row in range(6)]
    frames[2] = []
    frames[4] = [hand(120.0, 100.0)]  # no landmarks
    (track,) = build_tracks(frames, bridge_frames=2)
    for row in (0, 1, 3, 5):
        np.testing.assert_array_equal(track.landmarks_3d[row], shape + row)
    assert track.bridged[2] and np.isnan(track.landmarks_3d[[2, 4]]).all()


def test_one_hand_moving_steadily_is_one_track_detected_throughout():
    frames = [[hand(100.0 + 6.0 * row, 120.0 + 2.0 * row, score=0.8)] for row in range(20)]
    (track,) = build_tracks(frames)
    assert track.identity == 0 and track.side == "right"
    assert track.detected.all() and not track.bridged.any() and track.present.all()
    np.testing.assert_array_equal(track.keypoints, np.stack([f[0].keypoints for f in frames]))
    np.testing.assert_array_equal(track.scores, np.full(20, 0.8))
    assert track.segments() == [(0, 20)]


def _dropout(frames: int = 20, gap: range = range(8, 11)) -> list[list[DetectedHand]]:
    """A right hand moving along a parabola (the bridge is not its path), missing in ``gap``."""
    return [[] if row in gap else [hand(100.0 + 5.0 * row, 100.0 + 0.5 * row ** 2)]
            for row in range(frames)]


def test_a_short_dropout_is_bridged_by_linear_interpolation():
    frames = _dropout()
    (track,) = build_tracks(frames, bridge_frames=5)
    before, after = frames[7][0].keypoints, frames[11][0].keypoints
    for row in (8, 9, 10):
        weight = (row - 7) / 4.0
        np.testing.assert_allclose(track.keypoints[row], before + weight * (after - before),
                                   rtol=0, atol=1e-12)
    np.testing.assert_array_equal(track.bridged, np.isin(np.arange(20), [8, 9, 10]))
    np.testing.assert_array_equal(track.detected, ~track.bridged)
    assert track.present.all() and track.segments() == [(0, 20)]
    assert (track.scores[8:11] == 0).all()
    # The bridge is a straight line, not the hand's own (curved) path.
    assert np.abs(track.keypoints[9] - hand(145.0, 140.5).keypoints).max() > 1.0


def test_a_dropout_longer_than_the_bridge_ends_a_segment():
    (track,) = build_tracks(_dropout(), bridge_frames=2)
    assert track.segments() == [(0, 8), (11, 20)]
    assert not track.bridged.any() and not track.present[8:11].any()
    assert np.isnan(track.keypoints[8:11]).all() and np.isfinite(track.keypoints[11:]).all()
    (exact,) = build_tracks(_dropout(), bridge_frames=3)  # a gap of 3 fits a bridge of 3
    assert exact.segments() == [(0, 20)] and exact.bridged.sum() == 3


def test_a_hand_that_leaves_and_comes_back_elsewhere_keeps_its_identity():
    frames = ([[hand(50.0 + 2.0 * row, 100.0, side="left")] for row in range(10)] + [[]] * 30
              + [[hand(450.0, 250.0 + row, side="left")] for row in range(10)])
    (track,) = build_tracks(frames, bridge_frames=12)
    assert track.identity == 0 and track.side == "left"
    assert track.segments() == [(0, 10), (40, 50)]
    np.testing.assert_array_equal(track.keypoints[45], frames[45][0].keypoints)


def test_two_hands_crossing_paths_keep_their_identities():
    """A right hand moving right and a left hand moving left, 60 px apart vertically, pass each
    other; the detector lists them left to right, so their order swaps half way."""
    frames = []
    for row in range(40):
        right = hand(100.0 + 10.0 * row, 100.0, side="right")
        left = hand(490.0 - 10.0 * row, 160.0, side="left")
        frames.append(sorted([right, left], key=lambda h: h.box[0] + h.box[2]))
    first, second = build_tracks(frames)
    assert frames[0][0].side == "right" and frames[-1][0].side == "left"  # the order swapped
    assert (first.identity, first.side) == (0, "right")
    assert (second.identity, second.side) == (1, "left")
    rows = np.arange(40)
    np.testing.assert_allclose(first.keypoints[:, 0, 0], 100.0 + 10.0 * rows)
    np.testing.assert_allclose(second.keypoints[:, 0, 0], 490.0 - 10.0 * rows)
    assert first.detected.all() and second.detected.all()


def test_a_side_label_flipped_for_one_frame_is_outvoted():
    frames = [[hand(100.0 + 3.0 * row, 100.0, side="left" if row == 6 else "right",
                    score=0.95 if row == 6 else 0.8)] for row in range(15)]
    tracks = build_tracks(frames)
    assert len(tracks) == 1
    assert tracks[0].side == "right" and tracks[0].detected.all()


def test_the_side_is_the_score_weighed_majority():
    frames = [[hand(100.0 + row, 100.0, side="left" if row < 2 else "right",
                    score=0.99 if row < 2 else 0.6)] for row in range(5)]
    assert build_tracks(frames)[0].side == "left"  # 2 x 0.99 > 3 x 0.6


def test_max_hands_one_follows_the_first_hand_only():
    frames = [[hand(100.0, 100.0 + row, side="right"), hand(400.0, 100.0 + row, side="left")]
              for row in range(10)]
    (track,) = build_tracks(frames, max_hands=1)
    assert track.side == "right" and track.detected.all()
    np.testing.assert_array_equal(track.keypoints, np.stack([f[0].keypoints for f in frames]))
    assert len(build_tracks(frames, max_hands=2)) == 2


def test_no_hand_and_bad_arguments():
    assert build_tracks([[], [], []]) == []
    assert build_tracks([]) == []
    with pytest.raises(ValueError, match="bridge_frames"):
        build_tracks([[hand(0.0, 0.0)]], bridge_frames=-1)


def test_segments_present_and_size_of_a_track():
    detected = np.array([1, 1, 0, 0, 1, 0, 1, 1], bool)
    bridged = np.array([0, 0, 1, 0, 0, 0, 0, 0], bool)
    sizes = [100.0, 300.0, 0.0, 0.0, 200.0, 0.0, 120.0, 150.0]
    keypoints = np.stack([size * SHAPE for size in sizes])
    track = HandTrack(identity=0, side="right", keypoints=keypoints, detected=detected,
                      bridged=bridged, scores=detected * 0.9)
    np.testing.assert_array_equal(track.present, [1, 1, 1, 0, 1, 0, 1, 1])
    assert track.segments() == [(0, 3), (4, 5), (6, 8)]
    # The median over the 5 detections (the bridged row's keypoints do not count).
    assert track.size_px() == pytest.approx(150.0 * 2 ** 0.5)
    nothing = HandTrack(identity=0, side="right", keypoints=keypoints,
                        detected=np.zeros(8, bool), bridged=np.zeros(8, bool),
                        scores=np.zeros(8))
    assert nothing.segments() == [] and nothing.size_px() == 0.0
