"""How steady and how faithful a tracked hand is: the figures of ``lisa fit-video``'s report
and of the video benchmark.

* jitter: the mean second difference of the wrist-relative 3D keypoints, mm/frame^2 (a hand
  held still or moving smoothly has little; a fit that flickers between depths or finger poses
  from frame to frame has much);
* agreement: the mean distance between the fitted keypoints projected and the detector's,
  pixels, in the frames where the detector found the hand;
* acceleration error (with truth): the mean distance between the fitted and the true
  wrist-relative keypoints' second differences, mm/frame^2;
* look (:func:`appearance_psnr_db`): how well one shape and colour fit the whole clip, dB.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["jitter_mm", "agreement_px", "acceleration_error_mm", "nan_mean",
           "appearance_psnr_db"]


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


def appearance_psnr_db(fit: Any, max_faces: int | None = None) -> float:
    """How well one shape and colour code fit the whole clip: the PSNR (dB) between the hands
    of ``fit`` (a :class:`~lisa_hand.fitting.video.fit.VideoFit`) rendered at their fitted
    poses (their meshes decimated to ``max_faces``, default the overlay's, with the model's shading:
    :func:`lisa_hand.inference.mesh_render.render_mesh`) and every frame they were not fitted
    on (their keyframes left out), over the pixels a hand covers fully (NaN without any). Pose
    errors count too: compare fits with the same motion."""
    from ...inference.mesh_render import render_mesh
    from ...inference.skinned import SkinnedMesh
    from .config import FitVideoConfig

    max_faces = FitVideoConfig.overlay_faces if max_faces is None else max_faces
    squared, count = 0.0, 0
    posers = [SkinnedMesh(hand.keyframe.mesh, hand.params, max_faces) for hand in fit.hands]
    for row, frame in enumerate(fit.video.frames()):
        for hand, poser in zip(fit.hands, posers, strict=True):
            if row in hand.keyframe.rows or not np.isfinite(hand.motion.pose[row]).all():
                continue
            shown = render_mesh(fit.model, poser.posed(hand.motion.pose[row],
                                                       hand.motion.translation[row]),
                                fit.camera, 1)
            full = shown.alpha > 0.999
            gap = shown.rgb[full] - frame.rgb[full].astype(np.float32) / 255.0
            squared += float((gap.astype(np.float64) ** 2).sum())
            count += gap.size
    return -10.0 * math.log10(squared / count) if count and squared > 0 else math.nan
