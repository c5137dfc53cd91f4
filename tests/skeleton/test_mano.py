"""MANO .pkl loading (without chumpy) and the MANO layer against an independent NumPy reference."""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lisa_hand.skeleton import (
    JOINT_NAMES,
    KEYPOINT_NAMES,
    PARENTS,
    ManoLayer,
    ManoOutput,
    load_mano_pkl,
    mirror_points,
    mirror_pose,
)
from tests.skeleton.synthetic_mano import (
    FakeCh,
    official_layout,
    synthetic_mano_arrays,
    write_pickle_py2,
    write_synthetic_mano,
)

F64 = torch.float64
# smplx's MANO fingertip vertices, written out here independently of the package constant.
TIP_VERTEX = {"thumb": 744, "index": 320, "middle": 443, "ring": 554, "pinky": 671}


@pytest.fixture(scope="module")
def mano_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("mano")
    arrays = {
        "right": write_synthetic_mano(root / "MANO_RIGHT.pkl", "right", seed=0),
        "left": write_synthetic_mano(root / "MANO_LEFT.pkl", "left", seed=0),  # with the quirk
    }
    return root, arrays


# --------------------------------------------------------------------------------------------------
# Independent float64 NumPy reference: scipy Rodrigues, explicit FK loop, explicit LBS sums.


def _keypoint_source(name: str) -> tuple[str, object]:
    if name == "wrist":
        return "joint", 0
    finger, level = name.split("_")
    if level == "tip":
        return "vertex", TIP_VERTEX[finger]
    levels = ("cmc", "mcp", "ip") if finger == "thumb" else ("mcp", "pip", "dip")
    return "joint", JOINT_NAMES.index(f"{finger}{levels.index(level) + 1}")


def reference_mano(arrays, hand_pose, global_orient, betas, transl, *, num_pca=None, flat=True):
    """(vertices [B, 778, 3], joints [B, 16, 3], keypoints [B, 21, 3], full_pose [B, 48])."""
    batch = hand_pose.shape[0]
    if num_pca is not None:
        hand_pose = hand_pose @ arrays["hands_components"][:num_pca]
    if not flat:
        hand_pose = hand_pose + arrays["hands_mean"]
    full_pose = np.concatenate([global_orient, hand_pose], axis=1)
    out_v, out_j, out_k = [], [], []
    for b in range(batch):
        shaped = arrays["v_template"].copy()
        for s in range(betas.shape[1]):
            shaped += betas[b, s] * arrays["shapedirs"][:, :, s]
        rest = arrays["J_regressor"] @ shaped
        rotmats = Rotation.from_rotvec(full_pose[b].reshape(16, 3)).as_matrix()
        feature = np.concatenate([(rotmats[j] - np.eye(3)).ravel() for j in range(1, 16)])
        posed_rest = shaped + np.einsum("vcp,p->vc", arrays["posedirs"], feature)
        world = []
        for j in range(16):
            local = np.eye(4)
            local[:3, :3] = rotmats[j]
            local[:3, 3] = rest[j] - (rest[PARENTS[j]] if j else 0.0)
            world.append(local if j == 0 else world[PARENTS[j]] @ local)
        skinning = []
        for j in range(16):
            bone = world[j].copy()
            bone[:3, 3] -= world[j][:3, :3] @ rest[j]
            skinning.append(bone)
        vertices = np.zeros_like(shaped)
        for j in range(16):
            moved = posed_rest @ skinning[j][:3, :3].T + skinning[j][:3, 3]
            vertices += arrays["weights"][:, j : j + 1] * moved
        vertices += transl[b]
        joints = np.stack([frame[:3, 3] for frame in world]) + transl[b]
        keypoints = []
        for name in KEYPOINT_NAMES:
            kind, index = _keypoint_source(name)
            keypoints.append(joints[index] if kind == "joint" else vertices[index])
        out_v.append(vertices), out_j.append(joints), out_k.append(np.stack(keypoints))
    return np.stack(out_v), np.stack(out_j), np.stack(out_k), full_pose


