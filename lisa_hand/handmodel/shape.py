"""Hand shape parameters, their sampling distribution, and the rest-pose skeleton they produce.

Rest-pose convention (the same axes as MANO's right hand, so that a MANO pose vector means the same
motion here): right hand, wrist joint at the origin, fingers pointing along **-x**, palm facing
**-y** (palmar side down, back of the hand up, +y), thumb on the **+z** side, metres. A left hand
is the mirror image through the x = 0 plane (``lisa_hand.skeleton.mirror_points``), exactly as
MANO's left model: fingers along +x, palm -y, thumb +z.

Every bone ``b`` has an anatomical rest frame: ``bone_dirs[b]`` (along the bone, proximal to
distal), ``dorsal[b]`` (the back of the finger / nail side) and ``lateral[b] = dorsal x dir``,
the flexion axis (a positive rotation about it curls the finger toward the palm). For the four
fingers ``dorsal`` is about +y and ``lateral`` about +z; the thumb's frame is turned so that its
nail faces up and away from the fingers.

Lengths are fractions of the hand length ``L`` (wrist joint to the middle fingertip's surface,
rest pose) and are set from anthropometric tables of adult hands (phalanx lengths, palm breadth,
finger breadths) so that the palm, wrist to middle MCP joint, is about half of the hand.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS

__all__ = [
    "HandShape",
    "SHAPE_BOUNDS",
    "RestSkeleton",
    "sample_shape",
    "rest_skeleton",
    "FINGER_BONE_FRACTIONS",
]


@dataclass(frozen=True)
class HandShape:
    """Shape of one subject's hand (the defaults are an average adult hand)."""

    hand_length: float = 0.185
    """Wrist joint to the middle fingertip's surface in the rest pose, metres (adults 0.16-0.22)."""
    palm_length: float = 0.50
    """Wrist joint to the middle finger's MCP joint, as a fraction of ``hand_length``."""
    palm_width: float = 1.0
    """Scale of the palm's breadth: lateral spacing of the MCP joints (also widened by thicker
    fingers) and the palm outline."""
    palm_thickness: float = 1.0
    """Scale of the palm's, wrist's and thenar's thickness (dorsal to palmar)."""
    index_ratio: float = 0.93
    """Index finger length (MCP joint to tip) over the middle finger's."""
    ring_ratio: float = 0.965
    """Ring finger length (MCP joint to tip) over the middle finger's."""
    pinky_ratio: float = 0.78
    """Little finger length (MCP joint to tip) over the middle finger's."""
    thumb_length: float = 1.0
    """Scale of the thumb's three bones (metacarpal, proximal and distal phalanx)."""
    thumb_angle: float = 0.72
    """Rest angle between the thumb metacarpal and the middle finger in the palm plane, radians."""
    thumb_base: float = 1.0
    """Scale of the thumb's CMC joint position from the wrist (low-set < 1 < high-set)."""
    finger_thickness: float = 1.0
    """Scale of the radii of all fingers and the thumb."""
    knuckle_size: float = 1.0
    """Scale of the joint (knuckle) bulges: metacarpal heads and phalanx condyles."""
    fingertip_taper: float = 0.74
    """Radius at the fingertip over the radius at the MCP joint."""
    finger_spread: float = 1.0
    """Scale of the rest-pose splay of the four fingers (0 = parallel fingers)."""
    flesh: float = 1.0
    """Scale of the blend radii: larger values give softer, fleshier joints and webs."""

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TypeError(
                    f"HandShape.{field.name} must be a float, got {type(value).__name__}"
                )
            low, high = SHAPE_BOUNDS[field.name]
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(
                    f"HandShape.{field.name} = {value!r} is outside the valid range [{low}, {high}]"
                )

    def as_vector(self) -> np.ndarray:
        """All parameters as a float64 vector, in field order."""
        return np.array([getattr(self, f.name) for f in fields(self)], dtype=np.float64)


