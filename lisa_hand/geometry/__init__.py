"""Pure tensor geometry: rotations, rigid transforms, cameras and rays. Nothing learnable."""

from .cameras import (
    Camera,
    camera_center,
    intrinsics_from_fov,
    load_cameras,
    look_at,
    make_rig,
    pixel_centers,
    pixel_rays,
    project_points,
    save_cameras,
)
from .rotations import axis_angle_to_matrix, matrix_to_axis_angle, skew
from .transforms import apply_transform, invert_rigid, make_transform, transform_vectors

__all__ = [
    "Camera",
    "camera_center",
    "intrinsics_from_fov",
    "load_cameras",
    "look_at",
    "make_rig",
    "pixel_centers",
    "pixel_rays",
    "project_points",
    "save_cameras",
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "skew",
    "apply_transform",
    "invert_rigid",
    "make_transform",
    "transform_vectors",
]
