"""Choosing a tracked hand's keyframes: the best-seen frame, then the best-seen frame of each
other part of the track that is seen well enough."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.fitting.video.keyframe import (
    KEYFRAME_SHARE,
    choose_keyframe,
    choose_keyframes,
    view_score,
)
from lisa_hand.fitting.video.tracks import HandTrack

WIDTH, HEIGHT = 640, 480


def _hand(size: float, centre=(320.0, 240.0)) -> np.ndarray:
    """[21, 2] keypoints: a fan of fingers of ``size`` pixels around ``centre``."""
    angles = np.linspace(-0.8, 0.8, 21)
    radii = np.linspace(0.0, size, 21)
    return np.stack([centre[0] + radii * np.sin(angles), centre[1] - radii * np.cos(angles)], -1)


def _track(sizes, scores=None, outside=()) -> HandTrack:
    count = len(sizes)
    keypoints = np.stack([_hand(size) for size in sizes])
    for row in outside:
        keypoints[row, :, 0] += WIDTH  # every keypoint off the frame
    detected = np.isfinite(np.asarray(sizes, float))
    return HandTrack(identity=0, side="right", keypoints=keypoints, detected=detected,
                     bridged=np.zeros(count, bool),
                     scores=np.ones(count) if scores is None else np.asarray(scores, float))


def test_view_score_is_size_times_confidence_and_inside():
    small, large = view_score(_hand(50.0), 0.9, WIDTH, HEIGHT), view_score(_hand(100.0), 0.9,
                                                                            WIDTH, HEIGHT)
    assert small[0] and large[0]
    assert large[1] == pytest.approx(2.0 * small[1], rel=1e-6)
    assert not view_score(_hand(100.0) + [WIDTH, 0.0], 0.9, WIDTH, HEIGHT)[0]


def test_keyframes_are_the_best_seen_of_each_part():
    sizes = [60, 70, 80, 90, 100, 110, 120, 130, 140]  # the best at the end
    track = _track(sizes)
    assert choose_keyframe(track, WIDTH, HEIGHT) == 8
    # Three parts: rows 0-2, 3-5, 6-8; the first keyframe is the best of the last, the
    # others the best of the first two parts, in time order.
    assert choose_keyframes(track, WIDTH, HEIGHT, 3) == [8, 2, 5]
    assert choose_keyframes(track, WIDTH, HEIGHT, 1) == [8]
    # A part seen less than KEYFRAME_SHARE as well as the best gives none.
    weak = _track([10, 10, 10, 100, 100, 100, 130, 140, 140], scores=[1.0] * 9)
    assert 10 < KEYFRAME_SHARE * 140
    assert choose_keyframes(weak, WIDTH, HEIGHT, 3) == [7, 3]
    # Nor does a part whose frames all leave keypoints outside.
    assert choose_keyframes(_track(sizes, outside=(3, 4, 5)), WIDTH, HEIGHT, 3) == [8, 2]
