"""Fitting LISA to point clouds: the pure pieces against closed forms, file readers against
files written by numpy/trimesh, and whole fits of a tiny model to its own surface (the pose it
was posed with is known)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.data.scans import ScanConfig, simulate_scan
from lisa_hand.fields.config import FieldConfig
from lisa_hand.fitting.points.cloud import CloudDistance
from lisa_hand.fitting.points.fit import FitPointsConfig, fit_points
from lisa_hand.fitting.points.global_pose import cloud_candidate_rotations, cube_rotations
from lisa_hand.fitting.points.io import prepare_point_cloud, read_point_cloud
from lisa_hand.fitting.robust import robust_loss
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.geometry.meshing import extract_mesh
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel
from lisa_hand.skeleton.params import HandParams

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8)


pytestmark = pytest.mark.usefixtures("one_thread")


def template_rest_joints() -> torch.Tensor:
    """[16, 3] the template's mean skeleton (float32 metres)."""
    from lisa_hand.handmodel.template import load_template

    template = load_template().to(dtype=torch.float32)
    return template.rest_joints(torch.zeros(1, template.num_betas))[0]


def tiny_model(color: bool = False, seed: int = 0) -> TrainedModel:
    """A tiny LISA (geometric initialisation: a blob hand on the template's skeleton)."""
    torch.manual_seed(seed)
    field = LisaModel(FieldConfig(use_color=color, **TINY_FIELD),
                      init_rest_joints=template_rest_joints()).eval()
    generator = torch.Generator().manual_seed(seed)
    return TrainedModel(
        field=field,
        shape_codes=0.01 * torch.randn(3, 8, generator=generator),
        color_codes=0.01 * torch.randn(3, 8, generator=generator) if color else None,
        subject_ids=["s0", "s1", "s2"], beta=0.002, gain=torch.ones(3), bias=torch.zeros(3),
        source="test")


def true_hand(model: TrainedModel, seed: int) -> HandParams:
    """A posed hand of ``model``: bent fingers, a large random rotation, a translation."""
    generator = torch.Generator().manual_seed(seed)
    pose = torch.zeros(16, 3)
    pose[1:, 2] = 0.25 * torch.rand(15, generator=generator)  # fingers flexed about z
    pose[0] = torch.tensor([2.2, -0.9, 1.3]) * (1 + 0.1 * seed)
    return HandParams(pose=pose.reshape(48), translation=torch.tensor([0.05, -0.02, 0.3]),
                      rest_joints=template_rest_joints(), shape_code=model.mean_shape_code())


def surface(model: TrainedModel, params: HandParams, resolution: int = 48):
    """The model's marching-cubes mesh for ``params`` (vertices float32 metres, faces)."""
    field = model.field
    state = field.prepare(**{k: v for k, v in params.batch().items() if k != "color_code"},
                          color_code=None if model.color_codes is None
                          else model.mean_color_code()[None])
    centre = params.translation.numpy()
    with torch.no_grad():
        mesh = extract_mesh(field.sdf_fn(state), centre - 0.15, centre + 0.15, resolution,
                            lipschitz=2.0)
    return mesh


def scan_of(model: TrainedModel, params: HandParams, config: ScanConfig, seed: int):
    """A simulated scan of the hand's mesh, keeping only inliers on the zero level set.

    A freshly initialised field jumps where a blob leaves its bone's region, and marching cubes
    puts a wall there; those vertices are not on ``G = 0`` and are dropped.
    -> (points [N, 3], normals [N, 3], is_outlier [N]) float32 numpy
    """
    mesh = surface(model, params)
    scan = simulate_scan(mesh.vertices, mesh.faces, config, seed=seed)
    on_surface = sdf_at(model, params, scan.points).abs().numpy() < 3e-4
    keep = on_surface | scan.is_outlier
    return scan.points[keep], scan.normals[keep], scan.is_outlier[keep]


def sdf_at(model: TrainedModel, params: HandParams, points) -> torch.Tensor:
    field = model.field
    color = None if model.color_codes is None else model.mean_color_code()[None]
    state = field.prepare(params.pose[None], params.translation[None], params.rest_joints[None],
                          params.shape_code[None], color)
    with torch.no_grad():
        return field.sdf_fn(state)(torch.as_tensor(points, dtype=torch.float32))


