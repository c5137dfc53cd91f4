"""Pieces of a mesh and the specks among them (lisa_hand.geometry.pieces), against trimesh's
own connected components and closed-form sphere areas."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from lisa_hand.geometry.meshing import Mesh
from lisa_hand.geometry.pieces import (
    MIN_PIECE_FRACTION,
    Specks,
    drop_specks,
    piece_labels,
    surface_pieces,
)


def spheres(radii_centres, subdivisions=3):
    """One Mesh of several icospheres, with colours and 16 skinning weights that tell the
    spheres apart: (mesh, [trimesh of each sphere])."""
    parts = [trimesh.creation.icosphere(subdivisions, radius).apply_translation(centre)
             for radius, centre in radii_centres]
    joined = trimesh.util.concatenate(parts)
    count = len(joined.vertices)
    which = np.repeat(np.arange(len(parts)), [len(p.vertices) for p in parts])
    colors = np.stack([which * 40, np.arange(count) % 256, np.full(count, 7)], 1)
    weights = np.zeros((count, 16), np.float32)
    weights[np.arange(count), which] = 1.0
    return Mesh(joined.vertices, joined.faces, colors.astype(np.uint8), weights), parts


def test_pieces_match_trimesh_and_the_sphere_areas():
    mesh, parts = spheres([(0.05, (0, 0, 0)), (0.001, (0.2, 0, 0)), (0.01, (0, 0.2, 0))])
    areas, total = surface_pieces(mesh)
    expected = sorted((p.area for p in parts), reverse=True)
    np.testing.assert_allclose(areas, expected, rtol=1e-6)  # float32 vertices
    assert total == pytest.approx(sum(expected), rel=1e-6)
    # The icosphere's area approaches 4 pi r^2 from below (within 1 % at 3 subdivisions).
    assert areas[0] == pytest.approx(4 * math.pi * 0.05 ** 2, rel=0.01)
    split = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).split(
        only_watertight=False)
    assert len(split) == len(areas) == 3
    labels, label_areas = piece_labels(np.asarray(mesh.vertices, np.float64), mesh.faces)
    assert labels.shape == (len(mesh.faces),) and sorted(label_areas) == sorted(areas)


def test_a_triangle_soup_is_one_piece_per_sphere():
    one, _ = spheres([(0.05, (0, 0, 0))])
    soup = one.vertices[one.faces].reshape(-1, 3)  # every triangle its own three vertices
    areas, _ = surface_pieces(Mesh(soup, np.arange(len(soup)).reshape(-1, 3)))
    assert len(areas) == 1


def test_specks_go_floaters_stay_attributes_follow():
    # 0.05 m sphere: 314 cm^2; a 1 mm speck is 0.004 % of it, a 5 mm floater 0.33 %.
    mesh, parts = spheres([(0.05, (0, 0, 0)), (0.001, (0.2, 0, 0)), (0.005, (0, 0.2, 0)),
                           (0.0008, (0, 0, 0.2))])
    cleaned, specks = drop_specks(mesh)
    assert specks == Specks(2, pytest.approx(parts[1].area + parts[3].area, rel=1e-6))
    assert surface_pieces(cleaned)[1] == pytest.approx(parts[0].area + parts[2].area, rel=1e-6)
    # What is left is exactly the kept spheres' vertices, with their own colours and weights.
    kept = np.concatenate([np.flatnonzero(mesh.skin_weights[:, k]) for k in (0, 2)])
    np.testing.assert_array_equal(cleaned.vertices, mesh.vertices[kept])
    np.testing.assert_array_equal(cleaned.colors, mesh.colors[kept])
    np.testing.assert_array_equal(cleaned.skin_weights, mesh.skin_weights[kept])
    assert cleaned.faces.max() == len(cleaned.vertices) - 1
    assert trimesh.Trimesh(cleaned.vertices, cleaned.faces).is_watertight
    note = specks.note("mesh.ply")
    assert note.startswith("mesh.ply: 2 speck(s) below 0.1 % of the surface removed")
    assert specks.to_dict()["area_cm2"] == pytest.approx(1e4 * specks.area_m2)
    # A larger threshold takes the floater too; 0 takes nothing and returns the mesh itself.
    assert drop_specks(mesh, 0.01)[1].count == 3
    same, none = drop_specks(mesh, 0.0)
    assert same is mesh and none == Specks(0, 0.0) and none.note() is None


def test_the_largest_piece_is_always_kept_and_bad_input_is_refused():
    # Ten equal spheres: each is 10 % of the area, all below a 20 % threshold.
    mesh, _ = spheres([(0.01, (0.05 * k, 0, 0)) for k in range(10)], subdivisions=1)
    cleaned, specks = drop_specks(mesh, 0.2)
    assert specks.count == 9 and len(surface_pieces(cleaned)[0]) == 1
    alone, _ = spheres([(0.01, (0, 0, 0))])
    assert drop_specks(alone)[0] is alone
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert drop_specks(empty) == (empty, Specks(0, 0.0))
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="min_fraction must be in"):
            drop_specks(alone, bad)
    assert MIN_PIECE_FRACTION == pytest.approx(1e-3)
