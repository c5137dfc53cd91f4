"""The random choices of a synthetic dataset: subjects, the camera rig, each frame's pose and
placement, and the split by subject.

Every choice comes from a ``numpy.random.SeedSequence`` keyed by ``(seed, stream, subject,
frame)`` (one stream per kind of choice), so subject ``k`` and its frame ``f`` are the same
whatever the numbers of subjects, poses and workers. The rules are documented in
:mod:`lisa_hand.data.synth.dataset`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera, make_rig
from ..layout import subject_id
from ..shading import GainBias
from .config import SynthConfig, check_integer

__all__ = [
    "SubjectRecord",
    "FrameSetup",
    "split_subjects",
    "make_subject",
    "dataset_rig",
    "frame_setup",
    "preview_generator",
]

# Random streams of the SeedSequence keys (seed, stream, ...): one per kind of choice.
_STREAM_SUBJECT = 0
_STREAM_FRAME = 1
_STREAM_RIG = 2
_STREAM_SPLIT = 3
_STREAM_PREVIEW = 4


@dataclass(eq=False)
class SubjectRecord:
    """One subject: what ``subject.json`` holds, plus the hand itself."""

    index: int
    hand: Any
    """The :class:`lisa_hand.handmodel.OpenHand`."""
    template_betas: np.ndarray
    """[10] float64 betas of the template fitted to the hand."""
    template_rest_joints: np.ndarray
    """[16, 3] float64 metres, the template's rest skeleton for those betas."""

    @property
    def id(self) -> str:
        return subject_id(self.index)

    def to_json(self) -> dict[str, Any]:
        hand = self.hand
        return {
            "id": self.id,
            "side": hand.side,
            "shape": dataclasses.asdict(hand.shape),
            "appearance": dataclasses.asdict(hand.appearance),
            "detail_seed": int(hand.detail_seed),
            **({"hand_model": hand.model} if hand.model != "v1" else {}),
            "rest_joints": hand.rest_joints.tolist(),
            "template_betas": self.template_betas.tolist(),
            "template_rest_joints": self.template_rest_joints.tolist(),
        }


@dataclass(eq=False)
class FrameSetup:
    """The random choices of one frame (before any geometry is built)."""

    pose: torch.Tensor
    """[48] float64 axis-angle radians, in the subject's side convention; ``pose[:3]`` is the
    world rotation of the hand about its wrist."""
    translation: torch.Tensor
    """[3] float64 metres."""
    pose_name: str | None
    """The named pose used, or None for a sampled one."""
    rng: np.random.Generator
    """The frame's generator for what follows (scan, SDF samples, lights)."""



# ------------------------------------------------------------------------------------------------
# Seeded generators


def _numpy_rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, *key]))


def _torch_generator(rng: np.random.Generator) -> torch.Generator:
    return torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))


