"""How steady and how faithful a tracked hand is: the figures of ``lisa fit-video``'s report
and of the video benchmark.

* jitter: the mean second difference of the wrist-relative 3D keypoints, mm/frame^2 (a hand
  held still or moving smoothly has little; a fit that flickers between depths or finger poses
  from frame to frame has much);
* agreement: the mean distance between the fitted keypoints projected and the detector's,
  pixels, in the frames where the detector found the hand;
* acceleration error (with truth): the mean distance between the fitted and the true
  wrist-relative keypoints' second differences, mm/frame^2.
"""

from __future__ import annotations

import numpy as np

__all__ = ["jitter_mm", "agreement_px", "acceleration_error_mm", "nan_mean"]


def _relative(keypoints_3d: np.ndarray) -> np.ndarray:
    points = np.asarray(keypoints_3d, np.float64)
    if points.ndim != 3 or points.shape[1:] != (21, 3):
        raise ValueError(f"keypoints_3d must have shape [N, 21, 3], got {list(points.shape)}")
    return points - points[:, :1]


def _second_difference(points: np.ndarray) -> np.ndarray:
    return points[2:] - 2.0 * points[1:-1] + points[:-2]


def jitter_mm(keypoints_3d: np.ndarray) -> np.ndarray:
    """keypoints_3d: [N, 21, 3] metres (NaN rows: no hand) -> [N - 2] mm/frame^2 per frame
    triple (NaN where one of the three has no hand)."""
    relative = _relative(keypoints_3d)
    if len(relative) < 3:
        return np.zeros(0)
    return 1000.0 * np.linalg.norm(_second_difference(relative), axis=-1).mean(-1)


def agreement_px(keypoints_2d: np.ndarray, detected_2d: np.ndarray, detected: np.ndarray
                 ) -> np.ndarray:
    """keypoints_2d, detected_2d: [N, 21, 2] pixels (one image size); detected: [N] bool ->
    [N] mean keypoint distance, pixels (NaN where not detected or not fitted)."""
    distance = np.linalg.norm(np.asarray(keypoints_2d, np.float64)
                              - np.asarray(detected_2d, np.float64), axis=-1).mean(-1)
    return np.where(np.asarray(detected, bool), distance, np.nan)


def acceleration_error_mm(fitted_3d: np.ndarray, true_3d: np.ndarray) -> np.ndarray:
    """[N, 21, 3] metres each -> [N - 2] mm/frame^2: the mean distance between the fitted and
    the true wrist-relative second differences."""
    fitted, true = _relative(fitted_3d), _relative(true_3d)
    if fitted.shape != true.shape:
        raise ValueError(f"shapes differ: {list(fitted.shape)} and {list(true.shape)}")
    if len(fitted) < 3:
        return np.zeros(0)
    gap = _second_difference(fitted) - _second_difference(true)
    return 1000.0 * np.linalg.norm(gap, axis=-1).mean(-1)


def nan_mean(values: np.ndarray) -> float:
    """The mean of the finite values (NaN when there is none), as a float."""
    values = np.asarray(values, np.float64)
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else float("nan")
