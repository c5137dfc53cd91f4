"""What the two-hand benchmark (:mod:`benchmarks.two_hands`) reads and scores: a fit's output
folder (``hands.json`` and ``handN/keypoints.json``), the fitted hands matched to the true ones
in the photo, MRRPE, and one fit's result per scene and mode."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FITS = ("together", "alone")


# ------------------------------------------------------------------------------------------------
# Reading a fit's output folder


@dataclass
class FittedHand:
    """One fitted hand of an output folder (arrays None when missing or malformed)."""

    folder: str
    side: str | None
    keypoints_3d: np.ndarray | None
    """[21, 3] metres, camera frame."""
    keypoints_2d: np.ndarray | None
    """[21, 2] pixels of the photo (``keypoints_2d_fitted``)."""


@dataclass
class FitOutput:
    """What a ``fit_photo`` output folder holds."""

    hands: list[FittedHand]
    right_to_left_m: np.ndarray | None = None
    """[3] ``hands.json``'s left wrist minus right wrist, metres."""
    penetration_mm: float | None = None
    """``hands.json``'s deepest penetration between the fitted hands."""
    notes: list[str] = field(default_factory=list)


def _array(value: Any, shape: tuple[int, int]) -> np.ndarray | None:
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        return None
    return array if array.shape == shape else None


def _read_hand(folder: Path, name: str, side: str | None, notes: list[str],
               keypoints_2d: bool) -> FittedHand | None:
    path = folder / "keypoints.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        notes.append(f"{name}: no readable keypoints.json ({type(exc).__name__})")
        return None
    if not isinstance(data, dict):
        notes.append(f"{name}: keypoints.json is not an object")
        return None
    hand = FittedHand(name, side or data.get("side"),
                      _array(data.get("keypoints_3d"), (21, 3)),
                      _array(data.get("keypoints_2d_fitted"), (21, 2)))
    for key, value in (("keypoints_3d", hand.keypoints_3d),
                       ("keypoints_2d_fitted", hand.keypoints_2d if keypoints_2d else 0)):
        if value is None:
            notes.append(f"{name}: {key} missing or not of the expected shape")
    return hand


def read_fit_output(out_dir: Path, keypoints_2d: bool = True) -> FitOutput:
    """The fitted hands of a ``fit_photo`` output folder (see the module docstring): those
    ``hands.json`` lists, else its ``handN`` folders, else the one hand in ``out_dir``.
    keypoints_2d: note those missing (False: a scan's or views' fit, which has none)."""
    out_dir = Path(out_dir)
    notes: list[str] = []
    summary: dict = {}
    if (out_dir / "hands.json").is_file():
        try:
            summary = json.loads((out_dir / "hands.json").read_text())
        except (OSError, json.JSONDecodeError) as exc:
            notes.append(f"hands.json unreadable ({type(exc).__name__})")
        summary = summary if isinstance(summary, dict) else {}
    entries = summary.get("hands") if isinstance(summary.get("hands"), list) else None
    if entries is not None:
        listed = [(str(entry.get("folder", "")), entry.get("side")) for entry in entries
                  if isinstance(entry, dict)]
    else:
        listed = [(path.parent.name, None) for path in sorted(out_dir.glob("*/keypoints.json"))]
        if not listed and (out_dir / "keypoints.json").is_file():
            listed = [("", None)]
        if len(listed) > 1:
            notes.append("no hands.json beside several hand folders")
    hands = [hand for name, side in listed
             if (hand := _read_hand(out_dir / name, name or ".", side, notes,
                                    keypoints_2d)) is not None]
    right_to_left = _array(summary.get("right_to_left_m"), (3,)) if summary else None
    penetration = summary.get("penetration_mm") if summary else None
    if not isinstance(penetration, (int, float)) or isinstance(penetration, bool):
        penetration = None
    if len(hands) > 1 and penetration is None:
        notes.append("no penetration_mm in hands.json")
    return FitOutput(hands, right_to_left, None if penetration is None else float(penetration),
                     notes)


# ------------------------------------------------------------------------------------------------
# Metrics


def mean_distance_px(a: np.ndarray | None, b: np.ndarray) -> float:
    """Mean distance between two [21, 2] keypoint sets over the keypoints finite in both (inf
    when none, or ``a`` is None)."""
    if a is None:
        return math.inf
    finite = np.isfinite(a).all(1) & np.isfinite(b).all(1)
    return float(np.linalg.norm(a[finite] - b[finite], axis=1).mean()) if finite.any() else math.inf


def hand_size_px(keypoints_2d: np.ndarray) -> float:
    """A hand's size in the photo: the longer side of its keypoints' bounding box, pixels."""
    return float((keypoints_2d.max(0) - keypoints_2d.min(0)).max())


