"""Pose sequences to animate a hand with: read from JSON, completed, or a named motion."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch

from ..skeleton import POSE_DIM
from ..skeleton.params import MAX_TRANSLATION_M, HandParams

__all__ = ["MAX_POSES", "PoseSequence", "read_pose_sequence", "resolve_poses", "motion_poses"]

MAX_POSES = 10_000
"""The most poses a sequence file may hold (each one a mesh and a frame: about 7 minutes of
animation at 24 frames a second)."""


@dataclass
class PoseSequence:
    """Poses to animate a hand with (:func:`read_pose_sequence`).

    poses: [T, 48] (global rotation + 15 joints) or [T, 45] (finger joints only: the global
    rotation of the hand is kept), axis-angle radians, the hand's side.
    translations: [T, 3] metres, or None (the hand's translation is kept).
    """

    poses: torch.Tensor
    translations: torch.Tensor | None = None


def _sequence_lists(path: Path, data) -> tuple[list, list | None]:
    """The poses and translations (or None) of a parsed sequence file (ValueError naming it)."""
    translations = None
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"poses", "translations"})
        if unknown or "poses" not in data:
            raise ValueError(f"{path}: expected a list of poses or an object with keys 'poses' "
                             f"and optionally 'translations', got keys {sorted(data)}")
        translations = data.get("translations")
        data = data["poses"]
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a non-empty list of poses")
    if len(data) > MAX_POSES:
        raise ValueError(f"{path}: {len(data)} poses, more than the {MAX_POSES} a sequence may "
                         "hold; split it into several files")
    return data, translations


def read_pose_sequence(path: str | os.PathLike) -> PoseSequence:
    """Read a pose sequence (JSON): a list of poses, or ``{"poses": [...], "translations":
    [...]}`` (translations optional). Each pose is 48 numbers (global rotation then 15 joints,
    axis-angle radians, MANO order) or 45 (the 15 finger joints; the global rotation of the hand
    being animated is kept); translations are 3 numbers (metres) per pose. Errors name the
    file."""
    from ..utils.io import read_json

    path = Path(path)
    data, translations = _sequence_lists(path, read_json(path))
    try:
        poses = torch.tensor(data, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{path}: poses must be lists of 48 (or 45) numbers each") from None
    if poses.dim() != 2 or poses.shape[1] not in (POSE_DIM, POSE_DIM - 3):
        raise ValueError(f"{path}: poses must have shape [T, 48] or [T, 45], got "
                         f"{list(poses.shape)}")
    if not torch.isfinite(poses).all():
        raise ValueError(f"{path}: poses hold NaN or inf")
    if translations is not None:
        try:
            translations = torch.tensor(translations, dtype=torch.float32)
        except (TypeError, ValueError, RuntimeError):
            raise ValueError(f"{path}: translations must be lists of 3 numbers each") from None
        if translations.shape != (poses.shape[0], 3) or not torch.isfinite(translations).all():
            raise ValueError(f"{path}: translations must have shape [T, 3] = "
                             f"[{poses.shape[0]}, 3] with finite values, got "
                             f"{list(translations.shape)}")
        farthest = float(translations.double().norm(dim=1).max())
        if farthest > MAX_TRANSLATION_M:
            raise ValueError(f"{path}: a translation is {farthest:.3g} m from the origin (at "
                             f"most {MAX_TRANSLATION_M:g} m: positions in metres)")
    return PoseSequence(poses=poses, translations=translations)


def resolve_poses(
    params: HandParams, sequence: PoseSequence
) -> tuple[torch.Tensor, torch.Tensor]:
    """Complete a sequence with the hand's global rotation (45-D poses) and translation.

    -> (poses [T, 48] radians, translations [T, 3] metres)
    """
    poses = sequence.poses.float()
    num = poses.shape[0]
    if poses.shape[1] == POSE_DIM - 3:
        poses = torch.cat([params.pose[:3].expand(num, 3), poses], dim=1)
    translations = sequence.translations
    if translations is None:
        translations = params.translation.expand(num, 3)
    return poses.clone(), translations.float().clone()


def motion_poses(params: HandParams, name: str, frames_per_segment: int = 8) -> torch.Tensor:
    """From the hand's pose to a named pose (:data:`lisa_hand.handmodel.poses.POSE_NAMES`: flat,
    relaxed, fist, point, pinch, ok) and back, keeping its global rotation; finger joints move
    linearly in anatomical angles. -> [2 * frames_per_segment + 1, 48] radians"""
    from ..handmodel.poses import named_pose, pose_sequence

    target = named_pose(name, side=params.side).clone()
    target[:3] = params.pose[:3]
    return pose_sequence([params.pose, target, params.pose], frames_per_segment, params.side)
