"""Other things in a scan: pieces of it well apart from the hand (a cup beside it, the other
hand, a bit of background), found and left out (``fit_points(others="auto")``).

A crop around a hand often holds more than the hand. The fit's robust penalty shrugs off stray
points, but its global search starts from the cloud's centre and its coverage terms weigh every
point, so a cup beside the hand holding a third of a one-view scan can double the fit's error.
Such a thing is a separate piece: the scan's points are binned into ``link_m``
voxels, the occupied voxels joined with their 26 neighbours into pieces (scipy's ``label``),
and the piece with the most points is taken for the hand. Pieces within ``reach_m`` of it stay
(a fingertip seen apart from its finger, behind another), and so do small ones (under
``min_share`` of the hand's points: the robust penalty shrugs them off, and a thumb tip seen 5 cm
from the rest of a fist is one); the others are left out, unless they hold more than
``max_share`` of the hand's points: then which piece is the hand is not clear (the other hand,
a large object), nothing of them is left out, and they are counted (``Others.unclear``) for the
command to say so. A thing touching the hand (a held cup) is one piece with it and stays. When the
largest piece is larger than any hand (``max_hand_m`` across: a room's wall, a person) it is not
the hand, which then is one of the pieces it would leave out: nothing is (``Others.oversize``),
unless the sensor's position is known (a depth camera's frame, or a one-view scan's viewpoint
found from its points): then the hand is taken to be what is nearest the sensor, as depth-based
hand trackers assume of a hand held out before a person: :func:`nearest_part` keeps the points
within ``hand_reach_m`` of the scan's nearest point *along the scan's surface* (shortest paths
through the occupied voxels, scipy's ``dijkstra``), so that the hand and a stub of the forearm
stay and the body the arm leads to does not, however the hand is turned (``Others.nearest_m``).

A scan of two hands apart (both hands, two people's) is split by :func:`split_hands`, for each hand
to be fitted on its own (``lisa fit-points`` into ``OUT/hand0``, ``OUT/hand1``, or ``--hand N``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HAND_REACH_M", "Others", "OthersConfig", "find_others", "nearest_part", "split_hands"]

HAND_REACH_M = 0.3
"""How far along the scan's surface from its point nearest the sensor a hand is taken to reach
(:func:`nearest_part`), metres: an adult hand from fingertip to wrist is 0.17-0.22 m, a path
through the voxels runs up to 8% longer than on the surface, and a thumb tip nearest the sensor
is further from the little finger's side of the wrist; the rest is a stub of the forearm, which
the fit's wrist cut leaves out."""


@dataclass(frozen=True)
class Others:
    """What :func:`find_others` left out.

    removed: [N] bool, the points of the pieces left out. pieces: how many were. largest:
    points of the largest of them. gap_m: the distance from the hand's piece to the nearest of
    them, metres (inf when none). unclear: far pieces nearly as large as the hand's, kept.
    oversize: the largest piece's size (the diagonal of its bounding box, metres) when it is
    larger than a hand (nothing left out, unless the sensor was known), else None.
    nearest_m: when the hand was taken as the part of the scan nearest the sensor
    (:func:`nearest_part`; ``removed`` is the rest), the distance from the sensor to the scan's
    nearest point, metres; else None.
    """

    removed: np.ndarray
    pieces: int
    largest: int
    gap_m: float
    unclear: int = 0
    oversize: float | None = None
    nearest_m: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready (``params.json``'s "fit")."""
        return {"removed_points": int(self.removed.sum()), "pieces": self.pieces,
                "largest": self.largest, "gap_m": self.gap_m, "unclear": self.unclear,
                "oversize_m": self.oversize, "nearest_m": self.nearest_m}


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
    label 0), or None for fewer than two points (or a cloud tens of metres across)."""
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
    point_labels = labels[tuple(cells.T)]
    return point_labels, np.bincount(point_labels, minlength=count + 1)


def _extent(points: np.ndarray) -> float:
    """The diagonal of the bounding box of points [M, 3], metres."""
    return float(np.linalg.norm(points.max(0) - points.min(0)))


@dataclass(frozen=True)
class OthersConfig:
    """How :func:`find_others` tells the hand's piece of a scan from the rest."""

    link_m: float = 0.01
    """Voxel size, metres: points in touching voxels are one piece (gaps under about a
    centimetre are bridged)."""
    reach_m: float = 0.03
    """Pieces nearer the largest than this stay, metres."""
    min_share: float = 0.05
    """Pieces with fewer points than this share of the largest's stay."""
    max_share: float = 0.6
    """So do those with more (counted as unclear: maybe the other hand)."""
    max_hand_m: float = 0.6
    """The largest piece is taken for the hand only when its bounding box's diagonal is at most
    this, metres (a hand and a forearm in a crop: under half a metre)."""
    hand_reach_m: float = HAND_REACH_M
    """With a sensor, how far the part nearest it may reach along its surface, metres
    (:func:`nearest_part`)."""

    def __post_init__(self) -> None:
        if not (self.link_m > 0 and self.reach_m >= 0):
            raise ValueError(f"link_m must be > 0 and reach_m >= 0, got {self.link_m!r}, "
                             f"{self.reach_m!r}")


