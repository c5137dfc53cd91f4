"""What the viewer draws besides the surface, as arrays: vertex colours of the display modes,
the posed skeleton and the 21 keypoints (no viser here: plain numpy, testable on its own).

Colour modes (:data:`COLOR_MODES`):

* ``"skin"``: the model's calibrated colours (the mesh's own);
* ``"skinning weights"``: ``sum_j w_j(v) c_j``, a fixed colour ``c_j`` per bone blended by the
  vertex's skinning weights (LISA's dense correspondence: the same point of any hand, in any
  pose, gets the same colour);
* ``"normals"``: the area-weighted vertex normal, ``(n + 1) / 2`` as RGB.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..geometry.meshing import Mesh
from ..skeleton import NUM_JOINTS, PARENTS, forward_kinematics
from ..skeleton.params import HandParams

__all__ = [
    "COLOR_MODES",
    "BONE_COLORS",
    "weight_colors",
    "vertex_normals",
    "normal_colors",
    "display_colors",
    "posed_joints",
    "skeleton_segments",
    "hand_keypoints",
]

COLOR_MODES = ("skin", "skinning weights", "normals")


def _bone_palette() -> np.ndarray:
    """[16, 3] uint8: grey wrist, then each finger's three bones in shades of one hue (MANO
    order: index, middle, pinky, ring, thumb)."""
    hues = {"index": (230, 60, 60), "middle": (240, 170, 30), "pinky": (60, 120, 230),
            "ring": (60, 190, 90), "thumb": (170, 70, 200)}
    palette = [(150, 150, 150)]
    for finger in ("index", "middle", "pinky", "ring", "thumb"):
        base = np.array(hues[finger], dtype=np.float64)
        for shade in (1.0, 0.8, 0.6):
            palette.append(tuple(base * shade + 255.0 * (1.0 - shade) * 0.5))
    return np.round(np.array(palette)).astype(np.uint8)


BONE_COLORS = _bone_palette()
"""[16, 3] uint8, one colour per bone (MANO joint order)."""


def weight_colors(skin_weights: np.ndarray) -> np.ndarray:
    """skin_weights [V, 16] (rows sum to 1) -> [V, 3] uint8, ``sum_j w_j c_j``."""
    weights = np.asarray(skin_weights, dtype=np.float64)
    if weights.ndim != 2 or weights.shape[1] != NUM_JOINTS:
        raise ValueError(f"skin_weights must have shape [V, {NUM_JOINTS}], got {weights.shape}")
    blended = weights @ BONE_COLORS.astype(np.float64)
    return np.clip(np.round(blended), 0, 255).astype(np.uint8)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals: vertices [V, 3] metres, faces [F, 3] counter-clockwise
    seen from outside -> [V, 3] (zero for a vertex on no face)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    corners = vertices[faces]  # [F, 3, 3]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def normal_colors(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[V, 3] uint8, ``255 (n + 1) / 2`` of :func:`vertex_normals`."""
    normals = vertex_normals(vertices, faces)
    return np.clip(np.round(127.5 * (normals + 1.0)), 0, 255).astype(np.uint8)


def display_colors(mesh: Mesh, mode: str) -> np.ndarray:
    """The vertex colours [V, 3] uint8 of ``mesh`` in colour mode ``mode``
    (:data:`COLOR_MODES`); a mesh without colours or weights shows grey / its normals."""
    if mode not in COLOR_MODES:
        raise ValueError(f"unknown colour mode {mode!r}: one of {', '.join(COLOR_MODES)}")
    if mode == "skin" and mesh.colors is not None:
        return mesh.colors
    if mode == "skinning weights" and mesh.skin_weights is not None:
        return weight_colors(mesh.skin_weights)
    if mode == "skin":
        return np.full((mesh.num_vertices, 3), 180, dtype=np.uint8)
    return normal_colors(mesh.vertices, mesh.faces)


def posed_joints(params: HandParams) -> np.ndarray:
    """The 16 joints of the hand in its pose (forward kinematics of ``rest_joints``; a left
    hand's pose and skeleton are already mirrored) -> [16, 3] float64 metres."""
    with torch.no_grad():
        kinematics = forward_kinematics(params.pose.double()[None],
                                        params.rest_joints.double()[None],
                                        params.translation.double()[None])
    return kinematics.joints[0].numpy()


def skeleton_segments(params: HandParams) -> np.ndarray:
    """The 15 bones, joint to parent: [15, 2, 3] float64 metres (for line segments)."""
    joints = posed_joints(params)
    children = list(range(1, NUM_JOINTS))
    parents = [PARENTS[child] for child in children]
    return np.stack([joints[parents], joints[children]], axis=1)


def hand_keypoints(params: HandParams, template: Any = None) -> np.ndarray:
    """The 21 keypoints (OpenPose order: :func:`lisa_hand.fitting.outputs.hand_keypoints_3d`,
    the fingertips from the mesh ``template``, default the shipped one) -> [21, 3] float64
    metres."""
    from ..fitting.outputs import hand_keypoints_3d

    return hand_keypoints_3d(params, template)
