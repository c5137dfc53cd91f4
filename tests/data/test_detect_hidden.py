"""Hands whose palm is hidden (lisa_hand.data.detect_hidden): the landmark model alone on
squares around the hands found.

The search is checked with a stand-in landmark model that reads the hand whose palm lies in the
square it is given, off by a share of how far the square is from that hand's own square (so
that only settling finds the hand exactly); MediaPipe itself (the photo extra) on a rendered
photo in which its palm detector misses the hand behind (``tests/assets/two_hands``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lisa_hand.data.detect import DetectConfig, _Found, detect_hands
from lisa_hand.data.detect_hidden import (
    HIDDEN,
    MIN_STARTS,
    SETTLE_STEPS,
    search_hidden,
    square_of_keypoints,
)
from tests.assets import TWO_HANDS
from tests.data.mediapipe_fake import canvas, fake, marker


def upright_hand(scale: float = 100.0) -> np.ndarray:
    """[21, 2] pixels of a flat hand about the origin, fingers up (-y), wrist at the bottom."""
    points = [(0.0, 1.0)]  # wrist
    for x, top in ((-0.6, 0.3), (-0.3, -0.1), (0.0, -0.15), (0.3, -0.1), (0.55, 0.0)):
        points += [(x * (1 + 0.3 * k), top - 0.35 * k) for k in range(4)]
    return scale * np.asarray(points)


def turned(keypoints: np.ndarray, angle: float, centre=(0.0, 0.0)) -> np.ndarray:
    """The keypoints turned clockwise in the image (y down) by ``angle`` about the origin, then
    moved to ``centre``."""
    cos, sin = math.cos(angle), math.sin(angle)
    return keypoints @ np.array([[cos, sin], [-sin, cos]]) + np.asarray(centre)


def test_square_of_keypoints_turns_with_the_hand():
    hand = upright_hand()
    cx, cy, side, turn = square_of_keypoints(hand)
    assert turn == pytest.approx(0.0, abs=1e-12)
    palm = hand[[0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18]]
    low, high = palm.min(axis=0), palm.max(axis=0)
    assert side == pytest.approx(2.0 * max(high - low))
    assert (cx, cy) == pytest.approx((0.5 * (low[0] + high[0]),
                                      0.5 * (low[1] + high[1]) - 0.1 * (high[1] - low[1])))
    for angle in (0.4, math.pi / 2, 2.5, -1.2):  # the same hand turned: the same square, turned
        moved = turned(hand, angle, (300.0, 200.0))
        mx, my, mside, mturn = square_of_keypoints(moved)
        assert mturn == pytest.approx(angle)
        assert mside == pytest.approx(side)
        assert (mx, my) == pytest.approx(tuple(turned(np.array([[cx, cy]]), angle,
                                                      (300.0, 200.0))[0]))


class FakeLandmarks:
    """The landmark model's interface (``read(pixels, square)``) on known hands: it reads the
    hand whose palm keypoints lie in the square and whose fingers point within 60 degrees of the
    square's up (of several, the one whose own square is nearest the square's centre), off by
    ``pull`` times the gap between the square's centre and the hand's own square's (so a reading
    settles only by re-centring); ``noise``: random keypoints instead."""

    def __init__(self, hands: list[tuple[np.ndarray, str]], pull: float = 0.3,
                 noise: bool = False) -> None:
        self.hands, self.pull, self.noise = hands, pull, noise
        self.reads = 0
        self.rng = np.random.default_rng(0)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def read(self, pixels, square) -> _Found | None:
        self.reads += 1
        cx, cy, side, turn = square
        cos, sin = math.cos(turn), math.sin(turn)
        to_square = np.array([[cos, sin], [-sin, cos]])
        seen = []
        for keypoints, hand_side in self.hands:
            upright = (keypoints - (cx, cy)) @ to_square.T
            palm = upright[[0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18]]
            up = upright[9] - upright[0]
            if np.abs(palm).max() <= 0.5 * side and -up[1] >= 0.5 * np.linalg.norm(up):
                own = np.asarray(square_of_keypoints(keypoints)[:2])
                seen.append((np.linalg.norm(own - (cx, cy)), own, keypoints, hand_side))
        if not seen:
            return None
        _, own, keypoints, hand_side = min(seen, key=lambda item: item[0])  # the most centred
        if self.noise:
            return _Found(keypoints + self.rng.normal(0, 0.2 * side, keypoints.shape), 0.9)
        return _Found(keypoints + self.pull * (np.array([cx, cy]) - own),
                      0.95 if hand_side == "right" else 0.05)


FRONT = turned(upright_hand(), 0.2, (400.0, 400.0))
BEHIND = turned(upright_hand(), -0.3, (470.0, 330.0))  # overlapping it, a third of a hand off


def known(keypoints: np.ndarray) -> _Found:
    return _Found(keypoints, 0.05, support=3)


def test_hand_behind_is_found_and_settled():
    model = FakeLandmarks([(FRONT, "left"), (BEHIND, "right")])
    (hand,) = search_hidden(model, None, [known(FRONT)], DetectConfig(), max_hands=4)
    # The first readings around the front hand are 23-25 px off (0.3 x a square ~80 px away);
    # settled, the readings agree to 10% of the hand's size (its diagonal, 302 px) and are
    # 7 px off, their mean 1.2 px.
    size = np.linalg.norm(BEHIND.max(axis=0) - BEHIND.min(axis=0))
    assert np.linalg.norm(hand.keypoints - BEHIND, axis=1).mean() < 0.03 * size
    assert hand.p_right > 0.9 and hand.support >= MIN_STARTS
    assert model.reads <= 20 * SETTLE_STEPS


def test_one_hand_alone_gives_no_other():
    model = FakeLandmarks([(FRONT, "left")])
    assert search_hidden(model, None, [known(FRONT)], DetectConfig(), max_hands=4) == []
    assert model.reads > 0  # it looked, and every reading settled on the hand already found


def test_readings_that_do_not_settle_are_dropped():
    model = FakeLandmarks([(FRONT, "left"), (BEHIND, "right")], noise=True)
    assert search_hidden(model, None, [known(FRONT)], DetectConfig(), max_hands=4) == []


def test_no_search_when_enough_hands_are_found():
    model = FakeLandmarks([(FRONT, "left"), (BEHIND, "right")])
    assert search_hidden(model, None, [known(FRONT)], DetectConfig(), max_hands=1) == []
    assert model.reads == 0


def test_detect_hands_runs_it_last():
    """With the stand-in palm detector (a magenta marker is a hand) the marker is found, and the
    landmark model alone finds the hand that has no marker; not with ``hidden_search`` off, nor
    when ``max_hands`` hands are found already."""
    image = canvas()
    marker(image, 300, 250, 160, 300)
    (found,) = detect_hands(image, hands_factory=fake())
    hidden = turned(upright_hand(), 0.1, (found.box[0] + 180.0, found.box[1] + 60.0))
    model = FakeLandmarks([(found.keypoints, found.side), (hidden, "right")])
    hands = detect_hands(image, hands_factory=fake(), landmark_factory=lambda: model)
    assert len(hands) == 2
    (new,) = [hand for hand in hands if hand.found_by == HIDDEN]
    size = np.linalg.norm(hidden.max(axis=0) - hidden.min(axis=0))
    assert np.linalg.norm(new.keypoints - hidden, axis=1).mean() < 0.03 * size
    assert new.side == "right"
    assert len(detect_hands(image, config=DetectConfig(hidden_search=False),
                            hands_factory=fake(), landmark_factory=lambda: model)) == 1
    reads = model.reads
    assert len(detect_hands(image, max_hands=1, hands_factory=fake(),
                            landmark_factory=lambda: model)) == 1
    assert model.reads == reads


def test_hidden_context_checked():
    with pytest.raises(ValueError, match="hidden_context"):
        DetectConfig(hidden_context=0.5)


# --- MediaPipe (the photo extra) ------------------------------------------------------------


def test_mediapipe_finds_the_hand_behind(mediapipe):
    """A rendered left hand holding a right hand's wrist: the palm detector finds only the left
    one; the landmark model alone finds the right one, its seen keypoints as near the truth as
    the front hand's (measured: 5.6 and 6.8 px mean, 2.5 % and 3.8 % of the hands' size)."""
    from PIL import Image

    with Image.open(TWO_HANDS / "holding_wrist.jpg") as file:
        image = np.asarray(file.convert("RGB"))
    truth = json.loads((TWO_HANDS / "holding_wrist.json").read_text())["hands"]
    (front,) = detect_hands(image, config=DetectConfig(hidden_search=False))
    assert front.side == "left"
    hands = detect_hands(image)
    assert sorted(hand.side for hand in hands) == ["left", "right"]
    for hand in hands:
        true = np.asarray(truth[hand.side]["keypoints"])
        seen = np.asarray(truth[hand.side]["visible"])
        size = np.linalg.norm(true.max(axis=0) - true.min(axis=0))
        assert np.linalg.norm(hand.keypoints - true, axis=1)[seen].mean() < 0.05 * size
        assert hand.found_by == (HIDDEN if hand.side == "right" else "whole image")
        assert hand.landmarks_3d is not None and hand.landmarks_3d.shape == (21, 3)