def find_others(points, config: OthersConfig | None = None, sensor=None) -> Others | None:
    """The pieces of a scan apart from its largest one (see the module docstring), or None when
    none is.

    points: [N, 3] metres (numpy or torch). config: :class:`OthersConfig` (defaults: None).
    sensor: [3] metres, the sensor's position, or None; with it a scan whose largest piece is
    larger than a hand, or whose piece nearest the sensor reaches on along its surface further
    than ``config.max_hand_m`` from its nearest point (an arm leading to a body), keeps only the
    part nearest the sensor (:func:`nearest_part` with ``config.hand_reach_m``).
    """
    from scipy.spatial import cKDTree

    config = OthersConfig() if config is None else config
    link_m, reach_m, max_hand_m = config.link_m, config.reach_m, config.max_hand_m
    min_share, max_share, hand_reach_m = config.min_share, config.max_share, config.hand_reach_m
    points = _as_points(points)
    pieces = _pieces(points, link_m)
    if pieces is None:
        return None
    point_labels, sizes = pieces
    count = len(sizes) - 1
    hand = int(np.argmax(sizes))
    members = points[point_labels == hand]
    extent = _extent(members)
    if sensor is not None:
        kept, span = nearest_part(points, sensor, link_m, hand_reach_m)
        if max(extent, span) > max_hand_m:
            nearest = float(np.linalg.norm(points[kept] - np.asarray(sensor), axis=1).min())
            return Others(removed=~kept, pieces=0, largest=0, gap_m=float("inf"),
                          oversize=max(extent, span), nearest_m=nearest)
    elif extent > max_hand_m:
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


def nearest_part(points, sensor, link_m: float = 0.01, reach_m: float = HAND_REACH_M,
                 min_points: int = 50) -> tuple[np.ndarray, float]:
    """The part of a scan nearest its sensor (a hand held out before a person; module
    docstring): the points of the piece nearest the sensor within ``reach_m`` of its nearest
    point along the scan's surface, and those of other pieces within ``reach_m`` of that point
    (a fingertip seen apart from its finger).

    points: [N, 3] metres (numpy or torch). sensor: [3] metres. link_m: voxel size, metres (the
    points are binned into voxels, each joined to its 26 neighbours at their centres' distance).
    reach_m: metres (a hand from fingertip to wrist: about 0.2). min_points: the nearest point
    is taken from pieces of at least this many points (a speck or a flying pixel before the
    hand is not it). -> (kept [N] bool, span: how far the nearest piece reaches along its
    surface from its nearest point, metres).
    """
    from scipy.sparse.csgraph import dijkstra

    if not (link_m > 0 and reach_m > 0):
        raise ValueError(f"link_m and reach_m must be > 0, got {link_m!r}, {reach_m!r}")
    points = _as_points(points)
    sensor = np.asarray(sensor, np.float64).reshape(3)
    graph, point_voxel = _voxel_graph(points, link_m)
    pieces = _pieces(points, link_m)
    labels, sizes = pieces if pieces is not None else (np.ones(len(points), np.int64),
                                                       np.array([0, len(points)]))
    eligible = sizes[labels] >= min(min_points, int(sizes.max()))
    distance = np.linalg.norm(points - sensor, axis=1)
    start = np.flatnonzero(eligible)[np.argmin(distance[eligible])]
    along = dijkstra(graph, directed=False, indices=int(point_voxel[start]))[point_voxel]
    near = np.linalg.norm(points - points[start], axis=1) <= reach_m
    kept = (along <= reach_m) | (near & (labels != labels[start]))
    return kept, float(along[np.isfinite(along)].max())


