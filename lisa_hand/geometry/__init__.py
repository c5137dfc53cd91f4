"""Pure tensor geometry: rotations, rigid transforms, cameras and rays. Nothing learnable."""

from .rotations import axis_angle_to_matrix, matrix_to_axis_angle, skew
from .transforms import apply_transform, invert_rigid, make_transform, transform_vectors

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "skew",
    "apply_transform",
    "invert_rigid",
    "make_transform",
    "transform_vectors",
]
