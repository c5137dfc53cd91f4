"""The MANO-like mesh template: shipped asset, LBS against a NumPy reference, fitting open-hand
subjects, MANO as the template, files and errors."""

from __future__ import annotations

import dataclasses
import importlib.resources

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from lisa_hand.handmodel import named_pose, sample_hand
from lisa_hand.handmodel.template import MeshTemplate, load_template, save_template
from lisa_hand.handmodel.template_build import build_template
from lisa_hand.handmodel.template_mano import template_from_mano
from lisa_hand.skeleton import KEYPOINT_SOURCES, PARENTS, ManoLayer, load_mano_pkl, mirror_points
from tests.skeleton.synthetic_mano import write_synthetic_mano

F64 = torch.float64


@pytest.fixture(scope="module")
def template() -> MeshTemplate:
    return load_template()


@pytest.fixture(scope="module")
def held_out():
    """A subject outside the build's stream (seed 0, 200 draws)."""
    return sample_hand(torch.Generator().manual_seed(4242))


def _mesh(vertices: torch.Tensor, faces: torch.Tensor) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices.detach().numpy(), faces.numpy(), process=False)


# ----------------------------------------------------------------------------------------------
# The shipped asset


def test_shipped_asset_is_package_data_and_read_once(template):
    resource = importlib.resources.files("lisa_hand") / "assets" / "template.npz"
    assert resource.is_file() and len(resource.read_bytes()) < 1_000_000
    again = load_template()  # from the cache, not the file: the same values
    assert again is not template
    for name in ("v_template", "faces", "weights", "joint_regressor", "shapedirs"):
        torch.testing.assert_close(getattr(again, name), getattr(template, name), rtol=0, atol=0)
    torch.testing.assert_close(again.source.vertices, template.source.vertices, rtol=0, atol=0)
    assert again.info == template.info and again.fingertip_ids == template.fingertip_ids


def test_the_cached_template_cannot_be_changed_by_a_caller():
    first = load_template()
    expected = {name: getattr(first, name).clone()
                for name in ("v_template", "weights", "joint_regressor", "shapedirs")}
    for name in expected:
        getattr(first, name).add_(1.0)  # in place, as a careless caller might
    first.source.joints.zero_()
    first.info["num_subjects"] = -1
    second = load_template()
    for name, value in expected.items():
        torch.testing.assert_close(getattr(second, name), value, rtol=0, atol=0)
    assert second.source.joints.abs().sum() > 0 and second.info["num_subjects"] == 200


def test_shapes_dtypes_and_invariants(template):
    num_v = template.num_vertices
    assert template.name == "open-template"
    assert 700 <= num_v <= 900 and template.num_betas == 10
    assert template.v_template.shape == (num_v, 3) and template.v_template.dtype == F64
    assert template.faces.dtype == torch.int64 and template.faces.shape == (2 * num_v - 4, 3)
    assert template.weights.shape == (num_v, 16) and template.joint_regressor.shape == (16, num_v)
    assert template.shapedirs.shape == (num_v, 3, 10)
    assert len(template.fingertip_ids) == 5
    assert (template.weights >= 0).all() and (template.joint_regressor >= 0).all()
    torch.testing.assert_close(template.weights.sum(1), torch.ones(num_v, dtype=F64))
    torch.testing.assert_close(template.joint_regressor.sum(1), torch.ones(16, dtype=F64))
    # MANO axes: fingers along -x, thumb on +z; an adult hand is 16-22 cm long.
    extent = template.v_template.amax(0) - template.v_template.amin(0)
    assert 0.16 < float(-template.v_template[:, 0].min()) < 0.22 and float(extent[0]) < 0.25
    tips = template.v_template[list(template.fingertip_ids)]
    assert float(tips[0, 2]) > float(tips[1:, 2].max())  # thumb tip on the +z side
    assert float(tips[2, 0]) < float(tips[[1, 3, 4], 0].min())  # middle finger is the longest


def test_mesh_is_watertight_and_outward_for_any_shape(template):
    betas = torch.tensor([[0.0] * 10, [2.0, -2.0, 2.0, -2.0, 2.0, -2.0, 1.0, -1.0, 1.0, -1.0]])
    for vertices in template.rest_vertices(betas.double()):
        mesh = _mesh(vertices, template.faces)
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.euler_number == 2
        assert 1e-4 < mesh.volume < 8e-4  # cubic metres: about 0.3 litre, positive = outward


