"""The inputs of a photo fit besides the photo: the hands' 2D keypoints (:class:`PhotoHand`:
detected, :func:`find_hands`; a hand cut by the photo's border has its keypoints outside left
to the fit, :func:`detected_hand`; or read from a ``--keypoints`` file by
:func:`read_given_hands`), a ``--mask``
(:func:`read_given_mask`), and the view the fit sees (:func:`crop_view`: the region around the
hand, as an :class:`~lisa_hand.fitting.images.views.ImageView` with its own camera).

**The ``--keypoints`` file** gives 21 hand keypoints per hand in pixels of the ORIGINAL photo
(upright, i.e. after its EXIF orientation, at full size; continuous coordinates: ``(u, v)``,
``u`` to the right, ``v`` down, pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)``),
in OpenPose / MediaPipe order (:data:`lisa_hand.skeleton.KEYPOINT_NAMES`). Accepted forms (JSON):

* a list of 21 ``[u, v]`` (or ``[u, v, confidence]``: visible where the confidence is > 0);
* ``{"keypoints": [[u, v] x 21], "visible": [21] (optional), "side": "right" | "left"
  (optional), "landmarks_3d": [21, 3] (optional)}``; ``"keypoints"`` may also be [21, 3] with a
  confidence column; ``"landmarks_3d"``: the detector's 3D landmarks (metres, the camera's axes:
  MediaPipe's world landmarks), which settle how the fingers lean toward the camera;
* ``{"hands": [such objects]}`` or a list of such objects: several hands (``--hand N`` picks);
* the package's ``keypoints.json`` of a frame folder (:mod:`lisa_hand.data.keypoints`,
  ``{"views": {name: {"keypoints", "visible"}}}``): the view named like the photo (its stem or
  file name), or its only view; this form also serves several photos at once;
* a ``keypoints.json`` written by ``lisa fit-photo`` (its ``"keypoints_2d_detected"``,
  ``"side"`` and ``"landmarks_3d"``: the detection's fit again);
* OpenPose's JSON (``{"people": [{"hand_right_keypoints_2d": [63 values], ...}]}``: ``x, y,
  confidence`` triples; the side from the key).

At least :data:`MIN_VISIBLE` keypoints must be visible, finite and lie within the photo (up to
:data:`OUTSIDE_MARGIN` of its size beyond its border); keypoints that look normalised to [0, 1]
are refused with a hint.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera
from ...skeleton import NUM_KEYPOINTS
from ..images.views import ImageView
from .mask import hand_scale_px

__all__ = ["find_hands", "detected_hand", "votes_text", "fill_hidden",
           "MIN_VISIBLE", "OUTSIDE_MARGIN", "PhotoHand", "read_given_hands",
           "read_given_mask", "check_hand_size", "CropView", "crop_view"]

MIN_VISIBLE = 8
"""Fewest visible keypoints a given hand must have."""
OUTSIDE_MARGIN = 0.25
"""Visible keypoints may lie this fraction of the photo's width / height beyond its border."""
_FORMS = ("a list of 21 [u, v], {'keypoints': [[u, v] x 21]}, {'hands': [...]}, a frame "
          "folder's keypoints.json ({'views': ...}) or OpenPose's {'people': [...]}")


@dataclass(frozen=True)
class PhotoHand:
    """One hand in a photo: what the fit is given.

    keypoints: [21, 2] float64 pixels of the photo's (downscaled) image (``Photo.image``); rows
    that are not visible hold a stand-in (their nearest visible ancestor) and do not count.
    visible: [21] bool. side: "right", "left" or None (unknown). score: the detector's
    confidence, or None. source: "detected" or the ``--keypoints`` file. detector_keypoints:
    [21, 2] the detector's own keypoints, same pixels, when they differ from ``keypoints`` (the
    wrist moved to the skeleton's: :func:`lisa_hand.data.detect.to_skeleton_wrist`).
    side_votes: (right, left) of the detector's agreeing estimates
    (:attr:`lisa_hand.data.detect.DetectedHand.side_votes`), None when not detected.
    landmarks_3d: [21, 3] metres, the detector's 3D landmarks in the camera's axes
    (:attr:`lisa_hand.data.detect.DetectedHand.landmarks_3d`), or None.
    """

    keypoints: np.ndarray
    visible: np.ndarray
    side: str | None
    score: float | None
    source: str
    detector_keypoints: np.ndarray | None = None
    side_votes: tuple[int, int] | None = None
    landmarks_3d: np.ndarray | None = None

    @property
    def side_split(self) -> bool:
        """The detector's estimates disagree on the side."""
        return self.side_votes is not None and min(self.side_votes) > 0


