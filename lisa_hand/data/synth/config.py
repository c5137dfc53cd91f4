"""What ``lisa synth`` writes (:class:`SynthConfig`) and what a run reports (:class:`SynthSummary`).

The generator itself is :mod:`lisa_hand.data.synth.dataset`; the settings' effects are described
there
and in ``docs/data_formats.md``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..scans import ScanConfig
from ..shading import GainBiasConfig, ShadingConfig

__all__ = ["SynthConfig", "SynthSummary", "parse_resolution", "check_integer"]

_MAX_IMAGE_SIDE = 16384
_MAX_WORKERS = 8
_HAND_MODELS = ("v1", "v2", "v3")  # lisa_hand.handmodel.HAND_MODELS (checked equal by the tests)


@dataclass(frozen=True)
class SynthConfig:
    """What :func:`synthesize` writes (the defaults: InterHand-like 1024x667 images)."""

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
    hand_model: str = "v1"
    """Version of the open hand model the subjects are made of (``lisa_hand.handmodel.
    HAND_MODELS``): "v1" (default, what the shipped model was trained on), "v2" (rounded,
    padded palm, forearm stub, D-shaped fingers, anthropometric shape draws) or "v3"
    (MakeHuman's sculpted hand, anthropometric sizes, skin tones by ethnic mix)."""

    ages: tuple[float, float] = (18.0, 80.0)
    """Ages (years) of the v3 subjects, youngest and oldest (v1 and v2 hands have no age): a
    narrower range holds the rest of the population out, e.g. (18, 65) to test on older
    hands."""

    def __post_init__(self) -> None:
        for name in ("num_subjects", "num_poses", "num_views", "supersample"):
            check_integer(getattr(self, name), name, 1)
        check_integer(self.seed, "seed", 0)
        check_integer(self.num_sdf_samples, "num_sdf_samples", 0)
        check_integer(self.num_workers, "num_workers", 0)
        check_integer(self.voxels_per_length, "voxels_per_length", 16)
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
        if self.hand_model not in _HAND_MODELS:
            raise ValueError(f"hand_model must be one of {', '.join(_HAND_MODELS)}, got "
                             f"{self.hand_model!r}")
        ages = tuple(self.ages) if isinstance(self.ages, (tuple, list)) else ()
        if len(ages) != 2 or not all(isinstance(a, (int, float)) for a in ages) or not (
                1 <= ages[0] <= ages[1] <= 90):
            raise ValueError(f"ages must be (youngest, oldest) years within 1-90, got "
                             f"{self.ages!r}")

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
        change what is written; ``hand_model`` only when it is not the default "v1", so that a v1
        dataset's ``dataset.json`` matches one written by a version without the setting;
        ``ages`` only for v3)."""
        data = dataclasses.asdict(self)
        del data["num_workers"]
        if data["hand_model"] == "v1":
            del data["hand_model"]
        if self.hand_model == "v3":
            data["ages"] = list(self.ages)
        else:
            del data["ages"]  # only v3 hands have an age
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



# ------------------------------------------------------------------------------------------------
# Validation


def _is_number(value: Any) -> bool:
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, bool) and math.isfinite(float(value)))


def check_integer(value: Any, name: str, minimum: int) -> int:
    """``value`` as an int; ValueError naming ``name`` unless it is an integer (numpy ones too,
    bools excluded) of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)



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

