"""Mesh extraction from a signed distance callback: coarse-to-fine marching cubes.

The mesher only sees ``sdf_fn(points [N, 3] metres) -> sdf [N] metres``, so it is tested on
analytic fields before it meets a network. It evaluates the field on a grid of
``resolution`` samples a side, but only where the surface can be: a hierarchy of blocks is tested
at their centres with the Lipschitz bound of the field,

    |f(p) - level| >= |f(c) - level| - L |p - c|,

and a block whose centre value is far from the level set (further than ``L`` times its half
diagonal plus one cell diagonal) cannot contain the surface, nor touch a grid cell that does. Such
blocks get a value of the right sign without being evaluated; the others are split in eight until
blocks of two cells. Their grid points are evaluated unless the block centres around them (one
cell away at most) prove them further than one cell diagonal from the level set. Every grid cell
that marching cubes turns into triangles has all its corners within one cell diagonal of the
surface, so it has all eight corners evaluated as the dense grid would have them, and the mesh
equals the dense one (same faces, same vertices up to the callback's float rounding) whenever
``lipschitz`` bounds the field's gradient norm. Marching cubes itself (skimage, Lewiner) runs on
the dense array, masked to the evaluated points.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from .fields import SdfFn, check_sdf_output

__all__ = [
    "Mesh",
    "MeshExtraction",
    "extract_mesh",
    "extract_mesh_with_stats",
    "mesh_attributes",
    "colors_to_uint8",
    "sample_triangles",
]

# Blocks of this many cells a side end the hierarchy: their centre is a grid point (reused), and
# their 2^3 owned grid points are evaluated when they may touch the surface.
_FINEST_BLOCK = 2
# Relative slack on the Lipschitz bound, for float32 rounding of the field and of the coordinates.
_BOUND_SLACK = 1e-3


@dataclass
class Mesh:
    """A triangle mesh in the world frame.

    vertices: [V, 3] float32 metres.
    faces: [F, 3] int64 vertex indices, counter-clockwise seen from outside (normals point to
        positive SDF).
    colors: [V, 3] uint8 RGB, or None.
    skin_weights: [V, J] float32 per-vertex skinning weights (rows sum to 1 for LBS), or None.

    Arrays are converted to these dtypes on construction; shapes and index ranges are checked.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None
    skin_weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(_as_numpy(self.vertices, "vertices"), np.float32)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape [V, 3], got {self.vertices.shape}")
        num_vertices = self.vertices.shape[0]
        faces = _as_numpy(self.faces, "faces")
        if faces.size == 0:
            faces = faces.reshape(0, 3)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must have shape [F, 3], got {faces.shape}")
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            raise TypeError(f"faces must hold integer vertex indices, got dtype {faces.dtype}")
        self.faces = np.ascontiguousarray(faces, np.int64)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= num_vertices):
            raise ValueError(
                f"faces index vertices in [{self.faces.min()}, {self.faces.max()}], outside "
                f"[0, {num_vertices}) for {num_vertices} vertices"
            )
        if self.colors is not None:
            colors = _as_numpy(self.colors, "colors")
            if colors.shape != (num_vertices, 3):
                raise ValueError(
                    f"colors must have shape [V, 3] = [{num_vertices}, 3], got {colors.shape}"
                )
            if colors.dtype != np.uint8:
                raise TypeError(
                    f"colors must be uint8 (0-255), got {colors.dtype}; see colors_to_uint8"
                )
            self.colors = np.ascontiguousarray(colors)
        if self.skin_weights is not None:
            weights = _as_numpy(self.skin_weights, "skin_weights")
            if weights.ndim != 2 or weights.shape[0] != num_vertices:
                raise ValueError(
                    f"skin_weights must have shape [V, J] with V = {num_vertices}, "
                    f"got {weights.shape}"
                )
            self.skin_weights = np.ascontiguousarray(weights, np.float32)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])


@dataclass
class MeshExtraction:
    """Result of :func:`extract_mesh_with_stats`: the mesh and where the time went."""

    mesh: Mesh
    num_evaluations: int
    """SDF evaluations made (block centres plus grid points)."""
    num_grid_points: int
    """``resolution ** 3``: what dense evaluation would have cost."""
    seconds_evaluation: float
    """Wall time inside ``sdf_fn`` calls (including moving results to the CPU)."""
    seconds_marching_cubes: float
    seconds_total: float
    level_evaluations: list[int] = field(default_factory=list)
    """Evaluations per level of the hierarchy, coarse to fine (the last one: grid points)."""


