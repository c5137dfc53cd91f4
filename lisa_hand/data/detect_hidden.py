"""Hands whose palm is hidden: the last step of :func:`lisa_hand.data.detect.detect_hands`'s
further search (its module docstring, "More hands").

MediaPipe finds a hand in two steps: a palm detector proposes a rotated square around each
palm, then the landmark model reads the 21 keypoints in that square. A hand behind another one
(fingers interlaced, one hand holding the other's wrist) often shows its fingers but not its
palm, and the palm detector never proposes it, in whatever window it looks. The landmark model
alone still reads such a hand when given a square around it. So, while fewer hands than wanted
are found, the landmark model is run on its own (:class:`LandmarkModel`, MediaPipe's
``HandLandmarkCpu`` graph, the same model file) on squares around each hand found:
:attr:`DetectConfig.hidden_context` times its keypoint box, centred on it and shifted by half its
size left, right, up and down, each turned by 0, 90, 180 and 270 degrees (the model expects the
fingers up in its square).

What it reads there is **settled** the way MediaPipe tracks a hand through a video: the next
square is made from the keypoints just read (:func:`square_of_keypoints`: the palm's box, turned
so that the wrist-to-middle-knuckle line points up, twice its size, shifted toward the fingers),
read again, up to :data:`SETTLE_STEPS` times, until two readings agree
(:attr:`DetectConfig.agreement`). A reading that does not settle is dropped; one that settles on
a hand already found (:func:`lisa_hand.data.detect._same_hand`) is that hand. A new hand must be
settled on from at least :data:`MIN_STARTS` of the starting squares (the landmark model, asked
about a square without a hand, answers "no hand" or something that does not settle), and its
keypoints and side are the mean of those settled readings (:func:`lisa_hand.data.detect.
_consensus`). Its side comes from the landmark model's handedness, as MediaPipe's own.

Time: 20 squares a hand found, each read one to :data:`SETTLE_STEPS` times, 10-20 ms a reading on
one core: about 0.5-1 s a hand, spent only while fewer hands than wanted are found.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from .detect import DetectConfig, _consensus, _diagonal, _Found, _same_hand
from .world_landmarks import world_landmarks

__all__ = ["HIDDEN", "LandmarkModel", "square_of_keypoints", "search_hidden", "SETTLE_STEPS",
           "MIN_STARTS"]

HIDDEN = "the landmark model alone beside another hand (palm hidden)"
"""What :attr:`lisa_hand.data.detect.DetectedHand.found_by` says of a hand found here."""

SETTLE_STEPS = 4
"""Readings of one start at most before its keypoints must agree with the reading before."""

MIN_STARTS = 2
"""A new hand must be settled on from this many starting squares."""

_PALM = [0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18]
"""The keypoints whose box makes the next square (wrist, thumb base, the fingers' first two
joints: what stays put when the fingers curl), as MediaPipe's tracking uses."""

_TURNS = (0.0, 0.5 * math.pi, math.pi, -0.5 * math.pi)

_GRAPH = """
input_stream: "image"
input_stream: "roi"
output_stream: "landmarks"
output_stream: "world_landmarks"
output_stream: "handedness"
node {
  calculator: "HandLandmarkCpu"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  input_side_packet: "MODEL_COMPLEXITY:model_complexity"
  output_stream: "LANDMARKS:landmarks"
  output_stream: "WORLD_LANDMARKS:world_landmarks"
  output_stream: "HANDEDNESS:handedness"
}
"""

Square = tuple[float, float, float, float]
"""(centre x, centre y, side, turn): pixels, and radians, clockwise in the image, by which the
square is turned (the model reads it turned back: fingers up)."""


