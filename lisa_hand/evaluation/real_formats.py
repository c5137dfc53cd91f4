"""Evaluation on imported real datasets (``lisa import freihand`` / ``interhand2.6m``), with the
benchmarks' own definitions.

* FreiHAND (Zimmermann et al., ICCV 2019, and its evaluation script): MPJPE (root-aligned),
  PA-MPJPE (keypoints aligned by a similarity, Procrustes with scale), PA-MPVPE (vertices aligned
  the same way) and the F-scores at 5 mm and 15 mm of the aligned vertices: with ``d_gt`` the
  distance of each true vertex to the nearest predicted one and ``d_pred`` that of each predicted
  vertex to the nearest true one, ``P = mean(d_gt < t)``, ``R = mean(d_pred < t)`` and
  ``F = 2 P R / (P + R)`` (0 when both are 0). The script names the two the other way round; F is
  the same.
* InterHand2.6M (Moon et al., ECCV 2020): MPJPE of the keypoints after aligning the root (the
  wrist), and after Procrustes alignment.

:func:`evaluate_split` runs a predictor (a callback: frame in, keypoints and optionally vertices
out) over an imported split and averages the scores; :func:`photo_fit_predictor` is the one of
``lisa fit-photo`` with each frame's calibrated camera (FreiHAND's ``K``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..data.frame_table import read_frame_table
from ..data.layout import FramePaths, read_npz
from ..metrics.keypoints import mpjpe, pa_mpjpe, procrustes_align
from ..utils.io import read_json, write_json

__all__ = ["FSCORE_THRESHOLDS_M", "Prediction", "f_score", "pa_mpvpe", "freihand_scores",
           "interhand_scores", "SplitScores", "evaluate_split", "photo_fit_predictor"]

FSCORE_THRESHOLDS_M = (0.005, 0.015)
"""The FreiHAND benchmark's F-score thresholds (5 mm and 15 mm)."""


def _points(value: Any, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] < 1 \
            or not np.isfinite(array).all():
        raise ValueError(f"{name} must be finite [N, 3] points, got shape {list(array.shape)}")
    return array


def f_score(pred: Any, true: Any, threshold_m: float) -> tuple[float, float, float]:
    """FreiHAND's F-score of two point sets (no alignment here; see the module docstring).

    pred: [N, 3], true: [M, 3] metres; threshold_m > 0. -> (F, P, R) in [0, 1].
    """
    from scipy.spatial import cKDTree

    pred, true = _points(pred, "pred"), _points(true, "true")
    if not threshold_m > 0:
        raise ValueError(f"threshold_m must be > 0 (metres), got {threshold_m!r}")
    d_true, _ = cKDTree(pred).query(true)
    d_pred, _ = cKDTree(true).query(pred)
    precision = float(np.mean(d_true < threshold_m))
    recall = float(np.mean(d_pred < threshold_m))
    total = precision + recall
    return (2 * precision * recall / total if total > 0 else 0.0), precision, recall


def pa_mpvpe(pred_vertices: Any, true_vertices: Any) -> float:
    """Mean vertex error after Procrustes alignment with scale, mm (vertices in correspondence:
    pred [V, 3] and true [V, 3] metres, same topology)."""
    pred, true = _points(pred_vertices, "pred_vertices"), _points(true_vertices, "true_vertices")
    if pred.shape != true.shape:
        raise ValueError(f"pred_vertices {list(pred.shape)} and true_vertices "
                         f"{list(true.shape)} must correspond one to one")
    return float(np.linalg.norm(procrustes_align(pred, true) - true, axis=1).mean() * 1e3)


