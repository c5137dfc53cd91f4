"""What a fit of several hands writes beside each hand's folder: ``hands.json``
(:func:`hands_record`) and one mesh of every hand (:func:`joined_mesh`). The relative root
position error against a truth is :func:`lisa_hand.metrics.keypoints.mrrpe`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...geometry.meshing import Mesh
from ...skeleton.params import HandParams

__all__ = ["hands_record", "joined_mesh", "right_to_left"]


def right_to_left(sides: Sequence[str], roots: np.ndarray) -> np.ndarray | None:
    """The left hand's root minus the right hand's, [3] metres, when the hands are one right
    and one left; else None. roots: [K, 3] the hands' wrist keypoints."""
    if sorted(sides) != ["left", "right"]:
        return None
    return roots[list(sides).index("left")] - roots[list(sides).index("right")]


def hands_record(hands: Sequence[HandParams], folders: Sequence[str], roots: np.ndarray,
                 penetration_mm: np.ndarray, frame: str, joint: dict[str, Any] | None,
                 notes: Sequence[str]) -> dict[str, Any]:
    """What ``hands.json`` holds: ``hands`` (each one's ``folder``, ``side`` and ``root_m``, its
    wrist keypoint [3] metres), ``right_to_left_m`` ([3] metres, the left wrist minus the right
    one, in ``frame``; None unless one right and one left hand), ``penetration_mm`` (the deepest
    point of any hand inside another, millimetres, by the hands' own fields),
    ``penetration_pairs_mm`` ([K, K], entry (a, b): hand a inside hand b), ``frame``,
    ``joint`` (the joint stage's report, None when it did not run) and ``notes``."""
    sides = [hand.side for hand in hands]
    offset = right_to_left(sides, roots)
    return {
        "hands": [{"folder": folder, "side": side, "root_m": np.round(root, 6).tolist()}
                  for folder, side, root in zip(folders, sides, roots, strict=True)],
        "right_to_left_m": None if offset is None else np.round(offset, 6).tolist(),
        "penetration_mm": round(float(penetration_mm.max(initial=0.0)), 3),
        "penetration_pairs_mm": np.round(penetration_mm, 3).tolist(),
        "frame": frame, "joint": joint, "notes": list(notes),
    }


def joined_mesh(meshes: Sequence[Mesh]) -> Mesh:
    """Several meshes as one (vertex colours kept when every mesh has them; no skinning
    weights: they belong to each hand's own skeleton)."""
    offsets = np.cumsum([0] + [len(mesh.vertices) for mesh in meshes])
    colors = None
    if all(mesh.colors is not None for mesh in meshes):
        colors = np.concatenate([mesh.colors for mesh in meshes])
    return Mesh(vertices=np.concatenate([mesh.vertices for mesh in meshes]),
                faces=np.concatenate([mesh.faces + offset
                                      for mesh, offset in zip(meshes, offsets, strict=False)]),
                colors=colors)