def _voxel_graph(points: np.ndarray, link_m: float):
    """The occupied ``link_m`` voxels of points [N, 3] metres as a graph, each joined to its 26
    neighbours at their centres' distance -> (sparse [M, M] metres, each point's voxel [N])."""
    from scipy.sparse import coo_matrix

    cells = np.floor((points - points.min(0)) / link_m).astype(np.int64)
    shape = cells.max(0) + 2
    keys = (cells[:, 0] * shape[1] + cells[:, 1]) * shape[2] + cells[:, 2]
    voxels, point_voxel = np.unique(keys, return_inverse=True)
    coords = np.stack([voxels // (shape[1] * shape[2]), voxels // shape[2] % shape[1],
                       voxels % shape[2]], 1)
    rows, cols, lengths = [], [], []
    for offset in np.argwhere(np.ones((3, 3, 3), bool)) - 1:
        if tuple(offset) <= (0, 0, 0):  # each pair once: the 13 offsets after (0, 0, 0)
            continue
        moved = coords + offset
        key = (moved[:, 0] * shape[1] + moved[:, 1]) * shape[2] + moved[:, 2]
        found = np.searchsorted(voxels, key).clip(max=len(voxels) - 1)
        hit = (moved >= 0).all(1) & (voxels[found] == key)
        rows.append(np.flatnonzero(hit))
        cols.append(found[hit])
        lengths.append(np.full(int(hit.sum()), link_m * float(np.linalg.norm(offset))))
    graph = coo_matrix((np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(len(voxels), len(voxels))).tocsr()
    return graph, point_voxel.reshape(-1)


def split_hands(points, link_m: float = 0.01, reach_m: float = 0.03, max_share: float = 0.6,
                max_hand_m: float = 0.6, seed: int = 0, support: bool = True,
                found=None) -> list[np.ndarray] | None:
    """The hands of a scan that holds several (both hands, two people's), each to be fitted on
    its own, or None when it holds one.

    The pieces (as :func:`find_others` makes them, after a support plane is left out,
    :func:`.support.find_support`: a desk joins two hands lying on it) that may each be a hand:
    the largest, and the pieces ``reach_m`` or more from it holding more than ``max_share`` of
    its points, each at most ``max_hand_m`` across (what :func:`find_others` keeps as unclear).
    points: [N, 3] metres (numpy or torch). seed: of the support's search; support: False
    leaves the support plane in (``--support none``); found: the support already found (a
    :class:`.support.Support`, its ``removed`` over ``points``), not searched again.
    -> [H] masks [N] bool, largest hand first: the points to fit for each (all but the other
    hands' pieces: the desk and small things stay, for the fit to handle as it does), or None
    when fewer than two pieces may be hands.
    """
    from scipy.spatial import cKDTree

    from .support import find_support

    points = _as_points(points)
    plane = found if found is not None else (find_support(points, seed=seed) if support
                                             else None)
    rest = np.ones(len(points), bool) if plane is None else ~plane.removed
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
