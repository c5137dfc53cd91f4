"""Field components: configuration, encodings, stacked per-bone MLPs, bone regions, pose
conditioning, latent tables and compositions (LISA, NASA, NARF, single MLP).

The model that puts them together is :class:`lisa_hand.model.LisaModel`.
"""

from .bones import (
    CHILDREN,
    LEAF_BONES,
    NUM_SEGMENTS,
    PALM_CHILDREN,
    SEGMENT_BONES,
    bone_axes,
    bone_centres,
    bone_segments,
    capsule_distance,
    segment_distances,
    unpose_points,
)
from .composition import blend, masked_softmax, nasa_selection, one_hot_weights
from .config import COMPOSITIONS, POSE_CONDITIONINGS, PRECISIONS, FieldConfig
from .encoding import encoding_dim, positional_encoding
from .latents import LatentTable
from .mlp import ACTIVATIONS, StackedMLP, geometric_init_, soft_min_init_
from .pose import LOCAL_POSE_DIM, local_pose_mask, pose_feature_dim, pose_features

__all__ = [
    "CHILDREN",
    "LEAF_BONES",
    "NUM_SEGMENTS",
    "PALM_CHILDREN",
    "SEGMENT_BONES",
    "bone_axes",
    "bone_centres",
    "bone_segments",
    "capsule_distance",
    "segment_distances",
    "unpose_points",
    "blend",
    "masked_softmax",
    "nasa_selection",
    "one_hot_weights",
    "COMPOSITIONS",
    "POSE_CONDITIONINGS",
    "PRECISIONS",
    "FieldConfig",
    "encoding_dim",
    "positional_encoding",
    "LatentTable",
    "ACTIVATIONS",
    "StackedMLP",
    "geometric_init_",
    "soft_min_init_",
    "LOCAL_POSE_DIM",
    "local_pose_mask",
    "pose_feature_dim",
    "pose_features",
]