def test_shape_space_is_pca_with_unit_variance_betas(template):
    basis = template.shapedirs.reshape(-1, template.num_betas)
    gram = basis.T @ basis
    # Orthogonal directions, decreasing variance (the first is the hand's size, a few mm).
    torch.testing.assert_close(gram, torch.diag(torch.diagonal(gram)), atol=1e-12, rtol=0)
    norms = torch.diagonal(gram).sqrt()
    assert (norms[:-1] >= norms[1:]).all()
    assert 0.02 < float(norms[0]) < 0.2 and float(norms[-1]) > 1e-4
    ratios = template.info["explained_variance_ratio"]
    assert 0.97 < sum(ratios) <= 1.0


# ----------------------------------------------------------------------------------------------
# Shaping and posing


def test_rest_vertices_and_joints(template):
    zero = torch.zeros(10, dtype=F64)
    torch.testing.assert_close(template.rest_vertices(zero)[0], template.v_template)
    betas = torch.randn(3, 10, generator=torch.Generator().manual_seed(0), dtype=F64)
    rest = template.rest_vertices(betas)
    expected = template.v_template + (template.shapedirs @ betas.T).permute(2, 0, 1)
    torch.testing.assert_close(rest, expected)
    torch.testing.assert_close(template.rest_joints(betas), template.joint_regressor @ rest)


def test_forward_at_zero_pose_is_the_rest_pose(template):
    betas = torch.randn(2, 10, generator=torch.Generator().manual_seed(1), dtype=F64)
    out = template.forward(torch.zeros(2, 48, dtype=F64), betas)
    torch.testing.assert_close(out.vertices, template.rest_vertices(betas))
    torch.testing.assert_close(out.joints, template.rest_joints(betas))
    eye = torch.eye(4, dtype=F64).expand(2, 16, 4, 4)
    torch.testing.assert_close(out.transforms, eye)
    tips = out.vertices[:, list(template.fingertip_ids)]
    stacked = torch.cat([out.joints, tips], dim=1)
    torch.testing.assert_close(out.keypoints, stacked[:, list(KEYPOINT_SOURCES)])


def _reference_lbs(template: MeshTemplate, pose: np.ndarray, betas: np.ndarray, transl):
    """Independent float64 NumPy forward pass: scipy Rodrigues, explicit chain, explicit sums."""
    shaped = template.v_template.numpy() + template.shapedirs.numpy() @ betas
    rest = template.joint_regressor.numpy() @ shaped
    rotmats = Rotation.from_rotvec(pose.reshape(16, 3)).as_matrix()
    world = []
    for j in range(16):
        local = np.eye(4)
        local[:3, :3] = rotmats[j]
        local[:3, 3] = rest[j] - (rest[PARENTS[j]] if j else 0.0)
        world.append(local if j == 0 else world[PARENTS[j]] @ local)
    vertices = np.zeros_like(shaped)
    for j in range(16):
        moved = (shaped - rest[j]) @ world[j][:3, :3].T + world[j][:3, 3]
        vertices += template.weights.numpy()[:, j : j + 1] * moved
    joints = np.stack([frame[:3, 3] for frame in world])
    return vertices + transl, joints + transl


def test_forward_matches_a_numpy_reference(template):
    rng = np.random.default_rng(2)
    pose = rng.uniform(-0.5, 0.5, (2, 48))
    betas = rng.normal(0.0, 1.0, (2, 10))
    transl = rng.uniform(-0.1, 0.1, (2, 3))
    out = template.forward(*(torch.from_numpy(x) for x in (pose, betas, transl)))
    for b in range(2):
        vertices, joints = _reference_lbs(template, pose[b], betas[b], transl[b])
        np.testing.assert_allclose(out.vertices[b].numpy(), vertices, atol=1e-12)
        np.testing.assert_allclose(out.joints[b].numpy(), joints, atol=1e-12)
    # float32 copy: same result to float32 precision.
    single = template.to("cpu", torch.float32)
    assert single.v_template.dtype == torch.float32 and single.faces.dtype == torch.int64
    out32 = single.forward(*(torch.from_numpy(x).float() for x in (pose, betas, transl)))
    assert out32.vertices.dtype == torch.float32
    np.testing.assert_allclose(out32.vertices.numpy(), out.vertices.numpy(), atol=2e-6)


def test_skinning_weights_at_is_the_nearest_posed_vertex(template):
    pose = torch.from_numpy(named_pose("fist").numpy()).double()[None]
    posed = template.forward(pose, torch.zeros(1, 10, dtype=F64)).vertices[0]
    generator = torch.Generator().manual_seed(3)
    points = posed[torch.randint(len(posed), (300,), generator=generator)]
    points = points + 0.004 * torch.randn(300, 3, generator=generator, dtype=F64)
    weights = template.skinning_weights_at(points, posed)
    nearest = torch.cdist(points, posed).argmin(1)
    torch.testing.assert_close(weights, template.weights[nearest])
    assert weights.shape == (300, 16)


