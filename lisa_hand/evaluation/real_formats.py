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
  wrist), and after Procrustes alignment, per hand; for the two hands of an interacting frame
  (the importer's two frames of one capture and frame index, ``params.json``'s ``"source"``)
  also MRRPE, the error of the right-to-left root offset
  (:func:`lisa_hand.metrics.keypoints.mrrpe`; :func:`interacting_pairs`).

:func:`evaluate_split` runs a predictor (a callback: frame in, keypoints and optionally vertices
out) over an imported split and averages the scores; a predictor with a ``pair`` method is given
the two hands of an interacting frame at once. :func:`photo_fit_predictor` is the one of
``lisa fit-photo`` with each frame's calibrated camera (FreiHAND's ``K``), fitting the two hands
of an interacting frame in one photo, alone and then together.
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
from ..metrics.keypoints import mpjpe, mrrpe, pa_mpjpe, procrustes_align
from ..utils.io import read_json, write_json

__all__ = ["FSCORE_THRESHOLDS_M", "Prediction", "f_score", "pa_mpvpe", "freihand_scores",
           "interhand_scores", "SplitScores", "interacting_pairs", "evaluate_split",
           "photo_fit_predictor"]

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
    pairs: list[dict[str, Any]] = field(default_factory=list)
    """The two hands of each interacting frame: ``frames`` (right, left) and ``mrrpe_mm``."""

    @property
    def means(self) -> dict[str, float]:
        keys = sorted({key for row in self.frames for key in row["scores"]})
        means = {key: float(np.mean([row["scores"][key] for row in self.frames
                                     if key in row["scores"]])) for key in keys}
        if self.pairs:
            means["mrrpe_mm"] = float(np.mean([pair["mrrpe_mm"] for pair in self.pairs]))
        return means

    def to_dict(self) -> dict[str, Any]:
        return {"dataset": self.dataset, "num_frames": len(self.frames),
                "num_failed": len(self.failed), "means": self.means, "frames": self.frames,
                "pairs": self.pairs, "failed": self.failed}


def interacting_pairs(frames: list[FramePaths]) -> dict[int, tuple[int, int]]:
    """The two hands of each interacting frame of an imported InterHand2.6M split: frames whose
    ``params.json`` ``"source"`` has the same capture and frame index and ``hand_type``
    "interacting", one right and one left -> {frame index: (right's index, left's index)} for
    both frames of every pair."""
    groups: dict[tuple, dict[str, int]] = {}
    for index, paths in enumerate(frames):
        record = read_json(paths.params)
        source = record.get("source") or {}
        if not isinstance(source, dict) or source.get("hand_type") != "interacting":
            continue
        key = (source.get("split"), source.get("capture"), source.get("seq_name"),
               source.get("frame_idx"))
        groups.setdefault(key, {})[str(record.get("side"))] = index
    pairs = {}
    for sides in groups.values():
        if set(sides) == {"right", "left"}:
            for index in sides.values():
                pairs[index] = (sides["right"], sides["left"])
    return pairs


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
    partners = interacting_pairs([paths for paths, _ in pairs]) if dataset != "FreiHAND" else {}
    predicted: dict[int, Prediction] = {}
    for number, (paths, key) in enumerate(pairs):
        truth = read_json(paths.params)
        true_keypoints = np.asarray(truth["keypoints"], np.float64)
        try:
            prediction = _predicted(predict, pairs, partners, predicted, number)
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
        predicted[number] = prediction
        scores.frames.append({"frame": key, "scores": row})
        _score_pair(scores, pairs, partners, predicted, number)
        if log is not None:
            log(f"[{number + 1}/{len(pairs)}] {key}: " + ", ".join(
                f"{name} {value:.4g}" for name, value in row.items()))
        if out is not None:
            write_json(out, scores.to_dict())
    if out is not None:
        write_json(out, scores.to_dict())
    return scores


def _predicted(predict: Callable[[FramePaths], Prediction], pairs: list, partners: dict,
               predicted: dict[int, Prediction], number: int) -> Prediction:
    """Frame ``number``'s prediction: already made with its partner's, made with it (a
    predictor with ``pair``), or made alone."""
    if number in predicted:
        return predicted[number]
    pair = getattr(predict, "pair", None)
    if pair is None or number not in partners:
        return predict(pairs[number][0])
    right, left = partners[number]
    predicted[right], predicted[left] = pair(pairs[right][0], pairs[left][0])
    return predicted[number]


def _score_pair(scores: SplitScores, pairs: list, partners: dict,
                predicted: dict[int, Prediction], number: int) -> None:
    """Once both hands of an interacting frame are scored, their MRRPE."""
    if number not in partners:
        return
    right, left = partners[number]
    done = {row["frame"] for row in scores.frames}
    if number != max(right, left) or not {pairs[right][1], pairs[left][1]} <= done:
        return
    true = [np.asarray(read_json(pairs[index][0].params)["keypoints"], np.float64)
            for index in (right, left)]
    scores.pairs.append({"frames": [pairs[right][1], pairs[left][1]],
                         "mrrpe_mm": mrrpe(predicted[right].keypoints,
                                           predicted[left].keypoints, true[0], true[1])})


