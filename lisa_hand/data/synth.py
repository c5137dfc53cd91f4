"""The dataset generator behind ``lisa synth``: subjects of the open hand model, posed, scanned
and photographed by a multi-view rig, written in the layout of :mod:`lisa_hand.data.layout`
(documented file by file in ``docs/data_formats.md``).

Per subject ``k`` (:func:`make_subject`): a random hand (:func:`lisa_hand.handmodel.sample_hand`:
shape, appearance, detail seed), its side, and the MANO-like template fitted to it
(``template_betas``, ``template_rest_joints``: the skeleton LISA is trained with).

Per frame ``f`` of subject ``k`` (:func:`frame_setup`): a pose (a named pose with probability
``named_pose_fraction``, else a natural pose from :func:`lisa_hand.handmodel.sample_pose`), a
random global orientation (fingers up, a uniform turn about the vertical and a tilt of at most
``max_tilt_deg``), a translation that puts the centre of the hand's keypoints within
``translation_std`` of the rig's target (the origin), then

* ``mesh.ply``: the ground-truth mesh (marching cubes of the exact field, about 100k vertices
  at the default ``voxels_per_length``, vertex albedo and skinning weights);
* ``scan.npz``: a scan of that mesh (:func:`lisa_hand.data.scans.simulate_scan`, clean and full
  by default) with the exact skinning weights of the field at its points, the template's
  (nearest posed template vertex), and near-surface SDF samples (exact distances to the mesh,
  around clean surface samples, whatever the scan's noise);
* images, masks and depth of every camera (Embree ray casting of the same mesh,
  :func:`lisa_hand.data.images.render_views`, vertex albedo, the dataset's per-camera gain and
  bias), ``cameras.json`` and ``keypoints.json`` (projected, with occlusion from the depth map).

The rig (:func:`make_rig`, ``num_views`` cameras on a sphere around the origin, all looking at
it) and each camera's colour gain and bias are drawn once per dataset: the cameras and their
names are the same in every frame, as in a capture studio (the per-camera colour calibration of
LISA Section 4.2 is then learnable).

Determinism: every random choice comes from a ``numpy.random.SeedSequence`` keyed by
``(seed, stream, subject, frame)``, so subject ``k`` and its frame ``f`` are the same whatever the
numbers of subjects, poses and workers (each worker runs torch with one thread; the main process
too while it generates). Only ``scan.npz`` differs between two runs byte for byte (the ZIP
container stores the write time); its arrays are identical.

Split (:func:`split_subjects`, by subject, so test subjects never appear in training): with ``S``
subjects and fractions ``(train, val, test)``, ``num_test = max(1, round(test * S))`` when
``S >= 2`` (0 when ``S = 1``), ``num_val = round(val * S)`` reduced so that at least one subject
trains, ``num_train`` the rest; the subjects are shuffled by a seeded permutation and taken in
that order (test first, then val, then train); each list is sorted. Defaults 0.7/0.1/0.2: 20
subjects -> 14/2/4, 3 -> 2/0/1, 2 -> 1/0/1, 1 -> 1/0/0.

Timing, one frame at the defaults (about 120k mesh vertices, 20k scan points, 20k SDF samples)
and 8 views of 512x334, one core, measured on the shared 2-core machine: about 3.5 s of CPU, of
which the mesh (the exact field on the coarse-to-fine grid, then albedo and weights at the
vertices) takes half, the SDF samples' closest points a quarter, the images, the scan and the
file writes the rest (``SynthSummary.stage_seconds`` has the per-stage sums of a run). Two
workers write 20 subjects x 10 poses (200 frames) in about 800 s of CPU.

Worker processes are started with ``spawn``: a script that calls :func:`synthesize` with more
than one worker must guard its entry point with ``if __name__ == "__main__":`` (the ``lisa``
command does).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import re
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..geometry.cameras import Camera, make_rig, save_cameras
from ..skeleton import KEYPOINT_NAMES
from ..utils.io import ensure_writable_dir, write_json
from .images import (
    GainBias,
    GainBiasConfig,
    MeshRayCaster,
    ShadingConfig,
    project_keypoints,
    render_views,
)
from .layout import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FramePaths,
    frame_id,
    subject_id,
    write_depth,
    write_image,
    write_mask,
    write_npz,
)
from .scans import ScanConfig, sample_surface, sdf_samples, simulate_scan

__all__ = [
    "GENERATOR_VERSION",
    "SynthConfig",
    "SynthSummary",
    "SubjectRecord",
    "FrameSetup",
    "parse_resolution",
    "split_subjects",
    "make_subject",
    "dataset_rig",
    "frame_setup",
    "synthesize",
    "write_preview",
]

GENERATOR_VERSION = 1
"""Version of the generator: bumped whenever the files written for a given seed change."""

# Random streams of the SeedSequence keys (seed, stream, ...): one per kind of choice.
_STREAM_SUBJECT = 0
_STREAM_FRAME = 1
_STREAM_RIG = 2
_STREAM_SPLIT = 3
_STREAM_PREVIEW = 4

_MAX_IMAGE_SIDE = 16384
_MAX_WORKERS = 8
_SUBJECT_DIR = re.compile(r"^s\d{3,}$")
# Files of a previous dataset that ``overwrite`` removes (besides the subject folders).
_DATASET_FILES = ("dataset.json", "split.json")


@dataclass(frozen=True)
class SynthConfig:
    """What :func:`synthesize` writes (the defaults are the dataset of the issue, InterHand-like
    1024x667 images)."""

    num_subjects: int = 20
    """Subjects (folders s000, s001, ...); subject k is the same whatever this number."""
    num_poses: int = 10
    """Frames per subject (f000, f001, ...), each a different pose."""
    num_views: int = 8
    """Cameras of the rig; every frame has an image, mask and depth map per camera."""
    resolution: tuple[int, int] = (1024, 667)
    """Image size (width, height) in pixels."""
    seed: int = 0
    """Seed of every random choice (>= 0): the same seed writes the same dataset."""
    split_fractions: tuple[float, float, float] = (0.7, 0.1, 0.2)
    """(train, val, test) fractions of the subjects (see :func:`split_subjects`)."""
    scan: ScanConfig = field(default_factory=ScanConfig)
    """How the scan in ``scan.npz`` is simulated (default: 20k clean points, full surface)."""
    num_sdf_samples: int = 20000
    """Near-surface SDF samples per frame (``sdf_points``, ``sdf`` in ``scan.npz``)."""
    sdf_sigmas: tuple[float, ...] = (0.002, 0.01)
    """Scales of the SDF samples' offsets along the normal, metres (each sample picks one)."""
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    """Lights, ambient and background of the images (default: a light at each camera, black
    background)."""
    gain_bias: GainBiasConfig | None = field(default_factory=GainBiasConfig)
    """Per-camera colour gain and bias, drawn once per dataset; None: gain 1, bias 0."""
    supersample: int = 1
    """Anti-aliasing: rays per pixel side (1: one ray through each pixel centre, hard edges)."""
    named_pose_fraction: float = 0.2
    """Probability that a frame's pose is a named one (flat, relaxed, fist, point, pinch, ok)
    instead of a sampled natural pose."""
    pose_noise: float = 1.0
    """Scale of the per-joint noise of the sampled poses (``sample_pose(noise=...)``)."""
    left_fraction: float = 0.0
    """Probability that a subject is a left hand (0: all right hands, as LISA's experiments)."""
    max_tilt_deg: float = 45.0
    """Largest tilt of the fingers away from the vertical (world +y), degrees; the turn about the
    vertical is uniform in [0, 360)."""
    translation_std: float = 0.01
    """Std of the offset of the hand's keypoint centre from the rig's target, metres (each
    axis)."""
    rig_radius: float = 0.6
    """Distance of the cameras from the target, metres."""
    fov_deg: float = 40.0
    """Horizontal field of view of the cameras, degrees."""
    rig_coverage: float = 1.0
    """Fraction of the sphere around the hand the cameras are spread over (1: all around; less:
    a dome around +y)."""
    rig_jitter: float = 0.01
    """Std of the random offsets of each camera's position and aim point, metres."""
    voxels_per_length: int = 255
    """Mesh resolution: marching-cubes voxels per hand length (255: about 0.7 mm voxels,
    100k-150k vertices; lower it only for tests)."""
    write_depth: bool = True
    """Also write ``depth/NAME.png`` for every camera."""
    num_workers: int = 0
    """Worker processes (1: in this process; 0: one per CPU core, at most 8). The dataset does
    not depend on it."""

    def __post_init__(self) -> None:
        for name in ("num_subjects", "num_poses", "num_views", "supersample"):
            _check_int(getattr(self, name), name, 1)
        _check_int(self.seed, "seed", 0)
        _check_int(self.num_sdf_samples, "num_sdf_samples", 0)
        _check_int(self.num_workers, "num_workers", 0)
        _check_int(self.voxels_per_length, "voxels_per_length", 16)
        resolution = tuple(self.resolution) if isinstance(self.resolution, (tuple, list)) else ()
        if len(resolution) != 2 or not all(
            isinstance(v, (int, np.integer)) and not isinstance(v, bool)
            and 1 <= v <= _MAX_IMAGE_SIDE for v in resolution
        ):
            raise ValueError(f"resolution must be (width, height), two ints in [1, "
                             f"{_MAX_IMAGE_SIDE}] pixels, got {self.resolution!r}")
        object.__setattr__(self, "resolution", (int(resolution[0]), int(resolution[1])))
        fractions = tuple(self.split_fractions) if isinstance(self.split_fractions,
                                                              (tuple, list)) else ()
        if len(fractions) != 3 or not all(_is_number(v) and v >= 0 for v in fractions) \
                or abs(sum(fractions) - 1.0) > 1e-6:
            raise ValueError(f"split_fractions must be 3 numbers >= 0 (train, val, test) summing "
                             f"to 1, got {self.split_fractions!r}")
        object.__setattr__(self, "split_fractions", tuple(float(v) for v in fractions))
        sigmas = tuple(self.sdf_sigmas) if isinstance(self.sdf_sigmas, (tuple, list)) else ()
        if not sigmas or not all(_is_number(v) and v > 0 for v in sigmas):
            raise ValueError(f"sdf_sigmas must be one or more numbers > 0 (metres), got "
                             f"{self.sdf_sigmas!r}")
        object.__setattr__(self, "sdf_sigmas", tuple(float(v) for v in sigmas))
        for name, kind in (("scan", ScanConfig), ("shading", ShadingConfig)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"{name} must be a {kind.__name__}, got "
                                f"{type(getattr(self, name)).__name__}")
        if self.gain_bias is not None and not isinstance(self.gain_bias, GainBiasConfig):
            raise TypeError(f"gain_bias must be a GainBiasConfig or None, got "
                            f"{type(self.gain_bias).__name__}")
        for name, low, high in (("named_pose_fraction", 0.0, 1.0), ("left_fraction", 0.0, 1.0),
                                ("max_tilt_deg", 0.0, 180.0), ("rig_coverage", 1e-6, 1.0)):
            value = getattr(self, name)
            if not (_is_number(value) and low <= value <= high):
                raise ValueError(f"{name} must be a number in [{low}, {high}], got {value!r}")
        for name in ("pose_noise", "translation_std", "rig_jitter"):
            value = getattr(self, name)
            if not (_is_number(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not (_is_number(self.rig_radius) and self.rig_radius > 0):
            raise ValueError(f"rig_radius must be > 0 (metres), got {self.rig_radius!r}")
        if not (_is_number(self.fov_deg) and 0 < self.fov_deg < 180):
            raise ValueError(f"fov_deg must be in (0, 180) degrees, got {self.fov_deg!r}")
        if not isinstance(self.write_depth, bool):
            raise TypeError(f"write_depth must be a bool, got {self.write_depth!r}")

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    @property
    def num_frames(self) -> int:
        """Frames in all: subjects x poses."""
        return self.num_subjects * self.num_poses

    def workers(self) -> int:
        """The number of worker processes :func:`synthesize` starts (1: none)."""
        if self.num_workers:
            return min(self.num_workers, self.num_frames)
        return max(1, min(os.cpu_count() or 1, _MAX_WORKERS, self.num_frames))

    def to_dict(self) -> dict[str, Any]:
        """The settings that define the dataset, JSON-able (``num_workers`` left out: it does not
        change what is written)."""
        data = dataclasses.asdict(self)
        del data["num_workers"]
        return data


@dataclass
class SynthSummary:
    """What :func:`synthesize` wrote and how long it took."""

    root: Path
    """The dataset folder."""
    num_subjects: int
    num_frames: int
    """Frames in all (subjects x poses)."""
    num_views: int
    num_images: int
    """RGB images written (frames x views)."""
    split: dict[str, list[str]]
    """Subject ids per split (train, val, test)."""
    seconds: float
    """Wall-clock time of the whole run, seconds."""
    num_workers: int
    """Worker processes used (1: in process)."""
    stage_seconds: dict[str, float] = field(default_factory=dict)
    """Seconds summed over all frames (and workers) per stage: subject (hand + template fit),
    pose, mesh, scan (scan + weights), template (template weights), sdf, render, keypoints,
    write."""

    @property
    def seconds_per_frame(self) -> float:
        """Wall-clock seconds per frame."""
        return self.seconds / max(self.num_frames, 1)

    def describe(self) -> str:
        """A few lines for the terminal."""
        split = ", ".join(f"{len(v)} {k}" for k, v in self.split.items())
        per_stage = sum(self.stage_seconds.values())
        stages = ", ".join(
            f"{name} {value / max(self.num_frames, 1):.2f}"
            for name, value in self.stage_seconds.items()
        )
        return (
            f"wrote {self.root}: {self.num_subjects} subjects x "
            f"{self.num_frames // max(self.num_subjects, 1)} poses x {self.num_views} views = "
            f"{self.num_images} images (split: {split})\n"
            f"time: {self.seconds:.1f} s ({self.seconds_per_frame:.2f} s per frame, "
            f"{self.num_workers} worker(s); {per_stage / max(self.num_frames, 1):.2f} s of work "
            f"per frame: {stages})"
        )


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
# Small helpers


def _is_number(value: Any) -> bool:
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, bool) and math.isfinite(float(value)))