# ----------------------------------------------------------------------------------------------
# Fitting open-hand subjects


def test_fit_betas_puts_the_template_on_the_subjects_surface(template, held_out):
    betas = template.fit_betas(held_out)
    assert betas.shape == (10,) and betas.dtype == F64
    assert float(betas.abs().max()) < 5.0  # a typical subject: a few standard deviations at most
    vertices = template.rest_vertices(betas)[0]
    with torch.no_grad():
        sdf = held_out.posed(dtype=F64).sdf(vertices).abs()
    # Measured 0.12 mm mean, 0.36 mm 95th percentile over held-out subjects.
    assert float(sdf.mean()) < 0.5e-3 and float(sdf.quantile(0.95)) < 1.2e-3
    joint_error = (template.rest_joints(betas)[0] - held_out.rest_joints).norm(dim=1)
    assert float(joint_error.mean()) < 1.0e-3 and float(joint_error.max()) < 2.5e-3  # 0.3 mm
    tips = vertices[list(template.fingertip_ids)]
    assert float((tips - held_out.rest_fingertips).norm(dim=1).max()) < 2.5e-3
    # The mean template (betas = 0) is much further from this subject.
    with torch.no_grad():
        mean_sdf = held_out.posed(dtype=F64).sdf(template.v_template).abs()
    assert float(mean_sdf.mean()) > 3 * float(sdf.mean())


def test_fitted_template_follows_the_posed_hand(template, held_out):
    """LBS of the fitted template with the pseudo-ground-truth weights stays on the open hand's
    posed surface (measured 0.37 mm; in a fist, 1.6 mm: fingers then touch and the open hand's
    smooth union fills the contacts, which LBS cannot)."""
    betas = template.fit_betas(held_out)
    pose = named_pose("relaxed").double()
    out = template.forward(pose[None], betas[None])
    posed = held_out.posed(pose, dtype=F64)
    with torch.no_grad():
        sdf = posed.sdf(out.vertices[0]).abs()
    assert float(sdf.mean()) < 1.0e-3
    torch.testing.assert_close(out.joints[0], posed.joints, atol=2.5e-3, rtol=0)


def test_fit_betas_of_a_left_hand_equals_its_right_twin(template, held_out):
    left = dataclasses.replace(held_out, side="left")
    np.testing.assert_allclose(
        template.fit_betas(left).numpy(), template.fit_betas(held_out).numpy(), atol=1e-6
    )
    assert torch.equal(left.rest_joints, mirror_points(held_out.rest_joints))


# ----------------------------------------------------------------------------------------------
# Building (tiny)


def test_build_template_tiny_is_deterministic_and_valid(tmp_path):
    kwargs = dict(num_subjects=8, target_vertices=150, num_betas=3, seed=5, progress=False)
    built = build_template(**kwargs)
    assert built.num_vertices == 150 and built.num_betas == 3
    mesh = _mesh(built.v_template, built.faces)
    assert mesh.is_watertight and mesh.volume > 0
    # The training subjects' joints are regressed to within a few mm even at this size.
    hand = sample_hand(torch.Generator().manual_seed(5))  # the first training subject
    betas = built.fit_betas(hand)
    error = (built.rest_joints(betas)[0] - hand.rest_joints).norm(dim=1)
    assert float(error.mean()) < 2e-3
    path = save_template(built, tmp_path / "tiny.npz")
    again = load_template(path)
    for name in ("v_template", "weights", "joint_regressor", "shapedirs"):
        torch.testing.assert_close(getattr(again, name), getattr(built, name), rtol=0, atol=0)
    assert torch.equal(again.faces, built.faces) and again.fingertip_ids == built.fingertip_ids
    torch.testing.assert_close(again.fit_betas(hand), betas, rtol=0, atol=0)
    rebuilt = build_template(**kwargs)
    torch.testing.assert_close(rebuilt.shapedirs, built.shapedirs, rtol=0, atol=0)