def freihand_scores(pred_keypoints: Any, true_keypoints: Any, pred_vertices: Any = None,
                    true_vertices: Any = None) -> dict[str, float]:
    """One sample's FreiHAND scores: ``mpjpe_mm``, ``pa_mpjpe_mm`` and, with vertices,
    ``pa_mpvpe_mm``, ``f5`` and ``f15``. Vertex sets of the same size are taken to correspond one
    to one (MANO's 778 on both sides): PA-MPVPE, and the F-scores after aligning the vertices.
    Otherwise (another topology, e.g. a LISA mesh) there is no PA-MPVPE and the predicted
    vertices are moved by the similarity that aligns the keypoints before the F-scores.

    keypoints: [21, 3] metres; vertices: [V, 3] / [V', 3] metres or None.
    """
    scores = {"mpjpe_mm": mpjpe(pred_keypoints, true_keypoints),
              "pa_mpjpe_mm": pa_mpjpe(pred_keypoints, true_keypoints)}
    if pred_vertices is None or true_vertices is None:
        return scores
    pred_v, true_v = _points(pred_vertices, "pred_vertices"), _points(true_vertices,
                                                                       "true_vertices")
    if pred_v.shape == true_v.shape:
        scores["pa_mpvpe_mm"] = pa_mpvpe(pred_v, true_v)
        aligned = procrustes_align(pred_v, true_v)
    else:  # no correspondence (another topology): move the vertices with the keypoints
        aligned = _apply_similarity(_points(pred_keypoints, "pred_keypoints"),
                                    _points(true_keypoints, "true_keypoints"), pred_v)
    for threshold in FSCORE_THRESHOLDS_M:
        scores[f"f{round(threshold * 1e3)}"] = f_score(aligned, true_v, threshold)[0]
    return scores


