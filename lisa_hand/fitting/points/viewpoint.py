"""Where a one-view scan was seen from, found from the scan itself (``viewpoint="auto"``).

The free-space terms of a one-view fit (:mod:`.free_space`) need the sensor's position, which
a depth camera's points in its own frame give (the origin) but a cloud that was moved, cropped
or exported from another tool does not. :func:`estimate_viewpoint` finds it from the points:

0. **Noise smoothed first.** A depth camera's 1-2 mm of noise across the surface puts
   neighbours on one surface several millimetres apart in depth, which makes one view look like
   several. Each point is first moved onto the plane of its 16 nearest points, and the gap below
   is at least ``gap_noise`` times the scan's noise (:func:`scan_noise`).
1. **The axis: the direction from which nothing hides.** Seen from its sensor a one-view scan
   is one layer: no point lies behind another. For each of ``num_directions`` directions ``d``
   spread over the sphere, the cloud is projected from a sensor ``distance_m`` from its centre
   along ``d`` (perspective), and a point counts as hidden when one of its ``neighbours``
   nearest neighbours in that image, closer than ``radius_spacings`` times the cloud's point
   spacing (at the centre's range), lies more than ``gap_m`` nearer the sensor. From the best
   direction, refined by local searches, a one-view scan hides only points on surfaces seen
   at grazing angles (a few percent); a scan from all round hides about half of its points from
   any direction, and one that hides more than ``max_hidden`` is not taken for one view.
2. **Which way along it: surfaces bulge towards the sensor.** Fingers, knuckles and the back
   of the hand are convex surfaces seen from outside, so along the axis each point lies on
   average above its surface neighbours on the sensor's side (over points whose neighbours
   surround them, not on the scan's rim). A scan of the opposite, hollow side would be read the
   wrong way; a hand seldom shows one. The median over the points decides, so that stray points
   off the surface do not sway it as they would a mean.
3. **How far: the cloud's own origin when it can be the sensor.** When the origin of the
   cloud's frame lies within ``origin_angle_deg`` of the axis, on the sensor's side, between
   ``origin_range_m`` from the centre (a depth camera's points in its own frame), it is taken;
   else the sensor is put ``distance_m`` from the centre along the axis.

A hand seen nearly edge-on can hide more than ``max_hidden`` from its best direction and is
then left without a viewpoint, as a scan from all round is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ViewpointConfig", "ViewpointEstimate", "estimate_viewpoint", "scan_noise"]


@dataclass(frozen=True)
class ViewpointConfig:
    """How :func:`estimate_viewpoint` searches (see the module docstring)."""

    num_directions: int = 300
    """Directions tried over the whole sphere before the local refinement."""
    distance_m: float = 0.5
    """Sensor distance from the cloud's centre while searching, and of the result unless the
    origin is taken, metres (a depth camera's working range is about 0.3-1 m)."""
    radius_spacings: float = 1.5
    """Image neighbours nearer than this many point spacings can hide a point."""
    neighbours: int = 8
    """Image neighbours looked at per point."""
    gap_m: float = 0.005
    """A neighbour this much nearer the sensor hides a point, metres ..."""
    gap_radii: float = 1.5
    """... or this many times the neighbour radius, when more (a sparse scan's neighbours on
    a sloping surface are farther apart in depth) ..."""
    gap_noise: float = 5.0
    """... or this many times the scan's noise, when more (:func:`scan_noise`: a depth
    camera's 1-2 mm put neighbours on one surface 5 mm apart in depth often enough to make
    one view look like several)."""
    max_hidden: float = 0.15
    """A cloud that hides more than this fraction of its points from its best direction is not
    taken for one view (the estimate's ``one_view`` is False)."""
    max_points: int = 3000
    """The search runs on at most this many of the points (a fixed random subset)."""
    min_points: int = 2000
    """A sparser cloud is not taken for one view (``one_view`` False): with fewer points
    fewer wrong directions show a point behind another, so a wrong axis can look like one view."""
    origin_angle_deg: float = 30.0
    """The cloud's origin is taken as the sensor within this angle of the found axis."""
    origin_range_m: tuple[float, float] = (0.2, 3.0)
    """... and within this distance of the cloud's centre, metres."""
    surface_neighbours: int = 24
    """Surface neighbours of each point for the bulge test (step 2)."""

    def __post_init__(self) -> None:
        if self.num_directions < 6 or self.neighbours < 1 or self.surface_neighbours < 3:
            raise ValueError("ViewpointConfig: num_directions >= 6, neighbours >= 1 and "
                             "surface_neighbours >= 3 are needed")
        if not (self.distance_m > 0 and self.gap_m > 0 and self.radius_spacings > 0):
            raise ValueError("ViewpointConfig: distance_m, gap_m and radius_spacings must be "
                             "positive")


@dataclass(frozen=True)
class ViewpointEstimate:
    """What :func:`estimate_viewpoint` found."""

    position: np.ndarray
    """[3] float64 metres, the sensor position (in the cloud's frame)."""
    direction: np.ndarray
    """[3] unit vector from the cloud's centre towards the sensor."""
    hidden_fraction: float
    """Share of the points hidden behind others seen along the found axis, from the end of it
    that hides fewer (step 1 of the module docstring; 0 for a perfect one-view scan, about half
    for a scan from all round)."""
    one_view: bool
    """``hidden_fraction`` is at most ``ViewpointConfig.max_hidden``: the cloud looks like one
    view, and ``position`` can be given to the fit."""
    at_origin: bool
    """``position`` is the cloud's origin (its own frame looks like the camera's)."""
    num_points: int
    """Points in the cloud (fewer than ``ViewpointConfig.min_points``: not ``one_view``)."""


def _sphere(count: int) -> np.ndarray:
    """[count, 3] unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    ring = np.sqrt(1.0 - z * z)
    angle = math.pi * (1.0 + math.sqrt(5.0)) * index
    return np.stack([ring * np.cos(angle), ring * np.sin(angle), z], axis=1)


def _across(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors [3] that make a right-handed frame with the unit ``axis`` [3]."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(axis, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(axis, first)


def _local_planes(points: np.ndarray, neighbours: int) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
    """The plane that best fits each point's ``neighbours`` nearest points (itself included):
    (centres [N, 3], unit normals [N, 3], mean squared distances to them [N])."""
    from scipy.spatial import cKDTree

    _, index = cKDTree(points).query(points, neighbours)
    centres = points[index].mean(1)
    patches = points[index] - centres[:, None]  # [N, k, 3]
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", patches, patches) / neighbours)
    return centres, vectors[:, :, 0], values[:, 0]


def scan_noise(points: np.ndarray, neighbours: int = 16) -> float:
    """The noise of a scan across its surface, metres: the median over its points of the RMS
    distance of their ``neighbours`` nearest points to the plane that fits them best (corrected
    for the three fitted degrees of freedom). points: [N, 3] metres, N > neighbours. A smooth
    surface's curvature adds to it (about 0.2 mm on a finger at a 1.5 mm point spacing); noise
    near the point spacing is underestimated (the nearest points are those at a like height: 2 mm
    read as 1.3 mm at a 1.6 mm spacing)."""
    return _smoothed(points, neighbours)[1]


def _smoothed(points: np.ndarray, neighbours: int = 16) -> tuple[np.ndarray, float]:
    """(each point moved onto the plane of its ``neighbours`` nearest points [N, 3]: a depth
    camera's noise across the surface cut about fourfold, its shape kept at the scale of a
    finger; the scan's noise, :func:`scan_noise`), from one neighbour search."""
    centres, normals, squared = _local_planes(points, neighbours)
    height = ((points - centres) * normals).sum(1, keepdims=True)
    noise = math.sqrt(max(float(np.median(squared)), 0.0) * neighbours / (neighbours - 3))
    return points - height * normals, noise


def _hidden_fraction(points: np.ndarray, direction: np.ndarray, radius: float,
                     config: ViewpointConfig, noise: float = 0.0) -> float:
    """Share of ``points`` [N, 3] (metres, centred) hidden seen from ``distance_m`` along the
    unit ``direction`` [3] (step 1 of the module docstring), for a scan of ``noise`` metres
    (:func:`scan_noise`)."""
    from scipy.spatial import cKDTree

    rays = points - config.distance_m * direction
    ranges = np.linalg.norm(rays, axis=1)
    along = np.maximum(rays @ -direction, 1e-6)
    first, second = _across(-direction)
    image = np.stack([rays @ first, rays @ second], axis=1) * (config.distance_m / along)[:, None]
    distance, index = cKDTree(image).query(image, config.neighbours + 1,
                                           distance_upper_bound=radius)
    near = np.isfinite(distance[:, 1:])
    neighbour_range = np.append(ranges, np.inf)[index[:, 1:]]
    gap = max(config.gap_m, config.gap_radii * radius, config.gap_noise * noise)
    return float((near & (ranges[:, None] - neighbour_range > gap)).any(1).mean())


def _best_axis(points: np.ndarray, radius: float, config: ViewpointConfig, noise: float
               ) -> tuple[np.ndarray, float]:
    """(the unit direction [3] from which the fewest points hide, that fraction): a search over
    the sphere, then three rounds of the 8 neighbouring directions at shrinking steps."""
    directions = _sphere(config.num_directions)
    hidden = [_hidden_fraction(points, d, radius, config, noise) for d in directions]
    best, fewest = directions[int(np.argmin(hidden))], float(min(hidden))
    step = 0.5 * math.sqrt(4.0 * math.pi / config.num_directions)  # about the lattice spacing
    for _ in range(3):
        first, second = _across(best)
        tried = [best + step * (a * first + b * second)
                 for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b]
        for candidate in tried:
            candidate = candidate / np.linalg.norm(candidate)
            share = _hidden_fraction(points, candidate, radius, config, noise)
            if share < fewest:
                best, fewest = candidate, share
        step *= 0.5
    return best, fewest


def _bulge(points: np.ndarray, axis: np.ndarray, config: ViewpointConfig) -> float:
    """Median height, along the unit ``axis`` [3], of the points of ``points`` [N, 3] over
    their surface neighbours, each in units of its neighbours' spread across the axis; only
    points whose neighbours surround them count, and not those whose neighbours are spread more
    than twice as far as usual (outliers, sparse patches; step 2 of the module docstring): > 0
    when the surface bulges towards ``+axis``."""
    from scipy.spatial import cKDTree

    _, index = cKDTree(points).query(points, config.surface_neighbours + 1)
    index = index[:, 1:]
    first, second = _across(axis)
    image = np.stack([points @ first, points @ second], axis=1)
    height = points @ axis
    offsets = image[index] - image[:, None]  # [N, k, 2]
    spread = np.linalg.norm(offsets, axis=2).mean(1)
    counted = ((np.linalg.norm(offsets.mean(1), axis=1) < 0.25 * spread)
               & (spread < 2.0 * np.median(spread)) & (spread > 0))
    if not counted.any():
        return 0.0
    rise = height - height[index].mean(1)
    return float(np.median(rise[counted] / spread[counted]))


def estimate_viewpoint(points, config: ViewpointConfig | None = None,
                       seed: int = 0, side: np.ndarray | None = None) -> ViewpointEstimate:
    """The sensor position of a one-view scan, from its points (see the module docstring).

    points: [N, 3] metres (numpy or torch), finite, N >= 20. seed: of the subset searched.
    side: [3] a direction the sensor is known to lie along from the points (the normal of the
    desk the hand rests on, :mod:`.support`: the sensor saw its top): the axis is turned
    towards it instead of by the bulge of the surfaces (step 2), which a hand lying palm up
    reads the wrong way (its palm is hollow); None: the bulge decides.
    -> :class:`ViewpointEstimate`; use its ``position`` only when ``one_view``.
    """
    from scipy.spatial import cKDTree

    config = config or ViewpointConfig()
    cloud = np.asarray(points.detach().cpu() if hasattr(points, "detach") else points,
                       dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or cloud.shape[0] < 20:
        raise ValueError(f"points must have shape [N, 3] with N >= 20, got {list(cloud.shape)}")
    if not np.isfinite(cloud).all():
        raise ValueError("points must be finite")
    count = cloud.shape[0]
    if count > config.max_points:
        chosen = np.random.default_rng(seed).choice(cloud.shape[0], config.max_points,
                                                    replace=False)
        cloud = cloud[np.sort(chosen)]
    centre = cloud.mean(0)
    centred, noise = _smoothed(cloud - centre)
    spacing = float(np.median(cKDTree(centred).query(centred, 2)[0][:, 1]))
    radius = config.radius_spacings * max(spacing, 1e-6)
    axis, hidden = _best_axis(centred, radius, config, noise)
    if (_bulge(centred, axis, config) if side is None
            else float(axis @ np.asarray(side, np.float64))) < 0:
        axis = -axis
    to_origin = -centre
    origin_range = float(np.linalg.norm(to_origin))
    low, high = config.origin_range_m
    at_origin = bool(low <= origin_range <= high and to_origin @ axis
                     >= origin_range * math.cos(math.radians(config.origin_angle_deg)))
    position = np.zeros(3) if at_origin else centre + config.distance_m * axis
    return ViewpointEstimate(position=position, direction=axis, hidden_fraction=hidden,
                             one_view=hidden <= config.max_hidden and count >= config.min_points,
                             at_origin=at_origin, num_points=count)
