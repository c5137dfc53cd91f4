"""A tracked hand's shape, skeleton and colour from its keyframe (:func:`choose_keyframe`,
:func:`fit_keyframe`), and the pose that starts each further segment of the track
(:func:`segment_anchor`).

The keyframe is the frame where the hand is seen best: detected (not bridged), every keypoint
inside the frame, the largest hand times the detector's confidence. It is fitted as a photo
is (:mod:`lisa_hand.fitting.photo`: a coarse mask seeded by the keypoints, the region around
the hand as a view, the keypoint stage on the mesh template, the image fit on the LISA field,
its guard); the hand it gives keeps its shape code, skeleton and colour code through the clip.
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

__all__ = ["view_score", "choose_keyframe", "frame_photo", "KeyframeFit", "fit_keyframe",
           "segment_anchor"]


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
    """params: the fitted hand at its keyframe (camera frame, the hand's side). result: the
    image fit's :class:`lisa_hand.fitting.images.fit.FitImagesResult`. mesh: its surface with
    colours and skinning weights, cut at the wrist, specks dropped. notes: what the user
    should know."""

    params: HandParams
    result: Any
    mesh: Any
    notes: list[str]


def fit_keyframe(model: Any, photo: Any, camera: Camera, track: HandTrack, row: int,
                 side: str, config: Any, template: Any, progress: bool,
                 min_hand_px: float = 16.0) -> KeyframeFit:
    """Fit ``track``'s hand at ``row`` as a photo (module docstring). config: the keyframe's
    :class:`lisa_hand.fitting.photo.config.FitPhotoConfig`. A hand smaller than
    ``min_hand_px`` (wrist to knuckle, pixels) even there is refused (ValueError)."""
    from ...geometry.pieces import drop_specks
    from ...skeleton.wrist import wrist_plane
    from ..images.fit import fit_images
    from ..images.folder import fitted_mesh
    from ..photo.fit import keypoint_hand
    from ..photo.inputs import check_hand_size, crop_view
    from ..photo.mask import coarse_mask, mask_method

    hand = _photo_hand(track, row, side)
    check_hand_size(hand, photo, min_hand_px, f"{photo.path} (hand {track.identity} at its "
                    f"best-seen frame, {row})")
    method = mask_method()
    mask = None if method == "keypoints" else coarse_mask(photo.image, hand.keypoints)
    crop = crop_view(photo, camera, hand, mask, f"frame{row}", config.crop_margin,
                     config.view_max_side)
    start, _ = keypoint_hand([crop.view], side, config, template, progress)
    result = fit_images(model, [crop.view], config.fit, progress, side=side, start=start)
    cut = None if config.wrist_clip_m is None else wrist_plane(result.params,
                                                               config.wrist_clip_m)
    mesh, specks = drop_specks(fitted_mesh(model, result, config.mesh_resolution, cut))
    notes = list(result.notes)
    if specks.count:
        notes.append(specks.note("the hand's mesh"))
    return KeyframeFit(params=result.params, result=result, mesh=mesh, notes=notes)


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