FAST = dict(align_iters=20, align_keep=6, restarts=2, pose_iters=20,
            field_iters=40, points_per_iteration=128, proxy_points=300, init_poses=("zero",),
            fit_betas=False)


def rotation_error_deg(first: torch.Tensor, second: torch.Tensor) -> float:
    relative = axis_angle_to_matrix(first[:3]).T @ axis_angle_to_matrix(second[:3])
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(relative)) - 1) / 2))))


# ---------------------------------------------------------------------------------------------
# Pure functions


def test_robust_losses_closed_forms():
    sigma = 0.004
    residual = torch.tensor([-0.008, -0.002, 0.0, 0.001, 0.004, 1.0], dtype=torch.float64)
    l1 = robust_loss(residual, "l1", sigma)
    assert torch.allclose(l1, residual.abs())
    huber = robust_loss(residual, "huber", sigma)
    expected = [0.008 - 0.002, 0.002**2 / 0.008, 0.0, 0.001**2 / 0.008, 0.002, 1.0 - 0.002]
    assert torch.allclose(huber, torch.tensor(expected, dtype=torch.float64))
    gm = robust_loss(residual, "geman_mcclure", sigma)
    assert gm[4] == pytest.approx(sigma / 2)  # r = sigma: half the bound
    assert gm[5] < sigma and gm[5] == pytest.approx(sigma, rel=1e-4)  # bounded by sigma
    assert gm[1] == pytest.approx(sigma * 4e-6 / (4e-6 + 1.6e-5))
    # Outliers pull less than inliers: the gradient at 1 m is tiny next to the one at sigma.
    r = torch.tensor([sigma / math.sqrt(3), 1.0], dtype=torch.float64, requires_grad=True)
    robust_loss(r, "geman_mcclure", sigma).sum().backward()
    assert r.grad[1] < 1e-6 * r.grad[0]
    with pytest.raises(ValueError, match="kind"):
        robust_loss(residual, "cauchy", sigma)


def test_cube_rotations_are_the_24_proper_ones():
    rotations = cube_rotations()
    assert rotations.shape == (24, 3, 3)
    assert torch.equal(rotations[0], torch.eye(3, dtype=torch.float64))
    eye = torch.eye(3, dtype=torch.float64).expand(24, 3, 3)
    assert torch.allclose(rotations @ rotations.transpose(1, 2), eye)
    assert torch.allclose(torch.det(rotations), torch.ones(24, dtype=torch.float64))
    assert len({tuple(r.flatten().tolist()) for r in rotations}) == 24


def test_cloud_candidate_rotations_contain_the_true_rotation():
    generator = torch.Generator().manual_seed(0)
    proxy = torch.randn(500, 3, generator=generator, dtype=torch.float64) * torch.tensor(
        [0.08, 0.03, 0.01], dtype=torch.float64)  # three distinct spreads
    truth = axis_angle_to_matrix(torch.tensor([0.4, -2.0, 1.1], dtype=torch.float64))
    cloud = proxy @ truth.T + torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    candidates = cloud_candidate_rotations(cloud, proxy)
    errors = (candidates - truth).flatten(1).abs().amax(1)
    assert float(errors.min()) < 1e-9


def test_cloud_distance_grid_matches_brute_force():
    generator = torch.Generator().manual_seed(1)
    cloud = torch.rand(400, 3, generator=generator) * 0.1
    queries = torch.rand(1, 300, 3, generator=generator) * 0.14 - 0.02
    grid = CloudDistance(cloud)
    exact = torch.cdist(queries[0], cloud).amin(-1)
    approx = grid(queries)[0]
    # Within one cell diagonal (2 mm * sqrt(3)) plus interpolation slack.
    assert float((approx - exact).abs().max()) < 0.004
    assert float((approx - exact).abs().mean()) < 0.0015
    queries.requires_grad_(True)
    grid(queries).sum().backward()
    assert torch.isfinite(queries.grad).all() and queries.grad.abs().sum() > 0


# ---------------------------------------------------------------------------------------------
# Readers


def _write_binary_ply(path, points, normals):
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}"]
    header += [f"property float {name}" for name in ("x", "y", "z", "nx", "ny", "nz")]
    header += ["element face 0", "property list uchar int vertex_indices", "end_header"]
    table = np.concatenate([points, normals], axis=1).astype("<f4")
    path.write_bytes(("\n".join(header) + "\n").encode() + table.tobytes())


