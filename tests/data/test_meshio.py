"""Mesh files: PLY/OBJ/GLB round trips, foreign PLY layouts, atomic writes, clear errors."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from lisa_hand.data import meshio
from lisa_hand.data.meshio import load_mesh, save_mesh
from lisa_hand.geometry.meshing import Mesh


def random_mesh(with_colors=True, num_weights=16, seed=0) -> Mesh:
    rng = np.random.default_rng(seed)
    num_vertices = 40
    weights = None
    if num_weights:
        weights = rng.random((num_vertices, num_weights)).astype(np.float32)
        weights /= weights.sum(axis=1, keepdims=True)
    return Mesh(
        vertices=(rng.normal(size=(num_vertices, 3)) * 0.05).astype(np.float32),
        faces=rng.integers(0, num_vertices, size=(70, 3)),
        colors=rng.integers(0, 256, size=(num_vertices, 3)).astype(np.uint8) if with_colors
        else None,
        skin_weights=weights,
    )


def assert_same(loaded: Mesh, mesh: Mesh, weights=True):
    np.testing.assert_array_equal(loaded.vertices, mesh.vertices)  # float32 exact
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    if mesh.colors is None:
        assert loaded.colors is None
    else:
        np.testing.assert_array_equal(loaded.colors, mesh.colors)
    if weights and mesh.skin_weights is not None:
        np.testing.assert_array_equal(loaded.skin_weights, mesh.skin_weights)
    else:
        assert loaded.skin_weights is None


@pytest.mark.parametrize("with_colors", [True, False])
@pytest.mark.parametrize("num_weights", [16, 0])
def test_ply_round_trip(tmp_path, with_colors, num_weights):
    mesh = random_mesh(with_colors, num_weights)
    path = save_mesh(tmp_path / "sub" / "hand.ply", mesh)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    assert_same(load_mesh(path), mesh)


def test_ply_header_names_the_properties(tmp_path):
    path = save_mesh(tmp_path / "hand.ply", random_mesh(num_weights=3))
    header = path.read_bytes().split(b"end_header")[0].decode()
    for line in ("property uchar red", "property uchar blue", "property float w0",
                 "property float w2", "element face 70", "property list uchar int vertex_indices"):
        assert line in header
    assert "w3" not in header


def test_ply_agrees_with_trimesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh = random_mesh(num_weights=0)
    path = save_mesh(tmp_path / "hand.ply", mesh)
    other = trimesh.load(path, process=False)
    np.testing.assert_array_equal(np.asarray(other.vertices, np.float32), mesh.vertices)
    np.testing.assert_array_equal(other.faces, mesh.faces)
    np.testing.assert_array_equal(other.visual.vertex_colors[:, :3], mesh.colors)
    # And we read what trimesh writes (binary and ASCII).
    tri = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=mesh.colors, process=False)
    for encoding in ("binary", "ascii"):
        foreign = tmp_path / f"trimesh_{encoding}.ply"
        foreign.write_bytes(tri.export(file_type="ply", encoding=encoding))
        loaded = load_mesh(foreign)
        if encoding == "ascii":  # trimesh prints about 8 significant digits
            np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=0, atol=1e-8)
            loaded.vertices = mesh.vertices
        assert_same(loaded, mesh)


def test_big_endian_ascii_and_quad_ply(tmp_path):
    header = (
        "ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\n"
        "property double y\nproperty double z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=">f8")
    body = vertices.tobytes() + struct.pack(">B3i", 3, 0, 1, 2)
    (tmp_path / "big.ply").write_bytes(header.encode() + body)
    mesh = load_mesh(tmp_path / "big.ply")
    np.testing.assert_array_equal(mesh.vertices, vertices.astype(np.float32))
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])

    ascii_ply = (
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    )
    (tmp_path / "quad.ply").write_text(ascii_ply)
    np.testing.assert_array_equal(load_mesh(tmp_path / "quad.ply").faces, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("with_colors", [True, False])
def test_obj_round_trip(tmp_path, with_colors):
    mesh = random_mesh(with_colors, num_weights=0)
    path = save_mesh(tmp_path / "hand.obj", mesh)
    first = path.read_text().splitlines()[1]
    assert first.startswith("v ") and len(first.split()) == (7 if with_colors else 4)
    assert_same(load_mesh(path), mesh)


def test_obj_reader_handles_slashes_polygons_and_negative_indices(tmp_path):
    text = (
        "# a quad\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 1 1 0 0 0 1\nv 0 1 0 1 1 1\n"
        "vt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -3//1 -2//1\n"
    )
    (tmp_path / "quad.obj").write_text(text)
    mesh = load_mesh(tmp_path / "quad.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 1, 2]])
    np.testing.assert_array_equal(mesh.colors[[0, 3]], [[255, 0, 0], [255, 255, 255]])


@pytest.mark.parametrize("with_colors", [True, False])
def test_glb_round_trip(tmp_path, with_colors):
    mesh = random_mesh(with_colors, num_weights=0)
    path = save_mesh(tmp_path / "hand.glb", mesh)
    assert path.read_bytes()[:4] == b"glTF"
    assert_same(load_mesh(path), mesh)


@pytest.mark.parametrize("suffix", [".obj", ".glb"])
def test_weights_dropped_with_a_warning(tmp_path, suffix):
    mesh = random_mesh()
    with pytest.warns(UserWarning, match="skinning weights"):
        path = save_mesh(tmp_path / f"hand{suffix}", mesh)
    assert_same(load_mesh(path), mesh, weights=False)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_failed_write_leaves_no_file(tmp_path, monkeypatch, suffix):
    target = tmp_path / f"hand{suffix}"

    def broken_writer(path, mesh):
        path.write_bytes(b"half a mesh")
        raise RuntimeError("disk full")

    name = {".ply": "_write_ply", ".obj": "_write_obj", ".glb": "_write_glb"}[suffix]
    monkeypatch.setattr(meshio, name, broken_writer)
    with pytest.raises(RuntimeError, match="disk full"):
        save_mesh(target, random_mesh(num_weights=0))
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_the_previous_file(tmp_path, monkeypatch):
    mesh = random_mesh()
    path = save_mesh(tmp_path / "hand.ply", mesh)
    before = path.read_bytes()

    def broken_writer(path, mesh):
        raise RuntimeError("disk full")

    monkeypatch.setattr(meshio, "_write_ply", broken_writer)
    with pytest.raises(RuntimeError):
        save_mesh(path, random_mesh(seed=1))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["hand.ply"]


def test_errors_name_the_file(tmp_path):
    mesh = random_mesh()
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        load_mesh(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match=r"hand\.stl.*unknown mesh file extension"):
        load_mesh(tmp_path / "hand.stl")
    with pytest.raises(ValueError, match="unknown mesh file extension"):
        save_mesh(tmp_path / "hand.stl", mesh)
    with pytest.raises(TypeError, match="Mesh"):
        save_mesh(tmp_path / "hand.ply", mesh.vertices)

    data = save_mesh(tmp_path / "hand.ply", mesh).read_bytes()
    truncated = tmp_path / "truncated.ply"
    truncated.write_bytes(data[: len(data) - 100])
    with pytest.raises(ValueError, match="truncated.ply"):
        load_mesh(truncated)
    garbage = {"garbage.ply": b"solid nothing", "garbage.glb": b"not a glb at all",
               "garbage.obj": b"v 1 2\nf 1 2 3\n"}
    for name, content in garbage.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match=name.replace(".", r"\.")):
            load_mesh(tmp_path / name)
    (tmp_path / "bad_index.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    with pytest.raises(ValueError, match=r"bad_index\.obj.*faces index"):
        load_mesh(tmp_path / "bad_index.obj")


PLY_ASCII = "ply\nformat ascii 1.0\n"
PLY_XYZ = "property float x\nproperty float y\nproperty float z\n"
PLY_FACE = "element face 1\nproperty list uchar int vertex_indices\n"


def test_ply_faces_without_vertices_say_so(tmp_path):
    (tmp_path / "faces.ply").write_text(PLY_ASCII + PLY_FACE + "end_header\n3 0 1 2\n")
    (tmp_path / "zero.ply").write_text(PLY_ASCII + "element vertex 0\n" + PLY_XYZ + PLY_FACE
                                       + "end_header\n3 0 1 2\n")
    for name, message in (("faces.ply", "has 1 face(s) but no vertex element"),
                          ("zero.ply", "has no vertices (element vertex 0) but 1 face(s)")):
        for reader in (load_mesh, meshio.read_ply_vertices):
            with pytest.raises(ValueError) as info:
                reader(tmp_path / name)
            assert str(info.value).startswith(f"{tmp_path / name}: the PLY {message}"), (
                reader, str(info.value))
    # An ASCII PLY with no vertices and no faces is an empty mesh (as a binary one is), but
    # no cloud of points.
    (tmp_path / "empty.ply").write_text(PLY_ASCII + "element vertex 0\n" + PLY_XYZ
                                        + "element face 0\nproperty list uchar int "
                                          "vertex_indices\nend_header\n")
    empty = load_mesh(tmp_path / "empty.ply")
    assert empty.num_vertices == 0 and empty.num_faces == 0
    with pytest.raises(ValueError, match=r"empty\.ply: the PLY has no vertices \(element vertex "
                                         r"0\)$"):
        meshio.read_ply_vertices(tmp_path / "empty.ply")


def test_read_ply_vertices_reads_only_the_vertex_element(tmp_path):
    mesh = random_mesh(num_weights=2)
    save_mesh(tmp_path / "hand.ply", mesh)
    table = meshio.read_ply_vertices(tmp_path / "hand.ply")
    assert table.dtype.names == ("x", "y", "z", "red", "green", "blue", "w0", "w1")
    np.testing.assert_array_equal(table["y"], mesh.vertices[:, 1])
    # Truncated inside the faces: the vertices are all there.
    data = (tmp_path / "hand.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[: len(data) - 50])
    assert len(meshio.read_ply_vertices(tmp_path / "cut.ply")) == mesh.num_vertices
    (tmp_path / "short.ply").write_bytes(data[: data.index(b"end_header") + 20])
    with pytest.raises(ValueError, match=r"short\.ply: PLY file is truncated"):
        meshio.read_ply_vertices(tmp_path / "short.ply")


def test_a_folder_is_not_a_missing_file(tmp_path):
    (tmp_path / "hand.ply").mkdir()
    with pytest.raises(IsADirectoryError, match=r"hand\.ply: is a directory, expected a file"):
        load_mesh(tmp_path / "hand.ply")
