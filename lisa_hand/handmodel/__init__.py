"""The open hand model: a license-free procedural hand with exact ground truth.

A right hand (left = mirror image) on MANO's skeleton, defined as a signed distance function of
the posed point: per-bone round cones and a palm body blended with a smooth union (joints bulge
and crease when flexed), fingernails, creases, palm lines and fine bumps; per-subject shape
(:class:`HandShape`), appearance (:class:`Appearance`) and detail; natural poses from a synergy
space within joint limits. Two versions (:data:`HAND_MODELS`, ``OpenHand(model=...)``): v1
(default) and v2 (:mod:`.parts_v2`: rounded, padded palm, forearm stub, D-shaped fingers; shapes
from adult anthropometry, :mod:`.anthropometry`). :class:`OpenHand` is the entry point;
:meth:`OpenHand.posed` gives the exact SDF, skinning weights, albedo, joints, keypoints,
watertight meshes and surface samples.

Rest-pose convention (MANO's right-hand axes): wrist joint at the origin, fingers along -x, palm
facing -y, thumb on +z, metres. See :mod:`.shape` and :mod:`.poses`.
"""

from .anthropometry import sample_anthropometric_shape
from .appearance import APPEARANCE_BOUNDS, Appearance, albedo, sample_appearance, skin_color
from .hand import (
    DEFAULT_VOXELS_PER_LENGTH,
    HAND_MODELS,
    OpenHand,
    PosedHand,
    SurfaceSamples,
    sample_hand,
)
from .parts import HandParts, build_hand_parts
from .parts_v2 import build_hand_parts_v2
from .poses import (
    JOINT_LIMITS,
    POSE_NAMES,
    SYNERGY_DIM,
    SYNERGY_NAMES,
    angles_to_pose,
    clamp_to_limits,
    interpolate_poses,
    joint_frames,
    named_pose,
    pose_sequence,
    pose_to_angles,
    sample_pose,
    sample_synergies,
    synergy_to_angles,
    within_limits,
)
from .preview import VIEWS, contact_sheet, render_preview
from .sdf import HandFieldOutput, PosedField
from .shape import SHAPE_BOUNDS, HandShape, RestSkeleton, rest_skeleton, sample_shape

__all__ = [
    "APPEARANCE_BOUNDS",
    "Appearance",
    "albedo",
    "sample_appearance",
    "skin_color",
    "DEFAULT_VOXELS_PER_LENGTH",
    "HAND_MODELS",
    "OpenHand",
    "PosedHand",
    "SurfaceSamples",
    "sample_hand",
    "JOINT_LIMITS",
    "POSE_NAMES",
    "SYNERGY_DIM",
    "SYNERGY_NAMES",
    "angles_to_pose",
    "clamp_to_limits",
    "interpolate_poses",
    "joint_frames",
    "named_pose",
    "pose_sequence",
    "pose_to_angles",
    "sample_pose",
    "sample_synergies",
    "synergy_to_angles",
    "within_limits",
    "VIEWS",
    "contact_sheet",
    "render_preview",
    "HandParts",
    "build_hand_parts",
    "build_hand_parts_v2",
    "sample_anthropometric_shape",
    "HandFieldOutput",
    "PosedField",
    "SHAPE_BOUNDS",
    "HandShape",
    "RestSkeleton",
    "rest_skeleton",
    "sample_shape",
]