# Valid range of every parameter (wider than the sampling distribution: any value inside gives a
# plausible hand; outside, parts start to intersect or vanish).
SHAPE_BOUNDS: dict[str, tuple[float, float]] = {
    "hand_length": (0.12, 0.26),
    "palm_length": (0.44, 0.56),
    "palm_width": (0.75, 1.3),
    "palm_thickness": (0.75, 1.3),
    "index_ratio": (0.82, 1.02),
    "ring_ratio": (0.86, 1.06),
    "pinky_ratio": (0.66, 0.9),
    "thumb_length": (0.8, 1.2),
    "thumb_angle": (0.4, 1.0),
    "thumb_base": (0.85, 1.15),
    "finger_thickness": (0.75, 1.3),
    "knuckle_size": (0.6, 1.5),
    "fingertip_taper": (0.62, 0.92),
    "finger_spread": (0.0, 1.8),
    "flesh": (0.6, 1.6),
}

# (mean, standard deviation, low clip, high clip) of every parameter but the hand length, which
# comes from a two-component (smaller / larger hands) mixture in :func:`sample_shape`.
_DISTRIBUTION: dict[str, tuple[float, float, float, float]] = {
    "palm_length": (0.50, 0.012, 0.465, 0.535),
    "palm_width": (1.0, 0.05, 0.86, 1.16),
    "palm_thickness": (1.0, 0.07, 0.84, 1.18),
    "index_ratio": (0.93, 0.02, 0.87, 0.99),
    "ring_ratio": (0.965, 0.02, 0.91, 1.02),
    "pinky_ratio": (0.78, 0.025, 0.71, 0.85),
    "thumb_length": (1.0, 0.04, 0.9, 1.1),
    "thumb_angle": (0.72, 0.07, 0.55, 0.9),
    "thumb_base": (1.0, 0.04, 0.9, 1.1),
    "finger_thickness": (1.0, 0.07, 0.84, 1.18),
    "knuckle_size": (1.0, 0.12, 0.72, 1.32),
    "fingertip_taper": (0.74, 0.035, 0.66, 0.84),
    "finger_spread": (1.0, 0.18, 0.75, 1.5),
    "flesh": (1.0, 0.1, 0.8, 1.25),
}


def _normal(generator: torch.Generator) -> float:
    return float(torch.randn((), generator=generator, dtype=torch.float64))


def sample_shape(generator: torch.Generator) -> HandShape:
    """Draw a random adult hand shape.

    Hand length comes from a 50/50 mixture of N(17.5 cm, 1.0 cm) and N(19.0 cm, 1.0 cm), clipped
    to [16, 22] cm (adult female and male hand lengths); larger hands are also slightly broader and
    thicker. Every other parameter is an independent clipped normal around the average hand, with
    spreads matching anthropometric variation (finger length ratios to +-2-3 %, palm breadth to
    +-5 %, thickness to +-7 %).

    generator: a seeded ``torch.Generator`` (CPU); the same seed gives the same shape.
    """
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
    larger = float(torch.rand((), generator=generator, dtype=torch.float64)) < 0.5
    mean_length = 0.190 if larger else 0.175
    hand_length = float(np.clip(mean_length + 0.010 * _normal(generator), 0.16, 0.22))
    # Larger hands are relatively broader and thicker (about +3 % each).
    bias = 0.015 if larger else -0.015
    values: dict[str, float] = {"hand_length": hand_length}
    for name, (mean, std, low, high) in _DISTRIBUTION.items():
        shift = bias if name in ("palm_width", "palm_thickness", "finger_thickness") else 0.0
        values[name] = float(np.clip(mean + shift + std * _normal(generator), low, high))
    return HandShape(**values)


