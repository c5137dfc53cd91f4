"""Per-frame state and per-point output of the LISA field (:mod:`lisa_hand.model.lisa`).

:class:`FrameState` is what :meth:`LisaModel.prepare` computes once per frame (kinematics, bone
frames, region segments, the conditioning folded into first-layer biases); :class:`FieldOutput`
is what :meth:`LisaModel.field` returns for a batch of points; :func:`region_bounds` is the box
where a frame's field is more than its analytic stand-in; :func:`group_points` pads the points of
several frames into one batch (the grouped callbacks of :class:`LisaModel`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from ..skeleton import Kinematics

if TYPE_CHECKING:
    from .lisa import LisaModel

__all__ = ["FrameState", "FieldOutput", "region_bounds", "group_points"]


@dataclass
class FrameState:
    """What the field needs that is the same for every point of a frame (:meth:`LisaModel.prepare`).

    Differentiable with respect to the per-frame inputs (pose, translation, rest joints, codes).

    kinematics: forward kinematics of the frame (joints, transforms ``A_j``, ...).
    rest_joints: [B, 16, 3] metres.
    world_to_local: [B, 16, 3, 3] ``R_j^T / coordinate_scale``; with ``local_offset`` [B, 16, 3]
        it maps a world point to bone ``j``'s centred local coordinates in network units.
    region_origin: [B, 3] world metres, the posed wrist joint.
    segment_start, segment_dir: [B, 20, 3] the posed region segments in world axes (start
        relative to ``region_origin``, metres; unit direction); segment_length: [B, 20] metres.
        Owners: :data:`lisa_hand.fields.bones.SEGMENT_BONES`. Distances are rigid-invariant,
        so these equal the distances in each bone's rest frame.
    sdf_bias: [B, G, sdf_hidden] the SDF MLPs' first-layer bias, conditioning folded in.
    color_bias: [B, G, color_hidden] the same for the colour MLPs, or None without colour.
    hand_to_local: [B, 3, 3] and hand_offset [B, 3]: the single MLP's input frame (the root
        bone's rest frame, centred at the mean rest joint), or None for per-bone compositions.
    """

    kinematics: Kinematics
    rest_joints: torch.Tensor
    world_to_local: torch.Tensor
    local_offset: torch.Tensor
    region_origin: torch.Tensor
    segment_start: torch.Tensor
    segment_dir: torch.Tensor
    segment_length: torch.Tensor
    sdf_bias: torch.Tensor
    color_bias: torch.Tensor | None
    hand_to_local: torch.Tensor | None
    hand_offset: torch.Tensor | None

    @property
    def batch_size(self) -> int:
        return self.rest_joints.shape[0]


@dataclass
class FieldOutput:
    """Result of :meth:`LisaModel.field` for points ``[B, N, 3]``.

    sdf: [B, N] metres, negative inside the hand.
    rgb: [B, N, 3] in [0, 1], or None (geometry only).
    weights: [B, N, 16] skinning weights (>= 0, rows sum to 1), None for 'single'.
    bone_sdf: [B, N, 16] per-bone SDFs ``s_j`` in metres (MLP inside the bone's region, analytic
        stand-in outside), None for 'single'.
    region_mask: [B, N, 16] bool, point inside bone ``j``'s region.
    sdf_grad: [B, N, 3] spatial gradient of ``sdf`` (1/1), or None when not requested.
    """

    sdf: torch.Tensor
    rgb: torch.Tensor | None
    weights: torch.Tensor | None
    bone_sdf: torch.Tensor | None
    region_mask: torch.Tensor
    sdf_grad: torch.Tensor | None = None


def region_bounds(state: FrameState, model: LisaModel) -> tuple[torch.Tensor, torch.Tensor]:
    """Axis-aligned box around every bone's region (outside it the field is a stand-in).

    -> (low [B, 3], high [B, 3]) world metres, detached.
    """
    start = state.segment_start.detach()
    end = start + state.segment_dir.detach() * state.segment_length.detach()[..., None]
    ends = torch.cat([start, end], dim=1) + state.region_origin.detach()[:, None]
    radius = float(max(model.config.palm_region_radius, model.config.finger_region_radius))
    return ends.amin(dim=1) - radius, ends.amax(dim=1) + radius


_FAR_POINT_M = 1.0e3
"""Where :func:`group_points` puts padding: outside every bone's region of any hand (metres),
so padding costs no MLP evaluation (only the distance to the regions)."""


def group_points(
    points: torch.Tensor, groups: torch.Tensor, num_frames: int
) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Flat points of several frames into one padded batch.

    points: [N, 3] metres; groups: [N] long in [0, num_frames), the frame of each point.
    -> (padded [num_frames, M, 3] metres, M the largest frame's count, the rest far away;
    index (frame [N], position [N]) such that ``padded[index] == points``). Differentiable with
    respect to ``points``.
    """
    if groups.shape != points.shape[:1]:
        raise ValueError(f"groups must have shape [N]=({points.shape[0]},), got "
                         f"{tuple(groups.shape)}")
    counts = torch.bincount(groups, minlength=num_frames)
    if counts.numel() != num_frames:
        raise ValueError(f"groups must be in [0, {num_frames}), got up to {int(groups.max())}")
    starts = torch.cumsum(counts, 0) - counts
    sorted_groups, order = torch.sort(groups, stable=True)
    position = torch.empty_like(groups)
    position[order] = torch.arange(groups.numel(), device=groups.device) - starts[sorted_groups]
    size = int(counts.max()) if groups.numel() else 0
    padded = points.new_full((num_frames, size, 3), _FAR_POINT_M)
    index = (groups, position)
    return padded.index_put(index, points), index
