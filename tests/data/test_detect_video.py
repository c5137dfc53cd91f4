"""Hands in the frames of a clip (lisa_hand.data.detect.VideoHandDetector): with a stand-in for
MediaPipe's ``Hands`` that returns scripted landmarks (the mapping to pixels, MediaPipe's
mirrored labels, the order, the context), and with MediaPipe itself (the photo extra) on the
first frames of the real clip of ``tests/assets/videos``."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lisa_hand.data.detect import VideoHandDetector
from tests.assets import ASSETS

CLIP = ASSETS / "videos" / "hand_landmarker_test_video.mp4"
GRID = np.stack(np.meshgrid(np.linspace(0.0, 1.0, 3), np.linspace(0.0, 1.0, 7)),
                -1).reshape(-1, 2)  # 21 points spread over a unit box


def landmarks(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """[21, 2] normalised landmarks spread over the box (x0, y0) - (x1, y1), [0, 1] units."""
    return np.array([x0, y0]) + GRID * np.array([x1 - x0, y1 - y0])


class ScriptedHands:
    """MediaPipe's ``Hands`` interface: each ``process`` call returns the next frame of
    ``script``, a list of (normalised landmarks [21, 2], MediaPipe label, score) per frame.
    The detector's warm-up call on a blank frame when it starts (``warmups``) finds nothing
    and is not one of ``inputs``."""

    def __init__(self, script, **options):
        self.script, self.options = list(script), options
        self.inputs: list[np.ndarray] = []
        self.entered = self.exited = self.warmups = 0

    def __enter__(self):
        self.entered += 1
        return self

    def __exit__(self, *exc):
        self.exited += 1
        return False

    def process(self, rgb: np.ndarray):
        if not self.inputs and not rgb.any():
            self.warmups += 1
            return SimpleNamespace(multi_hand_landmarks=None, multi_handedness=None)
        self.inputs.append(rgb.copy())
        hands = self.script.pop(0)
        if not hands:
            return SimpleNamespace(multi_hand_landmarks=None, multi_handedness=None)
        return SimpleNamespace(
            multi_hand_landmarks=[SimpleNamespace(landmark=[SimpleNamespace(x=x, y=y)
                                                            for x, y in points])
                                  for points, _, _ in hands],
            multi_handedness=[SimpleNamespace(classification=[SimpleNamespace(label=label,
                                                                              score=score)])
                              for _, label, score in hands])


def scripted(script):
    """A ``hands_factory`` and the list its detectors land in."""
    made: list[ScriptedHands] = []

    def factory(**options):
        made.append(ScriptedHands(script, **options))
        return made[-1]

    return factory, made


def frame(width: int = 200, height: int = 100) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, size=(height, width, 3), dtype=np.uint8)


def test_keypoints_sides_and_order():
    right_hand = landmarks(0.6, 0.2, 0.9, 0.8)  # MediaPipe's "Left" is a right hand
    left_hand = landmarks(0.1, 0.3, 0.3, 0.7)
    factory, made = scripted([[(right_hand, "Left", 0.93), (left_hand, "Right", 0.71)], []])
    image = frame(200, 100)
    with VideoHandDetector(max_hands=2, min_detection_confidence=0.4,
                           min_tracking_confidence=0.6, model_complexity=0,
                           hands_factory=factory) as detector:
        first, second = detector(image)
        assert detector(image) == []
    (hands,) = made
    assert hands.options == dict(static_image_mode=False, max_num_hands=2, model_complexity=0,
                                 min_detection_confidence=0.4, min_tracking_confidence=0.6)
    assert (hands.entered, hands.exited, hands.warmups) == (1, 1, 1)  # one blank start-up run
    assert len(hands.inputs) == 2
    np.testing.assert_array_equal(hands.inputs[0], image)  # the frame as it is: no resizing
    # Left to right: the left hand first.
    assert (first.side, second.side) == ("left", "right")
    assert first.score == pytest.approx(0.71) and second.score == pytest.approx(0.93)
    assert first.side_votes == (0, 1) and second.side_votes == (1, 0)
    assert first.found_by == second.found_by == "video"
    np.testing.assert_allclose(second.keypoints, right_hand * [200.0, 100.0], atol=1e-9)
    np.testing.assert_allclose(first.keypoints, left_hand * [200.0, 100.0], atol=1e-9)
    assert second.box == pytest.approx((120.0, 20.0, 180.0, 80.0))
    assert first.box == pytest.approx((20.0, 30.0, 60.0, 70.0))


def test_a_low_score_for_a_label_is_the_other_side():
    """A label scored below 0.5 says the other side, with confidence 1 - score."""
    factory, _ = scripted([[(landmarks(0.2, 0.2, 0.5, 0.5), "Left", 0.3)]])
    with VideoHandDetector(hands_factory=factory) as detector:
        (hand,) = detector(frame())
    assert hand.side == "left" and hand.score == pytest.approx(0.7)


def test_float_frames_are_converted_to_bytes():
    factory, made = scripted([[]])
    image = np.linspace(0.0, 1.0, 30 * 40 * 3, dtype=np.float32).reshape(30, 40, 3)
    with VideoHandDetector(hands_factory=factory) as detector:
        assert detector(image) == []
    seen = made[0].inputs[0]
    assert seen.dtype == np.uint8
    np.testing.assert_array_equal(seen, np.round(image * 255.0).astype(np.uint8))


def test_used_outside_with_is_an_error():
    factory, made = scripted([[], []])
    detector = VideoHandDetector(hands_factory=factory)
    assert made == []  # nothing started before the block
    with pytest.raises(RuntimeError, match="with"):
        detector(frame())
    with detector:
        detector(frame())
    with pytest.raises(RuntimeError, match="with"):
        detector(frame())
    assert made[0].exited == 1


def test_the_context_is_closed_when_the_block_raises():
    factory, made = scripted([[]])
    with pytest.raises(KeyError), VideoHandDetector(hands_factory=factory):
        raise KeyError("inside")
    assert made[0].exited == 1


@pytest.mark.parametrize("arguments, name", [
    ({"max_hands": 0}, "max_hands"), ({"max_hands": True}, "max_hands"),
    ({"max_hands": 1.5}, "max_hands"), ({"min_detection_confidence": 0.0},
                                        "min_detection_confidence"),
    ({"min_detection_confidence": 1.0}, "min_detection_confidence"),
    ({"min_tracking_confidence": -0.2}, "min_tracking_confidence"),
    ({"min_tracking_confidence": 1.5}, "min_tracking_confidence"),
])
def test_bad_arguments(arguments, name):
    factory, made = scripted([])
    with pytest.raises(ValueError, match=name):
        VideoHandDetector(hands_factory=factory, **arguments)
    assert made == []


def test_bad_frames():
    factory, _ = scripted([[]] * 3)
    with VideoHandDetector(hands_factory=factory) as detector:
        with pytest.raises(ValueError, match=r"\[H, W, 3\]"):
            detector(np.zeros((10, 10), np.uint8))
        with pytest.raises(ValueError, match=r"\[H, W, 3\]"):
            detector(np.zeros((10, 10, 4), np.uint8))
        with pytest.raises(ValueError, match="float in"):
            detector(np.zeros((10, 10, 3), np.int32))


# --- MediaPipe (the photo extra) ------------------------------------------------------------


@pytest.mark.filterwarnings("ignore::UserWarning")  # protobuf deprecations inside mediapipe
def test_real_clip_first_frames():
    """The first 10 frames of the real clip (640 x 360, a right hand): one right hand in each,
    inside the frame, moving little from frame to frame."""
    from lisa_hand.data.detect import photo_extra_missing

    if photo_extra_missing():
        pytest.skip("the photo extra (pip install -e '.[photo]') is not installed")
    cv2 = pytest.importorskip("cv2")
    capture = cv2.VideoCapture(str(CLIP))
    frames = []
    while len(frames) < 10:
        ok, bgr = capture.read()
        assert ok
        frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    capture.release()
    assert frames[0].shape == (360, 640, 3)
    with VideoHandDetector(max_hands=2) as detector:
        found = [detector(rgb) for rgb in frames]
    assert all(len(hands) == 1 for hands in found), [len(hands) for hands in found]
    keypoints = np.stack([hands[0].keypoints for hands in found])
    assert all(hands[0].side == "right" and hands[0].score > 0.7 for hands in found)
    assert (keypoints > 0).all() and (keypoints[..., 0] < 640).all()
    assert (keypoints[..., 1] < 360).all()
    sizes = np.array([np.hypot(*(k.max(0) - k.min(0))) for k in keypoints])
    assert (sizes > 40).all()
    steps = np.linalg.norm(np.diff(keypoints, axis=0), axis=-1).mean(-1)
    assert (steps < 0.25 * sizes[1:]).all()  # one hand followed, not several


def test_mediapipe_start_up_lines_are_held_back(capfd):
    """As :func:`lisa_hand.data.detect.detect_hands` does, the detector keeps MediaPipe's
    TensorFlow Lite / absl start-up lines ("Feedback manager requires ...", printed by every
    new graph) off the terminal."""
    from lisa_hand.data.detect import photo_extra_missing

    if photo_extra_missing():
        pytest.skip("the photo extra (pip install -e '.[photo]') is not installed")
    capfd.readouterr()
    with VideoHandDetector(max_hands=1) as detector:
        detector(frame(160, 120))
        detector(frame(160, 120))
    assert "Feedback manager" not in capfd.readouterr().err
