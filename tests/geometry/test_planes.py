"""The cutting plane (:mod:`lisa_hand.geometry.planes`): sides, and meshes cut exactly along it,
checked against closed forms on a unit cube and a sphere."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lisa_hand.geometry.planes import Plane, clip_mesh


def test_signed_distance_and_sides():
    plane = Plane([0.0, 0.0, 1.0], [0.0, 0.0, 2.0])  # normal normalised
    np.testing.assert_allclose(plane.normal, [0, 0, 1])
    points = np.array([[0, 0, 3.0], [5, -2, 1.0], [0, 0, 0.5]])
    np.testing.assert_allclose(plane.signed_distance(points), [2.0, 0.0, -0.5])
    assert plane.keeps(points).tolist() == [True, True, False]
    assert plane.keeps(points, margin=0.6).tolist() == [True, True, True]
    np.testing.assert_allclose(plane.shifted(-0.5).point, [0, 0, 0.5])
    for bad in (([0, 0], [0, 0, 1]), ([0, 0, 0], [0, 0, 0]), ([np.nan, 0, 0], [1, 0, 0])):
        with pytest.raises(ValueError, match="plane"):
            Plane(*bad)


def test_a_box_cut_in_half_keeps_half_its_area_and_is_open_along_the_cut():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # centred at 0: area 6
    plane = Plane([0.0, 0.0, 0.25], [0.0, 0.0, 1.0])
    vertices, faces = clip_mesh(box.vertices, box.faces, plane)
    cut = trimesh.Trimesh(vertices, faces, process=False)
    # Kept: the top (1) and four side strips 1 x 0.25 -> area 2; nothing below the plane.
    assert cut.area == pytest.approx(2.0, abs=1e-9)
    assert vertices[:, 2].min() == pytest.approx(0.25, abs=1e-12)
    # The open rim lies on the plane: every boundary edge's vertices have z = 0.25.
    edges = np.sort(cut.edges, axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    rim = unique[counts == 1]
    assert len(rim) > 0
    np.testing.assert_allclose(vertices[rim.ravel(), 2], 0.25, atol=1e-12)
    assert trimesh.Trimesh(vertices, faces).is_winding_consistent


def test_a_sphere_cut_matches_the_spherical_cap_area():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    height = 0.5  # the cap above z = 0.5 has area 2 pi r h
    vertices, faces = clip_mesh(sphere.vertices, sphere.faces, Plane([0, 0, 0.5], [0, 0, 1]))
    area = trimesh.Trimesh(vertices, faces, process=False).area
    expected = 2 * np.pi * height * sphere.area / (4 * np.pi)  # the icosphere's own area scale
    assert area == pytest.approx(expected, rel=2e-3)


def test_all_or_nothing_kept():
    box = trimesh.creation.box()
    vertices, faces = clip_mesh(box.vertices, box.faces, Plane([0, 0, -5.0], [0, 0, 1]))
    assert len(faces) == len(box.faces)
    vertices, faces = clip_mesh(box.vertices, box.faces, Plane([0, 0, 5.0], [0, 0, 1]))
    assert vertices.shape == (0, 3) and faces.shape == (0, 3)
