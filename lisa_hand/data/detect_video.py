"""Hands in the frames of a clip with MediaPipe's tracking mode (:class:`VideoHandDetector`; the
photo extra, as :mod:`lisa_hand.data.detect`, whose window mapping it shares). Re-exported by
:mod:`lisa_hand.data.detect`."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from ..utils.stderr import native_stderr_captured
from .detect import PHOTO_EXTRA_HINT, DetectedHand, _as_uint8, _mediapipe_hands, _run

__all__ = ["VideoHandDetector"]


class VideoHandDetector:
    """Hands in the frames of a clip, one frame after the other, with MediaPipe's tracking mode
    (``static_image_mode=False``): the palm detector runs only until a hand is found, then each
    hand is followed by the landmark model on a crop around its previous keypoints (about 25 ms
    a 720p frame on one core, where the photo search of :func:`detect_hands` takes up to a
    second). It finds a hand again when it is lost. Frames must come in order.

    Use as a context manager: ``with VideoHandDetector(max_hands=2) as detector:
    detector(frame_rgb)`` -> the frame's :class:`DetectedHand` list (``found_by`` "video",
    ``side_votes`` (1, 0) or (0, 1)), left to right. hands_factory: as :func:`detect_hands`.
    """

    def __init__(self, max_hands: int = 2, min_detection_confidence: float = 0.5,
                 min_tracking_confidence: float = 0.5, model_complexity: int = 1,
                 hands_factory: Callable[..., Any] | None = None) -> None:
        if isinstance(max_hands, bool) or not isinstance(max_hands, int) or max_hands < 1:
            raise ValueError(f"max_hands must be a positive integer, got {max_hands!r}")
        for name, value in (("min_detection_confidence", min_detection_confidence),
                            ("min_tracking_confidence", min_tracking_confidence)):
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {value}")
        if hands_factory is None:
            try:
                hands_factory = _mediapipe_hands().Hands
            except (ImportError, AttributeError):
                raise ImportError(PHOTO_EXTRA_HINT) from None
        self._arguments = dict(static_image_mode=False, max_num_hands=max_hands,
                               model_complexity=model_complexity,
                               min_detection_confidence=min_detection_confidence,
                               min_tracking_confidence=min_tracking_confidence)
        self._factory = hands_factory
        self._hands: Any = None
        self._context: Any = None
        self._quiet_frames = 2

    def __enter__(self) -> VideoHandDetector:
        with native_stderr_captured():
            self._context = self._factory(**self._arguments)
            self._hands = self._context.__enter__()
            # MediaPipe's threads log their start-up while the graph first runs: run it once on
            # a blank frame here, so that those lines are held back too.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self._hands.process(np.zeros((64, 64, 3), np.uint8))
        return self

    def __exit__(self, *exc: Any) -> None:
        context, self._context, self._hands = self._context, None, None
        if context is not None:
            context.__exit__(*exc)

    def __call__(self, frame: np.ndarray) -> list[DetectedHand]:
        """frame: [H, W, 3] uint8 RGB (or float in [0, 1]) -> the hands found in it."""
        if self._hands is None:
            raise RuntimeError("VideoHandDetector is used inside a 'with' block")
        pixels = _as_uint8(frame)
        height, width = pixels.shape[:2]
        window = (0, 0, width, height)
        if self._quiet_frames > 0:  # the landmark model starts with the first hand found
            with native_stderr_captured():
                found = _run(self._hands, pixels, window, max(height, width),
                             np.zeros(3, np.uint8))
            self._quiet_frames -= bool(found)
        else:
            found = _run(self._hands, pixels, window, max(height, width), np.zeros(3, np.uint8))
        hands = [DetectedHand(keypoints=one.keypoints, score=max(one.p_right, 1 - one.p_right),
                              side="right" if one.p_right >= 0.5 else "left", box=one.box,
                              found_by="video",
                              side_votes=(1, 0) if one.p_right >= 0.5 else (0, 1),
                              landmarks_3d=one.landmarks)
                 for one in found]
        return sorted(hands, key=lambda hand: 0.5 * (hand.box[0] + hand.box[2]))