def match_hands(fitted: list[np.ndarray | None], true: list[np.ndarray]) -> list[int | None]:
    """Per true hand ([21, 2] pixels), the index of the fitted hand matched to it (the
    assignment of least total mean 2D distance; None: unmatched, or farther than half the true
    hand's size)."""
    from scipy.optimize import linear_sum_assignment

    matched: list[int | None] = [None] * len(true)
    if not fitted or not true:
        return matched
    cost = np.array([[mean_distance_px(f, t) for f in fitted] for t in true])
    rows, columns = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e12))
    for row, column in zip(rows, columns, strict=True):
        if cost[row, column] <= 0.5 * hand_size_px(true[row]):
            matched[row] = int(column)
    return matched


def mrrpe_mm(right_to_left: np.ndarray, true_right_to_left: np.ndarray) -> float:
    """|predicted - true| relative root position (left wrist minus right wrist), mm."""
    return float(np.linalg.norm(np.asarray(right_to_left) - true_right_to_left) * 1000.0)


# ------------------------------------------------------------------------------------------------
# Results


@dataclass
class HandResult:
    """One true hand in one fit: distances mm, NaN when not matched."""

    side: str
    subject: str
    matched: str | None
    """The fitted hand's folder ('.': the output folder itself), or None."""
    fitted_side: str | None
    mpjpe_mm: float
    pa_mpjpe_mm: float
    distance_2d_px: float
    """Mean 2D distance of the match."""


@dataclass
class ModeResult:
    """One fit of a scene (together or alone, from one input mode)."""

    hands_found: int
    """True hands with a matched fitted hand (0-2)."""
    fitted_hands: int
    """Fitted hands in the output (matched or not)."""
    hands: list[HandResult]
    mrrpe_mm: float
    """From the matched hands' wrists (NaN unless both matched)."""
    hands_json_mrrpe_mm: float | None
    """From ``hands.json``'s ``right_to_left_m`` (None: absent)."""
    penetration_mm: float | None
    """``hands.json``'s."""
    seconds: float
    error: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def mpjpe_mm(self) -> float:
        return _mean(hand.mpjpe_mm for hand in self.hands)

    @property
    def pa_mpjpe_mm(self) -> float:
        return _mean(hand.pa_mpjpe_mm for hand in self.hands)


@dataclass
class SceneResult:
    scene: str
    kind: str
    subjects: dict[str, str]
    """Side -> subject."""
    true_penetration_mm: float
    seconds_render: float
    seconds_input: float
    """Making the mode's input (scan, views; 0: the photo, made in ``seconds_render``)."""
    together: ModeResult
    alone: ModeResult


@dataclass
class RealResult:
    photo: str
    hands: int
    """Fitted hand folders."""
    overlay: str | None
    seconds: float
    error: str | None = None


def _mean(values) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan


def failed_fit(seconds: float, error: str) -> ModeResult:
    return ModeResult(0, 0, [], math.nan, None, None, seconds, error=error)


def score_fit(output: FitOutput, photo, seconds: float,
              matched: list[int | None] | None = None) -> ModeResult:
    """Match ``output``'s hands to the photo's true hands (None: by their 2D keypoints; else per
    true hand the fitted hand's index) and score them."""
    from lisa_hand.metrics import mpjpe, pa_mpjpe

    truths = [photo.right, photo.left]
    if matched is None:
        matched = match_hands([hand.keypoints_2d for hand in output.hands],
                              [truth.keypoints_2d for truth in truths])
    results, wrists = [], {}
    for truth, index in zip(truths, matched, strict=True):
        hand = None if index is None else output.hands[index]
        usable = hand is not None and hand.keypoints_3d is not None
        if usable and np.isfinite(hand.keypoints_3d).all():
            wrists[truth.side] = hand.keypoints_3d[0]
            errors = (mpjpe(hand.keypoints_3d, truth.keypoints_3d),
                      pa_mpjpe(hand.keypoints_3d, truth.keypoints_3d))
        else:
            errors = (math.nan, math.nan)
        results.append(HandResult(
            truth.side, truth.subject, None if hand is None else hand.folder,
            None if hand is None else hand.side, *errors,
            math.nan if hand is None or hand.keypoints_2d is None
            else mean_distance_px(hand.keypoints_2d, truth.keypoints_2d)))
    true_relative = photo.left.keypoints_3d[0] - photo.right.keypoints_3d[0]
    relative = (mrrpe_mm(wrists["left"] - wrists["right"], true_relative)
                if len(wrists) == 2 else math.nan)
    from_json = (None if output.right_to_left_m is None
                 else mrrpe_mm(output.right_to_left_m, true_relative))
    return ModeResult(sum(index is not None for index in matched), len(output.hands), results,
                      relative, from_json, output.penetration_mm, seconds,
                      notes=list(output.notes))
