"""Inference with a trained model (lisa_hand.inference): bounds, meshes, renders, poses, blends.

The model is a tiny LisaModel at its geometric initialisation (a blob of a hand on the average
skeleton): untrained, but a closed surface with colours and skinning weights, which is all the
inference code needs.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from lisa_hand import inference
from lisa_hand.bench.field import BENCH_REST_JOINTS
from lisa_hand.fields import FieldConfig
from lisa_hand.handmodel.poses import named_pose
from lisa_hand.metrics import mesh_distances
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel
from lisa_hand.render.image import ImageRenderConfig
from lisa_hand.skeleton import forward_kinematics, mirror_points, mirror_pose
from lisa_hand.skeleton.params import HandParams

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8,
                  palm_region_radius=0.07, finger_region_radius=0.035)
REST = torch.tensor(BENCH_REST_JOINTS)


def tiny_model(gain=(1.0, 1.0, 1.0), bias=(0.0, 0.0, 0.0), seed: int = 0) -> TrainedModel:
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    field = LisaModel(FieldConfig(**TINY_FIELD), init_rest_joints=REST).eval()
    return TrainedModel(
        field=field, shape_codes=0.1 * torch.randn(2, 8, generator=generator),
        color_codes=torch.randn(2, 8, generator=generator), subject_ids=["s0", "s1"],
        beta=0.002, gain=torch.tensor(gain), bias=torch.tensor(bias), source="tiny",
    )  # fmt: skip


def hand_params(model: TrainedModel, row: int = 0, side: str = "right") -> HandParams:
    pose = torch.zeros(48)
    pose[:3] = torch.tensor([0.3, -0.2, 0.1])
    pose[3:] = 0.08
    translation = torch.tensor([0.02, -0.01, 0.4])
    rest = REST
    if side == "left":
        pose, translation, rest = mirror_pose(pose), mirror_points(translation), mirror_points(REST)
    return HandParams(pose=pose, translation=translation, rest_joints=rest,
                      shape_code=model.shape_codes[row], color_code=model.color_codes[row],
                      side=side)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the CPU is shared
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def model() -> TrainedModel:
    return tiny_model(gain=(1.1, 0.9, 1.0), bias=(0.05, -0.02, 0.0))


# The geometric-init blob reaches 7 cm past the skeleton (a trained hand some 2 cm).
PADDING = 0.08


@pytest.fixture(scope="module")
def right_mesh(model):
    return inference.mesh_hand_with_stats(model, hand_params(model), 40,
                                          inference.MeshConfig(padding=PADDING))


def test_bounds_hold_the_surface(model, right_mesh):
    params = hand_params(model)
    center, radius = inference.hand_bounds(params, model.config)
    vertices = right_mesh.mesh.vertices
    assert np.linalg.norm(vertices - center.numpy(), axis=1).max() < radius
    assert not right_mesh.grown
    low, high = inference.skeleton_box(params, model.config, padding=PADDING)
    assert (vertices > low).all() and (vertices < high).all()
    # The skeleton box holds every posed joint, PADDING inside its sides.
    joints = forward_kinematics(params.pose[None], REST[None], params.translation[None]).joints[0]
    assert (joints.numpy() >= low + PADDING - 1e-6).all()
    assert (joints.numpy() <= high - PADDING + 1e-6).all()
    # Without padding the surface reaches the box: the grid grows instead of cutting it (dense
    # evaluation: the untrained field jumps at region edges, beyond any Lipschitz bound).
    grown = inference.mesh_hand_with_stats(
        model, params, 24, inference.MeshConfig(padding=0.0, coarse_to_fine=False, colors=False,
                                                skin_weights=False))
    assert grown.grown
    assert trimesh.Trimesh(grown.mesh.vertices, grown.mesh.faces, process=True).is_watertight
    assert np.linalg.norm(grown.mesh.vertices - center.numpy(), axis=1).max() < radius


def test_mesh_is_dense_evaluation_with_calibrated_colours_and_weights(model, right_mesh):
    params = hand_params(model)
    dense = inference.mesh_hand_with_stats(
        model, params, 40, inference.MeshConfig(padding=PADDING, coarse_to_fine=False,
                                                colors=False, skin_weights=False))
    fast = right_mesh
    assert fast.extraction.num_evaluations < 0.5 * dense.extraction.num_evaluations
    distances = mesh_distances(fast.mesh.vertices, fast.mesh.faces, dense.mesh.vertices,
                               dense.mesh.faces)
    assert distances.v2s_recon_to_scan_mm < 0.05 and distances.v2s_scan_to_recon_mm < 0.05
    # Independent evaluation of the field at the vertices: colours are gain * rgb + bias.
    mesh = fast.mesh
    state = model.field.prepare(**params.batch())
    with torch.no_grad():
        out = model.field.field(state, torch.from_numpy(mesh.vertices)[None])
    expected = (out.rgb[0] * torch.tensor([1.1, 0.9, 1.0]) + torch.tensor([0.05, -0.02, 0.0]))
    expected = np.rint(expected.clamp(0, 1).numpy() * 255)
    assert np.abs(mesh.colors.astype(float) - expected).max() <= 1
    assert mesh.skin_weights.shape == (mesh.num_vertices, 16)
    np.testing.assert_allclose(mesh.skin_weights, out.weights[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(mesh.skin_weights.sum(1), 1.0, atol=1e-5)
    # On the surface: the SDF at the vertices is ~0 (linear interpolation error; a few vertices
    # sit where the untrained blob meets the edge of a bone region, a jump of the field).
    assert np.quantile(out.sdf.abs().numpy(), 0.9) < 0.1 * fast.voxel_size


def test_left_hand_is_the_mirror_image(model, right_mesh):
    left = inference.mesh_hand(model, hand_params(model, side="left"), 40,
                               inference.MeshConfig(padding=PADDING, colors=False,
                                                    skin_weights=False))
    mirrored = right_mesh.mesh.vertices * np.array([-1.0, 1.0, 1.0], dtype=np.float32)
    assert left.num_vertices == right_mesh.mesh.num_vertices
    assert cKDTree(mirrored).query(left.vertices)[0].max() < 1e-6
    # Outward normals on both: the signed volume is positive.
    for mesh in (left, right_mesh.mesh):
        v = mesh.vertices.astype(np.float64)[mesh.faces]
        volume = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
        assert volume > 1e-5  # m^3: a blob of a hand holds some 100 cm^3


def test_render_calibration_and_framing(model):
    params = hand_params(model)
    plain = tiny_model()
    config = ImageRenderConfig(beta=0.002, lipschitz=1.5, normals="autograd")
    scene = inference.prepare_render(model, params, config)
    cameras = inference.orbit_views(scene, 2, 40, 32)
    assert [c.name for c in cameras] == ["orbit000", "orbit001"]
    calibrated = scene.render(cameras[0])
    raw = inference.render_hand(plain, params, cameras[:1], config)[0]
    mask = calibrated.mask
    border = torch.cat([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    assert mask[10:22, 16:22].all() and not border.any()  # the palm, in the middle
    rows = torch.nonzero(mask.any(dim=1))[:, 0]
    assert 0.5 < (rows.max() - rows.min() + 1) / 32 < 0.95  # framed: fingers up, margins left
    assert torch.equal(calibrated.rgb[0, 0], torch.zeros(3))  # black background
    # Calibration is affine per sample: rgb = gain * raw + bias * opacity (black background);
    # up to faint pixels whose samples all fall under the renderer's colour weight threshold
    # and get no colour at all: there the bias term is missing, |bias| * opacity <= 0.05 * 0.06
    # (32 samples a ray, each under 1e-2).
    gain, bias = torch.tensor([1.1, 0.9, 1.0]), torch.tensor([0.05, -0.02, 0.0])
    expected = raw.rgb * gain + bias * raw.opacity[..., None]
    faint = (calibrated.rgb - expected).abs().amax(dim=-1) > 1e-5
    assert not faint.any() or float(raw.opacity[faint].max()) < 0.06
    torch.testing.assert_close(calibrated.rgb, expected, atol=3e-3, rtol=0)
    torch.testing.assert_close(calibrated.rgb[mask], expected[mask], atol=1e-5, rtol=0)
    normals = calibrated.normals[mask]
    torch.testing.assert_close(normals.norm(dim=-1), torch.ones(normals.shape[0]))
    # The first camera faces the palm: the palm normal points at the camera.
    _, palm = scene.hand_axes()
    to_camera = cameras[0].center.double() - scene.framing_sphere()[0]
    assert float(palm @ to_camera) > 0.8 * float(to_camera.norm())


def test_blend_swaps_and_interpolates(model):
    a, b = hand_params(model, 0), hand_params(model, 1)
    b = b.with_pose(torch.zeros(48), torch.zeros(3))
    b.rest_joints = REST * 1.1
    same = inference.blend_params(a, b, shape=0.0, color=0.0)
    assert torch.equal(same.shape_code, a.shape_code) and torch.equal(same.color_code, a.color_code)
    assert torch.equal(same.rest_joints, a.rest_joints)
    swapped = inference.blend_params(a, b, shape=0.0, color=1.0)
    assert torch.equal(swapped.color_code, b.color_code)
    assert torch.equal(swapped.shape_code, a.shape_code) and torch.equal(swapped.pose, a.pose)
    half = inference.blend_params(a, b, shape=0.5, color=0.25)
    torch.testing.assert_close(half.shape_code, 0.5 * (a.shape_code + b.shape_code))
    torch.testing.assert_close(half.rest_joints, REST * 1.05)
    torch.testing.assert_close(half.color_code, 0.75 * a.color_code + 0.25 * b.color_code)
    assert half.extra["blend"] == {"shape": 0.5, "color": 0.25}
    # A left B lends its skeleton mirrored to a right A.
    left_b = hand_params(model, 1, side="left")
    torch.testing.assert_close(inference.blend_params(a, left_b, shape=1.0).rest_joints, REST)
    with pytest.raises(ValueError, match="shape must be in"):
        inference.blend_params(a, b, shape=1.5)
    other = hand_params(model, 1)
    other.model = "other.pt"
    with pytest.raises(ValueError, match="different models"):
        inference.blend_params(a, other, color=1.0)
    no_color = hand_params(model, 1)
    no_color.color_code = None
    with pytest.raises(ValueError, match="hand B has none"):
        inference.blend_params(a, no_color, color=0.5)


def test_pose_sequences(tmp_path, model):
    params = hand_params(model)
    fingers = torch.full((3, 45), 0.2)
    path = tmp_path / "seq.json"
    path.write_text(__import__("json").dumps(fingers.tolist()))
    poses, translations = inference.resolve_poses(params, inference.read_pose_sequence(path))
    assert poses.shape == (3, 48) and torch.equal(poses[:, :3], params.pose[:3].expand(3, 3))
    assert torch.equal(poses[:, 3:], fingers) and torch.equal(translations[1], params.translation)
    path.write_text(__import__("json").dumps(
        {"poses": torch.zeros(2, 48).tolist(), "translations": [[0, 0, 1], [0, 0, 2]]}))
    poses, translations = inference.resolve_poses(params, inference.read_pose_sequence(path))
    assert torch.equal(poses, torch.zeros(2, 48)) and translations[1, 2] == 2.0
    for bad, message in ((["x"], "poses must be"), ([[0.0] * 47], r"\[T, 48\] or \[T, 45\]"),
                         ({"poses": [[0.0] * 48], "translations": [[0.0]]}, "translations"),
                         ({"pose": []}, "keys")):
        path.write_text(__import__("json").dumps(bad))
        with pytest.raises(ValueError, match=message) as info:
            inference.read_pose_sequence(path)
        assert str(path) in str(info.value)

    motion = inference.motion_poses(params, "fist", frames_per_segment=3)
    assert motion.shape == (7, 48)
    torch.testing.assert_close(motion[0], params.pose)
    torch.testing.assert_close(motion[-1], params.pose, atol=1e-5, rtol=0)
    torch.testing.assert_close(motion[3, 3:], named_pose("fist")[3:], atol=1e-5, rtol=0)
    torch.testing.assert_close(motion[:, :3], params.pose[:3].expand(7, 3), atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="unknown pose name"):
        inference.motion_poses(params, "wave")


def test_repose_mesh_by_skinning(model, right_mesh):
    params = hand_params(model)
    mesh = right_mesh.mesh
    same = inference.repose_mesh(mesh, params, params.pose)
    np.testing.assert_allclose(same.vertices, mesh.vertices, atol=1e-6)
    new_pose = params.pose.clone()
    new_pose[3:] = 0.4
    moved = inference.repose_mesh(mesh, params, new_pose, torch.tensor([0.0, 0.0, 0.5]))
    assert moved.num_vertices == mesh.num_vertices and np.array_equal(moved.faces, mesh.faces)
    back = inference.repose_mesh(moved, params.with_pose(new_pose, torch.tensor([0.0, 0.0, 0.5])),
                                 params.pose, params.translation)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-5)
    # A vertex owned by one bone moves rigidly with it: A_j(new) A_j(old)^-1 v.
    owned = np.flatnonzero(mesh.skin_weights.max(axis=1) > 1 - 1e-6)
    assert owned.size > 10
    bone = mesh.skin_weights[owned].argmax(axis=1)
    old = forward_kinematics(params.pose[None].double(), REST[None].double(),
                             params.translation[None].double()).transforms[0]
    new = forward_kinematics(new_pose[None].double(), REST[None].double(),
                             torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64)).transforms[0]
    relative = (new @ torch.linalg.inv(old))[torch.from_numpy(bone)]
    v = torch.from_numpy(mesh.vertices[owned]).double()
    expected = (relative[:, :3, :3] @ v[..., None])[..., 0] + relative[:, :3, 3]
    np.testing.assert_allclose(moved.vertices[owned], expected.numpy(), atol=2e-6)


def test_bad_inputs(model):
    params = hand_params(model)
    wrong = hand_params(model)
    wrong.shape_code = torch.zeros(5)
    with pytest.raises(ValueError, match="shape_code has 5 entries"):
        inference.hand_state(model, wrong)
    with pytest.raises(ValueError, match="resolution must be >= 8"):
        inference.mesh_hand(model, params, 4)
    with pytest.raises(ValueError, match="resolution must look like"):
        inference.parse_image_size("512by512")
    assert inference.parse_image_size("64x48") == (64, 48)
    assert inference.file_stem(["cam 1", None, "cam 1", "../x"]) == [
        "cam_1", "view001", "cam_1_002", "x"]


def test_geometry_only_model_is_grey():
    torch.manual_seed(1)
    field = LisaModel(FieldConfig(use_color=False, **TINY_FIELD), init_rest_joints=REST).eval()
    prior = TrainedModel(field=field, shape_codes=torch.zeros(1, 8), color_codes=None,
                         subject_ids=["s0"], beta=0.002, gain=torch.ones(3), bias=torch.zeros(3),
                         source="prior")
    params = HandParams(pose=torch.zeros(48), translation=torch.zeros(3), rest_joints=REST,
                        shape_code=torch.zeros(8))
    mesh = inference.mesh_hand(prior, params, 24, inference.MeshConfig(padding=PADDING))
    grey = round(inference.GEOMETRY_ONLY_GREY * 255)
    assert np.abs(mesh.colors.astype(int) - grey).max() <= 1
    assert mesh.skin_weights.shape == (mesh.num_vertices, 16)
    scene = inference.prepare_render(prior, params)
    output = scene.render(inference.orbit_views(scene, 1, 24, 24)[0])
    expected = inference.GEOMETRY_ONLY_GREY * output.opacity[..., None].expand(-1, -1, 3)
    torch.testing.assert_close(output.rgb[output.mask], expected[output.mask], atol=1e-5, rtol=0)
