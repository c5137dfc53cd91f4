"""Where a hand's surface is: spheres and boxes that hold its zero level set.

:func:`hand_bounds` is a sphere that holds the zero level set: the posed bone regions (capsules
around the bone segments) plus a margin. Outside every region LISA's SDF is the positive
distance to the nearest region (:mod:`lisa_hand.model`), so the surface cannot leave them.
:func:`skeleton_box` is the tighter box where a hand's surface is expected;
:func:`grid_surface_box` the box of an occupancy grid's cells that may hold it.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..fields.bones import SEGMENT_BONES, bone_segments
from ..fields.config import FieldConfig
from ..render.occupancy import OccupancyGrid
from ..skeleton import forward_kinematics
from ..skeleton.params import HandParams

__all__ = [
    "posed_segments",
    "hand_bounds",
    "skeleton_box",
    "grid_surface_box",
    "union_sphere",
]


def posed_segments(
    params: HandParams, config: FieldConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    """The posed region segments of the hand, world frame: (start [20, 3], end [20, 3]) float64
    metres (owners :data:`lisa_hand.fields.bones.SEGMENT_BONES`; fingertips extended by the
    field's ``tip_extension``)."""
    with torch.no_grad():
        rest = params.rest_joints[None].double()
        kinematics = forward_kinematics(
            params.pose[None].double(), rest, params.translation[None].double()
        )
        start, end = bone_segments(rest, config.tip_extension)
        transforms = kinematics.transforms[0, list(SEGMENT_BONES)]
        rot, trans = transforms[:, :3, :3], transforms[:, :3, 3]
        start = (rot @ start[0, :, :, None])[..., 0] + trans
        end = (rot @ end[0, :, :, None])[..., 0] + trans
    return start, end


def hand_bounds(
    params: HandParams, config: FieldConfig | None = None, margin: float = 0.005
) -> tuple[torch.Tensor, float]:
    """A sphere that holds the hand's surface: the posed bone regions plus ``margin``.

    Each bone's region is a capsule of radius ``palm_region_radius`` (wrist bone) or
    ``finger_region_radius`` around its segments (fingertips extended by ``tip_extension``);
    LISA's zero level set lies inside their union (:mod:`lisa_hand.model`). The margin covers
    the renderer's shell around the surface.

    params: the hand (world frame, either side). config: the field's architecture (default
    ``FieldConfig()``). margin: metres.
    -> (center [3] float32 metres, radius metres)
    """
    config = FieldConfig() if config is None else config
    if not margin >= 0:
        raise ValueError(f"margin must be >= 0 (metres), got {margin!r}")
    start, end = posed_segments(params, config)
    radii = torch.tensor(
        [config.palm_region_radius if b == 0 else config.finger_region_radius
         for b in SEGMENT_BONES], dtype=torch.float64,
    )  # fmt: skip
    ends = torch.cat([start, end])
    center = 0.5 * (ends.amin(dim=0) + ends.amax(dim=0))
    reach = torch.maximum((start - center).norm(dim=-1), (end - center).norm(dim=-1)) + radii
    return center.float(), float(reach.max()) + float(margin)


def skeleton_box(
    params: HandParams, config: FieldConfig | None = None, padding: float = 0.03
) -> tuple[np.ndarray, np.ndarray]:
    """The box of the posed skeleton (joints and fingertips, extended by the field's
    ``tip_extension``) grown by ``padding`` on every side: where a hand's surface is expected
    (a palm is some 3 cm thick around its joints). -> (low [3], high [3]) float64 metres"""
    config = FieldConfig() if config is None else config
    if not padding >= 0:
        raise ValueError(f"padding must be >= 0 (metres), got {padding!r}")
    start, end = posed_segments(params, config)
    ends = torch.cat([start, end])
    low = ends.amin(dim=0).numpy() - padding
    high = ends.amax(dim=0).numpy() + padding
    return low, high


def grid_surface_box(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
    """The box of the grid's cells that may hold the zero level set (their distance bound
    within ``lipschitz`` half diagonals), grown by one cell. -> (low [3], high [3]) float64
    metres"""
    half_diagonal = 0.5 * math.sqrt(3.0) * grid.cell_size
    index = torch.nonzero(grid.distance_bound <= grid.lipschitz * half_diagonal)
    if index.numel() == 0:
        raise ValueError(
            "the hand's surface was not found inside its bone regions (the field is positive "
            "everywhere): check the model and the hand's codes"
        )
    low = grid.low.detach().double().cpu()
    first = index.amin(dim=0).double().cpu() - 1.0
    last = index.amax(dim=0).double().cpu() + 2.0
    return (low + grid.cell_size * first).numpy(), (low + grid.cell_size * last).numpy()


def union_sphere(spheres: list[tuple[torch.Tensor, float]]) -> tuple[torch.Tensor, float]:
    """A sphere holding all the given (center [3] metres, radius metres) spheres, centred on
    their box. -> (center [3] float64 metres, radius metres)"""
    if not spheres:
        raise ValueError("spheres must not be empty")
    centers = torch.stack([c.double() for c, _ in spheres])
    radii = torch.tensor([r for _, r in spheres], dtype=torch.float64)
    low = (centers - radii[:, None]).amin(dim=0)
    high = (centers + radii[:, None]).amax(dim=0)
    middle = 0.5 * (low + high)
    return middle, float(((centers - middle).norm(dim=-1) + radii).max())
