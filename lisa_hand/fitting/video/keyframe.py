"""A tracked hand's shape, skeleton and colour from a few keyframes (:func:`choose_keyframes`,
:func:`fit_keyframe`), and the pose that starts each further segment of the track
(:func:`segment_anchor`).

The keyframe is the frame where the hand is seen best: detected (not bridged), every keypoint
inside the frame, the largest hand times the detector's confidence. The further keyframes are
the best-seen frames of the other parts of the track (its detected frames cut into as many
equal runs as keyframes), seen at least half as well: other poses of the same hand. Each is
cut out as a photo is (:mod:`lisa_hand.fitting.photo`: a coarse mask seeded by the keypoints,
the region around the hand as a view). The keypoint stage on the mesh template gives the
first its pose and the clip its first skeleton (:func:`keyframe_start`), which the motion fit
refits on every frame; once the motion is fitted, one image fit on the LISA field takes every
keyframe at its pose (a pose a keyframe, one shape code and colour code:
:func:`lisa_hand.fitting.images.fit.fit_images`'s ``moments``), with its guard
(:func:`fit_keyframe`). The hand it gives keeps its shape code, skeleton and colour code
through the clip.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera
from ...skeleton.params import HandParams
from .tracks import HandTrack

__all__ = ["view_score", "choose_keyframe", "choose_keyframes", "frame_photo", "KeyframeFit",
           "keyframe_views", "keyframe_start", "fit_keyframe", "segment_anchor"]

KEYFRAME_SHARE = 0.5
"""A further keyframe is seen at least this well (size times confidence) as the first."""


def view_score(keypoints: np.ndarray, score: float, width: int, height: int
               ) -> tuple[bool, float]:
    """How well a detected hand is seen: (every keypoint [21, 2] inside the ``width`` x
    ``height`` frame, its size in pixels times the detector's ``score``); larger is better."""
    from .tracks import hand_size_px

    inside = bool((keypoints >= 0).all() and (keypoints[:, 0] < width).all()
                  and (keypoints[:, 1] < height).all())
    return inside, hand_size_px(keypoints) * float(score)


def choose_keyframe(track: HandTrack, width: int, height: int,
                    rows: Sequence[int] | None = None) -> int:
    """The row (of ``rows``, default all) where ``track`` is seen best (module docstring);
    frames with keypoints outside the ``width`` x ``height`` frame count only when no other
    is left."""
    candidates = [row for row in (range(len(track.detected)) if rows is None else rows)
                  if track.detected[row]]
    if not candidates:
        raise ValueError(f"hand {track.identity} is never detected in those frames")
    return max(candidates, key=lambda row: view_score(track.keypoints[row], track.scores[row],
                                                      width, height))


def choose_keyframes(track: HandTrack, width: int, height: int, count: int) -> list[int]:
    """Up to ``count`` rows to fit ``track``'s hand on (module docstring): the best-seen
    first (:func:`choose_keyframe`), then the best of each other part of its detected frames,
    in time order; a part without a frame that shows every keypoint at least
    :data:`KEYFRAME_SHARE` as well as the first gives none."""
    first = choose_keyframe(track, width, height)
    detected = np.flatnonzero(track.detected)
    best = view_score(track.keypoints[first], track.scores[first], width, height)[1]
    others = []
    for part in np.array_split(detected, count) if count > 1 else []:
        if len(part) == 0 or first in part:
            continue
        seen = {int(row): view_score(track.keypoints[row], track.scores[row], width, height)
                for row in part}
        good = [row for row, (inside, score) in seen.items()
                if inside and score >= KEYFRAME_SHARE * best]
        if good:
            others.append(max(good, key=lambda row: seen[row][1]))
    return [first, *sorted(others)]


def frame_photo(path: Any, rgb: np.ndarray, original_size: tuple[int, int], scale: float
                ) -> Any:
    """A processed frame ([h, w, 3] uint8) as the :class:`lisa_hand.data.photo.Photo` the photo
    fit's pieces take (``original_size``: the clip's (W, H); ``scale``: processing pixels per
    original pixel)."""
    from pathlib import Path

    from ...data.photo import Photo

    return Photo(path=Path(path), image=rgb.astype(np.float32) / 255.0,
                 original_size=original_size, scale=scale, focal_35mm=None)


def _photo_hand(track: HandTrack, row: int, side: str) -> Any:
    from ..photo.inputs import PhotoHand

    landmarks = None if track.landmarks_3d is None else track.landmarks_3d[row]
    if landmarks is not None and not np.isfinite(landmarks).all():
        landmarks = None
    return PhotoHand(keypoints=track.keypoints[row].copy(), visible=np.ones(21, bool),
                     side=side, score=float(track.scores[row]), source="detected",
                     landmarks_3d=None if landmarks is None else landmarks.copy())


@dataclass
class KeyframeFit:
    """params: the fitted hand at its (first) keyframe (camera frame, the hand's side). result:
    the image fit's :class:`lisa_hand.fitting.images.fit.FitImagesResult`. mesh: its surface
    with colours and skinning weights, cut at the wrist, specks dropped. notes: what the user
    should know. rows: the keyframes fitted, the first first."""

    params: HandParams
    result: Any
    mesh: Any
    notes: list[str]
    rows: list[int]


def keyframe_views(photos: dict[int, Any], camera: Camera, track: HandTrack,
                   rows: Sequence[int], side: str, config: Any, min_hand_px: float = 16.0
                   ) -> list[Any]:
    """``track``'s hand at its keyframes ``rows`` (:func:`choose_keyframes`; ``photos``: row ->
    :func:`frame_photo`) cut out as photos are (a coarse mask, the region around the hand) ->
    one :class:`~lisa_hand.fitting.images.views.ImageView` a row. config: the keyframes'
    :class:`lisa_hand.fitting.photo.config.FitPhotoConfig`. A hand smaller than
    ``min_hand_px`` (wrist to knuckle, pixels) even at the first is refused (ValueError)."""
    from ..photo.inputs import check_hand_size, crop_view
    from ..photo.mask import coarse_mask, mask_method

    first = rows[0]
    check_hand_size(_photo_hand(track, first, side), photos[first], min_hand_px,
                    f"{photos[first].path} (hand {track.identity} at its best-seen frame, "
                    f"{first})")
    method = mask_method()
    views = []
    for row in rows:
        hand = _photo_hand(track, row, side)
        mask = None if method == "keypoints" else coarse_mask(photos[row].image, hand.keypoints)
        views.append(crop_view(photos[row], camera, hand, mask, f"frame{row}",
                               config.crop_margin, config.view_max_side).view)
    return views


def keyframe_start(view: Any, side: str, config: Any, template: Any, progress: bool
                   ) -> HandParams:
    """The keypoint stage on the first keyframe's ``view`` -> the ``side`` hand whose skeleton
    (betas) starts the clip's and whose pose starts the motion there."""
    from ..photo.fit import keypoint_hand

    return keypoint_hand([view], side, config, template, progress)[0]


def fit_keyframe(model: Any, views: Sequence[Any], starts: Sequence[HandParams],
                 rows: Sequence[int], side: str, config: Any, progress: bool) -> KeyframeFit:
    """One image fit of the hand on its keyframes' ``views`` (:func:`keyframe_views`, a moment
    each: :func:`lisa_hand.fitting.images.fit.fit_images`): the shape and colour codes of the
    clip. starts: the ``side`` hand at each keyframe, at its fitted motion with the clip's
    skeleton (the first :func:`keyframe_start`'s when the motion keeps that skeleton).
    rows: the keyframes' rows."""
    from ...geometry.pieces import drop_specks
    from ...skeleton.wrist import wrist_plane
    from ..images.fit import fit_images
    from ..images.folder import fitted_mesh

    result = fit_images(model, views, config.fit, progress, side=side,
                        start=list(starts) if len(starts) > 1 else starts[0],
                        moments=range(len(views)))
    cut = None if config.wrist_clip_m is None else wrist_plane(result.params,
                                                               config.wrist_clip_m)
    mesh, specks = drop_specks(fitted_mesh(model, result, config.mesh_resolution, cut))
    notes = list(result.notes)
    if specks.count:
        notes.append(specks.note("the hand's mesh"))
    return KeyframeFit(params=result.params, result=result, mesh=mesh, notes=notes,
                       rows=list(rows))


def segment_anchor(photo: Any, camera: Camera, track: HandTrack, row: int, side: str,
                   config: Any, template: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """The pose [48] and translation [3] of ``track``'s hand at ``row`` from the keypoint stage
    alone (the start of a segment that does not hold the keyframe), the hand's side."""
    from ..photo.fit import keypoint_hand
    from ..photo.inputs import crop_view

    crop = crop_view(photo, camera, _photo_hand(track, row, side), None, f"frame{row}",
                     config.crop_margin, config.view_max_side)
    hand, _ = keypoint_hand([crop.view], side, config, template, False)
    return hand.pose, hand.translation