def _random_inputs(batch: int, pose_width: int, seed: int):
    rng = np.random.default_rng(seed)
    return (
        rng.uniform(-0.6, 0.6, (batch, pose_width)),
        rng.uniform(-1.0, 1.0, (batch, 3)),
        rng.normal(0.0, 1.5, (batch, 10)),
        rng.uniform(-0.2, 0.2, (batch, 3)),
    )


def _run(layer: ManoLayer, inputs, dtype=F64) -> ManoOutput:
    hand_pose, global_orient, betas, transl = (torch.as_tensor(x, dtype=dtype) for x in inputs)
    return layer(hand_pose=hand_pose, global_orient=global_orient, betas=betas, transl=transl)


# --------------------------------------------------------------------------------------------------
# Loader


def test_loader_reads_the_official_layout_without_chumpy(mano_dir):
    root, arrays = mano_dir
    raw = (root / "MANO_RIGHT.pkl").read_bytes()
    # The file really holds chumpy and scipy.sparse objects, as the official one does.
    assert b"chumpy.ch\nCh\n" in raw and b"scipy.sparse.csc\ncsc_matrix\n" in raw
    assert raw[:2] == b"\x80\x02"
    data = load_mano_pkl(root / "MANO_RIGHT.pkl")
    assert "chumpy" not in sys.modules and "chumpy.ch" not in sys.modules
    assert data.side == "right" and data.num_betas == 10
    expected = arrays["right"]
    np.testing.assert_array_equal(data.shape_dirs, expected["shapedirs"])
    np.testing.assert_array_equal(data.joint_regressor, expected["J_regressor"])
    np.testing.assert_array_equal(data.template_vertices, expected["v_template"])
    np.testing.assert_array_equal(data.pose_dirs, expected["posedirs"])
    np.testing.assert_array_equal(data.skinning_weights, expected["weights"])
    np.testing.assert_array_equal(data.hands_components, expected["hands_components"])
    np.testing.assert_array_equal(data.hands_mean, expected["hands_mean"])
    np.testing.assert_array_equal(data.faces, expected["f"].astype(np.int64))
    assert data.faces.dtype == np.int64 and data.shape_dirs.dtype == np.float64


@pytest.mark.parametrize("protocol", [2, 5])
def test_loader_reads_plain_python3_pickles(tmp_path, protocol):
    # Files re-saved by Python 3 without chumpy: dense arrays, NumPy 2 module names, and for
    # protocol 2 bytes written through _codecs.encode.
    arrays = synthetic_mano_arrays(seed=3)
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(pickle.dumps(arrays, protocol=protocol))
    data = load_mano_pkl(path)
    np.testing.assert_array_equal(data.joint_regressor, arrays["J_regressor"])
    np.testing.assert_array_equal(data.pose_dirs, arrays["posedirs"])


def test_side_from_name_or_argument(mano_dir, tmp_path):
    root, _ = mano_dir
    assert load_mano_pkl(root / "MANO_LEFT.pkl").side == "left"
    assert load_mano_pkl(root / "MANO_LEFT.pkl", side="left").side == "left"
    renamed = tmp_path / "hand_model.pkl"
    renamed.write_bytes((root / "MANO_LEFT.pkl").read_bytes())
    assert load_mano_pkl(renamed, side="left").side == "left"
    with pytest.raises(ValueError, match=r"hand_model\.pkl: cannot tell the hand side.*side="):
        load_mano_pkl(renamed)
    with pytest.raises(ValueError, match=r"MANO_LEFT\.pkl: side='right' contradicts the file name"):
        load_mano_pkl(root / "MANO_LEFT.pkl", side="right")
    with pytest.raises(ValueError, match="unknown hand side 'middle'"):
        load_mano_pkl(renamed, side="middle")


def test_fix_left_shapedirs_negates_x_of_every_direction(mano_dir):
    root, arrays = mano_dir
    fixed = load_mano_pkl(root / "MANO_LEFT.pkl", fix_left_shapedirs=True)
    original = arrays["left"]["shapedirs"]
    np.testing.assert_array_equal(fixed.shape_dirs[:, 0], -original[:, 0])
    np.testing.assert_array_equal(fixed.shape_dirs[:, 1:], original[:, 1:])
    right = load_mano_pkl(root / "MANO_RIGHT.pkl", fix_left_shapedirs=True)
    np.testing.assert_array_equal(right.shape_dirs, arrays["right"]["shapedirs"])


