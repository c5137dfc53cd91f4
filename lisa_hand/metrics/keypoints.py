"""3D keypoint errors of a fitted hand: MPJPE after root alignment and PA-MPJPE (Procrustes with
scale), in millimetres.

Both take the fitted keypoints ``pred`` and the true ones ``true``, ``[K, 3]`` in metres in one
frame (the 21 hand keypoints in the package's order, or any K), and return the mean over the
keypoints of the Euclidean distance after alignment, in mm:

* :func:`mpjpe`: ``pred`` is translated so that its root keypoint (``root``, the wrist by
  default) lands on the true root, ``mean_k |pred_k - pred_root + true_root - true_k|``. It keeps
  the errors of global rotation, scale (hand size, depth) and articulation; it removes the
  absolute position, which one uncalibrated view cannot fix.
* :func:`pa_mpjpe`: ``pred`` is first moved by the similarity ``s R x + t`` (rotation, isotropic
  scale, translation; no reflection) that brings it closest to ``true`` in the least-squares sense
  (Umeyama 1991, "Least-squares estimation of transformation parameters between two point
  patterns", Eqs. 40-42; :func:`procrustes_align`). It measures the articulation and the
  proportions of the hand alone.

Two hands: :func:`mrrpe`, InterHand2.6M's mean relative-root position error: the error of the
offset from the right hand's root to the left one's, which a root-aligned MPJPE of each hand
leaves out.

Pure functions: numpy arrays or torch tensors in, Python floats out, computed in float64 on the
CPU. Nothing here is differentiable.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..utils.arrays import as_numpy

__all__ = ["mpjpe", "pa_mpjpe", "procrustes_align", "mrrpe"]

_MM_PER_M = 1000.0


def _check_pair(pred: Any, true: Any) -> tuple[np.ndarray, np.ndarray]:
    """Both as float64 [K, 3] arrays of the same K >= 1, finite; ValueError otherwise."""
    arrays = []
    for name, value in (("pred", pred), ("true", true)):
        array = np.asarray(as_numpy(value, name), dtype=np.float64)
        if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] < 1:
            raise ValueError(f"{name} must have shape [K, 3] with K >= 1, got "
                             f"{list(array.shape)}")
        if not np.isfinite(array).all():
            raise ValueError(f"{name} holds non-finite values (NaN or inf)")
        arrays.append(array)
    if arrays[0].shape != arrays[1].shape:
        raise ValueError(f"pred and true must have the same shape, got {list(arrays[0].shape)} "
                         f"and {list(arrays[1].shape)}")
    return arrays[0], arrays[1]


def _mean_distance_mm(points_a: np.ndarray, points_b: np.ndarray) -> float:
    return float(np.linalg.norm(points_a - points_b, axis=1).mean() * _MM_PER_M)


def mpjpe(pred: Any, true: Any, root: int = 0) -> float:
    """Mean per-joint position error after root alignment, mm.

    pred, true: [K, 3] metres, same frame. root: index of the keypoint made to coincide (0: the
    wrist in the package's keypoint order).
    -> ``mean_k |(pred_k - pred_root) - (true_k - true_root)|`` in mm.
    """
    pred, true = _check_pair(pred, true)
    if isinstance(root, bool) or not isinstance(root, (int, np.integer)):
        raise TypeError(f"root must be an int, got {type(root).__name__}")
    if not 0 <= root < pred.shape[0]:
        raise ValueError(f"root must be in [0, {pred.shape[0]}), got {root}")
    return _mean_distance_mm(pred - pred[root], true - true[root])


def procrustes_align(pred: Any, true: Any) -> np.ndarray:
    """``pred`` moved by the similarity closest to ``true`` (Umeyama's least squares).

    Finds the rotation ``R`` (det +1), isotropic scale ``s > 0`` and translation ``t`` that
    minimise ``sum_k |true_k - (s R pred_k + t)|^2``: with centred points ``x = pred - mean``,
    ``y = true - mean``, ``Sigma = y^T x / K = U D V^T`` and ``S = diag(1, 1, sign(det U det V))``,
    ``R = U S V^T``, ``s = trace(D S) / (|x|^2 / K)``, ``t = mean(true) - s R mean(pred)``.

    pred, true: [K, 3] metres, K >= 3, ``pred`` not all on one point.
    -> [K, 3] float64, the aligned ``pred``.
    """
    pred, true = _check_pair(pred, true)
    if pred.shape[0] < 3:
        raise ValueError(f"Procrustes alignment needs K >= 3 keypoints, got {pred.shape[0]}")
    pred_mean, true_mean = pred.mean(0), true.mean(0)
    pred_centred, true_centred = pred - pred_mean, true - true_mean
    pred_variance = float(np.square(pred_centred).sum(1).mean())
    if pred_variance <= 1e-24:
        raise ValueError("pred keypoints all lie on one point: no Procrustes alignment")
    covariance = true_centred.T @ pred_centred / pred.shape[0]
    left, singular, right_t = np.linalg.svd(covariance)
    signs = np.ones(3)
    if np.linalg.det(left) * np.linalg.det(right_t) < 0:
        signs[2] = -1.0  # the closest proper rotation: flip the weakest axis, no reflection
    rotation = (left * signs) @ right_t
    scale = float((singular * signs).sum()) / pred_variance
    translation = true_mean - scale * rotation @ pred_mean
    return scale * pred @ rotation.T + translation


def pa_mpjpe(pred: Any, true: Any) -> float:
    """Mean per-joint position error after Procrustes alignment with scale, mm.

    pred, true: [K, 3] metres, K >= 3 (see :func:`procrustes_align`).
    -> ``mean_k |true_k - (s R pred_k + t)|`` in mm for the least-squares ``s, R, t``.
    """
    pred, true = _check_pair(pred, true)
    return _mean_distance_mm(procrustes_align(pred, true), true)


def mrrpe(pred_right: Any, pred_left: Any, true_right: Any, true_left: Any, root: int = 0
          ) -> float:
    """The relative root position error of two hands, mm (InterHand2.6M's MRRPE).

    pred_right, pred_left, true_right, true_left: [K, 3] metres, one frame. root: the keypoint
    that is a hand's root (0: the wrist). -> ``|(pred_left_root - pred_right_root) -
    (true_left_root - true_right_root)|`` in mm.
    """
    pred_right, true_right = _check_pair(pred_right, true_right)
    pred_left, true_left = _check_pair(pred_left, true_left)
    if not 0 <= root < pred_right.shape[0]:
        raise ValueError(f"root must be in [0, {pred_right.shape[0]}), got {root}")
    offset = (pred_left[root] - pred_right[root]) - (true_left[root] - true_right[root])
    return float(np.linalg.norm(offset) * _MM_PER_M)
