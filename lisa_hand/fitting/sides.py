"""Left hands: LISA and the template are right hands, so a left hand is fitted as the right
hand of the mirrored data (``x -> -x``, :func:`lisa_hand.skeleton.mirror_points`) and the
result mirrored back (as meshing and rendering treat a left hand's ``params.json``)."""

from __future__ import annotations

from dataclasses import replace

import torch

from ..skeleton import check_side, mirror_points, mirror_pose
from ..skeleton.params import HandParams

__all__ = ["mirror_hand", "mirror_cloud"]


def mirror_hand(params: HandParams) -> HandParams:
    """The mirror image of a hand: a right hand fitted in the mirrored world becomes the left
    hand of the real one, and back (pose, translation and skeleton mirrored, side swapped)."""
    side = "left" if check_side(params.side) == "right" else "right"
    return replace(params, pose=mirror_pose(params.pose),
                   translation=mirror_points(params.translation),
                   rest_joints=mirror_points(params.rest_joints), side=side,
                   extra=dict(params.extra))


def mirror_cloud(points: torch.Tensor, side: str) -> torch.Tensor:
    """points (or normals): [N, 3] of a ``side`` hand -> those of the right hand the fit sees
    (mirrored for 'left', unchanged for 'right')."""
    return mirror_points(points) if check_side(side) == "left" else points