def test_readers_of_every_format(tmp_path):
    import trimesh

    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 3)) * 0.05
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    np.save(tmp_path / "a.npy", points)
    np.save(tmp_path / "b.npy", np.concatenate([points, normals], axis=1))
    np.savez(tmp_path / "c.npz", points=points, normals=normals)
    np.savez(tmp_path / "d.npz", vertices=points)
    np.savetxt(tmp_path / "e.xyz", np.concatenate([points, normals], axis=1))
    np.savetxt(tmp_path / "f.xyz", points, header="x y z")
    _write_binary_ply(tmp_path / "g.ply", points, normals)
    trimesh.PointCloud(points).export(tmp_path / "h.ply")  # trimesh's own writer, no normals
    with open(tmp_path / "i.obj", "w") as handle:
        handle.writelines(f"v {x} {y} {z}\n" for x, y, z in points)
        handle.writelines(f"vn {x} {y} {z}\n" for x, y, z in normals)
    box = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    box.export(tmp_path / "j.obj")
    expected = {"a.npy": False, "b.npy": True, "c.npz": True, "d.npz": False, "e.xyz": True,
                "f.xyz": False, "g.ply": True, "h.ply": False, "i.obj": True}
    for name, with_normals in expected.items():
        read, read_normals = read_point_cloud(tmp_path / name)
        tolerance = 1e-6 if name.endswith((".ply",)) else 1e-12
        assert np.allclose(read, points, atol=tolerance), name
        assert (read_normals is not None) == with_normals, name
        if with_normals:
            assert np.allclose(read_normals, normals, atol=1e-6), name
    mesh_points, mesh_normals = read_point_cloud(tmp_path / "j.obj")  # a mesh: its vertices
    assert np.allclose(np.sort(mesh_points, axis=0), np.sort(box.vertices, axis=0))
    assert mesh_normals is None


def test_mesh_files_give_their_distinct_vertices(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.05, 0.02))  # 8 corners, 12 triangles
    box.export(tmp_path / "box.stl")  # STL repeats each corner for every triangle: 36 rows
    box.export(tmp_path / "box.off")
    scene = trimesh.Scene()
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix([0.2, 0, 0]))
    scene.export(tmp_path / "box.glb")
    corners = np.sort(box.vertices, axis=0)
    for name, shift in (("box.stl", 0.0), ("box.off", 0.0), ("box.glb", 0.2)):
        points, normals = read_point_cloud(tmp_path / name)
        assert points.shape == (8, 3) and normals is None, name
        assert np.allclose(np.sort(points, axis=0), corners + [shift, 0, 0], atol=1e-6), name
    (tmp_path / "bad.stl").write_bytes(b"solid x\nfacet normal 0 0 1\nnot stl\n")
    with pytest.raises(ValueError, match="bad.stl"):
        read_point_cloud(tmp_path / "bad.stl")


def test_reader_errors_name_the_file(tmp_path):
    np.save(tmp_path / "empty.npy", np.zeros((0, 3)))
    np.save(tmp_path / "flat.npy", np.zeros((10, 2)))
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10"
                                       b"\nproperty float x\nproperty float y\nproperty float z"
                                       b"\nend_header\n" + b"\0" * 12)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "cloud.pcd").write_text("x")
    for name, message in (("empty.npy", "empty"), ("flat.npy", r"\[N, 3\]"),
                          ("bad.ply", "truncated"), ("junk.npz", "cannot read"),
                          ("cloud.pcd", "unsupported")):
        with pytest.raises(ValueError, match=message) as info:
            read_point_cloud(tmp_path / name)
        assert str(tmp_path / name) in str(info.value)
    with pytest.raises(FileNotFoundError, match="missing.npy"):
        read_point_cloud(tmp_path / "missing.npy")