def extract_mesh(
    sdf_fn: SdfFn,
    bbox_min: Sequence[float] | np.ndarray | torch.Tensor,
    bbox_max: Sequence[float] | np.ndarray | torch.Tensor,
    resolution: int,
    *,
    coarse_resolution: int | None = None,
    level: float = 0.0,
    lipschitz: float = 1.0,
    chunk_size: int = 65536,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    progress: bool = False,
) -> Mesh:
    """Extract the ``level`` set of ``sdf_fn`` inside a box as a triangle mesh (marching cubes).

    sdf_fn: callback ``points [N, 3] metres (dtype, device) -> sdf [N] or [N, 1] metres``,
        negative inside. Called under ``torch.no_grad()`` on chunks of at most ``chunk_size``
        points. With the hierarchy on, it is also called at block centres up to one coarse
        block outside the box (on the high side).
    bbox_min, bbox_max: [3] metres, the box corners; the grid's first and last samples lie on them.
    resolution: grid samples per axis (>= 2); voxel size ``(bbox_max - bbox_min) / (resolution-1)``.
    coarse_resolution: blocks per axis of the coarsest level of the hierarchy, rounded so that a
        block is a power of two cells (None: about 8). ``coarse_resolution >= resolution`` (or a
        value that rounds to blocks of one cell) turns the hierarchy off: every grid point is
        evaluated, the dense reference.
    level: the iso-value, metres.
    lipschitz: an upper bound of ``|grad sdf|`` in the box: 1 for an exact SDF and for min/max
        or smooth-min unions of exact SDFs. The result equals dense evaluation when it holds; an
        underestimate can lose thin parts. For a neural field, measure the gradient norm in the
        box and add a margin; a larger value only costs evaluations.
    device, dtype: where and in what precision the query points are built (default CPU float32).
    progress: show a tqdm bar per level.

    Returns a :class:`Mesh` with world-frame float32 vertices and outward-facing triangles (no
    colours, no weights: see :func:`mesh_attributes`). Not differentiable. Raises ValueError when
    the level set is not in the box.
    """
    return extract_mesh_with_stats(
        sdf_fn, bbox_min, bbox_max, resolution, coarse_resolution=coarse_resolution,
        level=level, lipschitz=lipschitz, chunk_size=chunk_size, device=device, dtype=dtype,
        progress=progress,
    ).mesh


def extract_mesh_with_stats(
    sdf_fn: SdfFn,
    bbox_min: Sequence[float] | np.ndarray | torch.Tensor,
    bbox_max: Sequence[float] | np.ndarray | torch.Tensor,
    resolution: int,
    *,
    coarse_resolution: int | None = None,
    level: float = 0.0,
    lipschitz: float = 1.0,
    chunk_size: int = 65536,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    progress: bool = False,
) -> MeshExtraction:
    """:func:`extract_mesh` that also reports evaluation counts and timings (for benchmarks)."""
    start = time.perf_counter()
    bbox_min_np = _check_vector3(bbox_min, "bbox_min")
    bbox_max_np = _check_vector3(bbox_max, "bbox_max")
    if not np.all(bbox_max_np > bbox_min_np):
        raise ValueError(
            f"bbox_max must be greater than bbox_min on every axis, got bbox_min="
            f"{bbox_min_np.tolist()} and bbox_max={bbox_max_np.tolist()}"
        )
    resolution = _check_int(resolution, "resolution", minimum=2)
    chunk_size = _check_int(chunk_size, "chunk_size", minimum=1)
    if coarse_resolution is not None:
        coarse_resolution = _check_int(coarse_resolution, "coarse_resolution", minimum=2)
    if not (isinstance(lipschitz, (int, float)) and math.isfinite(lipschitz) and lipschitz > 0):
        raise ValueError(f"lipschitz must be a positive finite number, got {lipschitz!r}")
    if not math.isfinite(float(level)):
        raise ValueError(f"level must be finite, got {level!r}")
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    if not callable(sdf_fn):
        raise TypeError(f"sdf_fn must be callable, got {type(sdf_fn).__name__}")

    evaluator = _GridEvaluator(
        sdf_fn, bbox_min_np, (bbox_max_np - bbox_min_np) / (resolution - 1), chunk_size,
        torch.device(device) if device is not None else torch.device("cpu"), dtype, progress,
    )
    num_cells = resolution - 1
    top_block = _top_block_size(num_cells, coarse_resolution)
    if top_block < _FINEST_BLOCK:
        volume, mask, level_counts = _dense_volume(evaluator, resolution)
    else:
        volume, mask, level_counts = _hierarchical_volume(
            evaluator, resolution, top_block, float(level), float(lipschitz)
        )

    _check_level_in_volume(volume, float(level), bbox_min_np, bbox_max_np)
    mc_start = time.perf_counter()
    vertices_index, faces = _marching_cubes(volume, float(level), mask)
    seconds_mc = time.perf_counter() - mc_start
    vertices = bbox_min_np + vertices_index.astype(np.float64) * evaluator.spacing
    mesh = Mesh(vertices=vertices.astype(np.float32), faces=faces)
    return MeshExtraction(
        mesh=mesh,
        num_evaluations=evaluator.num_evaluations,
        num_grid_points=resolution**3,
        seconds_evaluation=evaluator.seconds,
        seconds_marching_cubes=seconds_mc,
        seconds_total=time.perf_counter() - start,
        level_evaluations=level_counts,
    )


