"""Other things in a scan: pieces of it well apart from the hand (a cup beside it, the other
hand, a bit of background), found and left out (``fit_points(others="auto")``).

A crop around a hand often holds more than the hand. The fit's robust penalty shrugs off stray
points, but its global search starts from the cloud's centre and its coverage terms weigh every
point: a cup 15 cm from the WebXR hand, a third of a one-view scan, took the fit from 1.77 to
3.85 mm V2S. Such a thing is a separate piece: the scan's points are binned into ``link_m``
voxels, the occupied voxels joined with their 26 neighbours into pieces (scipy's ``label``),
and the piece with the most points is taken for the hand. Pieces within ``reach_m`` of it stay
(a fingertip seen apart from its finger, behind another), and so do small ones (under
``min_share`` of the hand's points: the robust penalty shrugs them off, and a thumb tip seen 5 cm
from the rest of a fist is one); the others are left out, unless they hold more than
``max_share`` of the hand's points: then which piece is the hand is not clear (the other hand,
a large object), nothing of them is left out, and they are counted (``Others.unclear``) for the
command to say so. A thing touching the hand (a held cup) is one piece with it and stays. When the
largest piece is larger than any hand (``max_hand_m`` across: a room's wall, a person) it is not
the hand, which then is one of the pieces it would leave out: nothing is (``Others.oversize``).

A scan of two hands apart (both hands, two people's) is split by :func:`split_hands`, for each hand
to be fitted on its own (``lisa fit-points`` into ``OUT/hand0``, ``OUT/hand1``, or ``--hand N``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Others", "find_others", "split_hands"]


@dataclass(frozen=True)
class Others:
    """What :func:`find_others` left out.

    removed: [N] bool, the points of the pieces left out. pieces: how many were. largest:
    points of the largest of them. gap_m: the distance from the hand's piece to the nearest of
    them, metres (inf when none). unclear: far pieces nearly as large as the hand's, kept.
    oversize: the largest piece's size (the diagonal of its bounding box, metres) when it is
    larger than a hand (nothing left out), else None.
    """

    removed: np.ndarray
    pieces: int
    largest: int
    gap_m: float
    unclear: int = 0
    oversize: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready (``params.json``'s "fit")."""
        return {"removed_points": int(self.removed.sum()), "pieces": self.pieces,
                "largest": self.largest, "gap_m": self.gap_m, "unclear": self.unclear,
                "oversize_m": self.oversize}


