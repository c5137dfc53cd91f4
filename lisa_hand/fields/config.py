"""Typed configuration of the hand field (LISA Section 4.1) and of its baseline compositions."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = ["COMPOSITIONS", "POSE_CONDITIONINGS", "PRECISIONS", "FieldConfig"]

COMPOSITIONS = ("lisa", "nasa", "narf", "single")
POSE_CONDITIONINGS = ("local", "full")
PRECISIONS = ("float32", "mixed", "bfloat16")


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of the field ``G(x, pose, shape, color) -> (sdf, rgb)`` (paper Eq. 6-9).

    The four compositions share everything except how per-bone predictions become one value:
    'lisa' (skinning MLP on all unposed points and all per-bone SDFs, paper Eq. 9), 'nasa' (each
    point takes the bone with the smallest SDF and that bone's colour), 'narf' (skinning MLP on
    the unposed points only) and 'single' (the VolSDF baseline: one MLP, no per-bone reasoning).
    """

    composition: str = "lisa"
    """How per-bone predictions are combined: 'lisa', 'nasa', 'narf' or 'single'."""

    sdf_hidden: int = 128
    """Width of the hidden layers of each per-bone SDF MLP (and of the single MLP)."""

    sdf_depth: int = 3
    """Number of hidden layers (>= 1) of each SDF MLP (linear layers = depth + 1)."""

    color_hidden: int = 128
    """Width of the hidden layers of each per-bone colour MLP."""

    color_depth: int = 2
    """Number of hidden layers (>= 1) of each colour MLP."""

    skinning_hidden: int = 128
    """Width of the hidden layers of the skinning-weight MLP ('lisa' and 'narf')."""

    skinning_depth: int = 2
    """Number of hidden layers (>= 1) of the skinning-weight MLP."""

    pe_frequencies: int = 6
    """Positional-encoding octaves of the (scaled) bone-local point: sin/cos(2^k x), k < F."""

    shape_dim: int = 128
    """Size of the shape latent code beta+ (paper: 128)."""

    color_dim: int = 128
    """Size of the colour latent code gamma (paper: 128)."""

    pose_conditioning: str = "local"
    """Pose input of the MLPs: 'local' (vec(R - I) of the bone's own joint, its parent and its
    children, zeros elsewhere; generalises better to unseen poses) or 'full' (the 48-D pose)."""

    coordinate_scale: float = 0.05
    """Metres per network unit: bone-local points are divided by this before the encoding, and
    network SDF outputs multiplied by it, so that the MLPs see O(1) values."""

    softplus_beta: float = 100.0
    """Sharpness of the Softplus activations of the SDF MLPs (smooth second derivatives)."""

    palm_region_radius: float = 0.045
    """Radius (metres) of the wrist bone's region: capsules from the wrist to each finger base."""

    finger_region_radius: float = 0.022
    """Radius (metres) of each finger bone's region: a capsule around the bone's segment."""

    tip_extension: float = 0.8
    """Length of the last bone of each finger beyond its joint, as a fraction of the previous
    segment (the fingertip is not a joint)."""

    outside_margin: float = 0.01
    """Metres added to the distance-to-region stand-in SDF of a bone outside its region."""

    init_palm_radius: float = 0.03
    """Radius (metres) of the palm blob that the geometric initialisation starts from."""

    init_finger_radius: float = 0.009
    """Radius (metres) of each finger bone's blob at initialisation."""

    use_color: bool = True
    """Build the colour MLPs (False: geometry only, e.g. a shape prior)."""

    inference_precision: str = "float32"
    """Precision of the MLPs' hidden layers when no gradient is recorded: 'float32'; 'mixed'
    (the colour MLPs' hidden products in bfloat16, colour error ~1e-4, geometry exact); or
    'bfloat16' (all MLPs: SDF error ~0.2 mm or more, skinning weights ~1e-1). bfloat16 is fast
    on CPUs with AVX512-BF16/AMX and on GPUs, slow elsewhere. Gradients and float64 always run
    in the input dtype."""

    def __post_init__(self) -> None:
        choices = {
            "composition": COMPOSITIONS,
            "pose_conditioning": POSE_CONDITIONINGS,
            "inference_precision": PRECISIONS,
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        positive_ints = (
            "sdf_hidden",
            "sdf_depth",
            "color_hidden",
            "color_depth",
            "skinning_hidden",
            "skinning_depth",
            "shape_dim",
            "color_dim",
        )
        for name in positive_ints:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        frequencies = self.pe_frequencies
        if isinstance(frequencies, bool) or not isinstance(frequencies, int) or frequencies < 0:
            raise ValueError(f"pe_frequencies must be a non-negative int, got {frequencies!r}")
        positive_floats = (
            "coordinate_scale",
            "softplus_beta",
            "palm_region_radius",
            "finger_region_radius",
            "init_palm_radius",
            "init_finger_radius",
        )
        for name in positive_floats:
            if not float(getattr(self, name)) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("tip_extension", "outside_margin"):
            if not float(getattr(self, name)) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")

    @property
    def per_bone(self) -> bool:
        """True for the compositions with per-bone MLPs ('lisa', 'nasa', 'narf')."""
        return self.composition != "single"

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (for saving beside checkpoints)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> FieldConfig:
        """Inverse of :meth:`to_dict`; missing keys take their defaults, unknown keys are errors."""
        if not isinstance(values, dict):
            raise TypeError(f"FieldConfig.from_dict expects a dict, got {type(values).__name__}")
        known = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown FieldConfig keys {unknown}; known keys: {sorted(known)}")
        return cls(**values)