class LandmarkModel:
    """MediaPipe's hand landmark model on a given square of an image, without the palm detector
    (the photo extra). A context manager; :meth:`read` -> the hand it reads there or None."""

    def __init__(self, model_complexity: int = 1) -> None:
        from google.protobuf import text_format
        from mediapipe.framework import calculator_pb2
        from mediapipe.framework.formats import rect_pb2
        from mediapipe.python.solution_base import SolutionBase

        self._rect = rect_pb2.NormalizedRect
        graph = text_format.Parse(_GRAPH, calculator_pb2.CalculatorGraphConfig())
        self._graph = SolutionBase(graph_config=graph,
                                   side_inputs={"model_complexity": model_complexity},
                                   outputs=["landmarks", "world_landmarks", "handedness"])

    def __enter__(self) -> LandmarkModel:
        return self

    def __exit__(self, *exc) -> bool:
        self._graph.close()
        return False

    def read(self, pixels: np.ndarray, square: Square) -> _Found | None:
        """The hand the model reads in ``square`` of ``pixels`` [H, W, 3] uint8 (contiguous)
        -> keypoints in image pixels, side, world landmarks; None when it sees no hand."""
        height, width = pixels.shape[:2]
        cx, cy, side, turn = square
        roi = self._rect(x_center=cx / width, y_center=cy / height, width=side / width,
                         height=side / height, rotation=turn)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # protobuf deprecation warnings inside mediapipe
            out = self._graph.process({"image": pixels, "roi": roi})
        if out.landmarks is None or out.handedness is None:
            return None
        points = np.array([[p.x * width, p.y * height] for p in out.landmarks.landmark])
        if points.shape != (21, 2) or not np.isfinite(points).all():
            return None
        label = out.handedness.classification[0]
        says_right = label.label == "Left"  # MediaPipe's mirrored convention
        p_right = float(label.score) if says_right else 1.0 - float(label.score)
        return _Found(points, p_right, landmarks=world_landmarks(out.world_landmarks, False))


def square_of_keypoints(keypoints: np.ndarray) -> Square:
    """The square in which the landmark model reads the hand of ``keypoints`` [21, 2] pixels
    next (MediaPipe's tracking rule): turned so that the wrist-to-middle-knuckle line points
    up, around the box of the palm keypoints in that turned frame, shifted a tenth of it toward
    the fingers, its long side doubled."""
    wrist, knuckle = keypoints[0], keypoints[9]
    turn = 0.5 * math.pi - math.atan2(-(knuckle[1] - wrist[1]), knuckle[0] - wrist[0])
    turn = (turn + math.pi) % (2.0 * math.pi) - math.pi
    cos, sin = math.cos(turn), math.sin(turn)
    to_square = np.array([[cos, sin], [-sin, cos]])  # image -> the square's upright frame
    upright = keypoints[_PALM] @ to_square.T
    low, high = upright.min(axis=0), upright.max(axis=0)
    centre = 0.5 * (low + high) + np.array([0.0, -0.1 * (high[1] - low[1])])
    cx, cy = centre @ to_square  # back to the image
    return float(cx), float(cy), 2.0 * float(max(high - low)), turn


def _settle(model: LandmarkModel, pixels: np.ndarray, square: Square,
            agreement: float) -> _Found | None:
    """Read ``square``, then the square of what was read, until two readings agree -> the last
    reading, or None (no hand, or no agreement within :data:`SETTLE_STEPS` readings)."""
    last = model.read(pixels, square)
    for _ in range(SETTLE_STEPS - 1):
        if last is None:
            return None
        again = model.read(pixels, square_of_keypoints(last.keypoints))
        if again is None:
            return None
        size = max(1.0, _diagonal(again.box))
        if np.linalg.norm(again.keypoints - last.keypoints, axis=1).mean() <= agreement * size:
            return again
        last = again
    return None


def _starts(hand: _Found, config: DetectConfig) -> list[Square]:
    """The starting squares around a hand found (the module docstring)."""
    x0, y0, x1, y1 = hand.box
    length = max(8.0, x1 - x0, y1 - y0)
    side = config.hidden_context * length
    return [(0.5 * (x0 + x1) + dx * 0.5 * length, 0.5 * (y0 + y1) + dy * 0.5 * length, side, turn)
            for dx, dy in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)) for turn in _TURNS]


def search_hidden(model: Any, pixels: np.ndarray, known: list[_Found], config: DetectConfig,
                  max_hands: int) -> list[_Found]:
    """Hands other than ``known`` read by the landmark model ``model`` (:meth:`LandmarkModel.
    read`'s interface) around each of them (the module docstring) -> at most ``max_hands`` -
    len(known) new hands, most often settled on first."""
    found: list[_Found] = []
    for hand in sorted(known, key=lambda h: -_diagonal(h.box)):
        if len(known) + len(found) >= max_hands:
            break
        readings = [reading for square in _starts(hand, config)
                    if (reading := _settle(model, pixels, square, config.agreement)) is not None
                    and not any(_same_hand(reading, other, config) for other in known + found)]
        while readings:  # group the readings by hand, the largest group first
            groups = [[r for r in readings if _same_hand(r, seed, config)] for seed in readings]
            group = max(groups, key=len)
            if len(group) < MIN_STARTS:
                break
            found.append(_consensus(group, config.agreement)[0])
            readings = [r for r in readings if not any(r is g for g in group)]
            if len(known) + len(found) >= max_hands:
                break
    return found