def _image_factors(photo: Any) -> np.ndarray:
    """[2] image pixels per original pixel along u and v."""
    width, height = photo.original_size
    return np.array([photo.image.shape[1] / width, photo.image.shape[0] / height])


def fill_hidden(keypoints: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Keypoints with every hidden one replaced by its nearest visible ancestor (else the mean
    of the visible ones): harmless stand-ins for the mask's skeleton."""
    filled = keypoints.copy()
    mean = keypoints[visible].mean(0)
    for index in range(NUM_KEYPOINTS):
        if visible[index]:
            continue
        ancestor = index
        while ancestor != 0 and not visible[ancestor]:
            ancestor = 0 if ancestor % 4 == 1 else ancestor - 1
        filled[index] = keypoints[ancestor] if visible[ancestor] else mean
    return filled


def _side(value: Any, where: str) -> str | None:
    if value is None:
        return None
    if value not in ("right", "left"):
        raise ValueError(f"{where}: 'side' must be 'right' or 'left', got {value!r}")
    return value


def _landmarks(values: Any, where: str) -> np.ndarray | None:
    """[21, 3] metres (the detector's 3D landmarks) or None when not given."""
    if values is None:
        return None
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: 'landmarks_3d' must be numbers: [21, 3] metres") from None
    if array.shape != (NUM_KEYPOINTS, 3) or not np.isfinite(array).all():
        raise ValueError(f"{where}: 'landmarks_3d' must be [21, 3] finite metres, got "
                         f"{list(array.shape)}")
    if np.abs(array - array.mean(axis=0)).max() > 0.5:
        raise ValueError(f"{where}: 'landmarks_3d' span more than a metre: they must be metres")
    return array


def _array_hand(values: Any, visible: Any, side: Any, where: str,
                landmarks: Any = None) -> tuple:
    """(keypoints [21, 2], visible [21] bool, side, landmarks [21, 3] or None) from a [21, 2]
    or [21, 3] array (and the 3D landmarks, if given)."""
    try:
        array = np.asarray(values, dtype=np.float64)
        shown = None if visible is None else np.asarray(visible, dtype=np.float64) > 0
    except (TypeError, ValueError):
        raise ValueError(f"{where}: keypoints must be numbers: 21 [u, v] pixels of the "
                         "original photo") from None
    if array.ndim != 2 or array.shape[0] != NUM_KEYPOINTS or array.shape[1] not in (2, 3):
        raise ValueError(f"{where}: keypoints must be [21, 2] pixels (u, v) of the original "
                         f"photo (or [21, 3] with a confidence), got {list(array.shape)}")
    if shown is None:
        shown = array[:, 2] > 0 if array.shape[1] == 3 else np.ones(NUM_KEYPOINTS, bool)
    if shown.shape != (NUM_KEYPOINTS,):
        raise ValueError(f"{where}: 'visible' must be [21], got {list(shown.shape)}")
    return array[:, :2], shown, _side(side, where), _landmarks(landmarks, where)


def _entries(data: Any, path: Path, photo: Any) -> list[tuple]:
    """The hands of a parsed ``--keypoints`` file (see the module docstring)."""
    where = str(path)
    if isinstance(data, list) and data and all(isinstance(item, dict) for item in data):
        return [_array_hand(item.get("keypoints"), item.get("visible"), item.get("side"),
                            f"{where}: hand {index}", item.get("landmarks_3d"))
                for index, item in enumerate(data)]
    if isinstance(data, list):
        return [_array_hand(data, None, None, where)]
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected {_FORMS}")
    if "views" in data:
        return [_frame_view(path, data, photo)]
    if "hands" in data:
        if not isinstance(data["hands"], list) or not data["hands"]:
            raise ValueError(f"{where}: 'hands' must be a non-empty list of hands")
        return _entries(data["hands"], path, photo)
    if "people" in data:
        return _openpose(data["people"], where)
    for key in ("keypoints_2d_detected", "keypoints"):
        if key in data:
            return [_array_hand(data[key], data.get("visible"), data.get("side"), where,
                                data.get("landmarks_3d"))]
    raise ValueError(f"{where}: no keypoints found; expected {_FORMS}")


def _frame_view(path: Path, data: dict, photo: Any) -> tuple:
    """The photo's view of a frame folder's ``keypoints.json``."""
    from ...data.keypoints import read_keypoints

    views = data["views"] if isinstance(data["views"], dict) else {}
    names = [name for name in (photo.path.stem, photo.path.name) if name in views]
    if not names and len(views) == 1:
        names = list(views)
    if not names:
        raise ValueError(f"{path}: no view named {photo.path.stem!r} (the photo's name); "
                         f"views: {', '.join(map(str, views)) or 'none'}")
    entry = read_keypoints(path, names[:1])[names[0]]
    return entry.keypoints, entry.visible, _side(data.get("side"), str(path)), None


def _openpose(people: Any, where: str) -> list[tuple]:
    hands = []
    for person in people if isinstance(people, list) else []:
        for key, side in (("hand_right_keypoints_2d", "right"), ("hand_left_keypoints_2d",
                                                                  "left")):
            values = person.get(key) if isinstance(person, dict) else None
            if values is None:
                continue
            flat = np.asarray(values, dtype=np.float64).reshape(-1)
            if flat.size != 3 * NUM_KEYPOINTS:
                raise ValueError(f"{where}: {key} must hold 63 values (x, y, confidence), got "
                                 f"{flat.size}")
            if (flat[2::3] > 0).any():
                hands.append(_array_hand(flat.reshape(NUM_KEYPOINTS, 3), None, side, where))
    if not hands:
        raise ValueError(f"{where}: no hand with keypoints among OpenPose's 'people'")
    return hands


def _check_in_photo(keypoints: np.ndarray, visible: np.ndarray, photo: Any, where: str) -> None:
    width, height = photo.original_size
    points = keypoints[visible]
    if int(visible.sum()) < MIN_VISIBLE:
        raise ValueError(f"{where}: only {int(visible.sum())} visible keypoint(s); at least "
                         f"{MIN_VISIBLE} of the 21 are needed")
    if not np.isfinite(points).all():
        raise ValueError(f"{where}: visible keypoints hold NaN or inf")
    if points.max() <= 1.5 and max(width, height) > 64:
        raise ValueError(f"{where}: the keypoints look normalised to [0, 1]; give them in "
                         f"pixels of the original photo ({width}x{height}): multiply u by the "
                         "width and v by the height")
    low = -OUTSIDE_MARGIN * np.array([width, height])
    high = (1.0 + OUTSIDE_MARGIN) * np.array([width, height])
    outside = int(((points < low) | (points > high)).any(1).sum())
    if outside:
        raise ValueError(f"{where}: {outside} visible keypoint(s) lie outside the photo "
                         f"({width}x{height} pixels, upright): keypoints must be pixels of the "
                         "original photo")


def read_given_hands(path: str | os.PathLike, photo: Any) -> list[PhotoHand]:
    """The hands of a ``--keypoints`` file for ``photo`` (a
    :class:`lisa_hand.data.photo.Photo`), keypoints converted to ``photo.image``'s pixels.

    Errors (one line naming the file): unreadable JSON, none of the accepted forms, wrong
    shapes, fewer than :data:`MIN_VISIBLE` visible keypoints, non-finite ones, keypoints
    outside the photo or normalised to [0, 1].
    """
    from ...utils.io import read_json

    path = Path(path)
    hands = []
    entries = _entries(read_json(path), path, photo)
    for index, (keypoints, visible, side, landmarks) in enumerate(entries):
        where = f"{path}: hand {index}" if len(entries) > 1 else str(path)
        _check_in_photo(keypoints, visible, photo, where)
        filled = fill_hidden(keypoints, visible)
        hands.append(PhotoHand(keypoints=filled * _image_factors(photo), visible=visible,
                               side=side, score=None, source=str(path), landmarks_3d=landmarks))
    return hands


def read_given_mask(path: str | os.PathLike, photo: Any) -> np.ndarray:
    """A ``--mask`` image -> [H, W] bool at ``photo.image``'s size (nearest-neighbour resize).

    The mask must have the original photo's size (upright) or the downscaled image's; any
    nonzero pixel (of a grey, RGB or RGBA PNG) is the hand. An empty mask is refused.
    """
    from ...data.layout import read_mask
    from .mask import resize_array

    mask = read_mask(path)
    width, height = photo.original_size
    image_size = (photo.image.shape[1], photo.image.shape[0])
    size = (mask.shape[1], mask.shape[0])
    if size not in ((width, height), image_size):
        raise ValueError(f"{path}: mask is {size[0]}x{size[1]} but the photo "
                         f"{photo.path.name} is {width}x{height} (upright)")
    if not mask.any():
        raise ValueError(f"{path}: the mask is empty (no white pixel)")
    if size != image_size:
        mask = resize_array(mask, image_size, nearest=True)
    return mask


def check_hand_size(hand: PhotoHand, photo: Any, min_hand_px: float, label: str) -> None:
    """ValueError when the hand is smaller than ``min_hand_px`` (:func:`hand_scale_px`, about
    the wrist-to-knuckle length, in ``photo.image`` pixels)."""
    size = hand_scale_px(hand.keypoints[hand.visible] if hand.visible.all()
                         else hand.keypoints)
    if size < min_hand_px:
        factor = float(_image_factors(photo).mean())
        raise ValueError(f"{label}: the hand is too small to fit: {size / factor:.0f} pixels "
                         f"from wrist to knuckles in the photo, at least "
                         f"{min_hand_px / factor:.0f} are needed (a photo where the hand is "
                         "larger, or closer to the camera)")


@dataclass(frozen=True)
class CropView:
    """The region of a photo that the fit sees.

    view: the :class:`ImageView` (its camera: the photo's, cropped and scaled; R, t as given).
    box: (x0, y0, x1, y1) integer pixels of ``Photo.image``. factors: [2] view pixels per image
    pixel along u and v.
    """

    view: ImageView
    box: tuple[int, int, int, int]
    factors: np.ndarray

    def to_image(self, points: np.ndarray) -> np.ndarray:
        """[N, 2] view pixels -> ``Photo.image`` pixels."""
        return np.asarray(points, np.float64) / self.factors + self.box[:2]


def crop_view(photo: Any, camera: Camera, hand: PhotoHand, mask: np.ndarray | None,
              name: str, margin: float, max_side: int) -> CropView:
    """The view of the hand: ``photo.image`` cropped to the visible keypoints' box grown by
    ``margin`` hand sizes (:func:`hand_scale_px`) on each side, clipped to the image, and
    scaled so that its long side is at most ``max_side`` pixels;
    ``camera`` (at ``photo.image``'s size) shifted and scaled alike, the keypoints and the mask
    ([H, W] bool of ``photo.image``, or None: a view without a mask) with it.
    """
    from .mask import crop_box, resize_array

    image = photo.image
    scale = hand_scale_px(hand.keypoints)
    x0, y0, x1, y1 = crop_box(image.shape[:2], hand.keypoints[hand.visible], margin * scale)
    factor = min(1.0, max_side / max(x1 - x0, y1 - y0))
    size = (max(int(round((x1 - x0) * factor)), 8), max(int(round((y1 - y0) * factor)), 8))
    factors = np.array([size[0] / (x1 - x0), size[1] / (y1 - y0)])
    crop = np.ascontiguousarray(image[y0:y1, x0:x1])
    if size != (x1 - x0, y1 - y0):
        from PIL import Image

        channels = [np.asarray(Image.fromarray(crop[..., c]).resize(size, Image.BILINEAR))
                    for c in range(3)]
        crop = np.clip(np.stack(channels, -1), 0.0, 1.0).astype(np.float32)
    K = camera.K.double().cpu().clone()
    K[0, 2] -= x0
    K[1, 2] -= y0
    K = torch.diag(torch.tensor([factors[0], factors[1], 1.0], dtype=torch.float64)) @ K
    view_camera = Camera(K=K.float(), R=camera.R.float().cpu(), t=camera.t.float().cpu(),
                         width=size[0], height=size[1], name=name)
    keypoints = (hand.keypoints - [x0, y0]) * factors
    view_mask = None if mask is None else resize_array(mask[y0:y1, x0:x1], size)
    view = ImageView(name=name, camera=view_camera, rgb=torch.from_numpy(crop.copy()),
                     mask=torch.from_numpy(view_mask) if view_mask is not None
                     and view_mask.any() else None,
                     keypoints=torch.as_tensor(keypoints, dtype=torch.float32),
                     visible=torch.from_numpy(hand.visible.copy()),
                     landmarks_3d=None if hand.landmarks_3d is None
                     else torch.as_tensor(hand.landmarks_3d, dtype=torch.float32))
    return CropView(view=view, box=(x0, y0, x1, y1), factors=factors)


def votes_text(hand: PhotoHand) -> str:
    """The detector's side votes in words: "3 right : 1 left"."""
    right, left = hand.side_votes
    return f"{right} right : {left} left"


def find_hands(photo: Any, keypoints_json: Any, config: Any,
                log: Callable[[str], None]) -> list[PhotoHand]:
    """The hands of a photo: from ``keypoints_json`` or detected (errors: no photo extra, no
    hand found)."""
    from ...data import detect

    if keypoints_json is not None:
        return read_given_hands(keypoints_json, photo)
    hint = detect.photo_extra_missing()
    if hint is not None:
        raise ValueError(hint)
    found = detect.detect_hands(photo.image, max_hands=config.max_hands)
    if not found:
        raise ValueError(f"{photo.path}: no hand found (searched the whole photo, zoomed out "
                         "and in crops); pass the 21 keypoints with --keypoints KP.json")
    shift = config.detector_wrist_shift
    hands = [hand for hand in (detected_hand(photo, one, shift, log) for one in found)
             if hand is not None]
    if not hands:
        raise ValueError(f"{photo.path}: every hand found is cut by the photo's border (too "
                         "few of its keypoints inside); pass the 21 keypoints with --keypoints "
                         "KP.json")
    log(f"{photo.path.name}: {len(hands)} hand(s) found ("
        + ", ".join(f"{hand.side} {hand.score:.2f}" + (
            f", split vote {votes_text(hand)}" if hand.side_split else "") for hand in hands) + ")")
    return hands


def detected_hand(photo: Any, hand: Any, shift: float, log: Callable[[str], None]
                   ) -> PhotoHand | None:
    """A detected hand as the fit's input: keypoints outside the photo (a hand cut by its
    border: the detector's guesses) are not visible, said in one line; None (said) when fewer
    than :data:`MIN_VISIBLE` are inside."""
    from ...data import detect

    keypoints = detect.to_skeleton_wrist(hand.keypoints, shift)
    height, width = photo.image.shape[:2]
    inside = ((keypoints >= 0.0) & (keypoints <= [width, height])).all(axis=1)
    where = f"{photo.path.name}: the {hand.side} hand at x {keypoints[:, 0].mean():.0f} px"
    if inside.sum() < MIN_VISIBLE:
        log(f"{where} is cut by the photo's border ({int(inside.sum())} of 21 keypoints inside): "
            "not fitted")
        return None
    if not inside.all():
        log(f"{where} is cut by the photo's border: its {int((~inside).sum())} keypoint(s) "
            "outside are left to the fit's prior")
        keypoints = fill_hidden(keypoints, inside)
    return PhotoHand(keypoints=keypoints, visible=inside, side=hand.side,
                     score=float(hand.score), source="detected",
                     detector_keypoints=np.asarray(hand.keypoints, np.float64) if shift else None,
                     side_votes=tuple(hand.side_votes), landmarks_3d=hand.landmarks_3d)