def test_asset_entry_point_refuses_bad_arguments_in_one_line(tmp_path, capsys):
    from lisa_hand.handmodel.build_template_asset import main

    out = tmp_path / "template.npz"
    assert main(["--out", str(out), "--subjects", "3", "--betas", "10", "--held-out", "0"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("error: num_subjects must be an int >= 12") and error.count("\n") == 1
    assert not out.exists()


# ----------------------------------------------------------------------------------------------
# MANO as the template


@pytest.fixture(scope="module")
def mano_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("mano") / "MANO_RIGHT.pkl"
    write_synthetic_mano(path, "right", seed=0)
    return path


def test_template_from_mano_matches_the_mano_layer(mano_file):
    template = template_from_mano(mano_file, num_betas=10)
    assert template.name == "mano" and template.num_vertices == 778
    assert template.fingertip_ids == (744, 320, 443, 554, 671) and template.source is None
    layer = ManoLayer(mano_file, flat_hand_mean=True, dtype=F64)
    betas = torch.randn(2, 10, generator=torch.Generator().manual_seed(4), dtype=F64)
    zero = torch.zeros(2, 48, dtype=F64)
    out, expected = template.forward(zero, betas), layer(betas=betas)
    for name in ("vertices", "joints", "keypoints"):
        torch.testing.assert_close(getattr(out, name), getattr(expected, name))
    # Posed: equal to MANO without its pose blend shapes.
    data = load_mano_pkl(mano_file)
    plain = ManoLayer(dataclasses.replace(data, pose_dirs=np.zeros_like(data.pose_dirs)),
                      flat_hand_mean=True, dtype=F64)  # fmt: skip
    pose = 0.4 * torch.randn(2, 48, generator=torch.Generator().manual_seed(5), dtype=F64)
    posed = template.forward(pose, betas)
    reference = plain(hand_pose=pose[:, 3:], global_orient=pose[:, :3], betas=betas)
    torch.testing.assert_close(posed.vertices, reference.vertices)
    torch.testing.assert_close(posed.keypoints, reference.keypoints)
    # From the layer (which keeps no regressor): the same joints for every betas.
    from_layer = template_from_mano(layer, num_betas=10)
    torch.testing.assert_close(from_layer.rest_joints(betas), template.rest_joints(betas))
    assert template_from_mano(mano_file, num_betas=4).num_betas == 4
    with pytest.raises(ValueError, match="num_betas"):
        template_from_mano(mano_file, num_betas=11)
    with pytest.raises(ValueError, match="refusing"):
        save_template(template, mano_file.parent / "mano.npz")
    with pytest.raises(ValueError, match="correspondence"):
        template.fit_betas(sample_hand(torch.Generator().manual_seed(0)))


def test_template_from_mano_refuses_a_left_hand(tmp_path):
    path = tmp_path / "MANO_LEFT.pkl"
    write_synthetic_mano(path, "left", seed=0)
    with pytest.raises(ValueError, match="right"):
        template_from_mano(path)


# ----------------------------------------------------------------------------------------------
# Errors


def test_bad_inputs_raise_clear_errors(template):
    with pytest.raises(ValueError, match=r"betas must have shape \[B, 10\]"):
        template.rest_vertices(torch.zeros(1, 9, dtype=F64))
    with pytest.raises(ValueError, match="betas has batch size"):
        template.forward(torch.zeros(2, 48, dtype=F64), torch.zeros(1, 10, dtype=F64))
    with pytest.raises(ValueError, match="pose"):
        template.forward(torch.zeros(1, 45, dtype=F64), torch.zeros(1, 10, dtype=F64))
    with pytest.raises(TypeError, match="betas"):
        template.rest_vertices(np.zeros(10))
    with pytest.raises(ValueError, match="NaN"):
        template.rest_vertices(torch.full((10,), float("nan"), dtype=F64))
    with pytest.raises(ValueError, match="posed_vertices"):
        template.skinning_weights_at(torch.zeros(4, 3), torch.zeros(5, 3))
    with pytest.raises(TypeError, match="OpenHand"):
        template.fit_betas("hand")


def test_bad_files_raise_errors_naming_the_path(tmp_path, template):
    missing = tmp_path / "missing.npz"
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_template(missing)
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 not really a zip file")
    with pytest.raises(ValueError, match="corrupt.npz"):
        load_template(corrupt)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, v_template=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="wrong.npz.*missing"):
        load_template(wrong)
    # Right keys, inconsistent shapes.
    good = save_template(template, tmp_path / "good.npz")
    with np.load(good) as data:
        arrays = dict(data)
    arrays["weights"] = arrays["weights"][:-1]
    bad = tmp_path / "bad_shapes.npz"
    np.savez(bad, **arrays)
    with pytest.raises(ValueError, match="bad_shapes.npz.*weights"):
        load_template(bad)
    with pytest.raises(ValueError, match=r"\.npz"):
        save_template(template, tmp_path / "template.txt")
