import math

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.metrics import (
    MeshDistances,
    detect_length_unit,
    image_metrics,
    load_mesh,
    lpips_distance,
    lpips_unavailable_reason,
    mesh_distances,
    psnr,
    ssim,
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


def test_detect_length_unit():
    sphere = _sphere(0.1)  # 20 cm hand-sized ball: diagonal 0.35
    assert detect_length_unit(sphere.vertices) == "m"
    assert detect_length_unit(1000.0 * sphere.vertices) == "mm"


def _images(seed: int = 0, size: tuple[int, int] = (24, 32)) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.2, 0.8, size=(*size, 3))


def test_psnr_closed_form_and_mask():
    target = _images()
    offset = 0.05
    # MSE = offset^2 -> PSNR = -20 log10(offset) = 26.0206 dB.
    assert psnr(target + offset, target) == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert psnr(target + offset, target, max_value=2.0) == pytest.approx(
        20.0 * math.log10(2.0 / offset), rel=1e-9)
    assert psnr(target, target) == math.inf
    # A larger error outside the mask is ignored inside it.
    pred = target + offset
    mask = np.zeros(target.shape[:2], dtype=bool)
    mask[4:12, 5:20] = True
    pred[~mask] += 0.2
    assert psnr(pred, target, mask=mask) == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert psnr(pred, target) < psnr(pred, target, mask=mask) - 5.0


def test_psnr_uint8_and_torch_inputs():
    target = (np.arange(24 * 32 * 3) % 200).reshape(24, 32, 3).astype(np.uint8)
    pred = target + np.uint8(10)
    expected = -20.0 * math.log10(10.0 / 255.0)
    assert psnr(pred, target) == pytest.approx(expected, rel=1e-9)
    assert psnr(torch.from_numpy(pred / 255.0), target) == pytest.approx(expected, rel=1e-9)


def test_ssim_identical_constant_and_mask():
    image = _images()
    assert ssim(image, image) == pytest.approx(1.0, abs=1e-12)
    # Constant images a and b: the contrast/structure terms are C2 / C2 = 1 and the luminance
    # term is (2ab + C1) / (a^2 + b^2 + C1) with C1 = (0.01 L)^2.
    a, b, c1 = 0.3, 0.5, 0.01**2
    expected = (2 * a * b + c1) / (a * a + b * b + c1)
    flat_a, flat_b = np.full((20, 20, 3), a), np.full((20, 20, 3), b)
    assert ssim(flat_a, flat_b) == pytest.approx(expected, rel=1e-9)
    assert ssim(flat_a, flat_b, mask=np.ones((20, 20), bool)) == pytest.approx(expected, rel=1e-9)
    # Change only pixels farther than the window's half-width (5) from the mask: masked SSIM
    # stays exactly 1, the whole-image SSIM drops.
    noisy = image.copy()
    noisy[:, 20:] = _images(seed=3)[:, 20:]
    mask = np.zeros(image.shape[:2], dtype=bool)
    mask[:, :14] = True
    assert ssim(noisy, image, mask=mask) == pytest.approx(1.0, abs=1e-12)
    assert ssim(noisy, image) < 0.9


def test_image_shape_errors():
    with pytest.raises(ValueError, match=r"pred \[24, 32, 3\] and target \[24, 31, 3\]"):
        psnr(_images(), _images()[:, :31])
    with pytest.raises(ValueError, match=r"pred \[24, 32, 3\] and target \[20, 32, 3\]"):
        ssim(_images(), _images()[:20])
    with pytest.raises(ValueError, match=r"mask must have shape \[H, W\] = \[24, 32\]"):
        psnr(_images(), _images(), mask=np.ones((24, 30), bool))
    with pytest.raises(ValueError, match="mask is empty"):
        psnr(_images(), _images(), mask=np.zeros((24, 32), bool))
    with pytest.raises(ValueError, match=r"pred must have shape \[H, W, 3\]"):
        psnr(np.zeros((4, 4, 5)), np.zeros((4, 4, 5)))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))


def test_lpips_reports_availability():
    reason = lpips_unavailable_reason()
    image = _images()
    value = lpips_distance(image, image)
    if reason:
        assert value is None
        assert "\n" not in reason and reason.startswith("LPIPS unavailable")
    else:
        assert value == pytest.approx(0.0, abs=1e-6)
        assert lpips_distance(image, _images(seed=5)) > 0.01
    assert "unknown LPIPS network" in lpips_unavailable_reason(net="resnet")


def test_image_metrics_combines_psnr_ssim_and_lpips():
    target = _images()
    offset = 0.05
    mask = np.zeros(target.shape[:2], dtype=bool)
    mask[4:12, 5:20] = True
    pred = target + offset
    pred[~mask] += 0.2
    result = image_metrics(pred, target, mask)
    assert result.psnr_db == pytest.approx(psnr(pred, target), rel=1e-12)
    assert result.psnr_mask_db == pytest.approx(-20.0 * math.log10(offset), rel=1e-9)
    assert result.ssim == pytest.approx(ssim(pred, target), rel=1e-12)
    assert result.ssim_mask == pytest.approx(ssim(pred, target, mask=mask), rel=1e-12)
    reason = lpips_unavailable_reason()
    if reason:  # no weights: NaN and the one-line reason, never a download
        assert math.isnan(result.lpips) and result.lpips_message == reason
        assert result.to_dict()["lpips"] is None
    else:
        assert result.lpips > 0.0 and result.lpips_message == ""
    unmasked = image_metrics(pred, target)
    assert math.isnan(unmasked.psnr_mask_db) and math.isnan(unmasked.ssim_mask)
    assert list(unmasked.to_dict()) == ["psnr_db", "ssim", "psnr_mask_db", "ssim_mask", "lpips"]
    with pytest.raises(ValueError, match="mask must have shape"):
        image_metrics(pred, target, mask[:, :10])