def _apply_similarity(source: np.ndarray, target: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points`` moved by the similarity that best aligns ``source`` to ``target``."""
    aligned = procrustes_align(source, target)
    # aligned = s R source + t exactly: s R from the centred correspondences (21 keypoints span
    # 3D), t from the means.
    source_c, aligned_c = source - source.mean(0), aligned - aligned.mean(0)
    linear, *_ = np.linalg.lstsq(source_c, aligned_c, rcond=None)
    return (points - source.mean(0)) @ linear + aligned.mean(0)


def interhand_scores(pred_keypoints: Any, true_keypoints: Any) -> dict[str, float]:
    """One hand's InterHand2.6M scores: ``mpjpe_mm`` (wrist aligned), ``pa_mpjpe_mm``."""
    return {"mpjpe_mm": mpjpe(pred_keypoints, true_keypoints),
            "pa_mpjpe_mm": pa_mpjpe(pred_keypoints, true_keypoints)}


@dataclass(frozen=True)
class Prediction:
    """What a predictor returns for one frame (world frame of the dataset, metres)."""

    keypoints: np.ndarray
    """[21, 3] OpenPose order."""
    vertices: np.ndarray | None = None
    """[V, 3] a mesh's vertices (MANO topology for PA-MPVPE), or None."""


@dataclass
class SplitScores:
    """Scores of a predictor over an imported split: per frame, and their means."""

    dataset: str
    frames: list[dict[str, Any]] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    @property
    def means(self) -> dict[str, float]:
        keys = sorted({key for row in self.frames for key in row["scores"]})
        return {key: float(np.mean([row["scores"][key] for row in self.frames
                                    if key in row["scores"]])) for key in keys}

    def to_dict(self) -> dict[str, Any]:
        return {"dataset": self.dataset, "num_frames": len(self.frames),
                "num_failed": len(self.failed), "means": self.means, "frames": self.frames,
                "failed": self.failed}


def evaluate_split(data_dir: str | os.PathLike, split: str,
                   predict: Callable[[FramePaths], Prediction], *,
                   out: str | os.PathLike | None = None, max_frames: int | None = None,
                   log: Callable[[str], None] | None = None) -> SplitScores:
    """Score ``predict`` on every frame of an imported split (FreiHAND scores for a FreiHAND
    import, InterHand2.6M ones otherwise; ground truth: ``params.json`` keypoints and, when
    present, ``mano_mesh.npz`` vertices). A frame whose prediction raises ValueError is counted
    as failed with its message. ``out``: a JSON file for the scores (written atomically, after
    every frame: an interrupted run keeps what it scored). max_frames: the first this many
    frames only. log: called with a line per frame.
    """
    table = read_frame_table(data_dir, split)
    dataset = str(read_json(Path(data_dir) / "dataset.json").get("generator", "unknown"))
    scores = SplitScores(dataset=dataset)
    pairs = list(zip(table.frames, table.frame_keys, strict=True))[:max_frames]
    for number, (paths, key) in enumerate(pairs):
        truth = read_json(paths.params)
        true_keypoints = np.asarray(truth["keypoints"], np.float64)
        try:
            prediction = predict(paths)
            if dataset == "FreiHAND":
                mesh = paths.root / "mano_mesh.npz"
                true_vertices = read_npz(mesh)["vertices"] if mesh.is_file() else None
                row = freihand_scores(prediction.keypoints, true_keypoints,
                                      prediction.vertices, true_vertices)
            else:
                row = interhand_scores(prediction.keypoints, true_keypoints)
        except ValueError as exc:
            scores.failed.append(f"{key}: {exc}")
            if log is not None:
                log(f"[{number + 1}/{len(pairs)}] {key}: failed: {exc}")
            continue
        scores.frames.append({"frame": key, "scores": row})
        if log is not None:
            log(f"[{number + 1}/{len(pairs)}] {key}: " + ", ".join(
                f"{name} {value:.4g}" for name, value in row.items()))
        if out is not None:
            write_json(out, scores.to_dict())
    if out is not None:
        write_json(out, scores.to_dict())
    return scores


def photo_fit_predictor(work_dir: str | os.PathLike, *, keypoints: str = "given",
                        model_path: str | os.PathLike | None = None, device: str = "auto",
                        config: Any = None, view: int = 0) -> Callable[[FramePaths], Prediction]:
    """A predictor that fits each frame's photo with ``lisa fit-photo``'s fitter
    (:func:`lisa_hand.fitting.photo.fit.fit_photo_folder`) and the frame's own camera.

    work_dir: where each fit writes its folder (``work_dir/s000_f000``). keypoints: "given"
    (the frame's ``keypoints.json``: the dataset's 2D keypoints, an oracle-2D setting) or
    "detect" (MediaPipe, the ``[photo]`` extra). model_path, device, config: as the fitter's.
    view: which of the frame's cameras is the photo. The frame's mask is used when it has one.
    -> a callable for :func:`evaluate_split`: keypoints (``keypoints_3d``) and the vertices of
    the fitted ``mesh.ply``, moved from the camera frame to the dataset's world frame.
    """
    from ..data.meshio import load_mesh
    from ..fitting.photo.fit import fit_photo_folder
    from ..geometry.cameras import load_cameras, save_cameras

    if keypoints not in ("given", "detect"):
        raise ValueError(f"keypoints must be 'given' or 'detect', got {keypoints!r}")
    work = Path(work_dir)

    def predict(paths: FramePaths) -> Prediction:
        camera = load_cameras(paths.cameras)[view]
        out = work / f"{paths.root.parent.name}_{paths.root.name}"
        calibration = save_cameras(work / f"{out.name}.cameras.json", [camera])
        mask = paths.mask(camera.name)
        side = str(read_json(paths.params).get("side", "auto"))
        fit_photo_folder(paths.image(camera.name), out, side=side, camera_json=calibration,
                         keypoints_json=paths.keypoints if keypoints == "given" else None,
                         mask_path=mask if mask.is_file() else None, hand=0,
                         model_path=model_path, device=device, progress=False, log=None,
                         config=config)
        record = read_json(out / "keypoints.json")
        rotation = camera.R.double().numpy()
        translation = camera.t.double().numpy()

        def to_world(points: np.ndarray) -> np.ndarray:
            return (np.asarray(points, np.float64) - translation) @ rotation

        vertices = np.asarray(load_mesh(out / "mesh.ply").vertices, np.float64)
        return Prediction(keypoints=to_world(record["keypoints_3d"]),
                          vertices=to_world(vertices))

    return predict