# --------------------------------------------------------------------------------------------------
# Layer against the reference


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("num_pca", [None, 12])
@pytest.mark.parametrize("flat", [True, False])
def test_layer_matches_numpy_reference_float64(mano_dir, side, num_pca, flat):
    root, arrays = mano_dir
    layer = ManoLayer(
        root / f"MANO_{side.upper()}.pkl",
        use_pca=num_pca is not None,
        num_pca_comps=num_pca or 6,
        flat_hand_mean=flat,
        dtype=F64,
    )
    inputs = _random_inputs(3, num_pca or 45, seed=len(side) + (num_pca or 0) + flat)
    out = _run(layer, inputs)
    vertices, joints, keypoints, full_pose = reference_mano(
        arrays[side], *inputs, num_pca=num_pca, flat=flat
    )
    assert out.vertices.shape == (3, 778, 3) and out.vertices.dtype == F64
    np.testing.assert_allclose(out.full_pose.numpy(), full_pose, atol=1e-14)
    np.testing.assert_allclose(out.vertices.numpy(), vertices, atol=1e-12)
    np.testing.assert_allclose(out.joints.numpy(), joints, atol=1e-12)
    np.testing.assert_allclose(out.keypoints.numpy(), keypoints, atol=1e-12)
    assert out.transforms.shape == (3, 16, 4, 4) and out.bone_frames.shape == (3, 16, 4, 4)
    expected_rest = np.einsum(
        "jv,bvc->bjc", arrays[side]["J_regressor"], _shaped(arrays[side], inputs)
    )
    np.testing.assert_allclose(out.rest_joints.numpy(), expected_rest, atol=1e-12)


def _shaped(arrays, inputs):
    return arrays["v_template"] + np.einsum("bs,vcs->bvc", inputs[2], arrays["shapedirs"])


def test_layer_float32_matches_reference(mano_dir):
    root, arrays = mano_dir
    layer = ManoLayer(root / "MANO_RIGHT.pkl", flat_hand_mean=False)
    inputs = _random_inputs(2, 45, seed=11)
    out = _run(layer, inputs, dtype=torch.float32)
    vertices, joints, keypoints, _ = reference_mano(arrays["right"], *inputs, flat=False)
    assert out.vertices.dtype == torch.float32 and layer.template_vertices.dtype == torch.float32
    np.testing.assert_allclose(out.vertices.double().numpy(), vertices, atol=2e-6)
    np.testing.assert_allclose(out.keypoints.double().numpy(), keypoints, atol=2e-6)


def test_layer_follows_dtype_conversion(mano_dir):
    root, _ = mano_dir
    inputs = _random_inputs(1, 45, seed=17)
    converted = ManoLayer(root / "MANO_RIGHT.pkl").to(F64)
    assert converted.dtype == F64 and converted.faces.dtype == torch.long
    built = ManoLayer(root / "MANO_RIGHT.pkl", dtype=F64)
    torch.testing.assert_close(_run(converted, inputs).vertices, _run(built, inputs).vertices)


def test_defaults_flat_and_mean_hand(mano_dir):
    root, arrays = mano_dir
    flat = ManoLayer(root / "MANO_RIGHT.pkl", flat_hand_mean=True, dtype=F64)()
    right = arrays["right"]
    assert flat.vertices.shape == (1, 778, 3)
    np.testing.assert_allclose(flat.vertices[0].numpy(), right["v_template"], atol=1e-15)
    np.testing.assert_allclose(
        flat.joints[0].numpy(), right["J_regressor"] @ right["v_template"], atol=1e-15
    )
    mean = ManoLayer(root / "MANO_RIGHT.pkl", use_pca=True, dtype=F64)(
        betas=torch.zeros(2, 10, dtype=F64)
    )
    assert mean.full_pose.shape == (2, 48)
    np.testing.assert_array_equal(
        mean.full_pose[:, 3:].numpy(), np.tile(right["hands_mean"], (2, 1))
    )
    np.testing.assert_array_equal(mean.full_pose[:, :3].numpy(), np.zeros((2, 3)))