def test_prepare_point_cloud_fallbacks_and_units():
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, size=(100, 3))
    points[:7] = np.nan
    cloud = prepare_point_cloud(points, name="scan")
    assert cloud.points.shape == (93, 3) and cloud.unit == "m"
    assert "dropped 7 of 100" in cloud.notes[0]
    in_mm = prepare_point_cloud(1000.0 * points[7:], units="auto")
    assert in_mm.unit == "mm" and np.allclose(in_mm.points, points[7:])
    assert "millimetres" in in_mm.notes[0]
    with pytest.raises(ValueError, match="scan: .*looks like millimetres"):
        prepare_point_cloud(1000.0 * points[7:], units="m", name="scan")
    subsampled = prepare_point_cloud(points[7:], max_points=40, seed=1)
    assert subsampled.points.shape == (40, 3) and "subsampled 93 points to 40" in \
        subsampled.notes[0]
    with pytest.raises(ValueError, match="only 5 of 100 points"):
        bad = np.full((100, 3), np.nan)
        bad[:5] = 0.01 * np.arange(15).reshape(5, 3)
        prepare_point_cloud(bad)
    with pytest.raises(ValueError, match="too small for a hand"):
        prepare_point_cloud(0.01 * points[7:])
    with pytest.raises(ValueError, match="too large for a hand"):
        prepare_point_cloud(20000.0 * points[7:], units="mm")  # 3.4 m
    zero_normals = np.zeros((93, 3))
    assert prepare_point_cloud(points[7:], zero_normals).normals is None


# ---------------------------------------------------------------------------------------------
# Whole fits


def test_fit_recovers_pose_from_a_rotated_start():
    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, normals, _ = scan_of(model, truth, ScanConfig(num_points=1000), seed=0)
    steps = []
    result = fit_points(model, points, normals, FitPointsConfig(**FAST),
                        rest_joints=truth.rest_joints, callback=steps.append)
    fitted = result.params
    # The start is the cloud's centroid in 24 cube orientations; the truth is ~140 degrees away
    # from the identity, and the fit lands on it.
    assert rotation_error_deg(fitted.pose, truth.pose) < 5.0
    assert float((fitted.translation - truth.translation).norm()) < 0.004
    residual = sdf_at(model, fitted, points).abs()
    assert float(residual.mean()) < 0.0005
    assert result.residual_mean_mm == pytest.approx(1e3 * float(residual.mean()), rel=1e-3)
    assert result.inlier_fraction > 0.99
    # The surfaces agree the other way too: the true surface is on the fitted zero level set.
    truth_surface = sdf_at(model, truth, surface(model, truth).vertices).abs() < 3e-4
    true_vertices = surface(model, truth).vertices[truth_surface.numpy()]
    assert float(sdf_at(model, fitted, true_vertices).abs().mean()) < 0.0007
    stages = [step.stage for step in steps]
    assert stages.count("align") == FAST["align_iters"]
    # The second finger pass adds its field steps when its restarts changed the hand.
    second = FitPointsConfig().second_pass_iters
    assert stages.count("field") in (FAST["field_iters"], FAST["field_iters"] + second)
    assert fitted.extra["fit"]["num_points"] == len(points)
    assert steps[-1].params().pose.shape == (48,)


def test_partial_scan_and_outliers():
    model = tiny_model(seed=1)
    truth = true_hand(model, seed=1)
    points, _, is_outlier = scan_of(
        model, truth, ScanConfig(num_points=800, partial=True, outlier_fraction=0.2,
                                 outlier_box_scale=1.5), seed=1)
    inliers = points[~is_outlier]
    errors = {}
    for loss in ("geman_mcclure", "l1"):
        config = FitPointsConfig(**dict(FAST, field_iters=60), robust_loss=loss)
        fitted = fit_points(model, points, None, config, rest_joints=truth.rest_joints).params
        errors[loss] = float(sdf_at(model, fitted, inliers).abs().mean())
    # One view with 20% outliers: the robust fit puts the seen side on the surface; the
    # paper's L1 lets the outliers drag the hand.
    assert errors["geman_mcclure"] < 0.001
    assert errors["l1"] > 2.0 * errors["geman_mcclure"]


def test_fit_points_rejects_bad_input():
    model = tiny_model()
    good = np.random.default_rng(0).uniform(-0.05, 0.05, size=(100, 3))
    with pytest.raises(ValueError, match="millimetres"):
        fit_points(model, 1000.0 * good)
    bad = good.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fit_points(model, bad)
    with pytest.raises(ValueError, match="fewer than"):
        fit_points(model, good[:5])
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        fit_points(model, good[:, :2])
    with pytest.raises(TypeError, match="TrainedModel"):
        fit_points(model.field, good)
    with pytest.raises(ValueError, match="robust_loss"):
        FitPointsConfig(robust_loss="cauchy")
    with pytest.raises(ValueError, match="unknown pose name"):
        FitPointsConfig(init_poses=("jazz",))