# Fractions of each finger's length (MCP joint to tip surface) taken by its three bones, and the
# finger radius (metres, for the average 18.5 cm hand) at its MCP joint. Anthropometric phalanx
# lengths: index 40/22/16+3 mm, middle 45/26/17+3, ring 41/26/17+3, little 33/18/16+3.
FINGER_BONE_FRACTIONS = {
    "index": (0.49, 0.28, 0.23),
    "middle": (0.49, 0.29, 0.22),
    "ring": (0.48, 0.295, 0.225),
    "pinky": (0.455, 0.28, 0.265),
}
_FINGER_BASE_RADIUS = {"index": 0.0108, "middle": 0.0110, "ring": 0.0104, "pinky": 0.0094}
# MCP joints, for the average hand, relative to the middle MCP joint: (dx, dy, dz) metres; dz is
# scaled by ``palm_width``, dx and dy by the hand length (the MCP line is an arc; the index and
# little fingers' knuckles sit lower, the palm's transverse arch).
_MCP_OFFSETS = {
    "index": (0.0030, -0.0015, 0.0230),
    "middle": (0.0, 0.0, 0.0),
    "ring": (0.0040, -0.0020, -0.0205),
    "pinky": (0.0150, -0.0050, -0.0385),
}
_MIDDLE_MCP_Z = -0.0020
# Rest splay of each finger about the dorsal axis (radians, + toward the thumb), times
# finger_spread.
_FINGER_SPLAY = {"index": 0.09, "middle": 0.015, "ring": -0.07, "pinky": -0.17}
# Thumb, for the average hand: CMC joint (metres), bone lengths as fractions of L (metacarpal,
# proximal, distal + pad), in-plane angles of the three bones relative to the metacarpal's
# ``thumb_angle`` (radians), their palmar tilt (radians), and radii at CMC, MCP, IP and tip (m).
_THUMB_CMC = (-0.029, -0.011, 0.020)
_THUMB_FRACTIONS = (0.23, 0.165, 0.145)
_THUMB_ANGLE_OFFSETS = (0.0, -0.16, -0.28)
_THUMB_TILT = (0.22, 0.12, 0.08)
_THUMB_RADII = (0.0125, 0.0115, 0.0110, 0.0097)
# How far the thumb's nail side is turned from the back of the hand toward +z (radians).
_THUMB_PRONATION = 1.35