def test_left_mirrors_right_only_with_the_shapedirs_fix(mano_dir):
    root, _ = mano_dir
    inputs = _random_inputs(2, 45, seed=12)
    right = ManoLayer(root / "MANO_RIGHT.pkl", dtype=F64)
    hand_pose, global_orient, betas, transl = (torch.as_tensor(x) for x in inputs)
    expected = right(hand_pose, global_orient, betas, transl)
    mirrored_inputs = (
        mirror_pose(hand_pose),
        mirror_pose(global_orient),
        betas,
        mirror_points(transl),
    )
    fixed = ManoLayer(root / "MANO_LEFT.pkl", fix_left_shapedirs=True, dtype=F64)(*mirrored_inputs)
    torch.testing.assert_close(fixed.vertices, mirror_points(expected.vertices), atol=1e-12, rtol=0)
    torch.testing.assert_close(
        fixed.keypoints, mirror_points(expected.keypoints), atol=1e-12, rtol=0
    )
    as_file = ManoLayer(root / "MANO_LEFT.pkl", dtype=F64)
    # The file's quirk: with betas the left hand is no mirror image ...
    quirky = as_file(*mirrored_inputs)
    assert (quirky.vertices - mirror_points(expected.vertices)).abs().max() > 1e-3
    # ... but at the mean shape it is.
    no_shape = (*mirrored_inputs[:2], torch.zeros_like(betas), mirrored_inputs[3])
    torch.testing.assert_close(
        as_file(*no_shape).vertices,
        mirror_points(right(hand_pose, global_orient, None, transl).vertices),
        atol=1e-12,
        rtol=0,
    )


def test_layer_gradcheck(mano_dir):
    root, _ = mano_dir
    layer = ManoLayer(root / "MANO_RIGHT.pkl", use_pca=True, num_pca_comps=9, dtype=F64)
    rng = np.random.default_rng(13)
    probe = torch.as_tensor(rng.standard_normal((1, 778, 3)))
    inputs = tuple(
        torch.tensor(x, requires_grad=True) for x in _random_inputs(1, 9, seed=13)
    )  # PCA coefficients, orientation, betas, translation

    def weighted_vertices(hand_pose, global_orient, betas, transl):
        out = layer(hand_pose, global_orient, betas, transl)
        return (out.vertices * probe).sum(), out.keypoints.sum()

    assert torch.autograd.gradcheck(weighted_vertices, inputs, eps=1e-6, atol=1e-6)


def test_buffers_stay_out_of_state_dict(mano_dir):
    root, _ = mano_dir
    layer = ManoLayer(root / "MANO_RIGHT.pkl", use_pca=True)
    assert layer.state_dict() == {}
    assert layer.faces.dtype == torch.long and layer.faces.shape == (1538, 3)
    assert layer.hand_components.shape == (6, 45)
    assert "use_pca=True, num_pca_comps=6" in repr(layer)


def test_layer_from_loaded_data(mano_dir):
    root, _ = mano_dir
    data = load_mano_pkl(root / "MANO_RIGHT.pkl")
    inputs = _random_inputs(1, 45, seed=14)
    from_data = _run(ManoLayer(data, dtype=F64), inputs)
    from_path = _run(ManoLayer(root / "MANO_RIGHT.pkl", dtype=F64), inputs)
    torch.testing.assert_close(from_data.vertices, from_path.vertices, atol=0, rtol=0)
    with pytest.raises(ValueError, match="side='left' but the ManoData is a right hand"):
        ManoLayer(data, side="left")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_layer_on_cuda_matches_cpu(mano_dir):
    root, _ = mano_dir
    layer = ManoLayer(root / "MANO_LEFT.pkl", use_pca=True, num_pca_comps=10, dtype=F64)
    inputs = _random_inputs(4, 10, seed=15)
    cpu = _run(layer, inputs)
    gpu_inputs = tuple(torch.as_tensor(x, device="cuda") for x in inputs)
    gpu = layer.to("cuda")(*gpu_inputs)
    assert gpu.vertices.is_cuda and gpu.keypoints.is_cuda
    torch.testing.assert_close(gpu.vertices.cpu(), cpu.vertices, atol=1e-10, rtol=0)
    torch.testing.assert_close(gpu.keypoints.cpu(), cpu.keypoints, atol=1e-10, rtol=0)