def _to_numpy64(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    return np.asarray(value, dtype=np.float64)



def preview_generator(config: SynthConfig, index: int) -> torch.Generator:
    """The torch generator of subject ``index``'s extra preview poses (its own stream)."""
    return _torch_generator(_numpy_rng(config.seed, _STREAM_PREVIEW, index))


def split_subjects(num_subjects: int, fractions: Sequence[float] = (0.7, 0.1, 0.2),
                   seed: int = 0) -> dict[str, list[str]]:
    """Subject ids per split, by subject (see the module docstring for the exact rule).

    -> {"train": [...], "val": [...], "test": [...]}, each sorted.
    """
    num_subjects = check_integer(num_subjects, "num_subjects", 1)
    _, val_fraction, test_fraction = (float(v) for v in fractions)
    num_test = max(1, math.floor(test_fraction * num_subjects + 0.5)) if num_subjects >= 2 else 0
    num_test = min(num_test, num_subjects - 1) if num_subjects >= 2 else 0
    num_val = min(math.floor(val_fraction * num_subjects + 0.5), num_subjects - 1 - num_test)
    num_val = max(num_val, 0)
    order = _numpy_rng(seed, _STREAM_SPLIT).permutation(num_subjects)
    test = order[:num_test]
    val = order[num_test:num_test + num_val]
    train = order[num_test + num_val:]
    return {name: [subject_id(int(i)) for i in sorted(ids)]
            for name, ids in (("train", train), ("val", val), ("test", test))}



# ------------------------------------------------------------------------------------------------
# Subjects, rig, frames


def make_subject(config: SynthConfig, index: int, fit_template: bool = True) -> SubjectRecord:
    """Subject ``index`` of the dataset ``config`` describes (depends on the seed, the index,
    ``left_fraction``, ``hand_model`` and, for v3, ``ages`` only).

    fit_template: fit the MANO-like template (``template_betas``, ``template_rest_joints``);
    False leaves them empty (previews).
    """
    from ...handmodel import sample_hand
    from ...handmodel.template import load_template

    index = check_integer(index, "index", 0)
    rng = _numpy_rng(config.seed, _STREAM_SUBJECT, index)
    side = "left" if rng.random() < config.left_fraction else "right"
    hand = sample_hand(_torch_generator(rng), side=side, model=config.hand_model,
                       ages=tuple(config.ages))
    betas = np.zeros(0)
    template_joints = np.zeros((0, 3))
    if fit_template:
        template = load_template()
        betas = _to_numpy64(template.fit_betas(hand)).reshape(-1)
        betas_t = torch.as_tensor(betas, dtype=torch.float64)[None]
        template_joints = _to_numpy64(template.rest_joints(betas_t))[0]
        if side == "left":  # the template is a right hand; a left subject gets its mirror image
            template_joints = template_joints * np.array([-1.0, 1.0, 1.0])
    return SubjectRecord(index=index, hand=hand, template_betas=betas,
                         template_rest_joints=template_joints)


def dataset_rig(config: SynthConfig) -> tuple[list[Camera], GainBias]:
    """The cameras of every frame (named cam000, ...) and their gain [C, 3] and bias [C, 3]."""
    rng = _numpy_rng(config.seed, _STREAM_RIG)
    cameras = make_rig(config.num_views, target=(0.0, 0.0, 0.0), radius=config.rig_radius,
                       width=config.width, height=config.height, fov_deg=config.fov_deg,
                       seed=int(rng.integers(0, 2**31 - 1)), jitter=config.rig_jitter,
                       coverage=config.rig_coverage, up=(0.0, 1.0, 0.0))
    if config.gain_bias is None:
        gain_bias = GainBias(gain=np.ones((config.num_views, 3)),
                             bias=np.zeros((config.num_views, 3)))
    else:
        gain_bias = config.gain_bias.sample(config.num_views, rng)
    return cameras, gain_bias


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    from ...geometry.rotations import axis_angle_to_matrix

    return axis_angle_to_matrix(torch.as_tensor(axis * angle, dtype=torch.float64)).numpy()


def _global_orientation(rng: np.random.Generator, side: str, max_tilt_deg: float) -> np.ndarray:
    """[3] axis-angle: fingers up (+y), turned about +y uniformly, tilted by up to the limit."""
    from ...geometry.rotations import matrix_to_axis_angle

    # Rest hands point their fingers along -x (right) or +x (left); turn them to +y.
    base = _rotation_about(np.array([0.0, 0.0, 1.0]), -math.pi / 2 if side == "right"
                           else math.pi / 2)
    # Tilt uniform over the spherical cap of half-angle max_tilt_deg around +y.
    cos_tilt = 1.0 - rng.random() * (1.0 - math.cos(math.radians(max_tilt_deg)))
    tilt_direction = rng.random() * 2.0 * math.pi
    tilt_axis = np.array([math.cos(tilt_direction), 0.0, math.sin(tilt_direction)])
    tilt = _rotation_about(tilt_axis, math.acos(min(max(cos_tilt, -1.0), 1.0)))
    turn = _rotation_about(np.array([0.0, 1.0, 0.0]), rng.random() * 2.0 * math.pi)
    rotation = tilt @ turn @ base
    return matrix_to_axis_angle(torch.from_numpy(rotation)).numpy()


def frame_setup(config: SynthConfig, subject: SubjectRecord, frame: int) -> FrameSetup:
    """Pose, orientation and translation of frame ``frame`` of ``subject`` (depends on the seed,
    the subject index and the frame index only)."""
    from ...handmodel import POSE_NAMES, named_pose, sample_pose

    frame = check_integer(frame, "frame", 0)
    rng = _numpy_rng(config.seed, _STREAM_FRAME, subject.index, frame)
    side = subject.hand.side
    generator = _torch_generator(rng)
    pose_name = None
    if rng.random() < config.named_pose_fraction:
        pose_name = POSE_NAMES[int(rng.integers(len(POSE_NAMES)))]
        pose = named_pose(pose_name, side=side, dtype=torch.float64)
    else:
        pose = sample_pose(generator, 1, noise=config.pose_noise, side=side)[0].double()
    pose = pose.clone()
    pose[:3] = torch.from_numpy(_global_orientation(rng, side, config.max_tilt_deg))
    centred = subject.hand.posed(pose)
    keypoints = centred.keypoints.numpy()
    centre = 0.5 * (keypoints.min(0) + keypoints.max(0))
    translation = -centre + config.translation_std * rng.standard_normal(3)
    return FrameSetup(pose=pose, translation=torch.from_numpy(translation), pose_name=pose_name,
                      rng=rng)

