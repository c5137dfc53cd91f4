"""Several hands through one clip: where the left hand is from the right one and how deep any
hand is inside another, frame by frame (:func:`clip_contact`), for ``hands.json``.

Each hand is a body of :mod:`lisa_hand.fitting.pair.contact` (its LISA field, its fitted mesh
skinned to the clip's skeleton), moved to its fitted pose and translation in each frame; the
deepest point of one hand's surface inside another is that frame's penetration, as a photo's
``hands.json`` measures it. Hands apart cost no network (the other hand's box is far).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

__all__ = ["ClipContact", "clip_contact"]


@dataclass(frozen=True)
class ClipContact:
    """right_to_left_m: [N, 3] metres, the left wrist keypoint minus the right one in the camera
    frame (NaN in frames without both, or unless the hands are one right and one left).
    penetration_mm: [N] the deepest point of any hand inside another (NaN in frames with fewer
    than two hands)."""

    right_to_left_m: np.ndarray
    penetration_mm: np.ndarray

    @property
    def deepest_mm(self) -> float:
        """The clip's deepest penetration, millimetres (0 without any frame of two hands)."""
        known = self.penetration_mm[np.isfinite(self.penetration_mm)]
        return float(known.max()) if len(known) else 0.0


def clip_contact(model: Any, hands: Sequence[Any], max_faces: int = 5000) -> ClipContact:
    """The frames of ``hands`` (:class:`lisa_hand.fitting.video.fit.TrackedHand`, two or more;
    their motion [N] rows each) -> :class:`ClipContact`. The surfaces are each hand's keyframe
    mesh decimated to ``max_faces``."""
    from ...skeleton.params import HandParams
    from ..pair.contact import HandBody, penetration_depths
    from ..pair.record import right_to_left
    from ..sides import mirror_hand

    count = len(hands[0].motion.pose)
    bodies = [HandBody.of(model, hand.params, hand.keyframe.mesh, 0, 0, max_faces)
              for hand in hands]
    sides = [hand.side for hand in hands]
    offsets = np.full((count, 3), np.nan)
    depths = np.full(count, np.nan)

    def at(hand: Any, body: Any, row: int) -> Any:
        params: HandParams = replace(
            hand.params, pose=torch.from_numpy(hand.motion.pose[row]).to(hand.params.pose),
            translation=torch.from_numpy(hand.motion.translation[row])
            .to(hand.params.translation))
        return replace(body, right=mirror_hand(params) if body.flip else params)

    for row in range(count):
        present = [number for number, hand in enumerate(hands)
                   if np.isfinite(hand.motion.pose[row]).all()]
        if len(present) < 2:
            continue
        depths[row] = penetration_depths(model, [at(hands[n], bodies[n], row)
                                                 for n in present]).max()
        if len(present) == len(hands):
            offset = right_to_left(sides, np.stack([hand.motion.keypoints_3d[row, 0]
                                                    for hand in hands]))
            if offset is not None:
                offsets[row] = offset
    return ClipContact(right_to_left_m=offsets, penetration_mm=depths)