def mesh_attributes(
    vertices: np.ndarray | torch.Tensor,
    attr_fn: Callable[[torch.Tensor], torch.Tensor],
    chunk_size: int = 65536,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> np.ndarray:
    """Evaluate a per-point attribute (colour, skinning weights) at mesh vertices, in chunks.

    vertices: [V, 3] metres (numpy or torch).
    attr_fn: callback ``points [N, 3] metres (dtype, device) -> [N] or [N, C]``, called under
        ``torch.no_grad()`` on at most ``chunk_size`` points at a time.
    device, dtype: where and in what precision the points are passed (default: the device of a
        torch ``vertices``, else CPU; float32).

    Returns [V, C] float32 (C = 1 for a scalar attribute). Colours in [0, 1] become the uint8
    that :class:`Mesh` stores with :func:`colors_to_uint8`.
    """
    if isinstance(vertices, torch.Tensor):
        if device is None:
            device = vertices.device
        points = vertices.detach()
    else:
        points = torch.from_numpy(np.asarray(vertices))
    if points.dim() != 2 or points.shape[1] != 3:
        raise ValueError(f"vertices must have shape [V, 3], got {tuple(points.shape)}")
    chunk_size = _check_int(chunk_size, "chunk_size", minimum=1)
    if not callable(attr_fn):
        raise TypeError(f"attr_fn must be callable, got {type(attr_fn).__name__}")
    device = torch.device(device) if device is not None else torch.device("cpu")
    outputs = []
    with torch.no_grad():
        for begin in range(0, points.shape[0], chunk_size):
            chunk = points[begin : begin + chunk_size].to(device=device, dtype=dtype)
            values = attr_fn(chunk)
            if not isinstance(values, torch.Tensor):
                raise TypeError(f"attr_fn must return a torch.Tensor, got {type(values).__name__}")
            if values.dim() == 1:
                values = values[:, None]
            if values.dim() != 2 or values.shape[0] != chunk.shape[0]:
                raise ValueError(
                    f"attr_fn must return [N] or [N, C] for N = {chunk.shape[0]} points, got "
                    f"{tuple(values.shape)}"
                )
            outputs.append(values.detach().to("cpu", torch.float32))
    if not outputs:
        raise ValueError("vertices is empty: no attribute to evaluate")
    return torch.cat(outputs).numpy()


def colors_to_uint8(colors: np.ndarray | torch.Tensor) -> np.ndarray:
    """Convert colours in [0, 1] (any shape, numpy or torch) to uint8 0-255, clipping, rounding."""
    if isinstance(colors, torch.Tensor):
        colors = colors.detach().cpu().numpy()
    colors = np.asarray(colors, dtype=np.float64)
    return np.rint(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8)


# ----------------------------------------------------------------------------------------------
# Grid evaluation


class _GridEvaluator:
    """Evaluate ``sdf_fn`` at integer grid coordinates; counts calls and time."""

    def __init__(self, sdf_fn, bbox_min, spacing, chunk_size, device, dtype, progress):
        self.sdf_fn = sdf_fn
        self.bbox_min = bbox_min
        self.spacing = spacing
        self.chunk_size = chunk_size
        self.device = device
        self.dtype = dtype
        self.progress = progress
        self.num_evaluations = 0
        self.seconds = 0.0
        self._origin = torch.as_tensor(bbox_min, dtype=dtype, device=device)
        self._spacing = torch.as_tensor(spacing, dtype=dtype, device=device)

    def at_indices(self, indices: np.ndarray, desc: str) -> np.ndarray:
        """indices: [M, 3] integer grid coordinates -> [M] float SDF values (numpy)."""
        out = np.empty(indices.shape[0], dtype=_numpy_dtype(self.dtype))
        for begin, end in self._chunks(indices.shape[0], desc):
            grid = torch.from_numpy(indices[begin:end]).to(self.device)
            out[begin:end] = self._evaluate(grid)
        return out

    def dense(self, resolution: int) -> np.ndarray:
        """Every grid point -> [R, R, R] values (x index first)."""
        total = resolution**3
        out = np.empty(total, dtype=_numpy_dtype(self.dtype))
        for begin, end in self._chunks(total, "dense"):
            flat = torch.arange(begin, end, device=self.device)
            grid = torch.stack(
                [flat // (resolution * resolution), (flat // resolution) % resolution,
                 flat % resolution], dim=-1,
            )
            out[begin:end] = self._evaluate(grid)
        return out.reshape(resolution, resolution, resolution)

    def _chunks(self, total: int, desc: str):
        ranges = [(b, min(b + self.chunk_size, total)) for b in range(0, total, self.chunk_size)]
        if self.progress:
            from tqdm.auto import tqdm

            return tqdm(ranges, desc=f"meshing {desc}", leave=False)
        return ranges

    def _evaluate(self, grid: torch.Tensor) -> np.ndarray:
        start = time.perf_counter()
        points = self._origin + grid.to(self.dtype) * self._spacing
        with torch.no_grad():
            values = self.sdf_fn(points)
        values = check_sdf_output(values, points.shape[0])
        values = values.detach().to("cpu", self.dtype).numpy()
        if not np.isfinite(values).all():
            raise ValueError(
                f"sdf_fn returned {int((~np.isfinite(values)).sum())} NaN or inf values"
            )
        self.num_evaluations += points.shape[0]
        self.seconds += time.perf_counter() - start
        return values


def _top_block_size(num_cells: int, coarse_resolution: int | None) -> int:
    """Cells a side of the coarsest blocks: a power of two, 1 for dense evaluation."""
    if coarse_resolution is None:
        coarse_resolution = 8
    if coarse_resolution > num_cells:
        return 1
    return 2 ** round(math.log2(num_cells / coarse_resolution))


def _dense_volume(evaluator: _GridEvaluator, resolution: int):
    volume = evaluator.dense(resolution)
    return volume, None, [evaluator.num_evaluations]


def _hierarchical_volume(
    evaluator: _GridEvaluator, resolution: int, top_block: int, level: float, lipschitz: float
):
    """Evaluate the grid coarse to fine; returns (volume [R,R,R], evaluated mask, counts).

    Block ``b`` of size ``s`` cells spans grid points ``[b s, b s + s]`` per axis and owns the
    points ``[b s, b s + s)``; ownership nests across levels because ``s`` halves. A far block
    fills its owned points with ``level +- (|f(c) - level| - L * half diagonal)``, a lower bound of
    ``|f - level|`` there with the right sign; the near blocks of size 2 have their points
    evaluated. Padded blocks past the grid are evaluated at their centres (outside the box).
    """
    cell_diagonal = float(np.linalg.norm(evaluator.spacing))
    num_blocks = -(-resolution // top_block)  # ceil: top blocks own every grid point
    active = np.ones((num_blocks,) * 3, dtype=bool)
    fill = np.full((num_blocks,) * 3, np.nan, dtype=_numpy_dtype(evaluator.dtype))
    counts = []
    size = top_block
    while True:
        block_index = np.argwhere(active).astype(np.int64)
        center_values = evaluator.at_indices(block_index * size + size // 2, f"{size}-cell blocks")
        counts.append(block_index.shape[0])
        half_diagonal = 0.5 * size * cell_diagonal
        deviation = center_values - level
        bound = lipschitz * (half_diagonal + cell_diagonal) * (1.0 + _BOUND_SLACK)
        near = np.abs(deviation) <= bound
        far = ~near
        margin = np.abs(deviation[far]) - lipschitz * half_diagonal
        fi, fj, fk = block_index[far].T
        fill[fi, fj, fk] = level + np.sign(deviation[far]) * margin
        active = np.zeros_like(active)
        ni, nj, nk = block_index[near].T
        active[ni, nj, nk] = True
        if size == _FINEST_BLOCK or not near.any():
            break
        # Split near blocks in eight; children starting past the grid own no point.
        size //= 2
        active = _upsample2(active)
        fill = _upsample2(fill)
        outside = np.arange(active.shape[0]) * size >= resolution
        active[outside, :, :] = False
        active[:, outside, :] = False
        active[:, :, outside] = False

    # Owned points -> dense volume: far fills first, then the points of near blocks.
    volume = np.ascontiguousarray(_upsample(fill, size)[:resolution, :resolution, :resolution])
    mask = np.zeros((resolution,) * 3, dtype=bool)
    if size != _FINEST_BLOCK or not near.any():
        return volume, mask, counts
    centre_grid = np.full(active.shape, np.nan, dtype=volume.dtype)
    centre_grid[tuple(block_index.T)] = center_values
    near_index = block_index[near]
    offsets = np.stack(np.meshgrid(*([np.arange(size)] * 3), indexing="ij"), -1).reshape(-1, 3)
    # A point further than one cell diagonal from the level set is no corner of a cell that
    # marching cubes triangulates; the evaluated block centres around it often prove it.
    bound, sign = _centre_lower_bound(
        near_index, offsets, centre_grid, evaluator.spacing, level, lipschitz
    )
    points = (near_index[:, None, :] * size + offsets[None, :, :]).reshape(-1, 3)
    bound, sign = bound.reshape(-1), sign.reshape(-1)
    inside = np.all(points < resolution, axis=1)
    points, bound, sign = points[inside], bound[inside], sign[inside]
    needed = bound <= lipschitz * cell_diagonal * (1.0 + _BOUND_SLACK)
    skipped = points[~needed]
    volume[tuple(skipped.T)] = level + sign[~needed] * bound[~needed]
    is_centre = np.all(points % 2 == 1, axis=1)  # already evaluated
    known = points[needed & is_centre]
    volume[tuple(known.T)] = centre_grid[tuple((known // 2).T)]
    points = points[needed & ~is_centre]
    volume[tuple(points.T)] = evaluator.at_indices(points, "grid points")
    counts.append(points.shape[0])
    mask[tuple(points.T)] = True
    mask[tuple(known.T)] = True
    assert not np.isnan(volume).any(), "every grid point is owned by a far or an evaluated block"
    return volume, mask, counts


def _centre_lower_bound(
    block_index: np.ndarray, offsets: np.ndarray, centre_grid: np.ndarray, spacing: np.ndarray,
    level: float, lipschitz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Best Lipschitz lower bound of ``|f - level|`` at the points of 2-cell blocks.

    block_index: [M, 3] blocks; offsets: [8, 3] the points ``2 b + o`` (o in {0, 1}^3) they own.
    centre_grid: [nb, nb, nb] field values at the centres ``2 b + 1`` (NaN where not evaluated).
    Each point looks at the centres in the cube of one cell around it: along an axis where it is
    odd, its own block's; where it is even (o = 0), those of blocks ``b`` and ``b - 1``, one cell
    away. Returns the bound [M, 8] (<= 0 when nothing is proven) and the sign [M, 8] of
    ``f - level`` that the best centre proves.
    """
    shifts = np.stack(np.meshgrid(*([[0, -1]] * 3), indexing="ij"), -1).reshape(-1, 3)
    limit = np.array(centre_grid.shape)
    deviations = []
    for shift in shifts:  # signed deviation at the centre of block b + shift, 0 if unknown
        block = block_index + shift
        valid = np.all((block >= 0) & (block < limit), axis=1)
        value = centre_grid[tuple(np.where(valid[:, None], block, 0).T)].astype(np.float64)
        deviations.append(np.where(valid & ~np.isnan(value), value - level, 0.0))
    bound = np.empty((block_index.shape[0], offsets.shape[0]))
    sign = np.empty_like(bound)
    for k, offset in enumerate(offsets):
        best = np.zeros(block_index.shape[0])
        for shift, deviation in zip(shifts, deviations, strict=True):
            if np.any((shift != 0) & (offset != 0)):
                continue  # along odd axes the point sits on its own block's centre plane
            best = np.where(np.abs(deviation) > np.abs(best), deviation, best)
        distance = float(np.linalg.norm(np.where(offset == 0, spacing, 0.0)))
        bound[:, k] = np.abs(best) - lipschitz * distance
        sign[:, k] = np.sign(best)
    return bound, sign


def _upsample2(array: np.ndarray) -> np.ndarray:
    """Repeat every entry of a 3-D array into a 2x2x2 block."""
    return _upsample(array, 2)


def _upsample(array: np.ndarray, factor: int) -> np.ndarray:
    """Repeat every entry of a 3-D array into a factor^3 block (a broadcast, then one copy)."""
    ni, nj, nk = array.shape
    spread = np.broadcast_to(
        array[:, None, :, None, :, None], (ni, factor, nj, factor, nk, factor)
    )
    return spread.reshape(ni * factor, nj * factor, nk * factor)


def _check_level_in_volume(volume, level, bbox_min, bbox_max) -> None:
    low, high = float(volume.min()), float(volume.max())
    if not (low < level < high):
        raise ValueError(
            f"the level set sdf = {level} was not found in the box [{bbox_min.tolist()}, "
            f"{bbox_max.tolist()}]: the field stays {'above' if low >= level else 'below'} it on "
            "the grid (enlarge the box, raise the resolution, or check the field's sign)"
        )


def _marching_cubes(volume: np.ndarray, level: float, mask: np.ndarray | None):
    """Run skimage's Lewiner marching cubes; returns vertices in index units and int64 faces."""
    from skimage.measure import marching_cubes

    # skimage's "descent" (its default, meant for fields that grow into the object) emits the
    # faces in the order that makes normals point to growing values: outward for an SDF.
    try:
        vertices, faces, _, _ = marching_cubes(
            volume, level=level, gradient_direction="descent", mask=mask
        )
    except RuntimeError as exc:  # skimage: "No surface found at the given iso value."
        raise ValueError(f"the level set sdf = {level} was not found in the box ({exc})") from None
    return vertices, np.ascontiguousarray(faces, dtype=np.int64)


# ----------------------------------------------------------------------------------------------
# Validation helpers


def _numpy_dtype(dtype: torch.dtype):
    return np.float64 if dtype == torch.float64 else np.float32


def _as_numpy(array, name: str) -> np.ndarray:
    if isinstance(array, torch.Tensor):
        return array.detach().cpu().numpy()
    if isinstance(array, np.ndarray):
        return array
    try:
        return np.asarray(array)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array, got {type(array).__name__} ({exc})") from None


def _check_vector3(value, name: str) -> np.ndarray:
    array = np.asarray(_as_numpy(value, name), dtype=np.float64)
    if array.shape != (3,):
        raise ValueError(f"{name} must have shape [3] (metres), got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} must be finite, got {array.tolist()}")
    return array


def _check_int(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def sample_triangles(areas: torch.Tensor, num: int, generator: torch.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points spread uniformly over triangles: ``num`` faces drawn by area, then a uniform point
    in each, as barycentric ``(1 - u - v, u, v)``.

    areas: [F] (any positive multiple of the triangles' areas). generator: a seeded CPU
    ``torch.Generator``. -> (face [num] int64, u [num], v [num] float64), CPU.
    """
    face = torch.multinomial(areas.double().cpu(), num, replacement=True, generator=generator)
    u, v = torch.rand(2, num, generator=generator, dtype=torch.float64)
    flip = (u + v) > 1.0
    return face, torch.where(flip, 1.0 - u, u), torch.where(flip, 1.0 - v, v)