# --------------------------------------------------------------------------------------------------
# Bad input


def test_layer_rejects_bad_inputs(mano_dir):
    root, _ = mano_dir
    layer = ManoLayer(root / "MANO_RIGHT.pkl")
    with pytest.raises(ValueError, match=r"hand_pose must have shape \[B, 45\], got \(2, 44\)"):
        layer(hand_pose=torch.zeros(2, 44))
    nan_pose = torch.zeros(1, 45)
    nan_pose[0, 7] = float("nan")
    with pytest.raises(ValueError, match="hand_pose contains NaN or inf"):
        layer(hand_pose=nan_pose)
    with pytest.raises(ValueError, match=r"betas must have shape \[B, 10\], got \(1, 5\)"):
        layer(betas=torch.zeros(1, 5))
    with pytest.raises(ValueError, match=r"global_orient must have shape \[B, 3\], got \(3,\)"):
        layer(global_orient=torch.zeros(3))
    with pytest.raises(ValueError, match="transl has batch size 3, other inputs 2"):
        layer(hand_pose=torch.zeros(2, 45), transl=torch.zeros(3, 3))
    with pytest.raises(TypeError, match="betas has dtype torch.float64 but the layer computes in"):
        layer(betas=torch.zeros(1, 10, dtype=F64))
    with pytest.raises(TypeError, match="hand_pose must be a torch.Tensor, got ndarray"):
        layer(hand_pose=np.zeros((1, 45)))
    pca = ManoLayer(root / "MANO_RIGHT.pkl", use_pca=True, num_pca_comps=6)
    with pytest.raises(ValueError, match=r"hand_pose must have shape \[B, 6\], got \(1, 45\)"):
        pca(hand_pose=torch.zeros(1, 45))
    with pytest.raises(ValueError, match=r"num_pca_comps must be in \[1, 45\], got 46"):
        ManoLayer(root / "MANO_RIGHT.pkl", use_pca=True, num_pca_comps=46)
    with pytest.raises(TypeError, match="dtype must be torch.float32 or torch.float64"):
        ManoLayer(root / "MANO_RIGHT.pkl", dtype=torch.float16)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"MANO_RIGHT\.pkl: no such MANO model file"):
        load_mano_pkl(tmp_path / "MANO_RIGHT.pkl")
    with pytest.raises(FileNotFoundError, match="no such MANO model file"):
        ManoLayer(tmp_path / "MANO_LEFT.pkl")


