"""The further search of :func:`lisa_hand.data.detect.detect_hands` (its module docstring,
"More hands"): once a search level has found fewer hands than wanted, windows beside each hand,
the image with the hands painted out, one finer crop level, and last the landmark model alone
(:mod:`lisa_hand.data.detect_hidden`). It works with the detector's
window mechanics (:func:`lisa_hand.data.detect._find`); the detector imports it when it first
searches further."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .detect import DetectConfig, Named, Window, _diagonal, _find, _Found, _square

__all__ = ["search_further"]

_BESIDE, _PAINTED, _AFTER = "beside another hand", "another hand painted out", "after another hand"
_DETECTABLE = 0.1  # the smallest hand the palm detector finds well, a share of its input's side


def search_further(hands: Any, pixels: np.ndarray, found: list[_Found], around: list[_Found],
                   levels: list[tuple[str, list[Window]]], index: int, fill: np.ndarray,
                   config: DetectConfig, max_hands: int, landmark: Any = None) -> list[Named]:
    """More hands after level ``index`` found ``found`` (:mod:`lisa_hand.data.detect`, "More
    hands"): with the palm detector ``hands`` (:func:`_palm_search`), then, while fewer than
    ``max_hands`` are known, with the landmark model alone (``landmark``, None: not) around
    every hand (:func:`lisa_hand.data.detect_hidden.search_hidden`)."""
    more = _palm_search(hands, pixels, found, around, levels, index, fill, config, max_hands)
    known = found + [hand for hand, _ in more]
    if landmark is not None and len(known) < max_hands:
        from .detect_hidden import HIDDEN, search_hidden

        more += [(hand, HIDDEN) for hand in
                 search_hidden(landmark, pixels, known, config, max_hands)]
    return more


def _palm_search(hands: Any, pixels: np.ndarray, found: list[_Found], around: list[_Found],
                 levels: list[tuple[str, list[Window]]], index: int, fill: np.ndarray,
                 config: DetectConfig, max_hands: int) -> list[Named]:
    """More hands with the palm detector: beside each hand (``around``: what its refinement
    windows showed besides it), with the hands painted out, again around the new ones; if
    neither finds one, in the coarsest crop level after ``index`` whose crops show a hand
    ``further_smallest`` times the smallest found one at :data:`_DETECTABLE` of their long side
    (the finest where none does; none where the whole image does)."""
    known, fresh, more = list(found), list(found), []
    while fresh and len(known) < max_hands:
        windows = [window for hand in fresh for window in _beside(hand, config)]
        beside, around = _find(hands, pixels, windows, config.refine_side_px, fill, config, known,
                               True, config.mirror, around)
        painted = _painted_out(pixels, known + beside, fill, config)
        hidden, _ = _find(hands, painted, levels[0][1], config.window_side_px, fill, config,
                          known + beside, True)
        fresh = beside + hidden
        known += fresh
        more += [(hand, _BESIDE) for hand in beside] + [(hand, _PAINTED) for hand in hidden]
    smallest = config.further_smallest * min(max(h.box[2] - h.box[0], h.box[3] - h.box[1])
                                             for h in known)
    if (more or len(known) >= max_hands or index + 1 >= len(levels)
            or smallest >= _DETECTABLE * max(pixels.shape[:2])):
        return more
    name, windows = next(((name, windows) for name, windows in levels[index + 1:] if smallest
                          >= _DETECTABLE * max(windows[0][2] - windows[0][0],
                                               windows[0][3] - windows[0][1])), levels[-1])
    # Not painted out: a flat patch beside a neck or a face can make a crop's best "palm" of it.
    small, _ = _find(hands, pixels, windows, config.window_side_px, fill, config, known, True)
    return [(hand, f"{name} {_AFTER}") for hand in small]


def _beside(hand: _Found, config: DetectConfig) -> list[Window]:
    """Square windows :attr:`DetectConfig.beside_context` times the hand's keypoint box, shifted
    by :attr:`DetectConfig.beside_shift` of it left, right, up and down (the refinement windows
    are the ones centred on it)."""
    x0, y0, x1, y1 = hand.box
    length = max(8.0, x1 - x0, y1 - y0)
    shift, side = config.beside_shift * length, config.beside_context * length
    return [_square(0.5 * (x0 + x1) + dx * shift, 0.5 * (y0 + y1) + dy * shift, side)
            for dx, dy in ((-1, 0), (1, 0), (0, -1), (0, 1))]


def _painted_out(pixels: np.ndarray, found: list[_Found], fill: np.ndarray,
                 config: DetectConfig) -> np.ndarray:
    """A copy of the image with each hand's grown keypoint hull filled with ``fill``."""
    from PIL import Image, ImageDraw
    from scipy.spatial import ConvexHull

    mask = Image.new("L", (pixels.shape[1], pixels.shape[0]), 0)
    angles = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    for hand in found:  # the hull of a circle around each keypoint
        radius = max(1.0, config.paint_margin * _diagonal(hand.box))
        points = (hand.keypoints[:, None] + radius * circle[None]).reshape(-1, 2)
        ImageDraw.Draw(mask).polygon(list(map(tuple, points[ConvexHull(points).vertices])), 255)
    painted = pixels.copy()
    painted[np.asarray(mask) > 0] = fill
    return painted
