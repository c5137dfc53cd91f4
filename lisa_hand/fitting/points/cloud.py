"""The point cloud a fit runs on: checked tensors, random subsets, its dense part, nearest
distances and a distance grid (the unsigned distance to the cloud anywhere near it)."""

from __future__ import annotations

import functools

import numpy as np
import torch

__all__ = ["TargetCloud", "check_points", "target_cloud", "dense_points", "nearest_distance",
           "CloudDistance"]

_DISTANCE_EPS = 1e-9  # metres^2 inside the square root of a distance (finite gradient at 0)
_GRID_VOXEL = 0.002  # metres, cell of the cloud's distance grid
_GRID_MARGIN = 0.03  # metres around the cloud's bounding box
_GRID_MAX_CELLS = 160  # cells per axis at most (the voxel grows for large clouds)


class TargetCloud:
    """A cloud ready for the fit's stages, with the one random generator of its subsets (the
    stages draw from it in turn, so a seeded fit is deterministic).

    points: [N, 3] world metres; normals: [N, 3] unit outward normals or None (same device and
    dtype); generator: a CPU ``torch.Generator``. For a one-view scan whose sensor position is
    known (:mod:`.free_space`): free, [M, 3] world metres, points the sensor saw to be empty,
    and depth, its :class:`~.free_space.DepthImage`; None otherwise. support: [2, 3] the plane
    the hand rests on (:mod:`.support`): a point on it (metres) and its unit normal towards the
    hand, in this cloud's frame, device and dtype; or None.
    """

    def __init__(self, points: torch.Tensor, normals: torch.Tensor | None,
                 generator: torch.Generator, free: torch.Tensor | None = None,
                 depth=None, support=None) -> None:
        self.points = points
        self.normals = normals
        self.generator = generator
        self.free = free
        self.depth = depth
        self.support = support

    def replace(self, **changes) -> TargetCloud:
        """A copy with the named attributes (``points``, ``normals``, ``free``, ``depth``,
        ``support``) changed; the same generator."""
        fields = dict(points=self.points, normals=self.normals, free=self.free,
                      depth=self.depth, support=self.support)
        unknown = set(changes) - set(fields)
        if unknown:
            raise TypeError(f"TargetCloud has no {', '.join(sorted(unknown))}")
        fields.update(changes)
        copy = TargetCloud(generator=self.generator, **fields)
        if "points" not in changes and "distance_grid" in self.__dict__:  # same points
            copy.__dict__["distance_grid"] = self.__dict__["distance_grid"]
        return copy

    @property
    def num_points(self) -> int:
        return self.points.shape[0]

    def sample(self, count: int) -> torch.Tensor:
        """[min(N, count)] indices of distinct random points (all of them, in order, when the
        cloud has at most ``count``)."""
        num = self.points.shape[0]
        if num <= count:
            return torch.arange(num, device=self.points.device)
        return torch.randperm(num, generator=self.generator)[:count].to(self.points.device)

    @functools.cached_property
    def distance_grid(self) -> CloudDistance:
        """The cloud's :class:`CloudDistance` (built on first use)."""
        return CloudDistance(self.points)


def _to_tensor(value, name: str, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    if isinstance(value, np.ndarray):
        value = torch.from_numpy(np.ascontiguousarray(value))
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"{name} must be a numpy array or torch.Tensor, got "
                        f"{type(value).__name__}")
    if value.dim() != 2 or value.shape[1] != 3:
        raise ValueError(f"{name} must have shape [N, 3], got {list(value.shape)}")
    if not torch.isfinite(value).all():
        raise ValueError(f"{name} holds NaN or inf (drop those points first, e.g. with "
                         "lisa_hand.fitting.points.inputs.prepare_point_cloud)")
    return value.detach().to(device=device, dtype=dtype)


def check_points(points, min_points: int = 20, dtype: torch.dtype = torch.float32,
                 device: torch.device | str = "cpu") -> torch.Tensor:
    """``points`` ([N, 3] metres, numpy or torch) as a tensor on ``device``, or one ValueError
    for a cloud a fit cannot take: not [N, 3], NaN or inf, fewer than ``min_points`` points,
    or sized like centimetres or millimetres (:func:`lisa_hand.data.units.detect_length_unit`)
    or over 2 units across."""
    from ...data.units import POSSIBLE_DIAGONAL_M, UNIT_NAMES, detect_length_unit

    cloud = _to_tensor(points, "points", dtype, torch.device(device))
    if cloud.shape[0] < min_points:
        raise ValueError(f"points: {cloud.shape[0]} points, fewer than the {min_points} "
                         "needed to fit a hand")
    size = float((cloud.amax(0) - cloud.amin(0)).norm())
    unit = detect_length_unit(cloud)
    if unit in ("cm", "mm") or size > POSSIBLE_DIAGONAL_M[1]:
        looks = UNIT_NAMES[unit] if unit in ("cm", "mm") else "millimetres"
        raise ValueError(f"points are {size:.4g} units across, which looks like {looks} "
                         "(a hand is about 0.2 m): convert them to metres")
    return cloud


