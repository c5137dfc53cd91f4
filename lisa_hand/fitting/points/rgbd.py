"""A depth camera's colour image (RGB-D): the hand found in it, its pixels the depth's mask.

Depth cameras (RealSense, Azure Kinect, a phone's LiDAR) write a colour image beside the depth.
Aligned to the depth camera (RealSense's ``rs.align(rs.stream.depth)``, Azure Kinect's
``transformed color``), its pixels are the depth image's. MediaPipe finds the hand in it (the
photo extra, :mod:`lisa_hand.data.detect`), which gives what the depth alone cannot:
which pixels are the hand's when something else is nearer the sensor or touches it, and which
hand it is. The mask is the detected skeleton drawn with bones a hand size wide
(:func:`~lisa_hand.fitting.photo.mask.keypoint_mask`), grown by :data:`HAND_MARGIN` hand sizes:
generous on purpose, since what it takes in from behind the hand lies apart in depth (pixels
over 0.3 m from the hand's depth are dropped, nearer ones left to the point fit's ``--others``),
while a finger cut off is lost.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import distance_transform_edt

from ...data.depth import DepthFrame, read_depth_image
from ...data.detect import detect_hands, photo_extra_missing
from ...data.photo import read_photo
from ..photo.mask import hand_scale_px, keypoint_mask
from .others import HAND_REACH_M

__all__ = ["HAND_MARGIN", "ColourHand", "find_colour_hand", "with_colour_hand"]

HAND_MARGIN = 0.25
"""How far the mask reaches past the drawn skeleton, in hand sizes (wrist to middle knuckle,
:func:`~lisa_hand.fitting.photo.mask.hand_scale_px`): MediaPipe's fingertips fall a little short
of the real ones, and a bone drawn a hand size wide is not a fat finger's width."""


@dataclass(frozen=True, eq=False)
class ColourHand:
    """The hand found in a colour image registered to a depth image."""

    mask: np.ndarray
    """[H, W] bool: the hand's pixels (grown by :data:`HAND_MARGIN`)."""
    skeleton: np.ndarray
    """[H, W] bool: the detected skeleton as drawn, before it was grown."""
    side: str
    """"right" or "left", as the detector called it."""
    keypoints: np.ndarray
    """[21, 2] float64 pixels, the detected keypoints."""
    note: str
    """One sentence saying what was found."""


def find_colour_hand(colour: str | os.PathLike, size: tuple[int, int], *,
                     side: str | None = None,
                     detect: Callable[[np.ndarray], list[Any]] | None = None) -> ColourHand:
    """Find the hand in ``colour``, a colour image with the depth image's pixels.

    size: (width, height) of the depth image; side: "right" or "left" to take only a hand of
    that side, None: any; detect: what finds the hands in an [H, W, 3] float RGB image (default:
    :func:`~lisa_hand.data.detect.detect_hands`). With several hands, the largest is
    taken. Errors are one line naming the file: another size, no hand, the photo extra missing.
    """
    path = Path(colour)
    photo = read_photo(path, max_side=max(16, max(size)))  # never downscaled below the depth's
    if photo.original_size != tuple(size):
        raise ValueError(f"{path}: the colour image is {photo.original_size[0]}x"
                         f"{photo.original_size[1]} pixels, the depth image {size[0]}x{size[1]}: "
                         "align the colour image to the depth camera first (the same pixels), "
                         "or pass --mask MASK.png")
    if detect is None:
        missing = photo_extra_missing()
        if missing is not None:
            raise ValueError(f"{path}: finding the hand in a colour image needs the photo extra "
                             "(MediaPipe): pip install -e '.[photo]'; or pass --mask MASK.png")
        detect = detect_hands
    hands = list(detect(photo.image))
    found = len(hands)
    if side is not None:
        hands = [one for one in hands if one.side == side]
    if not hands:
        which = f"no {side} hand" if side is not None and found else "no hand"
        raise ValueError(f"{path}: {which} found in the colour image"
                         f"{f' ({found} of the other side)' if found else ''}; "
                         "pass --mask MASK.png instead")
    sizes = [hand_scale_px(np.asarray(one.keypoints, dtype=np.float64)) for one in hands]
    chosen = hands[int(np.argmax(sizes))]
    keypoints = np.asarray(chosen.keypoints, dtype=np.float64)
    height, width = size[1], size[0]
    drawn = keypoint_mask((height, width), keypoints)
    # (the distance transform of an image with no drawn pixel is not a distance: keep none)
    mask = (distance_transform_edt(~drawn) <= HAND_MARGIN * max(sizes)) & drawn.any()
    others = f", the largest of {len(hands)}" if len(hands) > 1 else ""
    note = (f"found a {chosen.side} hand in the colour image {path}{others} (MediaPipe, score "
            f"{chosen.score:.2f}): a mask of {int(mask.sum())} of its {width * height} pixels")
    return ColourHand(mask=mask, skeleton=drawn, side=chosen.side, keypoints=keypoints,
                      note=note)


def with_colour_hand(depth_path: str | os.PathLike, frame: DepthFrame,
                     colour: str | os.PathLike, *, side: str | None = None,
                     detect: Callable[[np.ndarray], list[Any]] | None = None
                     ) -> tuple[DepthFrame, ColourHand]:
    """``frame`` with the mask of the hand found in ``colour`` (:func:`find_colour_hand`; the
    depth image ``depth_path`` gives the size), less the pixels farther than
    :data:`~lisa_hand.fitting.points.others.HAND_REACH_M` in depth from the median depth under the
    drawn skeleton (the room behind the hand) -> (the new frame, what was found)."""
    if frame.mask is not None:
        raise ValueError(f"{colour}: a colour image and a mask both say which pixels are the "
                         "hand's: pass one of them")
    depth = read_depth_image(depth_path, frame.scale_m)
    found = find_colour_hand(colour, (depth.shape[1], depth.shape[0]), side=side, detect=detect)
    drawn = found.skeleton & (depth > 0)
    if not drawn.any():
        raise ValueError(f"{depth_path}: no pixel of the hand found in {colour} has a depth "
                         "(is the colour image aligned to the depth camera?)")
    # The margin also takes in what lies behind the hand: keep what is within a hand's reach of
    # the depth of the pixels under the drawn skeleton (the hand's own, mostly).
    near = np.abs(depth - float(np.median(depth[drawn]))) <= HAND_REACH_M
    mask = found.mask & near
    kept = int((mask & (depth > 0)).sum())
    note = (f"{found.note}; {kept} of them with a depth within {HAND_REACH_M:g} m of the "
            "hand's")
    found = dataclasses.replace(found, mask=mask, note=note)
    return dataclasses.replace(frame, mask=mask), found

