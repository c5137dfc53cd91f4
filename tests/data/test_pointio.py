"""Point-cloud files (lisa_hand.data.pointio): points and normals as stored, PLY and OBJ through
the mesh reader's parsers, errors in one line naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.data.meshio import load_mesh, read_obj_vertices
from lisa_hand.data.pointio import POINT_FILE_SUFFIXES, read_points


def test_a_points_only_obj_with_colours_and_normals(tmp_path):
    rng = np.random.default_rng(0)
    points, colours = rng.normal(size=(20, 3)), rng.uniform(size=(20, 3))
    normals = rng.normal(size=(20, 3))
    with open(tmp_path / "cloud.obj", "w") as handle:
        handle.writelines("v " + " ".join(map(repr, map(float, row))) + "\n"
                          for row in np.concatenate([points, colours], axis=1))
        handle.writelines("vn " + " ".join(map(repr, map(float, row))) + "\n" for row in normals)
    table = read_obj_vertices(tmp_path / "cloud.obj")
    np.testing.assert_array_equal(table.positions, points)  # float64, as stored
    np.testing.assert_array_equal(table.colors, colours)
    np.testing.assert_array_equal(table.normals, normals)
    read, read_normals = read_points(tmp_path / "cloud.obj")
    np.testing.assert_array_equal(read, points)
    np.testing.assert_array_equal(read_normals, normals)
    mesh = load_mesh(tmp_path / "cloud.obj")  # the same parser: a mesh without faces
    assert mesh.num_faces == 0 and mesh.colors is not None
    np.testing.assert_allclose(mesh.vertices, points, rtol=1e-6)


def test_a_mesh_objs_corner_normals_are_not_per_vertex_normals(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2//1 4//1 3//1\n"
    (tmp_path / "quad.obj").write_text(text)
    table = read_obj_vertices(tmp_path / "quad.obj")
    assert table.positions.shape == (4, 3) and table.normals is None and table.colors is None
    assert read_points(tmp_path / "quad.obj")[1] is None


def test_errors_are_one_line_naming_the_file(tmp_path):
    (tmp_path / "short.obj").write_text("v 1 2\n")
    (tmp_path / "text.obj").write_text("v 1 2 x\n")
    (tmp_path / "flat.xyz").write_text("1 2\n3 4\n")
    (tmp_path / "cloud.pcd").write_text("x")
    for name, message in (("short.obj", "fewer than 3"), ("text.obj", "not a valid OBJ"),
                          ("flat.xyz", r"\[N, 3\] or \[N, 6\]"), ("cloud.pcd", "unsupported")):
        with pytest.raises(ValueError, match=message) as info:
            read_points(tmp_path / name)
        assert str(info.value).startswith(str(tmp_path / name)), name
        assert "\n" not in str(info.value), name
    with pytest.raises(FileNotFoundError, match="missing.npy"):
        read_points(tmp_path / "missing.npy")
    assert POINT_FILE_SUFFIXES == (".ply", ".obj", ".xyz", ".npy", ".npz")
