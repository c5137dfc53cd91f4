"""Hands followed through a clip: the detections of every frame joined into tracks, one identity
per hand (:func:`build_tracks`).

A detection joins the track whose last keypoints are nearest (mean keypoint distance, at most
``match_fraction`` of the track's hand size in pixels), whichever side the detector gives it
in that frame: the detector's side flips for a frame now and then, a hand's place does not. A
detection near no track joins the track of its side that is not in the frame (a hand that left
and came back: one identity per side), else starts a new track while there are fewer than
``max_hands``. Each track's side is the majority of its detections' sides, weighed by score.

Short dropouts are bridged: a gap of at most ``bridge_frames`` frames between two detections of
a track is filled by interpolating the keypoints linearly (marked ``bridged``: the pose fit
gives those frames no keypoint term, only the motion prior). A longer gap ends a segment: the
hand is absent there and the next segment starts afresh (same identity, same shape).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...data.detect import DetectedHand
from ...skeleton import NUM_KEYPOINTS

__all__ = ["HandTrack", "build_tracks", "hand_size_px"]


def hand_size_px(keypoints: np.ndarray) -> float:
    """The diagonal of the keypoints' box [21, 2] pixels (a hand's size in the image)."""
    low, high = keypoints.min(axis=0), keypoints.max(axis=0)
    return float(np.hypot(*(high - low)))


@dataclass(frozen=True)
class HandTrack:
    """One hand through the N frames of a clip (rows are the clip's frames, in order).

    keypoints: [N, 21, 2] float64 pixels of the processed frames (NaN where the hand is absent).
    detected: [N] bool, the detector found it there. bridged: [N] bool, interpolated across a
    short dropout. scores: [N] the detector's side confidence (0 where not detected).
    side: "right" or "left" (the majority of its detections). identity: its index among the
    clip's tracks (0, 1 ...), in order of first appearance. landmarks_3d: [N, 21, 3] metres,
    the detector's 3D landmarks (:attr:`lisa_hand.data.detect.DetectedHand.landmarks_3d`; NaN
    where not detected or not given), or None.
    """

    identity: int
    side: str
    keypoints: np.ndarray
    detected: np.ndarray
    bridged: np.ndarray
    scores: np.ndarray
    landmarks_3d: np.ndarray | None = None

    @property
    def present(self) -> np.ndarray:
        """[N] bool: detected or bridged."""
        return self.detected | self.bridged

    def segments(self) -> list[tuple[int, int]]:
        """The runs of frames where the hand is present, as (first, last + 1) row ranges."""
        runs, start = [], None
        for row, here in enumerate(self.present.tolist() + [False]):
            if here and start is None:
                start = row
            elif not here and start is not None:
                runs.append((start, row))
                start = None
        return runs

    def size_px(self) -> float:
        """The median hand size (:func:`hand_size_px`) over its detections, pixels."""
        sizes = [hand_size_px(self.keypoints[row]) for row in np.flatnonzero(self.detected)]
        return float(np.median(sizes)) if sizes else 0.0


@dataclass
class _Open:
    """A track being built."""

    identity: int
    keypoints: np.ndarray  # [N, 21, 2]
    detected: np.ndarray
    scores: np.ndarray
    landmarks: np.ndarray  # [N, 21, 3]
    right: float = 0.0  # summed scores for "right"
    left: float = 0.0
    last: int = -1  # the row of its last detection

    def size(self) -> float:
        return hand_size_px(self.keypoints[self.last])

    def side(self) -> str:
        return "right" if self.right >= self.left else "left"


def _distance(keypoints: np.ndarray, track: _Open) -> float:
    """Mean keypoint distance to the track's last detection, in units of its hand size."""
    last = track.keypoints[track.last]
    return float(np.linalg.norm(keypoints - last, axis=-1).mean()) / max(track.size(), 1.0)


def _assign(hands: Sequence[DetectedHand], tracks: list[_Open], row: int, max_hands: int,
            match_fraction: float, recent: int) -> list[_Open | None]:
    """Each detection's track (None: a new one), greedily by distance over the tracks seen in
    the last ``recent`` frames, then by side over the tracks absent from this frame."""
    pairs = sorted((_distance(hand.keypoints, track), index, number)
                   for index, hand in enumerate(hands) for number, track in enumerate(tracks)
                   if row - track.last <= recent)
    chosen: list[_Open | None] = [None] * len(hands)
    taken: set[int] = set()
    for distance, index, number in pairs:
        if distance <= match_fraction and chosen[index] is None and number not in taken:
            chosen[index] = tracks[number]
            taken.add(number)
    for index, hand in enumerate(hands):
        if chosen[index] is not None:
            continue
        back = [number for number, track in enumerate(tracks)
                if number not in taken and track.side() == hand.side and track.last < row]
        if back:  # the hand of that side came back
            number = max(back, key=lambda n: tracks[n].last)
            chosen[index] = tracks[number]
            taken.add(number)
    return chosen


def build_tracks(detections: Sequence[Sequence[DetectedHand]], *, max_hands: int = 2,
                 bridge_frames: int = 12, match_fraction: float = 1.0) -> list[HandTrack]:
    """Join a clip's detections into tracks (see the module docstring).

    detections: per frame, in order, the hands the detector found (pixels of the processed
    frames). max_hands: at most this many tracks (further detections are dropped).
    bridge_frames: the longest dropout bridged, frames. match_fraction: a detection further
    than this from a track's last keypoints (mean distance over the hand's size) is not that
    hand. -> the tracks, in order of first appearance; [] when no frame has a hand.
    """
    if bridge_frames < 0:
        raise ValueError(f"bridge_frames must be >= 0, got {bridge_frames}")
    count = len(detections)
    tracks: list[_Open] = []
    for row, hands in enumerate(detections):
        chosen = _assign(hands, tracks, row, max_hands, match_fraction, bridge_frames + 1)
        for hand, track in zip(hands, chosen, strict=True):
            if track is None:
                if len(tracks) >= max_hands:
                    continue
                track = _Open(identity=len(tracks),
                              keypoints=np.full((count, NUM_KEYPOINTS, 2), np.nan),
                              detected=np.zeros(count, bool), scores=np.zeros(count),
                              landmarks=np.full((count, NUM_KEYPOINTS, 3), np.nan))
                tracks.append(track)
            if track.detected[row]:
                continue
            track.keypoints[row] = hand.keypoints
            track.detected[row] = True
            track.scores[row] = hand.score
            if hand.landmarks_3d is not None:
                track.landmarks[row] = hand.landmarks_3d
            if hand.side == "right":
                track.right += hand.score
            else:
                track.left += hand.score
            track.last = row
    return [_finish(track, bridge_frames) for track in tracks]


def _finish(track: _Open, bridge_frames: int) -> HandTrack:
    """The open track with its short gaps bridged."""
    keypoints = track.keypoints.copy()
    bridged = np.zeros_like(track.detected)
    rows = np.flatnonzero(track.detected)
    for before, after in zip(rows[:-1], rows[1:], strict=True):
        gap = after - before - 1
        if 0 < gap <= bridge_frames:
            for row in range(before + 1, after):
                weight = (row - before) / (after - before)
                keypoints[row] = (1 - weight) * keypoints[before] + weight * keypoints[after]
                bridged[row] = True
    return HandTrack(identity=track.identity, side=track.side(), keypoints=keypoints,
                     detected=track.detected.copy(), bridged=bridged, scores=track.scores.copy(),
                     landmarks_3d=track.landmarks.copy())