def test_corrupt_files(mano_dir, tmp_path):
    root, _ = mano_dir
    noise = tmp_path / "MANO_RIGHT.pkl"
    noise.write_bytes(np.random.default_rng(16).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"MANO_RIGHT\.pkl: not a readable MANO model pickle"):
        load_mano_pkl(noise)
    truncated = tmp_path / "MANO_LEFT.pkl"
    full = (root / "MANO_LEFT.pkl").read_bytes()
    truncated.write_bytes(full[: len(full) // 2])
    with pytest.raises(ValueError, match=r"MANO_LEFT\.pkl: not a readable MANO model pickle \("):
        load_mano_pkl(truncated)
    empty = tmp_path / "empty_right.pkl"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="not a readable MANO model pickle"):
        load_mano_pkl(empty)


def _layout_with(tmp_path, name: str, edit) -> os.PathLike:
    content = official_layout(synthetic_mano_arrays(seed=1))
    content = edit(content)
    return write_pickle_py2(tmp_path / name, content)


def test_pickles_of_another_layout(tmp_path):
    def drop_regressor(content):
        del content["J_regressor"]
        return content

    path = _layout_with(tmp_path, "MANO_RIGHT.pkl", drop_regressor)
    with pytest.raises(
        ValueError, match=r"MANO_RIGHT\.pkl: not a MANO model, missing key\(s\) J_regressor"
    ):
        load_mano_pkl(path)

    listed = write_pickle_py2(tmp_path / "list_right.pkl", [1, 2, 3])
    with pytest.raises(
        ValueError,
        match=r"list_right\.pkl: not a MANO model \(expected a dict of arrays, got list\)",
    ):
        load_mano_pkl(listed)

    def small_template(content):
        content["v_template"] = content["v_template"][:100]
        return content

    path = _layout_with(tmp_path, "small_right.pkl", small_template)
    with pytest.raises(
        ValueError,
        match=r"small_right\.pkl: key 'v_template' must have shape \[778, 3\], got \(100, 3\)",
    ):
        load_mano_pkl(path)

    def bad_tree(content):
        content["kintree_table"] = content["kintree_table"].copy()
        content["kintree_table"][0, 5] = 1
        return content

    path = _layout_with(tmp_path, "tree_right.pkl", bad_tree)
    with pytest.raises(ValueError, match="'kintree_table' is not MANO's kinematic tree"):
        load_mano_pkl(path)

    def text_weights(content):
        content["weights"] = "lbs"
        return content

    path = _layout_with(tmp_path, "text_right.pkl", text_weights)
    with pytest.raises(ValueError, match="key 'weights' is not a numeric array"):
        load_mano_pkl(path)

    def dual_quaternion(content):
        content["bs_style"] = "dqs"
        return content

    path = _layout_with(tmp_path, "dqs_right.pkl", dual_quaternion)
    with pytest.raises(ValueError, match=r"dqs_right\.pkl: bs_style='dqs' is not supported"):
        load_mano_pkl(path)

    def nan_posedirs(content):
        content["posedirs"] = content["posedirs"].copy()
        content["posedirs"][3, 1, 7] = np.nan
        return content

    path = _layout_with(tmp_path, "nan_right.pkl", nan_posedirs)
    with pytest.raises(ValueError, match="key 'posedirs' contains NaN or inf"):
        load_mano_pkl(path)


def test_chumpy_expressions_are_evaluated_or_refused(tmp_path):
    class FakeReshape:  # chumpy.reordering.Reshape of a Ch: its value is a.r.reshape(newshape)
        def __init__(self, a, newshape):
            self.a, self.newshape = a, newshape

    class FakeAdd:  # any other chumpy operator: its value needs chumpy itself
        def __init__(self, a, b):
            self.a, self.b = a, b

    aliases = {FakeReshape: ("chumpy.reordering", "Reshape"), FakeAdd: ("chumpy.ch_ops", "add")}
    arrays = synthetic_mano_arrays(seed=2)
    content = official_layout(arrays)
    content["shapedirs"] = FakeReshape(FakeCh(arrays["shapedirs"].reshape(778, 30)), (778, 3, 10))
    path = write_pickle_py2(tmp_path / "reshaped_right.pkl", content, aliases)
    assert b"chumpy.reordering\nReshape\n" in path.read_bytes()
    np.testing.assert_array_equal(load_mano_pkl(path).shape_dirs, arrays["shapedirs"])

    content["shapedirs"] = FakeAdd(FakeCh(arrays["shapedirs"]), FakeCh(arrays["shapedirs"]))
    path = write_pickle_py2(tmp_path / "summed_right.pkl", content, aliases)
    with pytest.raises(ValueError, match=r"key 'shapedirs' is a chumpy object chumpy\.ch_ops\.add"):
        load_mano_pkl(path)


class _Exploit:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch {self.target}",))


def test_hostile_pickle_is_refused_and_never_run(tmp_path):
    target = tmp_path / "pwned"
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(pickle.dumps({"v_template": _Exploit(target)}, protocol=2))
    with pytest.raises(
        ValueError, match=r"refers to \w+\.system, which a MANO model file never contains"
    ):
        load_mano_pkl(path)
    assert not target.exists()