class _PhotoFitPredictor:
    """:func:`photo_fit_predictor`'s callable: one frame (``__call__``) or the two hands of an
    interacting frame in one photo (``pair``)."""

    def __init__(self, work_dir: Path, keypoints: str, model_path: Any, device: str,
                 config: Any, view: int) -> None:
        self.work, self.keypoints, self.view = work_dir, keypoints, view
        self.options = {"model_path": model_path, "device": device, "config": config,
                        "progress": False, "log": None}

    def _camera(self, paths: FramePaths, out: Path) -> tuple[Any, Path]:
        from ..geometry.cameras import load_cameras, save_cameras

        camera = load_cameras(paths.cameras)[self.view]
        return camera, save_cameras(self.work / f"{out.name}.cameras.json", [camera])

    @staticmethod
    def _prediction(camera: Any, folder: Path) -> Prediction:
        """The fit in ``folder`` moved from the camera frame to the dataset's world frame."""
        from ..data.meshio import load_mesh

        record = read_json(folder / "keypoints.json")
        rotation = camera.R.double().numpy()
        translation = camera.t.double().numpy()

        def to_world(points: np.ndarray) -> np.ndarray:
            return (np.asarray(points, np.float64) - translation) @ rotation

        vertices = np.asarray(load_mesh(folder / "mesh.ply").vertices, np.float64)
        return Prediction(keypoints=to_world(record["keypoints_3d"]),
                          vertices=to_world(vertices))

    def __call__(self, paths: FramePaths) -> Prediction:
        from ..fitting.photo.fit import fit_photo_folder

        out = self.work / f"{paths.root.parent.name}_{paths.root.name}"
        camera, calibration = self._camera(paths, out)
        mask = paths.mask(camera.name)
        side = str(read_json(paths.params).get("side", "auto"))
        fit_photo_folder(paths.image(camera.name), out, side=side, camera_json=calibration,
                         keypoints_json=paths.keypoints if self.keypoints == "given" else None,
                         mask_path=mask if mask.is_file() else None, hand=0, **self.options)
        return self._prediction(camera, out)

    def pair(self, right: FramePaths, left: FramePaths) -> tuple[Prediction, Prediction]:
        """Both hands of one photo fitted (alone, then together): the right frame's photo and
        camera, each frame's keypoints (given) or both hands detected."""
        from ..data.keypoints import read_keypoints
        from ..fitting.photo.fit import fit_photo_folder
        from ..utils.io import write_json

        out = self.work / f"{right.root.parent.name}_{right.root.name}_pair"
        camera, calibration = self._camera(right, out)
        given = None
        if self.keypoints == "given":
            hands = []
            for paths, side in ((right, "right"), (left, "left")):
                entry = read_keypoints(paths.keypoints, [camera.name])[camera.name]
                hands.append({"keypoints": np.asarray(entry.keypoints).tolist(),
                              "visible": np.asarray(entry.visible).tolist(), "side": side})
            given = write_json(self.work / f"{out.name}.keypoints.json", {"hands": hands})
        reports = fit_photo_folder(right.image(camera.name), out, side="auto",
                                   camera_json=calibration, keypoints_json=given, **self.options)
        found = {report.side: report.folder for report in reports}
        if set(found) != {"right", "left"} or len(reports) != 2:
            raise ValueError(f"{right.root} and {left.root}: the photo fit found "
                             f"{', '.join(report.side for report in reports)} hand(s), not one "
                             "right and one left")
        return (self._prediction(camera, found["right"]),
                self._prediction(camera, found["left"]))


def photo_fit_predictor(work_dir: str | os.PathLike, *, keypoints: str = "given",
                        model_path: str | os.PathLike | None = None, device: str = "auto",
                        config: Any = None, view: int = 0) -> Callable[[FramePaths], Prediction]:
    """A predictor that fits each frame's photo with ``lisa fit-photo``'s fitter
    (:func:`lisa_hand.fitting.photo.fit.fit_photo_folder`) and the frame's own camera.

    work_dir: where each fit writes its folder (``work_dir/s000_f000``). keypoints: "given"
    (the frame's ``keypoints.json``: the dataset's 2D keypoints, an oracle-2D setting) or
    "detect" (MediaPipe, the ``[photo]`` extra). model_path, device, config: as the fitter's
    (``config.fit.joint``: how the two hands of an interacting frame are fitted together;
    ``iters=0``: each alone). view: which of the frame's cameras is the photo. The frame's
    mask is used when it has one (not for the two hands of an interacting frame: one mask).
    -> a callable for :func:`evaluate_split`: keypoints (``keypoints_3d``) and the vertices of
    the fitted ``mesh.ply``, moved from the camera frame to the dataset's world frame; its
    ``pair(right, left)`` fits both hands of an interacting frame in one photo.
    """
    if keypoints not in ("given", "detect"):
        raise ValueError(f"keypoints must be 'given' or 'detect', got {keypoints!r}")
    return _PhotoFitPredictor(Path(work_dir), keypoints, model_path, device, config, view)