@dataclass
class RestSkeleton:
    """Rest-pose skeleton of one hand shape (right hand, metres, see the module docstring).

    joints: [16, 3] MANO joint positions (wrist, index, middle, pinky, ring, thumb chains).
    fingertips: [5, 3] surface points at the finger ends (thumb, index, middle, ring, pinky).
    bone_ends: [16, 3] where each bone ends: its child joint, or its fingertip for distal bones,
        or the middle MCP joint for the wrist bone.
    radii: [16, 2] flesh radius at the start and end of each bone (the wrist bone: palm half
        thickness, twice).
    bone_dirs: [16, 3] unit vectors along each bone (the wrist bone: toward the fingers, -x).
    dorsal: [16, 3] unit vectors to the back of each bone, orthogonal to ``bone_dirs``.
    lateral: [16, 3] ``dorsal x bone_dirs``, each bone's flexion axis.
    """

    joints: torch.Tensor
    fingertips: torch.Tensor
    bone_ends: torch.Tensor
    radii: torch.Tensor
    bone_dirs: torch.Tensor
    dorsal: torch.Tensor
    lateral: torch.Tensor


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _rotate_about(vector: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of ``vector`` about unit ``axis`` by ``angle`` radians."""
    return (
        vector * math.cos(angle)
        + np.cross(axis, vector) * math.sin(angle)
        + axis * np.dot(axis, vector) * (1.0 - math.cos(angle))
    )


def _thumb_direction(angle: float, tilt: float) -> np.ndarray:
    """In-plane angle from -x toward +z, then tilted toward the palm (-y) by ``tilt``."""
    in_plane = np.array([-math.cos(angle), 0.0, math.sin(angle)])
    return _unit(in_plane * math.cos(tilt) + np.array([0.0, -math.sin(tilt), 0.0]))


@dataclass
class _Bones:
    """The rest skeleton's arrays while they are filled in (float64, metres)."""

    joints: np.ndarray
    ends: np.ndarray
    radii: np.ndarray
    dirs: np.ndarray
    dorsal: np.ndarray
    tips: np.ndarray

    @classmethod
    def zeros(cls) -> _Bones:
        three = (NUM_JOINTS, 3)
        return cls(joints=np.zeros(three), ends=np.zeros(three), radii=np.zeros((NUM_JOINTS, 2)),
                   dirs=np.zeros(three), dorsal=np.zeros(three), tips=np.zeros((5, 3)))


_UP = np.array([0.0, 1.0, 0.0])


def _place_fingers(shape: HandShape, middle_mcp: np.ndarray, bones: _Bones) -> None:
    """The four fingers' bones, straight chains from their MCP joints (splayed in the palm
    plane, tapering toward the tip)."""
    length = shape.hand_length
    scale = length / 0.185  # offsets above are for the average 18.5 cm hand
    thick = shape.finger_thickness * scale
    middle_finger = (1.0 - shape.palm_length) * length
    ratios = {"index": shape.index_ratio, "middle": 1.0, "ring": shape.ring_ratio}
    ratios["pinky"] = shape.pinky_ratio
    for finger in ("index", "middle", "ring", "pinky"):
        chain = FINGER_JOINTS[finger]
        dx, dy, dz = _MCP_OFFSETS[finger]
        # Thicker fingers sit further apart (broader knuckles), so that neighbours do not touch.
        spacing = shape.palm_width * (0.6 + 0.4 * shape.finger_thickness)
        mcp = middle_mcp + np.array([dx * scale, dy * scale, dz * scale * spacing])
        splay = _FINGER_SPLAY[finger] * shape.finger_spread
        direction = _rotate_about(np.array([-1.0, 0.0, 0.0]), _UP, splay)
        finger_length = ratios[finger] * middle_finger
        fractions = FINGER_BONE_FRACTIONS[finger]
        base_radius = _FINGER_BASE_RADIUS[finger] * thick
        taper = shape.fingertip_taper
        position, walked = mcp, 0.0
        for bone, fraction in zip(chain, fractions, strict=True):
            bones.joints[bone] = position
            start_radius = base_radius * (1.0 - (1.0 - taper) * walked)
            walked += fraction
            end_radius = base_radius * (1.0 - (1.0 - taper) * walked)
            position = position + direction * fraction * finger_length
            bones.ends[bone] = position
            bones.radii[bone] = (start_radius, end_radius)
            bones.dirs[bone] = direction
            bones.dorsal[bone] = _UP
        bones.tips[FINGER_NAMES.index(finger)] = position


def _place_thumb(shape: HandShape, bones: _Bones) -> None:
    """The thumb's three bones from its CMC joint, each turned by its own angle and tilt, the
    nail side pronated toward +z."""
    length = shape.hand_length
    scale = length / 0.185
    cmc = np.array(_THUMB_CMC) * scale * np.array([shape.thumb_base, 1.0, shape.thumb_base])
    cmc[2] *= shape.palm_width
    position = cmc
    for k, bone in enumerate(FINGER_JOINTS["thumb"]):
        direction = _thumb_direction(shape.thumb_angle + _THUMB_ANGLE_OFFSETS[k], _THUMB_TILT[k])
        bones.joints[bone] = position
        position = position + direction * _THUMB_FRACTIONS[k] * length * shape.thumb_length
        bones.ends[bone] = position
        thumb_scale = shape.finger_thickness * scale
        bones.radii[bone] = (_THUMB_RADII[k] * thumb_scale, _THUMB_RADII[k + 1] * thumb_scale)
        bones.dirs[bone] = direction
        # Nail side: "up" made orthogonal to the bone, then turned about the bone toward +z.
        base_up = _unit(_UP - direction * np.dot(_UP, direction))
        bones.dorsal[bone] = _unit(_rotate_about(base_up, direction, -_THUMB_PRONATION))
    bones.tips[0] = position


def rest_skeleton(shape: HandShape, dtype: torch.dtype = torch.float64) -> RestSkeleton:
    """Rest-pose joints, fingertips, bone frames and flesh radii of a hand shape.

    shape: a :class:`HandShape`.
    -> :class:`RestSkeleton` with tensors of ``dtype`` (CPU).
    """
    if not isinstance(shape, HandShape):
        raise TypeError(f"shape must be a HandShape, got {type(shape).__name__}")
    length = shape.hand_length
    scale = length / 0.185  # offsets above are for the average 18.5 cm hand
    bones = _Bones.zeros()
    middle_mcp = np.array([-shape.palm_length * length, 0.0, _MIDDLE_MCP_Z * scale])
    _place_fingers(shape, middle_mcp, bones)
    _place_thumb(shape, bones)
    # Wrist bone: toward the middle MCP joint; radii = palm half thickness.
    bones.ends[0] = middle_mcp
    bones.dirs[0] = np.array([-1.0, 0.0, 0.0])
    bones.dorsal[0] = _UP
    bones.radii[0] = 0.012 * scale * shape.palm_thickness
    lateral = np.cross(bones.dorsal, bones.dirs)

    def as_tensor(array: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(array, dtype=dtype)

    return RestSkeleton(
        joints=as_tensor(bones.joints),
        fingertips=as_tensor(bones.tips),
        bone_ends=as_tensor(bones.ends),
        radii=as_tensor(bones.radii),
        bone_dirs=as_tensor(bones.dirs),
        dorsal=as_tensor(bones.dorsal),
        lateral=as_tensor(lateral),
    )
