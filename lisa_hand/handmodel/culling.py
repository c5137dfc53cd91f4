"""Culling for the open hand's field: which parts can matter near a group of query points.

:class:`~lisa_hand.handmodel.sdf.PosedField` groups query points into cubic cells of a few
centimetres (:func:`group_in_cells`) and evaluates, per cell, only the parts, creases, nails and
palm lines that can reach it (:func:`reachable_parts`): a dropped part's blend weight is below
``exp(-10)`` everywhere in the cell, which changes the distance by < 1e-7 m.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from .detail import CREASE_SUPPORT
from .parts import local_coordinates
from .primitives import round_cone_sdf, rounded_polygon_sdf

if TYPE_CHECKING:
    from .sdf import PosedField

__all__ = ["group_in_cells", "reachable_parts"]

# A part whose distance exceeds the nearest part's by this many blend radii is dropped (its
# weight exp(-10) ~ 5e-5 changes the distance by < 1e-7 m).
_CULL_BLENDS = 10.0
# The number of points per culling cell aimed at.
_TARGET_GROUP = 1500


def group_in_cells(
    points: torch.Tensor, min_cell: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, float]:
    """Group points in cubic cells of at least ``min_cell`` metres (larger where points are
    sparse: about ``_TARGET_GROUP`` points per cell).

    points: [N, 3] metres (not differentiated through).
    -> (point order sorted by cell [N], points per non-empty cell [M], cell centres [M, 3],
    cell edge in metres)."""
    detached = points.detach()
    num = detached.shape[0]
    low = detached.amin(0)
    extent = (detached.amax(0) - low).clamp_min(min_cell)
    # Cells of at least cell_size, larger where points are sparse (few points per cell cost
    # more in per-call overhead than culling saves).
    cell = max(min_cell, float((extent.prod() * _TARGET_GROUP / num) ** (1.0 / 3.0)))
    cells = torch.floor((detached - low) / cell).long()
    dims = cells.amax(0) + 1
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    keys, order = torch.sort(keys)
    unique, counts = torch.unique_consecutive(keys, return_counts=True)
    cell_index = torch.stack(
        [unique // (dims[1] * dims[2]), (unique // dims[2]) % dims[1], unique % dims[2]], -1
    )
    centers = low + (cell_index.to(detached.dtype) + 0.5) * cell
    return order, counts, centers, cell


def reachable_parts(
    field: PosedField, centers: torch.Tensor, half_diagonal: float
) -> tuple[torch.Tensor, ...]:
    """Which parts and details of ``field`` can matter within ``half_diagonal`` of each centre.

    centers: [M, 3] world points, metres. Uses the exact part distances at the centres: within a
    cell a part's distance lies in ``d(c) +- half_diagonal`` (distances are 1-Lipschitz), so a
    part whose lowest possible distance exceeds the highest possible nearest distance by
    ``_CULL_BLENDS`` blend radii weighs less than ``exp(-10)`` everywhere in the cell.
    -> masks [M, P] cones, [M, Q] slabs, [M, C] creases, [M, 5] nails, [M] palm lines.
    """
    tpl = field.parts
    along, up, side = local_coordinates(centers, field.cone_matrix, field.cone_offset)
    cone_d = round_cone_sdf(
        along, up * up + side * side, tpl.cone_length, tpl.cone_radii[:, 0],
        tpl.cone_radii[:, 1],
    )  # fmt: skip
    slab_d = torch.stack(
        [
            rounded_polygon_sdf(
                torch.stack(local_coordinates(centers, field.slab_matrix[q : q + 1],
                                   field.slab_offset[q : q + 1]), -1)[:, 0],
                tpl.slab_vertices[q], tpl.slab_radius[q],
            )
            for q in range(len(tpl.slab_vertices))
        ], dim=1,
    )  # fmt: skip
    spread = 2.0 * half_diagonal
    palm_min = torch.minimum(cone_d[:, tpl.cone_palm].amin(1), slab_d.amin(1))
    top_min = torch.minimum(cone_d[:, ~tpl.cone_palm].amin(1), palm_min)
    top_limit = (top_min + spread + _CULL_BLENDS * tpl.blend)[:, None]
    palm_limit = (palm_min + spread + _CULL_BLENDS * tpl.blend_palm)[:, None]
    palm_on = palm_min[:, None] <= top_limit
    cone_mask = torch.where(
        tpl.cone_palm, (cone_d <= palm_limit) & palm_on, cone_d <= top_limit
    )
    slab_mask = (slab_d <= palm_limit) & palm_on
    c_along, c_up, c_side = local_coordinates(centers, field.crease_matrix, field.crease_offset)
    crease_mask = (c_along.abs() <= CREASE_SUPPORT * tpl.crease_width + half_diagonal) & (
        (c_up * c_up + c_side * c_side).sqrt() <= tpl.crease_radius + 0.006 + half_diagonal
    )
    n_along, n_up, n_side = local_coordinates(centers, field.nail_matrix, field.nail_offset)
    nail_mask = (
        (n_along >= tpl.nail_start - 0.004 - half_diagonal)
        & (n_along <= tpl.nail_end + 0.002 + half_diagonal)
        & ((n_up * n_up + n_side * n_side).sqrt() <= tpl.nail_radius + 0.004 + half_diagonal)
    )
    line_dist = (centers[:, None] - field.line_center).norm(dim=-1)
    line_mask = palm_on[:, 0] & (line_dist <= tpl.line_bound + half_diagonal).any(1)
    return cone_mask, slab_mask, crease_mask, nail_mask, line_mask
