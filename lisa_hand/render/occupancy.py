"""Empty-space skipping: an occupancy grid of the shell around an SDF's zero level set.

:func:`build_occupancy_grid` spends a few ten thousand SDF evaluations (coarse to fine) on lower
bounds of ``|sdf|`` per cell; :meth:`OccupancyGrid.ray_bounds` then shrinks each ray's
``[near, far]`` to the cells it may meet the shell ``|sdf| <= threshold`` in, with table lookups
only (no field evaluations). The image renderer (:mod:`lisa_hand.render.image`) uses it to drop
the rays that miss the hand; a turntable shares one grid across its views. Not differentiable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..geometry.fields import SdfFn, call_sdf

__all__ = ["OccupancyGrid", "build_occupancy_grid"]

_SQRT3 = math.sqrt(3.0)
# Distance bound given to the grid's border cells ("far from everything"), metres.
_FAR_BOUND = 1e3


@dataclass
class OccupancyGrid:
    """Lower bounds of ``|sdf|`` on a grid over the bounding sphere's cube, and the cells that may
    hold points of the shell ``|sdf| <= threshold`` around the surface.

    Cell ``[i, j, k]`` covers ``low + cell_size * ([i, i+1] x [j, j+1] x [k, k+1])`` (x, y, z).
    For an SDF whose absolute value is ``lipschitz``-Lipschitz (it overestimates distances by at
    most that factor), ``|sdf(x)| >= distance_bound[cell] - lipschitz * |x - centre|`` for every
    point ``x`` (of any cell), and a cell is occupied when that bound may reach the threshold
    somewhere in it: ``distance_bound <= lipschitz * half_diagonal + threshold``. Cells deep inside
    are empty too: a ray reaches them only through the shell.

    distance_bound: [G, G, G] metres, a lower bound of ``|sdf|`` at each cell centre (the value
        itself where it was evaluated). occupied: [G, G, G] bool. low: [3] metres, the cube's
        minimum corner. cell_size, threshold: metres. lipschitz: >= 1.
    num_evaluations: SDF evaluations spent building it.
    """

    distance_bound: torch.Tensor
    occupied: torch.Tensor
    low: torch.Tensor
    cell_size: float
    threshold: float
    lipschitz: float
    num_evaluations: int

    @property
    def resolution(self) -> int:
        return self.occupied.shape[0]

    def bounding_box(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(low [3], high [3])`` metres of the occupied cells grown by one cell; None if empty."""
        index = torch.nonzero(self.occupied)
        if index.numel() == 0:
            return None
        dtype = self.low.dtype
        first = index.amin(dim=0).to(dtype) - 1.0
        last = index.amax(dim=0).to(dtype) + 2.0
        return self.low + self.cell_size * first, self.low + self.cell_size * last

    @torch.no_grad()
    def ray_bounds(
        self,
        origins: torch.Tensor,
        directions: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        chunk_size: int = 16384,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Shrink ``[near, far]`` to where the ray may meet the shell ``|sdf| <= threshold``.

        Table lookups only, no field evaluations: each ray is probed at ``G + 1`` evenly spaced
        points ``t_k`` of ``[near, far]`` (spacing ``delta`` below one cell). A probe's bound
        ``b_k = distance_bound[cell] - L |x_k - centre|`` holds ``|sdf| >= b_k`` there, so on the
        piece ``[t_k, t_k+1]`` ``|sdf| >= (b_k + b_k+1 - L delta) / 2`` (and ``b - L delta / 2``
        on the two half pieces at the ends). Rays with no piece reaching the threshold miss the
        shell (``hit = False``); the others start at the first such piece, advanced by the
        sphere-tracing step ``(b_k - threshold) / L`` that is safe from its probe, and end at the
        last one, moved back the same way.

        origins, directions: [R, 3] metres / unit. near, far: [R] metres, inside the cube
        (e.g. from the sphere the grid was built in).
        Returns ``(near [R], far [R], hit [R] bool)``; rays without a hit get near = far = 0.
        """
        device, dtype = origins.device, origins.dtype
        table = self._padded_table(device, dtype)
        # Probe positions in grid units (cell i spans [i + 1, i + 2) with the border).
        low = self.low.to(device=device, dtype=dtype)
        start_grid = (origins - low) / self.cell_size + 1.0
        dir_grid = directions / self.cell_size
        new_near, new_far = torch.zeros_like(near), torch.zeros_like(far)
        hit = torch.zeros(near.shape, dtype=torch.bool, device=device)
        for start in range(0, origins.shape[0], chunk_size):
            rows = slice(start, start + chunk_size)
            ray_near, ray_far = near[rows], far[rows]
            bound, t_probe, spacing = self._probe_bounds(
                table, start_grid[rows], dir_grid[rows], ray_near, ray_far
            )
            new_near[rows], new_far[rows], hit[rows] = self._shell_span(
                bound, t_probe, spacing, ray_near, ray_far
            )
        return new_near, new_far, hit

    def _padded_table(self, device, dtype) -> torch.Tensor:
        """The distance bounds with a border of :data:`_FAR_BOUND` (probes outside clamp onto
        it), flattened: [(G + 2)^3] metres."""
        padded = self.resolution + 2
        table = torch.full((padded, padded, padded), _FAR_BOUND, dtype=dtype, device=device)
        table[1:-1, 1:-1, 1:-1] = self.distance_bound.to(device=device, dtype=dtype)
        return table.reshape(-1)

    def _probe_bounds(self, table, start_grid, dir_grid, ray_near, ray_far):
        """Lower bounds of ``|sdf|`` at the ``P = G + 1`` probes of each ray.

        table: [(G + 2)^3] from :meth:`_padded_table`. start_grid, dir_grid: [R, 3] the rays in
        grid units. ray_near, ray_far: [R] metres.
        Returns ``(bound [R, P] metres, t_probe [R, P] metres, spacing [R] metres)``.
        """
        padded = self.resolution + 2
        num_probes = self.resolution + 1
        device, dtype = start_grid.device, start_grid.dtype
        offsets = torch.arange(num_probes, device=device, dtype=dtype) + 0.5
        weights = torch.tensor([padded * padded, padded, 1.0], device=device, dtype=dtype)
        spacing = (ray_far - ray_near) / num_probes  # [R]
        t_probe = ray_near[:, None] + offsets * spacing[:, None]  # [R, P]
        position = start_grid[:, None, :] + t_probe[..., None] * dir_grid[:, None, :]
        position = position.clamp_(0.0, padded - 1e-3)
        cells = position.floor()
        from_centre = torch.linalg.vector_norm(position - cells - 0.5, dim=-1)
        bound = table[(cells @ weights).long()] - self.lipschitz * self.cell_size * from_centre
        return bound, t_probe, spacing

    def _shell_span(self, bound, t_probe, spacing, ray_near, ray_far):
        """From the probes' bounds [R, P] to each ray's span of the shell:
        ``(near [R], far [R], hit [R] bool)`` (see :meth:`ray_bounds`)."""
        lipschitz, threshold = self.lipschitz, self.threshold
        num_probes = bound.shape[1]
        # Lower bounds of |sdf| on the pieces: [near, t_0], [t_k, t_k+1], [t_P-1, far].
        half_step = 0.5 * lipschitz * spacing[:, None]
        pieces = torch.cat(
            [
                bound[:, :1] - half_step,
                0.5 * (bound[:, :-1] + bound[:, 1:]) - half_step,
                bound[:, -1:] - half_step,
            ],
            dim=-1,
        )  # [R, P + 1]
        reach = (pieces <= threshold).to(torch.uint8)
        first = reach.argmax(dim=-1)  # piece index; piece k > 0 starts at probe k - 1
        any_hit = reach.gather(-1, first[:, None])[:, 0] > 0
        last = num_probes - reach.flip(-1).argmax(dim=-1)  # piece k < P ends at probe k
        safe = (bound - threshold).clamp_min(0.0) / lipschitz  # [R, P]
        from_probe = (first - 1).clamp(min=0)
        lo = (
            t_probe.gather(-1, from_probe[:, None])[:, 0]
            + safe.gather(-1, from_probe[:, None])[:, 0]
        )
        lo = torch.where(first == 0, ray_near, lo)
        to_probe = last.clamp(max=num_probes - 1)
        hi = (
            t_probe.gather(-1, to_probe[:, None])[:, 0]
            - safe.gather(-1, to_probe[:, None])[:, 0]
        )
        hi = torch.where(last == num_probes, ray_far, hi)
        # The safe steps from both ends may cover a lone piece: then it misses too.
        any_hit &= hi > lo
        new_near = torch.where(any_hit, lo, torch.zeros_like(lo))
        new_far = torch.where(any_hit, hi, torch.zeros_like(hi))
        return new_near, new_far, any_hit


def _cube_index(size: int, device) -> torch.Tensor:
    """[size^3, 3] integer cell indices (i, j, k) of a cube, x index slowest."""
    axis = torch.arange(size, device=device)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


@torch.no_grad()
def build_occupancy_grid(
    sdf_fn: SdfFn,
    center: torch.Tensor,
    radius: float,
    *,
    resolution: int = 64,
    coarse_resolution: int = 16,
    threshold: float = 0.0,
    lipschitz: float = 1.0,
    chunk_size: int = 65536,
) -> OccupancyGrid:
    """Occupancy grid of the shell ``{|sdf| <= threshold}`` in the cube around a bounding sphere.

    Coarse to fine: the SDF is evaluated at the centres of ``coarse_resolution^3`` cells; only
    the occupied ones (``|sdf| <= lipschitz * half_diagonal + threshold``) are split into
    ``(resolution / coarse_resolution)^3`` cells whose centres are evaluated and tested the same
    way. The other fine cells get the bound ``|sdf(C)| - lipschitz * |c - C|`` from their coarse
    centre ``C``. For a hand in its bounding sphere that is some 50k SDF evaluations for 64^3.

    sdf_fn: points [N, 3] metres -> sdf [N] metres (an SDF that overestimates distances by at
        most ``lipschitz``). center: [3] metres (its dtype and device are used). radius: metres.
    threshold: metres (e.g. the sampler's shell ``band_outside * beta`` plus a margin).
    chunk_size: most points per ``sdf_fn`` call.
    """
    if not isinstance(center, torch.Tensor) or center.shape != (3,):
        shape = getattr(center, "shape", center)
        raise ValueError(f"center must be a tensor of shape [3] (metres), got {shape}")
    if not radius > 0:
        raise ValueError(f"radius must be > 0 (metres), got {radius!r}")
    if coarse_resolution < 1 or resolution % coarse_resolution:
        raise ValueError(
            f"coarse_resolution ({coarse_resolution}) must divide resolution ({resolution})"
        )
    if not lipschitz >= 1:
        raise ValueError(f"lipschitz must be >= 1, got {lipschitz!r}")
    device, dtype = center.device, center.dtype
    low = center - radius
    factor = resolution // coarse_resolution
    coarse_cell = 2.0 * radius / coarse_resolution
    cell = 2.0 * radius / resolution

    coarse_index = _cube_index(coarse_resolution, device)
    centres = low + (coarse_index.to(dtype) + 0.5) * coarse_cell
    coarse_abs = call_sdf(sdf_fn, centres, chunk_size).abs()
    coarse_occupied = coarse_abs <= lipschitz * 0.5 * _SQRT3 * coarse_cell + threshold
    num_evaluations = centres.shape[0]

    # Every fine cell: the bound from its coarse cell's centre.
    fine_index = _cube_index(resolution, device)
    parent = fine_index // factor
    parent_flat = (
        parent * torch.tensor([coarse_resolution**2, coarse_resolution, 1], device=device)
    ).sum(-1)
    offset = ((fine_index % factor).to(dtype) + 0.5) / factor - 0.5  # in coarse cells
    bound = coarse_abs[parent_flat] - lipschitz * coarse_cell * offset.norm(dim=-1)
    # The fine cells of occupied coarse cells: evaluated.
    refine = coarse_occupied[parent_flat]
    if bool(refine.any()):
        centres = low + (fine_index[refine].to(dtype) + 0.5) * cell
        bound[refine] = call_sdf(sdf_fn, centres, chunk_size).abs()
        num_evaluations += centres.shape[0]
    occupied = bound <= lipschitz * 0.5 * _SQRT3 * cell + threshold
    shape = (resolution, resolution, resolution)
    return OccupancyGrid(
        distance_bound=bound.reshape(shape),
        occupied=occupied.reshape(shape),
        low=low,
        cell_size=cell,
        threshold=float(threshold),
        lipschitz=float(lipschitz),
        num_evaluations=num_evaluations,
    )
