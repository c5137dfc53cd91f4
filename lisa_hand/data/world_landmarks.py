"""MediaPipe's world landmarks: each detected hand's 21 points in 3D as its landmark model sees
it (metres, the size of an average hand, the camera's axes: x right, y down, z away from it;
origin near the hand's centre), kept as
:attr:`lisa_hand.data.detect.DetectedHand.landmarks_3d`.

Their size and origin are not the hand's (their wrist is not the skeleton's either); the
directions of their bones tell which way each finger bends toward or away from the camera,
which the 2D keypoints leave open (:func:`lisa_hand.fitting.images.terms.direction_misfit`).
A window that was mirrored before detection gives them mirrored: x is negated back.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..skeleton import NUM_KEYPOINTS

__all__ = ["world_landmarks", "mean_landmarks"]


def world_landmarks(landmarks: Any, mirrored: bool) -> np.ndarray | None:
    """MediaPipe's world landmarks of one hand (its ``landmark`` list of x, y, z) -> [21, 3]
    float64 metres in the camera's axes (None if absent or not finite); from a mirrored window,
    mirrored back (x negated)."""
    if landmarks is None:
        return None
    points = np.array([[point.x, point.y, point.z] for point in landmarks.landmark], np.float64)
    if points.shape != (NUM_KEYPOINTS, 3) or not np.isfinite(points).all():
        return None
    if mirrored:
        points[:, 0] = -points[:, 0]
    return points


def mean_landmarks(shapes: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """The mean [21, 3] of the given landmarks, those that are None skipped (None: all are)."""
    given = [shape for shape in shapes if shape is not None]
    return np.mean(given, axis=0) if given else None
