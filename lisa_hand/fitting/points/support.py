"""The surface a hand rests on (a desk, a turntable, a wall behind it), found in a scan, taken out
of it and kept as a bound.

A depth camera looking at a hand on a desk returns the desk too: in a 30 cm crop around the hand
most of the points. Fitted as they are, the hand is pulled into the desk (``python -m
benchmarks fit --webxr-table none`` shows it).
Such a surface is the largest plane of the cloud, and it is not part of a hand:

* **found** by RANSAC (:func:`find_support`: planes through three random points, the one with
  the most points within ``threshold_m``, refined by least squares on them), and taken only when
  it is a support and not a flat part of the hand: at least ``min_fraction`` of the points on it,
  the points clearly off it (more than two thresholds) nearly all on one side of it (a hand on
  a desk lies above it), and its points spread over an area (convex hull, in the plane) at least
  ``min_spread`` times that of the points off it, and they surround those: in ``min_surround``
  of ``sectors`` directions round them (in the plane) they reach ``reach_m`` past them. The last
  two tell a desk from the flat back of a hand seen from behind, whose other points also lie on
  one side of it: a desk reaches out round the hand, the back or the palm of a hand stays within
  the hand's own outline. (The spread alone is not enough: a plane through the hand, its
  threshold widened by the hand's own thickness, can spread over many times a raised thumb's
  area; such a plane reaches past the rest of the hand in some directions only, a desk or a
  wall in view in all of them.)
* **taken out**: the points within the threshold of it or beyond it (the fit never sees them).
* **kept as a bound** (:func:`support_points`): the hand lies on the side of the points off the
  plane. The fit's proxy stages penalise proxy points beyond the plane, its surface stage asks
  the field to be outside at points just beyond it under the hand, as it does where a sensor saw
  empty space (:mod:`.free_space`); for a one-view scan from above, that bounds the hidden palm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...geometry.planes import Plane

__all__ = ["SupportConfig", "Support", "find_support", "support_points"]


@dataclass(frozen=True)
class SupportConfig:
    """How :func:`find_support` looks for a support plane."""

    threshold_m: float = 0.0025
    """Points within this distance of a plane are on it (a depth sensor's noise at half a metre,
    1-2 mm, with room), or within ``noise_spans`` times the plane's own noise when that is
    larger (:func:`_noise_threshold`), up to ``max_threshold_m``."""
    noise_spans: float = 2.5
    """The plane's points lie within this many standard deviations of its noise."""
    max_threshold_m: float = 0.01
    """The largest threshold the plane's noise may set (a depth camera's noise grows with the
    square of the distance: a wall 70 cm away, 3 mm)."""
    iterations: int = 1000
    """RANSAC planes tried: three random points all on a plane holding a fifth of the cloud
    come once in 125 draws, so such a plane is missed once in about 3000 searches."""
    max_points: int = 20_000
    """RANSAC scores planes on at most this many random points of the cloud."""
    min_fraction: float = 0.2
    """Share of the points the plane must hold (fewer cost the fit little: its robust penalty
    takes them for outliers)."""
    one_side: float = 0.97
    """Share of the points clearly off the plane (beyond twice its threshold, five standard
    deviations of its noise) that must lie on one side of it. Nothing lies behind a desk; a
    plane through a flat hand, its threshold widened by the hand's own thickness, has the hand
    on both sides of it, if only just beyond the threshold (two flat hands side by side, whose
    plane reaches round the few points farther off it)."""
    min_spread: float = 1.5
    """The plane's points must spread over this many times the area of the points off it."""
    min_hand_points: int = 200
    """Points that must be left off the plane (else there is no hand beside it)."""
    min_surround: float = 0.75
    """Share of the directions round the hand (:data:`sectors` of them, in the plane) in which
    the plane's points must reach ``reach_m`` or more beyond the hand's: a desk or a wall
    surrounds the hand, a flat part of the hand (with a forearm, a long one) does not."""
    sectors: int = 12
    """Directions (equal sectors of the plane round the hand) of the ``min_surround`` test."""
    reach_m: float = 0.03
    """How far past the hand the plane's points must reach in a direction, metres."""

    def __post_init__(self) -> None:
        if not 0 < self.threshold_m <= self.max_threshold_m:
            raise ValueError(f"threshold_m must be > 0 (metres) and at most max_threshold_m, "
                             f"got {self.threshold_m!r} and {self.max_threshold_m!r}")
        if not self.noise_spans > 0:
            raise ValueError(f"noise_spans must be > 0, got {self.noise_spans!r}")
        for name in ("iterations", "max_points", "min_hand_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not 0 < self.min_fraction < 1 or not 0.5 < self.one_side <= 1:
            raise ValueError("min_fraction must be in (0, 1) and one_side in (0.5, 1]")
        if not self.min_spread >= 0:
            raise ValueError(f"min_spread must be >= 0, got {self.min_spread!r}")
        if not 0 <= self.min_surround <= 1 or not self.reach_m >= 0:
            raise ValueError(f"min_surround must be in [0, 1] and reach_m >= 0 (metres), got "
                             f"{self.min_surround!r} and {self.reach_m!r}")
        if isinstance(self.sectors, bool) or not isinstance(self.sectors, int) or \
                self.sectors < 1:
            raise ValueError(f"sectors must be a positive integer, got {self.sectors!r}")


@dataclass(frozen=True)
class Support:
    """A support plane found in a cloud.

    plane: its :class:`~lisa_hand.geometry.planes.Plane`, the normal towards the hand.
    removed: [N] bool, the cloud's points on it or beyond it (left out of the fit).
    fraction: share of the cloud's points on the plane. spread: the area of its points over
    that of the points off it (convex hulls in the plane). threshold_m: the distance within
    which points were taken to be on it (:func:`_noise_threshold`), metres. surround: the share
    of the directions round the hand in which it reaches past it (:func:`_surround`).
    """

    plane: Plane
    removed: np.ndarray
    fraction: float
    spread: float
    threshold_m: float = SupportConfig.threshold_m
    surround: float = 1.0

    def to_dict(self) -> dict:
        """JSON-ready (``params.json``'s "fit")."""
        return {**self.plane.to_dict(), "removed_points": int(self.removed.sum()),
                "fraction": self.fraction, "spread": self.spread,
                "threshold_m": self.threshold_m, "surround": self.surround}


def _plane_through(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[T, 3, 3] triples -> (unit normals [T, 3] (zero for degenerate triples), offsets [T]:
    the planes n . x = offset)."""
    normals = np.cross(samples[:, 1] - samples[:, 0], samples[:, 2] - samples[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-12), 0.0)
    return normals, (normals * samples[:, 0]).sum(1)


def _least_squares_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane nearest ``points`` [M, 3] in the least-squares sense -> (unit normal, offset)."""
    centre = points.mean(0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][-1]
    return normal, float(normal @ centre)


def _in_plane(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """[M, 3] points -> [M, 2] their coordinates in the plane of ``normal`` (metres)."""
    axis = np.eye(3)[int(np.argmin(np.abs(normal)))]
    first = np.cross(normal, axis)
    first /= np.linalg.norm(first)
    second = np.cross(normal, first)
    return np.stack([points @ first, points @ second], 1)


def _surround(on: np.ndarray, off: np.ndarray, normal: np.ndarray, sectors: int,
              margin: float) -> float:
    """Share of the ``sectors`` directions round the points off the plane (``off`` [M, 3], the
    hand, projected into the plane, about their centre) in which the plane's points (``on``
    [K, 3]) reach ``margin`` metres or more beyond them: 1 for a desk or a wall round the hand,
    about half or less for a flat part of the hand itself."""
    on_flat, off_flat = _in_plane(on, normal), _in_plane(off, normal)
    centre = off_flat.mean(0)

    def reach(flat: np.ndarray) -> np.ndarray:
        offset = flat - centre
        angle = np.arctan2(offset[:, 1], offset[:, 0])
        sector = np.floor((angle + np.pi) / (2.0 * np.pi) * sectors).astype(np.int64) % sectors
        farthest = np.zeros(sectors)
        np.maximum.at(farthest, sector, np.linalg.norm(offset, axis=1))
        return farthest

    return float(np.mean(reach(on_flat) >= reach(off_flat) + margin))


def _hull_area(points: np.ndarray, normal: np.ndarray) -> float:
    """Area (metres^2) of the convex hull of ``points`` [M, 3] projected into the plane of
    ``normal``; 0 for fewer than three points or a degenerate set."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 3:
        return 0.0
    flat = _in_plane(points, normal)
    try:
        return float(ConvexHull(flat).volume)  # a 2D hull's "volume" is its area
    except QhullError:
        return 0.0


def _noise_threshold(distance: np.ndarray, config: SupportConfig) -> float:
    """The distance (metres) within which points are on a plane: ``config.threshold_m``, or
    ``noise_spans`` standard deviations of the plane's noise when larger, at most
    ``max_threshold_m``. distance: [N] signed distances of the cloud's points to the plane. The
    noise is a robust one (1.4826 times the median absolute distance) of the points within
    ``max_threshold_m`` of the plane: most of them are the plane's, whose noise sets it, and the
    few of a hand touching it barely move a median."""
    band = np.abs(distance[np.abs(distance) <= config.max_threshold_m])
    if len(band) < 3:
        return config.threshold_m
    sigma = 1.4826 * float(np.median(band))
    return float(min(max(config.threshold_m, config.noise_spans * sigma),
                     config.max_threshold_m))


def find_support(points, config: SupportConfig | None = None, seed: int = 0
                 ) -> Support | None:
    """The support plane of a cloud, or None when it has none (see the module docstring).

    points: [N, 3] world metres (numpy or torch). seed: the RANSAC draws'.
    """
    config = SupportConfig() if config is None else config
    points = np.asarray(points.detach().cpu().double().numpy()
                        if isinstance(points, torch.Tensor) else points, np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {list(points.shape)}")
    count = len(points)
    if count < config.min_hand_points + 3:
        return None
    rng = np.random.default_rng(seed)
    scored = points[rng.choice(count, min(count, config.max_points), replace=False)]
    triples = scored[rng.integers(0, len(scored), (config.iterations, 3))]
    normals, offsets = _plane_through(triples)
    best, best_hits = None, 0
    for chunk in range(0, config.iterations, 50):  # [50, M] distances at a time
        near = np.abs(scored @ normals[chunk:chunk + 50].T - offsets[chunk:chunk + 50])
        hits = (near <= config.threshold_m).sum(0) * (np.abs(normals[chunk:chunk + 50]).sum(1)
                                                      > 0)
        if hits.max() > best_hits:
            best_hits, best = int(hits.max()), chunk + int(hits.argmax())
    if best is None:
        return None
    normal, offset = normals[best], offsets[best]
    threshold = config.threshold_m
    for _ in range(3):  # least squares on the plane's points, its noise, then count again
        on = np.abs(points @ normal - offset) <= threshold
        if on.sum() < 3:
            return None
        normal, offset = _least_squares_plane(points[on])
        threshold = _noise_threshold(points @ normal - offset, config)
    distance = points @ normal - offset
    on = np.abs(distance) <= threshold
    off = np.abs(distance) > 3.0 * threshold
    if on.mean() < config.min_fraction or off.sum() < config.min_hand_points:
        return None
    clear = np.abs(distance) > 2.0 * threshold  # beyond the plane's noise (5 sigmas of it)
    above = float((distance[clear] > 0).mean())
    if max(above, 1.0 - above) < config.one_side:
        return None
    if above < 0.5:  # the normal towards the hand
        normal, offset, distance = -normal, -offset, -distance
    spread = _hull_area(points[on], normal) / max(_hull_area(points[off], normal), 1e-12)
    if spread < config.min_spread:
        return None
    surround = _surround(points[on], points[off], normal, config.sectors, config.reach_m)
    if surround < config.min_surround:
        return None
    removed = distance <= threshold
    return Support(plane=Plane(normal * offset, normal), removed=removed,
                   fraction=float(on.mean()), spread=float(spread), threshold_m=threshold,
                   surround=surround)


def support_points(plane: Plane, hand_points: torch.Tensor, count: int,
                   generator: torch.Generator, depth_m: tuple[float, float] = (0.002, 0.008)
                   ) -> torch.Tensor:
    """[count, 3] points just beyond the support ``plane`` under the hand: the ``hand_points``
    ([N, 3] world metres, the cloud left after :func:`find_support`) projected onto it and moved
    ``depth_m`` (uniform) beyond it, where the field must be outside. Same device and dtype as
    ``hand_points``; drawn from ``generator`` (CPU)."""
    like = dict(device=hand_points.device, dtype=hand_points.dtype)
    normal = torch.as_tensor(plane.normal).to(**like)
    origin = torch.as_tensor(plane.point).to(**like)
    pick = torch.randint(0, hand_points.shape[0], (count,), generator=generator)
    chosen = hand_points[pick.to(hand_points.device)]
    height = (chosen - origin) @ normal
    low, high = depth_m
    beyond = low + (high - low) * torch.rand(count, generator=generator).to(**like)
    return chosen - (height + beyond)[:, None] * normal