def target_cloud(points, normals=None, *, dtype: torch.dtype = torch.float32,
                 device: torch.device | str = "cpu", min_points: int = 20,
                 max_points: int = 200_000, seed: int = 0) -> TargetCloud:
    """Check a cloud and make it a :class:`TargetCloud`.

    points: [N, 3] metres, finite (numpy or torch); normals: [N, 3] or None (normalised here).
    A cloud :func:`check_points` refuses is an error; a larger one than ``max_points`` is randomly
    subsampled (seed ``seed``). The subsets' generator is seeded with ``seed``.
    """
    device = torch.device(device)
    cloud = check_points(points, min_points, dtype, device)
    normal_tensor = None
    if normals is not None:
        normal_tensor = _to_tensor(normals, "normals", dtype, device)
        if normal_tensor.shape != cloud.shape:
            raise ValueError(f"normals must have the points' shape {list(cloud.shape)}, got "
                             f"{list(normal_tensor.shape)}")
        normal_tensor = normal_tensor / normal_tensor.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if cloud.shape[0] > max_points:
        generator = torch.Generator(device="cpu").manual_seed(seed)
        keep = torch.randperm(cloud.shape[0], generator=generator)[:max_points].to(device)
        cloud = cloud[keep]
        normal_tensor = None if normal_tensor is None else normal_tensor[keep]
    return TargetCloud(cloud, normal_tensor, torch.Generator(device="cpu").manual_seed(seed))


def dense_points(points: torch.Tensor, neighbours: int = 8, factor: float = 3.0) -> torch.Tensor:
    """The points of a cloud that lie in dense parts (a surface), for a robust centroid and
    principal axes: those whose distance to their ``neighbours``-th nearest neighbour is at most
    ``factor`` times the median of that distance. Scattered outliers have far neighbours.

    points: [N, 3] -> [M, 3] (all of them when N <= neighbours).
    """
    from scipy.spatial import cKDTree

    if points.shape[0] <= neighbours:
        return points
    array = points.detach().cpu().double().numpy()
    distance = cKDTree(array).query(array, k=neighbours + 1)[0][:, -1]
    keep = distance <= factor * np.median(distance)
    return points[torch.from_numpy(keep).to(points.device)]


def point_spacing(points: torch.Tensor) -> float:
    """The median distance (metres) from a point of the cloud points [N, 3] to its nearest
    neighbour: about the side of the surface patch each point stands for (0 for fewer than two
    points)."""
    from scipy.spatial import cKDTree

    if points.shape[0] < 2:
        return 0.0
    array = points.detach().cpu().double().numpy()
    return float(np.median(cKDTree(array).query(array, k=2)[0][:, 1]))


def nearest_distance(cloud: torch.Tensor, proxy: torch.Tensor,
                     normals: torch.Tensor | None = None, tangent_weight: float = 1.0
                     ) -> torch.Tensor:
    """Distance from each cloud point to its nearest proxy point.

    cloud: [K, N, 3]; proxy: [K, P, 3] -> [K, N] metres (differentiable in both; the nearest
    point is chosen without gradient, by the Euclidean distance). normals: [K, P, 3] unit
    normals of the proxy points, or None: then the offset ``r`` from the nearest point counts
    ``sqrt((n . r)^2 + tangent_weight |r - (n . r) n|^2)`` (1: point-to-point, 0:
    point-to-plane).
    """
    with torch.no_grad():
        nearest = torch.cdist(cloud, proxy).argmin(dim=-1)  # [K, N]
    index = nearest[..., None].expand(-1, -1, 3)
    offset = cloud - torch.gather(proxy, 1, index)
    squared = offset.square().sum(-1)
    if normals is not None and tangent_weight != 1.0:
        along = (offset * torch.gather(normals, 1, index)).sum(-1)
        squared = tangent_weight * squared + (1.0 - tangent_weight) * along.square()
    return (squared + _DISTANCE_EPS).sqrt()


class CloudDistance:
    """Unsigned distance to a point cloud on a grid (built once, differentiable lookups).

    The distance from every cell centre to the nearest occupied cell (Euclidean distance
    transform, scipy), read back with trilinear interpolation: error below about one cell
    (2 mm). Points outside the grid read its border (the margin is 3 cm: beyond it everything
    is far). cloud: [N, 3] metres.
    """

    def __init__(self, cloud: torch.Tensor) -> None:
        from scipy.ndimage import distance_transform_edt

        points = cloud.detach().double().cpu().numpy()
        low = points.min(axis=0) - _GRID_MARGIN
        high = points.max(axis=0) + _GRID_MARGIN
        voxel = max(_GRID_VOXEL, float((high - low).max()) / (_GRID_MAX_CELLS - 1))
        dims = np.ceil((high - low) / voxel).astype(np.int64) + 1
        occupied = np.zeros(dims, dtype=bool)
        cells = np.clip(np.rint((points - low) / voxel).astype(np.int64), 0, dims - 1)
        occupied[cells[:, 0], cells[:, 1], cells[:, 2]] = True
        distance = distance_transform_edt(~occupied) * voxel
        # grid_sample reads [N, C, D, H, W] with coordinates (x -> W, y -> H, z -> D): store the
        # x axis last.
        grid = torch.from_numpy(np.ascontiguousarray(distance.transpose(2, 1, 0)))
        self.grid = grid.to(device=cloud.device, dtype=cloud.dtype)[None, None]
        self.low = torch.as_tensor(low, device=cloud.device, dtype=cloud.dtype)
        self.extent = torch.as_tensor((dims - 1) * voxel, device=cloud.device, dtype=cloud.dtype)

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """points: [K, P, 3] metres -> [K, P] metres (differentiable in the points)."""
        count, num = points.shape[:2]
        normalised = 2.0 * (points - self.low) / self.extent - 1.0
        values = torch.nn.functional.grid_sample(
            self.grid.expand(count, -1, -1, -1, -1), normalised[:, :, None, None, :],
            mode="bilinear", padding_mode="border", align_corners=True)
        return values.reshape(count, num)
