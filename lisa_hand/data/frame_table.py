"""The frames of one split of a LISA-open dataset, with the per-frame parameters LISA is given
(the layout of :mod:`lisa_hand.data.layout`): the table both dataset readers of
:mod:`lisa_hand.data.datasets` share, so that frame ``i`` of either is the same frame.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..skeleton import NUM_JOINTS, POSE_DIM
from ..utils.io import read_json
from .layout import FramePaths, read_split

__all__ = ["SPLITS", "FrameTable", "read_frame_table"]

SPLITS = ("train", "val", "test")
"""The split names of ``split.json``."""


@dataclass(eq=False)
class FrameTable:
    """The subjects and frames of one split, with the per-frame parameters LISA is given.

    F frames, S subjects; frames are sorted by (subject, frame folder).
    """

    root: Path
    """The dataset folder."""
    split: str
    """'train', 'val' or 'test'."""
    subject_ids: list[str]
    """[S] sorted subject ids of the split (``subject_index`` indexes this list)."""
    frames: list[FramePaths]
    """[F] frame folders."""
    frame_subject: torch.Tensor
    """[F] long, subject index of each frame."""
    pose: torch.Tensor
    """[F, 48] float32 axis-angle radians (``params.json`` "pose")."""
    translation: torch.Tensor
    """[F, 3] float32 metres (``params.json`` "translation")."""
    rest_joints: torch.Tensor
    """[S, 16, 3] float32 metres, each subject's template skeleton (``subject.json``
    "template_rest_joints"): the skeleton LISA is trained and fitted with."""

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def num_subjects(self) -> int:
        return len(self.subject_ids)

    @property
    def frame_keys(self) -> list[str]:
        """[F] ``"s000/f000"`` names of the frames."""
        return [f"{p.root.parent.name}/{p.root.name}" for p in self.frames]


def _float_array(value: Any, shape: tuple[int, ...], path: Path, key: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {key!r} must be a numeric array of shape {list(shape)}") \
            from None
    if array.size == math.prod(shape):
        array = array.reshape(shape)
    if array.shape != shape or not np.isfinite(array).all():
        raise ValueError(f"{path}: {key!r} must be finite with shape {list(shape)}, got "
                         f"{list(array.shape)}")
    return array


def _read_entries(path: Path, shapes: dict[str, tuple[int, ...]]) -> list[np.ndarray]:
    """The arrays ``shapes`` names from one JSON object file, checked."""
    data = read_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object")
    missing = [key for key in shapes if key not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {', '.join(repr(k) for k in missing)}")
    return [_float_array(data[key], shape, path, key) for key, shape in shapes.items()]


def read_frame_table(root: str | os.PathLike, split: str = "train") -> FrameTable:
    """Read ``split.json``, the split's ``subject.json`` and ``params.json`` files.

    root: the dataset folder (``lisa synth`` output). split: 'train', 'val' or 'test'.
    Raises FileNotFoundError / ValueError naming the missing or malformed file.
    """
    root = Path(root)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"{root}: is a file, not a dataset folder (a folder with "
                                 "split.json and one folder per subject, as 'lisa synth' and "
                                 "'lisa import' write)")
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such dataset folder")
    subjects = sorted(read_split(root)[split])
    if not subjects:
        raise ValueError(f"{root / 'split.json'}: split {split!r} lists no subjects")
    frames: list[FramePaths] = []
    frame_subject: list[int] = []
    rest_joints = []
    for index, subject in enumerate(subjects):
        folder = root / subject
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: subject folder listed in split.json is missing")
        subject_json = folder / "subject.json"
        rest_joints.extend(_read_entries(subject_json, {"template_rest_joints": (NUM_JOINTS, 3)}))
        subject_frames = [FramePaths(p) for p in sorted(folder.glob("f*")) if p.is_dir()]
        if not subject_frames:
            raise ValueError(f"{folder}: subject {subject!r} has no frame folders (f000, ...)")
        frames.extend(subject_frames)
        frame_subject.extend([index] * len(subject_frames))
    poses, translations = [], []
    for paths in frames:
        pose, translation = _read_entries(paths.params, {"pose": (POSE_DIM,), "translation": (3,)})
        poses.append(pose)
        translations.append(translation)
    return FrameTable(
        root=root,
        split=split,
        subject_ids=subjects,
        frames=frames,
        frame_subject=torch.tensor(frame_subject, dtype=torch.long),
        pose=torch.from_numpy(np.stack(poses)).float(),
        translation=torch.from_numpy(np.stack(translations)).float(),
        rest_joints=torch.from_numpy(np.stack(rest_joints)).float(),
    )
