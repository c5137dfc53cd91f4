"""Mesh distances (V2V, V2S) against closed forms, and the mesh/point-set reader."""

import math

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.metrics import (
    MeshDistances,
    compare_mesh_files,
    load_mesh,
    mesh_distances,
)

R_INNER = 0.050
R_OUTER = 0.052
SUBDIVISIONS = 5  # 10242 vertices, 20480 faces


def _random_rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _sphere(radius: float, rotation_seed: int | None = None) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=SUBDIVISIONS, radius=radius)
    if rotation_seed is not None:
        mesh.vertices = mesh.vertices @ _random_rotation(rotation_seed).T
    return mesh


def _max_sagitta(mesh: trimesh.Trimesh, radius: float) -> float:
    """Largest gap between the sphere and the polyhedron inscribed in it.

    A face with circumradius r_c lies in a plane at distance sqrt(R^2 - r_c^2) from the centre, so
    the polyhedron contains the ball of radius R - max sagitta and lies inside the ball of
    radius R.
    """
    tri = mesh.vertices[mesh.faces]
    a = np.linalg.norm(tri[:, 1] - tri[:, 2], axis=1)
    b = np.linalg.norm(tri[:, 0] - tri[:, 2], axis=1)
    c = np.linalg.norm(tri[:, 0] - tri[:, 1], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    circumradius = a * b * c / (4.0 * area)
    return float(np.max(radius - np.sqrt(radius**2 - circumradius**2)))


def test_concentric_spheres_v2s_equals_radius_gap():
    inner = _sphere(R_INNER)
    outer = _sphere(R_OUTER, rotation_seed=0)  # rotated: its vertices are not aligned with inner's
    result = mesh_distances(inner.vertices, inner.faces, outer.vertices, outer.faces)
    gap_mm = 1000.0 * (R_OUTER - R_INNER)
    sag_inner_mm = 1000.0 * _max_sagitta(inner, R_INNER)
    sag_outer_mm = 1000.0 * _max_sagitta(outer, R_OUTER)
    # Each polyhedron lies between the balls of radius R - sagitta and R (sagitta ~0.015 mm
    # here), so exactly: inner vertex -> outer surface in [gap - sag_outer, gap] and outer
    # vertex -> inner surface in [gap, gap + sag_inner]: a tolerance under 1% of the 2 mm gap,
    # derived from the meshes rather than guessed.
    assert sag_inner_mm < 0.02 and sag_outer_mm < 0.02
    assert gap_mm - sag_outer_mm - 1e-9 <= result.v2s_recon_to_scan_mm <= gap_mm + 1e-9
    assert gap_mm - 1e-9 <= result.v2s_scan_to_recon_mm <= gap_mm + sag_inner_mm + 1e-9
    # The nearest vertex is a point of the surface, so V2V >= V2S; with the rotated vertices
    # it is strictly larger.
    assert result.v2v_recon_to_scan_mm > result.v2s_recon_to_scan_mm + 0.05
    assert result.v2v_scan_to_recon_mm > result.v2s_scan_to_recon_mm + 0.05
    # The nearest vertex is at most one edge (~2.1 mm here) away from the closest surface point.
    max_edge_mm = 1000.0 * outer.edges_unique_length.max()
    assert result.v2v_recon_to_scan_mm < gap_mm + max_edge_mm


def test_v2v_matches_brute_force_and_units():
    rng = np.random.default_rng(1)
    recon = rng.normal(size=(40, 3)) * 0.05
    scan = rng.normal(size=(60, 3)) * 0.05
    pairwise = np.linalg.norm(recon[:, None] - scan[None], axis=-1)
    result = mesh_distances(torch.from_numpy(recon).float(), None, scan, None, unit_scale=1.0)
    assert result.v2v_recon_to_scan_mm == pytest.approx(pairwise.min(1).mean(), rel=1e-6)
    assert result.v2v_scan_to_recon_mm == pytest.approx(pairwise.min(0).mean(), rel=1e-6)
    # Point sets have no surface: V2S is undefined (NaN) in both directions here.
    assert math.isnan(result.v2s_recon_to_scan_mm) and math.isnan(result.v2s_scan_to_recon_mm)


def test_identical_meshes_give_zero_and_dict_keys():
    sphere = _sphere(R_INNER)
    result = mesh_distances(sphere.vertices, sphere.faces, sphere.vertices, sphere.faces)
    assert isinstance(result, MeshDistances)
    assert list(result.to_dict()) == ["v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm",
                                      "v2v_scan_to_recon_mm", "v2s_scan_to_recon_mm"]
    for value in result.to_dict().values():
        assert abs(value) < 1e-9


def test_point_scan_makes_recon_to_scan_v2s_nan():
    inner, outer = _sphere(R_INNER), _sphere(R_OUTER)
    result = mesh_distances(outer.vertices, outer.faces, inner.vertices, None)
    assert math.isnan(result.v2s_recon_to_scan_mm)
    assert result.v2s_scan_to_recon_mm == pytest.approx(2.0, abs=2e-3)


def test_mesh_distance_input_errors():
    with pytest.raises(ValueError, match=r"recon_vertices must have shape \[V, 3\]"):
        mesh_distances(np.zeros((4, 2)), None, np.zeros((4, 3)))
    with pytest.raises(ValueError, match="scan_faces indexes vertices outside"):
        mesh_distances(np.zeros((4, 3)), None, np.zeros((3, 3)), np.array([[0, 1, 5]]))


def test_load_mesh_formats_and_errors(tmp_path):
    sphere = _sphere(R_INNER)
    sphere.export(tmp_path / "sphere.ply")
    sphere.export(tmp_path / "sphere.obj")
    loaded = load_mesh(tmp_path / "sphere.ply")
    assert loaded.vertices.shape == sphere.vertices.shape
    np.testing.assert_array_equal(loaded.faces, sphere.faces)
    np.testing.assert_allclose(load_mesh(tmp_path / "sphere.obj").vertices, sphere.vertices,
                               atol=1e-6)
    trimesh.PointCloud(sphere.vertices).export(tmp_path / "points.ply")
    points = load_mesh(tmp_path / "points.ply")
    assert points.faces is None and points.vertices.shape == sphere.vertices.shape
    np.save(tmp_path / "points.npy", sphere.vertices)
    assert load_mesh(tmp_path / "points.npy").faces is None
    np.savez(tmp_path / "mesh.npz", vertices=sphere.vertices, faces=sphere.faces)
    np.testing.assert_array_equal(load_mesh(tmp_path / "mesh.npz").faces, sphere.faces)
    np.savetxt(tmp_path / "points.xyz", np.hstack([sphere.vertices, sphere.vertex_normals]))
    np.testing.assert_allclose(load_mesh(tmp_path / "points.xyz").vertices, sphere.vertices)
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        load_mesh(tmp_path / "missing.ply")
    (tmp_path / "garbage.npy").write_bytes(b"not numpy")
    with pytest.raises(ValueError, match="garbage.npy"):
        load_mesh(tmp_path / "garbage.npy")
    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(ValueError, match="empty.obj"):
        load_mesh(tmp_path / "empty.obj")
    with pytest.raises(ValueError, match=r"notes\.txt: unsupported file type"):
        (tmp_path / "notes.txt").write_text("x")
        load_mesh(tmp_path / "notes.txt")


def test_compare_mesh_files_decides_each_unit_from_the_hand_size(tmp_path):
    recon = _sphere(R_INNER)  # 0.17 m across: metres
    scan = _sphere(R_OUTER)
    recon.export(tmp_path / "recon.ply")
    np.save(tmp_path / "scan_cm.npy", 100.0 * scan.vertices)  # 18 units across: centimetres
    np.save(tmp_path / "scan_mm.npy", 1000.0 * scan.vertices)
    expected = mesh_distances(recon.vertices, recon.faces, scan.vertices, None)
    for name, unit in (("scan_cm.npy", "cm"), ("scan_mm.npy", "mm")):
        result = compare_mesh_files(tmp_path / "recon.ply", tmp_path / name)
        assert (result.recon_unit, result.scan_unit) == ("m", unit)
        assert result.recon_note is None
        assert f"read as {'centimetres' if unit == 'cm' else 'millimetres'}" in result.scan_note
        assert result.distances.v2v_recon_to_scan_mm == pytest.approx(  # float32 PLY
            expected.v2v_recon_to_scan_mm, abs=1e-5)
    # A unit given for both files that makes one of them no hand is refused, naming the file
    # and the unit that fits (it used to print 53 m distances).
    with pytest.raises(ValueError, match=r"scan_mm\.npy: the point set is 180.1 units .*180 m, "
                                         r"too large for a hand.*looks like millimetres: pass "
                                         r"--units mm"):
        compare_mesh_files(tmp_path / "scan_mm.npy", tmp_path / "scan_mm.npy", units="m")
    both_cm = compare_mesh_files(tmp_path / "scan_cm.npy", tmp_path / "scan_cm.npy", units="cm")
    assert both_cm.scan_unit == "cm" and not both_cm.scan_unit_detected
    with pytest.raises(ValueError, match="units must be one of auto, m, cm, mm"):
        compare_mesh_files(tmp_path / "recon.ply", tmp_path / "recon.ply", units="inch")


def test_load_mesh_names_folders_and_ply_faces_without_vertices(tmp_path):
    (tmp_path / "folder.ply").mkdir()
    with pytest.raises(IsADirectoryError, match=r"folder\.ply: is a directory, expected a file"):
        load_mesh(tmp_path / "folder.ply")
    header = "ply\nformat ascii 1.0\n"
    face = "element face 1\nproperty list uchar int vertex_indices\n"
    xyz = "property float x\nproperty float y\nproperty float z\n"
    (tmp_path / "faces.ply").write_text(header + face + "end_header\n3 0 1 2\n")
    (tmp_path / "zero.ply").write_text(header + "element vertex 0\n" + xyz + face
                                       + "end_header\n3 0 1 2\n")
    with pytest.raises(ValueError, match=r"faces\.ply: the PLY has 1 face\(s\) but no vertex "
                                         "element"):
        load_mesh(tmp_path / "faces.ply")
    with pytest.raises(ValueError, match=r"zero\.ply: the PLY has no vertices \(element vertex "
                                         r"0\) but 1 face\(s\)"):
        load_mesh(tmp_path / "zero.ply")


def test_roughness_is_small_on_a_sphere_and_grows_with_bumps():
    import trimesh

    from lisa_hand.metrics.mesh import surface_roughness

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    smooth = surface_roughness(sphere.vertices, sphere.faces)
    noise = np.random.default_rng(0).normal(0.0, 0.0005, len(sphere.vertices))
    bumpy = sphere.vertices * (1.0 + noise / 0.05)[:, None]
    rough = surface_roughness(bumpy, sphere.faces)
    assert smooth < 0.1  # mm: a sphere of 2.5k vertices (2 mm edges) barely moves
    assert 0.25 < rough < 0.45  # 0.5 mm SD bumps, 0.4 mm mean size: most of it is removed
    doubled = surface_roughness(sphere.vertices * (1.0 + 2 * noise / 0.05)[:, None], sphere.faces)
    assert 1.6 < doubled / rough < 2.2  # twice the bumps, about twice the figure
    with pytest.raises(ValueError, match="faces"):
        surface_roughness(sphere.vertices, None)