def _as_points(points) -> np.ndarray:
    """[N, 3] float64 numpy points from numpy or torch, checked."""
    points = np.asarray(points.detach().cpu() if hasattr(points, "detach") else points,
                        np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {list(points.shape)}")
    return points


def _pieces(points: np.ndarray, link_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The scan's pieces: points [N, 3] metres binned into ``link_m`` voxels, touching voxels
    (26 neighbours) joined -> (labels [N] int, 1..P; sizes [P + 1], points a label, 0 for
    label 0), or None for fewer than two pieces (or a cloud tens of metres across)."""
    from scipy.ndimage import label

    if len(points) < 2:
        return None
    cells = np.floor((points - points.min(0)) / link_m).astype(np.int64)
    shape = cells.max(0) + 1
    if int(np.prod(shape)) > 50_000_000:  # a cloud tens of metres across: not a hand's crop
        return None
    grid = np.zeros(tuple(shape), bool)
    grid[tuple(cells.T)] = True
    labels, count = label(grid, structure=np.ones((3, 3, 3), bool))
    if count < 2:
        return None
    point_labels = labels[tuple(cells.T)]
    return point_labels, np.bincount(point_labels, minlength=count + 1)


def _extent(points: np.ndarray) -> float:
    """The diagonal of the bounding box of points [M, 3], metres."""
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def find_others(points, link_m: float = 0.01, reach_m: float = 0.03, min_share: float = 0.05,
                max_share: float = 0.6, max_hand_m: float = 0.6) -> Others | None:
    """The pieces of a scan apart from its largest one (see the module docstring), or None when
    none is.

    points: [N, 3] metres (numpy or torch). link_m: voxel size, metres (points in touching
    voxels are one piece: gaps under about a centimetre are bridged). reach_m: pieces nearer
    the largest than this stay, metres. min_share: pieces with fewer points than this share of
    the largest's stay; max_share: so do those with more (counted as unclear). max_hand_m: the
    largest piece is taken for the hand only when its bounding box's diagonal is at most this,
    metres (a hand and a forearm in a crop: under half a metre).
    """
    from scipy.spatial import cKDTree

    if not (link_m > 0 and reach_m >= 0):
        raise ValueError(f"link_m must be > 0 and reach_m >= 0, got {link_m!r}, {reach_m!r}")
    points = _as_points(points)
    pieces = _pieces(points, link_m)
    if pieces is None:
        return None
    point_labels, sizes = pieces
    count = len(sizes) - 1
    hand = int(np.argmax(sizes))
    members = points[point_labels == hand]
    extent = _extent(members)
    if extent > max_hand_m:
        return Others(removed=np.zeros(len(points), bool), pieces=0, largest=0,
                      gap_m=float("inf"), oversize=extent)
    tree = cKDTree(members)
    removed = np.zeros(len(points), bool)
    gaps, left_out, largest, unclear = [], 0, 0, 0
    for piece in range(1, count + 1):
        if piece == hand or sizes[piece] < min_share * sizes[hand]:
            continue
        members = point_labels == piece
        gap = float(tree.query(points[members])[0].min())
        if gap < reach_m:
            continue
        if sizes[piece] > max_share * sizes[hand]:
            unclear += 1
            continue
        removed |= members
        gaps.append(gap)
        left_out += 1
        largest = max(largest, int(sizes[piece]))
    if not (left_out or unclear):
        return None
    return Others(removed=removed, pieces=left_out, largest=largest,
                  gap_m=min(gaps) if gaps else float("inf"), unclear=unclear)


def split_hands(points, link_m: float = 0.01, reach_m: float = 0.03, max_share: float = 0.6,
                max_hand_m: float = 0.6, seed: int = 0) -> list[np.ndarray] | None:
    """The hands of a scan that holds several (both hands, two people's), each to be fitted on
    its own, or None when it holds one.

    The pieces (as :func:`find_others` makes them, after a support plane is left out,
    :func:`.support.find_support`: a desk joins two hands lying on it) that may each be a hand:
    the largest, and the pieces ``reach_m`` or more from it holding more than ``max_share`` of
    its points, each at most ``max_hand_m`` across (what :func:`find_others` keeps as unclear).
    points: [N, 3] metres (numpy or torch). seed: of the support's search.
    -> [H] masks [N] bool, largest hand first: the points to fit for each (all but the other
    hands' pieces: the desk and small things stay, for the fit to handle as it does), or None
    when fewer than two pieces may be hands.
    """
    from scipy.spatial import cKDTree

    from .support import find_support

    points = _as_points(points)
    support = find_support(points, seed=seed)
    rest = np.ones(len(points), bool) if support is None else ~support.removed
    pieces = _pieces(points[rest], link_m)
    if pieces is None:
        return None
    point_labels, sizes = pieces
    largest = int(np.argmax(sizes))
    first = points[rest][point_labels == largest]
    if _extent(first) > max_hand_m:
        return None
    tree = cKDTree(first)
    hands = [largest]
    for piece in np.argsort(-sizes):
        piece = int(piece)
        if piece in (0, largest) or sizes[piece] <= max_share * sizes[largest]:
            continue
        members = points[rest][point_labels == piece]
        if _extent(members) <= max_hand_m and tree.query(members)[0].min() >= reach_m:
            hands.append(piece)
    if len(hands) < 2:
        return None
    labels = np.zeros(len(points), np.int64)
    labels[rest] = point_labels
    return [~np.isin(labels, [other for other in hands if other != hand]) for hand in hands]
