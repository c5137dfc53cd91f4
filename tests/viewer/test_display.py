"""Display colours, skeleton and keypoints of the viewer (lisa_hand.viewer.display)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.geometry.meshing import Mesh
from lisa_hand.skeleton import PARENTS
from lisa_hand.viewer.display import (
    BONE_COLORS,
    display_colors,
    hand_keypoints,
    normal_colors,
    skeleton_segments,
    vertex_normals,
    weight_colors,
)


def test_weight_colors_blend_the_bone_palette():
    weights = np.zeros((3, 16))
    weights[0, 4] = 1.0
    weights[1, [1, 13]] = 0.5
    weights[2] = 1.0 / 16
    colors = weight_colors(weights)
    assert colors.dtype == np.uint8
    assert np.array_equal(colors[0], BONE_COLORS[4])
    expected = np.round(0.5 * (BONE_COLORS[1].astype(float) + BONE_COLORS[13]))
    assert np.abs(colors[1].astype(int) - expected).max() <= 1
    assert np.abs(colors[2].astype(int) - BONE_COLORS.mean(0)).max() <= 1
    assert len({tuple(c) for c in BONE_COLORS}) == 16  # every bone its own colour
    with pytest.raises(ValueError, match="16"):
        weight_colors(np.ones((2, 5)))


def test_vertex_normals_of_a_sphere_point_outwards():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    normals = vertex_normals(sphere.vertices, sphere.faces)
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.einsum("vc,vc->v", normals, radial).min() > 0.995
    colors = normal_colors(sphere.vertices, sphere.faces)
    top = int(np.argmax(sphere.vertices[:, 2]))  # normal (0, 0, 1) -> (128, 128, 255)
    assert np.abs(colors[top].astype(int) - [128, 128, 255]).max() <= 2


def test_display_modes():
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    weights = np.zeros((len(sphere.vertices), 16))
    weights[:, 2] = 1.0
    skin = np.full((len(sphere.vertices), 3), 77, np.uint8)
    mesh = Mesh(sphere.vertices, sphere.faces, colors=skin, skin_weights=weights)
    assert np.array_equal(display_colors(mesh, "skin"), skin)
    assert np.array_equal(display_colors(mesh, "skinning weights")[0], BONE_COLORS[2])
    assert display_colors(mesh, "normals").shape == skin.shape
    bare = Mesh(sphere.vertices, sphere.faces)
    assert np.all(display_colors(bare, "skin") == 180)
    with pytest.raises(ValueError, match="colour mode"):
        display_colors(mesh, "depth")


def test_skeleton_at_rest_is_the_rest_joints(hands):
    params = hands[0].params.with_pose(torch.zeros(48), torch.zeros(3))
    segments = skeleton_segments(params)
    rest = params.rest_joints.double().numpy()
    assert segments.shape == (15, 2, 3)
    for bone, child in enumerate(range(1, 16)):
        assert np.allclose(segments[bone, 0], rest[PARENTS[child]], atol=1e-6)
        assert np.allclose(segments[bone, 1], rest[child], atol=1e-6)
    keypoints = hand_keypoints(hands[0].params)
    assert keypoints.shape == (21, 3)
    assert np.allclose(keypoints[0], skeleton_segments(hands[0].params)[0, 0], atol=1e-6)