def _check_int(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _numpy_rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, *key]))


def _torch_generator(rng: np.random.Generator) -> torch.Generator:
    return torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))


def _to_numpy64(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    return np.asarray(value, dtype=np.float64)


def parse_resolution(text: str) -> tuple[int, int]:
    """``"1024x667"`` -> ``(1024, 667)`` (width, height; ``x`` or ``X``, positive integers)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if match is None:
        raise ValueError(f"resolution must be WIDTHxHEIGHT in pixels (e.g. 1024x667), got "
                         f"{text!r}")
    width, height = int(match.group(1)), int(match.group(2))
    if not (1 <= width <= _MAX_IMAGE_SIDE and 1 <= height <= _MAX_IMAGE_SIDE):
        raise ValueError(f"resolution {text!r}: width and height must be in [1, "
                         f"{_MAX_IMAGE_SIDE}] pixels")
    return width, height


def split_subjects(num_subjects: int, fractions: Sequence[float] = (0.7, 0.1, 0.2),
                   seed: int = 0) -> dict[str, list[str]]:
    """Subject ids per split, by subject (see the module docstring for the exact rule).

    -> {"train": [...], "val": [...], "test": [...]}, each sorted.
    """
    num_subjects = _check_int(num_subjects, "num_subjects", 1)
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


@functools.lru_cache(maxsize=1)
def _template():
    from ..handmodel.template import load_template

    return load_template()


# ------------------------------------------------------------------------------------------------
# Subjects, rig, frames


def make_subject(config: SynthConfig, index: int, fit_template: bool = True) -> SubjectRecord:
    """Subject ``index`` of the dataset ``config`` describes (depends on the seed, the index and
    ``left_fraction`` only).

    fit_template: fit the MANO-like template (``template_betas``, ``template_rest_joints``);
    False leaves them empty (previews).
    """
    from ..handmodel import sample_hand

    index = _check_int(index, "index", 0)
    rng = _numpy_rng(config.seed, _STREAM_SUBJECT, index)
    side = "left" if rng.random() < config.left_fraction else "right"
    hand = sample_hand(_torch_generator(rng), side=side)
    betas = np.zeros(0)
    template_joints = np.zeros((0, 3))
    if fit_template:
        template = _template()
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
    from ..geometry.rotations import axis_angle_to_matrix

    return axis_angle_to_matrix(torch.as_tensor(axis * angle, dtype=torch.float64)).numpy()


def _global_orientation(rng: np.random.Generator, side: str, max_tilt_deg: float) -> np.ndarray:
    """[3] axis-angle: fingers up (+y), turned about +y uniformly, tilted by up to the limit."""
    from ..geometry.rotations import matrix_to_axis_angle

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
    from ..handmodel import POSE_NAMES, named_pose, sample_pose

    frame = _check_int(frame, "frame", 0)
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


# ------------------------------------------------------------------------------------------------
# One frame


def _scan_is_clean(scan: ScanConfig) -> bool:
    """Points exactly on the whole surface (no noise, no outliers, not partial)."""
    return (not scan.partial and scan.noise_normal_std == 0 and scan.noise_isotropic_std == 0
            and round(scan.outlier_fraction * scan.num_points) == 0)


# Directions of the inside/outside rays of :func:`_mesh_sdf_fn` (unit, none along a grid axis or
# a grid diagonal, so that no ray runs along the faces of a marching-cubes mesh).
_SIGN_DIRECTIONS = np.array([[0.4862, 0.7293, 0.4814], [-0.6521, 0.2314, -0.7219],
                             [0.2087, -0.8903, 0.4047]])
_SIGN_DIRECTIONS /= np.linalg.norm(_SIGN_DIRECTIONS, axis=1, keepdims=True)


def _mesh_sdf_fn(caster):
    """``points [N, 3] -> [N]`` signed distance to a watertight mesh, metres, negative inside.

    The magnitude is the distance to the closest point of the mesh (point-cloud-utils, recomputed
    in float64 from that point); the sign is the majority over three rays from the point: a ray
    whose first hit is a back face (its normal along the ray) starts inside. Same values as
    winding numbers for a watertight mesh, at half the cost on a 250k-face mesh.

    caster: a :class:`lisa_hand.data.images.MeshRayCaster` of the mesh (also used for the images).
    """
    import point_cloud_utils as pcu

    vertices = caster.vertices.astype(np.float64)
    faces = caster.faces

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        query = points.detach().cpu().numpy().astype(np.float64)
        _, face_ids, barycentric = pcu.closest_points_on_mesh(query, vertices, faces)
        closest = (np.asarray(barycentric)[:, :, None]
                   * vertices[faces[np.asarray(face_ids)]]).sum(axis=1)
        magnitude = np.linalg.norm(query - closest, axis=1)
        votes = np.zeros(query.shape[0], dtype=np.int64)
        for direction in _SIGN_DIRECTIONS:
            directions = np.broadcast_to(direction, query.shape)
            hits = caster.intersect(query, directions)
            facing = (caster.face_normals[np.maximum(hits.face_ids, 0)] @ direction) > 0
            votes += hits.hit & facing
        inside = votes >= 2
        return torch.from_numpy(np.where(inside, -magnitude, magnitude)).to(points.dtype)

    return sdf_fn


def _template_weights(subject: SubjectRecord, setup: FrameSetup,
                      points: np.ndarray) -> np.ndarray:
    """[N, 16] float32 weights of the nearest vertex of the template posed like the frame (its
    mirror image for a left hand: the template is a right hand)."""
    from ..skeleton import mirror_points, mirror_pose

    template = _template()
    left = subject.hand.side == "left"
    pose, translation = setup.pose, setup.translation
    if left:
        pose, translation = mirror_pose(pose), mirror_points(translation)
    betas = torch.as_tensor(subject.template_betas, dtype=template.dtype)
    posed = template.forward(pose[None].to(template.dtype), betas[None],
                             translation[None].to(template.dtype))
    vertices = posed.vertices[0]
    if left:
        vertices = mirror_points(vertices)
    weights = template.skinning_weights_at(torch.from_numpy(points).to(template.dtype), vertices)
    return _to_numpy64(weights).astype(np.float32)


def _write_frame(root: Path, config: SynthConfig, subject: SubjectRecord, frame: int,
                 cameras: list[Camera], gain_bias: GainBias) -> dict[str, float]:
    """Generate and write one frame folder; -> seconds per stage."""
    times: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        times[name] = times.get(name, 0.0) + now - clock
        clock = now

    hand = subject.hand
    setup = frame_setup(config, subject, frame)
    rng = setup.rng
    posed = hand.posed(setup.pose, setup.translation)
    lap("pose")

    voxel_size = hand.shape.hand_length / config.voxels_per_length
    mesh = posed.mesh(voxel_size=voxel_size)
    caster = MeshRayCaster(mesh.vertices, mesh.faces)  # for the SDF signs and the images
    lap("mesh")

    scan = simulate_scan(mesh.vertices, mesh.faces, config.scan, seed=rng)
    with torch.no_grad():
        weights = posed.evaluate(torch.from_numpy(scan.points)).weights
    weights = weights.float().cpu().numpy()
    lap("scan")

    template_weights = _template_weights(subject, setup, scan.points)
    lap("template")

    if config.num_sdf_samples:
        if _scan_is_clean(config.scan):
            surface_points, surface_normals = scan.points, scan.normals
        else:  # SDF samples around the true surface, whatever the sensor's noise or view
            surface_points, surface_normals, _ = sample_surface(
                mesh.vertices, mesh.faces, config.num_sdf_samples, rng)
        near = sdf_samples(_mesh_sdf_fn(caster), surface_points, surface_normals,
                           num_samples=config.num_sdf_samples, sigma=config.sdf_sigmas,
                           generator=rng)
        sdf_points, sdf_values = near.points, near.sdf
    else:
        sdf_points, sdf_values = np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    lap("sdf")

    albedo = mesh.colors.astype(np.float32) / 255.0
    views = render_views(None, None, cameras, albedo, shading=config.shading, generator=rng,
                         gain_bias=gain_bias, supersample=config.supersample, caster=caster)
    lap("render")

    keypoint_views = {}
    for camera, view in zip(cameras, views, strict=True):
        projection = project_keypoints(posed.keypoints, camera, depth=view.depth)
        keypoint_views[camera.name] = {
            "keypoints": projection.pixels.astype(np.float64).tolist(),
            "visible": projection.visible.tolist(),
            "in_image": projection.in_image.tolist(),
            "depth": projection.depth.astype(np.float64).tolist(),
        }
    lap("keypoints")

    from .meshio import save_mesh

    paths = FramePaths(root / subject.id / frame_id(frame))
    save_mesh(paths.mesh, mesh)
    write_npz(paths.scan, points=scan.points, normals=scan.normals, weights=weights,
              template_weights=template_weights, sdf_points=sdf_points, sdf=sdf_values,
              is_outlier=scan.is_outlier)
    for camera, view in zip(cameras, views, strict=True):
        write_image(paths.image(camera.name), view.rgb)
        write_mask(paths.mask(camera.name), view.mask)
        if config.write_depth:
            write_depth(paths.depth(camera.name), view.depth)
    save_cameras(paths.cameras, cameras)
    write_json(paths.keypoints, {"names": list(KEYPOINT_NAMES), "views": keypoint_views})
    names = [camera.name for camera in cameras]
    write_json(paths.params, {
        "subject": subject.id,
        "side": hand.side,
        "pose": setup.pose.tolist(),
        "translation": setup.translation.tolist(),
        "joints": posed.joints.tolist(),
        "keypoints": posed.keypoints.tolist(),
        "pose_name": setup.pose_name,
        "camera_gain": {n: gain_bias.gain[i].astype(np.float64).tolist()
                        for i, n in enumerate(names)},
        "camera_bias": {n: gain_bias.bias[i].astype(np.float64).tolist()
                        for i, n in enumerate(names)},
    })
    lap("write")
    return times


# ------------------------------------------------------------------------------------------------
# Workers


@functools.lru_cache(maxsize=4)
def _rig_cached(config: SynthConfig) -> tuple[list[Camera], GainBias]:
    return dataset_rig(config)


_WORKER_SUBJECTS: dict[tuple, SubjectRecord] = {}


def _init_worker() -> None:
    torch.set_num_threads(1)


def _subject_task(config: SynthConfig, index: int) -> tuple[dict[str, Any], float]:
    start = time.perf_counter()
    record = make_subject(config, index)
    return record.to_json(), time.perf_counter() - start


def _frame_task(root: str, config: SynthConfig, subject_json: dict[str, Any],
                frame: int) -> dict[str, float]:
    index = int(subject_json["id"][1:])
    key = (config, index)
    record = _WORKER_SUBJECTS.get(key)
    if record is None:
        record = make_subject(config, index, fit_template=False)
        record.template_betas = np.asarray(subject_json["template_betas"], np.float64)
        record.template_rest_joints = np.asarray(subject_json["template_rest_joints"],
                                                 np.float64)
        _WORKER_SUBJECTS.clear()  # frames arrive subject by subject: keep the current one
        _WORKER_SUBJECTS[key] = record
    cameras, gain_bias = _rig_cached(config)
    return _write_frame(Path(root), config, record, frame, cameras, gain_bias)


class _InProcess:
    """The executor interface, run in this process with one torch thread (for determinism)."""

    def __init__(self) -> None:
        self._threads = torch.get_num_threads()
        torch.set_num_threads(1)

    def submit(self, fn, *args):
        from concurrent.futures import Future

        future: Future = Future()
        try:
            future.set_result(fn(*args))
        except BaseException as exc:  # handed to the caller by future.result()
            future.set_exception(exc)
        return future

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        torch.set_num_threads(self._threads)


def _executor(num_workers: int):
    if num_workers <= 1:
        return _InProcess()
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: a fresh interpreter per worker (forking a process whose torch thread pools are
    # running can deadlock).
    return ProcessPoolExecutor(max_workers=num_workers, initializer=_init_worker,
                               mp_context=multiprocessing.get_context("spawn"))


# ------------------------------------------------------------------------------------------------
# The dataset


def _prepare_output(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a folder")
    if out.is_dir():
        entries = sorted(p.name for p in out.iterdir())
        if entries and not overwrite:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise FileExistsError(f"{out}: output folder is not empty ({shown}); choose another "
                                  f"folder or overwrite it (overwrite=True, --overwrite)")
        if overwrite:
            # Only what a dataset holds: subject folders and the dataset files; anything else the
            # folder contains is left alone.
            for name in entries:
                path = out / name
                if path.is_dir() and _SUBJECT_DIR.match(name):
                    shutil.rmtree(path)
                elif name in _DATASET_FILES and path.is_file():
                    path.unlink()
    ensure_writable_dir(out)


def synthesize(out: str | os.PathLike, config: SynthConfig | None = None, progress: bool = True,
               overwrite: bool = False) -> SynthSummary:
    """Write a dataset (layout of :mod:`lisa_hand.data.layout`) into the folder ``out``.

    out: the dataset folder; created if missing, must be empty unless ``overwrite`` (which first
        removes a previous dataset's subject folders s000..., ``dataset.json`` and
        ``split.json``, nothing else).
    config: what to write (default :class:`SynthConfig()`).
    progress: show a tqdm bar over the frames.
    Raises FileExistsError for a non-empty ``out``, OSError for an unwritable one, ValueError
    for bad settings. ``dataset.json`` is written last: a folder without it is unfinished.
    -> :class:`SynthSummary` (counts, split, wall-clock seconds, seconds per stage).
    """
    config = SynthConfig() if config is None else config
    if not isinstance(config, SynthConfig):
        raise TypeError(f"config must be a SynthConfig, got {type(config).__name__}")
    out = Path(out)
    _prepare_output(out, overwrite)
    start = time.perf_counter()
    from concurrent.futures import as_completed

    from tqdm.auto import tqdm

    split = split_subjects(config.num_subjects, config.split_fractions, config.seed)
    cameras, _ = dataset_rig(config)
    num_workers = config.workers()
    stage_seconds: dict[str, float] = {"subject": 0.0}
    executor = _executor(num_workers)
    bar = tqdm(total=config.num_subjects + config.num_frames, desc="synth", unit="task",
               disable=not progress, dynamic_ncols=True)
    try:
        futures = [executor.submit(_subject_task, config, k) for k in range(config.num_subjects)]
        subjects: list[dict[str, Any]] = []
        for future in futures:
            subject_json, seconds = future.result()
            subjects.append(subject_json)
            stage_seconds["subject"] += seconds
            write_json(out / subject_json["id"] / "subject.json", subject_json)
            bar.update(1)
        futures = [executor.submit(_frame_task, str(out), config, subjects[k], f)
                   for k in range(config.num_subjects) for f in range(config.num_poses)]
        for future in as_completed(futures):
            for name, seconds in future.result().items():
                stage_seconds[name] = stage_seconds.get(name, 0.0) + seconds
            bar.update(1)
    except BaseException:
        executor.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        bar.close()
    executor.shutdown(wait=True)

    write_json(out / "split.json", split)
    write_json(out / "dataset.json", {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "generator": "lisa_hand.data.synth",
        "generator_version": GENERATOR_VERSION,
        "lisa_hand_version": _package_version(),
        "config": config.to_dict(),
        "num_subjects": config.num_subjects,
        "num_poses": config.num_poses,
        "num_frames": config.num_frames,
        "num_views": config.num_views,
        "width": config.width,
        "height": config.height,
        "camera_names": [camera.name for camera in cameras],
        "split_counts": {name: len(ids) for name, ids in split.items()},
    })
    return SynthSummary(root=out, num_subjects=config.num_subjects, num_frames=config.num_frames,
                        num_views=config.num_views,
                        num_images=config.num_frames * config.num_views, split=split,
                        seconds=time.perf_counter() - start, num_workers=num_workers,
                        stage_seconds=stage_seconds)


def _package_version() -> str:
    from .. import __version__

    return __version__


# ------------------------------------------------------------------------------------------------
# Preview


# Views of the preview tiles, cycled over the columns (names of lisa_hand.handmodel.VIEWS).
_PREVIEW_VIEWS = ("oblique", "oblique", "oblique_palmar", "palmar", "oblique", "oblique_palmar")
_PREVIEW_NAMED = ("relaxed", "fist", "pinch", "point", "ok")


def write_preview(path: str | os.PathLike, config: SynthConfig | None = None,
                  num_subjects: int = 4, num_poses: int = 6, tile_size: int = 320) -> Path:
    """A contact sheet PNG: ``num_subjects`` rows (the dataset's subjects s000, s001, ...) by
    ``num_poses`` columns (named poses, then the subject's own dataset poses), each hand shown
    without its global rotation from a named view (:func:`lisa_hand.handmodel.render_preview`,
    white background, the dataset's mesh resolution). -> the path written.
    """
    from ..handmodel import VIEWS, contact_sheet, named_pose, render_preview

    config = SynthConfig() if config is None else config
    if not isinstance(config, SynthConfig):
        raise TypeError(f"config must be a SynthConfig, got {type(config).__name__}")
    num_subjects = _check_int(num_subjects, "num_subjects", 1)
    num_poses = _check_int(num_poses, "num_poses", 1)
    tile_size = _check_int(tile_size, "tile_size", 32)
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: the preview is a PNG file (name it *.png)")
    path.parent.mkdir(parents=True, exist_ok=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        tiles = []
        for index in range(num_subjects):
            subject = make_subject(config, index, fit_template=False)
            side = subject.hand.side
            num_named = min(len(_PREVIEW_NAMED), (num_poses + 1) // 2)
            poses = [named_pose(name, side=side, dtype=torch.float64)
                     for name in _PREVIEW_NAMED[:num_named]]
            sampled = _sampled_preview_poses(config, subject, num_poses - num_named)
            for column, pose in enumerate(poses + sampled):
                pose = pose.clone()
                pose[:3] = 0.0
                mesh = subject.hand.posed(pose).mesh(
                    voxel_size=subject.hand.shape.hand_length / config.voxels_per_length,
                    skin_weights=False)
                look, up = VIEWS[_PREVIEW_VIEWS[column % len(_PREVIEW_VIEWS)]]
                if side == "left":  # the mirror image of the right hand's view
                    look, up = (-look[0], look[1], look[2]), (-up[0], up[1], up[2])
                tiles.append(render_preview(mesh.vertices, mesh.faces, mesh.colors,
                                            view=(look, up), size=tile_size))
        sheet = contact_sheet(tiles, columns=num_poses)
    finally:
        torch.set_num_threads(threads)
    return write_image(path, sheet)


def _sampled_preview_poses(config: SynthConfig, subject: SubjectRecord,
                           count: int) -> list[torch.Tensor]:
    """``count`` sampled poses: the subject's first dataset poses that are not named ones, then
    (if the dataset has too few, e.g. ``named_pose_fraction = 1``) fresh natural poses."""
    from ..handmodel import sample_pose

    poses: list[torch.Tensor] = []
    frame = 0
    while len(poses) < count and frame < min(config.num_poses, count + 16):
        setup = frame_setup(config, subject, frame)
        if setup.pose_name is None:
            poses.append(setup.pose)
        frame += 1
    if len(poses) < count:
        generator = _torch_generator(_numpy_rng(config.seed, _STREAM_PREVIEW, subject.index))
        extra = sample_pose(generator, count - len(poses), noise=config.pose_noise,
                            side=subject.hand.side).double()
        poses.extend(extra.unbind(0))
    return poses
