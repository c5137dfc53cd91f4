"""``lisa mesh``, ``lisa render``, ``lisa animate`` and ``lisa blend`` on a tiny exported model
(an untrained LisaModel at its geometric initialisation: a blob of a hand)."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from lisa_hand.cli import animate, blend, main, mesh, render
from lisa_hand.cli.options import parse_image_size, read_cameras
from lisa_hand.data.meshio import load_mesh
from lisa_hand.fields import FieldConfig
from lisa_hand.metrics import mesh_distances
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel, export_trained
from lisa_hand.skeleton import AVERAGE_REST_JOINTS
from lisa_hand.skeleton.params import HandParams, read_params, write_params

VERBS = (mesh, render, animate, blend)
TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8,
                  palm_region_radius=0.07, finger_region_radius=0.035)
REST = torch.tensor(AVERAGE_REST_JOINTS)
PADDING = "0.08"  # metres: the untrained blob reaches 7 cm past the skeleton


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A tiny exported model and two hands fitted with it (params.json naming the model)."""
    folder = tmp_path_factory.mktemp("inference")
    torch.manual_seed(0)
    generator = torch.Generator().manual_seed(0)
    model = TrainedModel(
        field=LisaModel(FieldConfig(**TINY_FIELD), init_rest_joints=REST).eval(),
        shape_codes=0.1 * torch.randn(2, 8, generator=generator),
        color_codes=torch.randn(2, 8, generator=generator), subject_ids=["s0", "s1"],
        beta=0.002, gain=torch.tensor([1.1, 0.9, 1.0]), bias=torch.tensor([0.05, -0.02, 0.0]),
        source="tiny",
    )  # fmt: skip
    model_path, _ = export_trained(model, folder / "model.pt")
    pose = torch.zeros(48)
    pose[:3] = torch.tensor([0.3, -0.2, 0.1])
    pose[3:] = 0.08
    hands = []
    for row in range(2):
        params = HandParams(
            pose=pose, translation=torch.tensor([0.0, 0.0, 0.4]),
            rest_joints=REST * (1.0 + 0.05 * row), shape_code=model.shape_codes[row],
            color_code=model.color_codes[row], model=str(model_path),
        )  # fmt: skip
        hands.append(write_params(folder / f"hand{row}.json", params))
    return {"folder": folder, "model": model_path, "a": hands[0], "b": hands[1]}


@pytest.fixture()
def app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def _root() -> None:
        """Test app."""

    for verb in VERBS:
        verb.register(app)
    return app


def run(app, args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, (result.output, result.exception)
    return result


def test_mesh_formats_colours_weights_and_dense_reference(app, files, tmp_path):
    out = tmp_path / "hand.ply"
    result = run(app, ["mesh", files["a"], "--res", 40, "--padding", PADDING, "--out", out])
    assert "colours and 16 skinning weights" in result.output
    ply = load_mesh(out)
    assert ply.colors is not None and ply.skin_weights.shape == (ply.num_vertices, 16)
    np.testing.assert_allclose(ply.skin_weights.sum(1), 1.0, atol=1e-5)
    assert len(np.unique(ply.colors, axis=0)) > 10  # the field's colours, not a constant

    dense = tmp_path / "dense.ply"
    run(app, ["mesh", files["a"], "--res", 40, "--padding", PADDING, "--dense", "--out", dense])
    reference = load_mesh(dense)
    distances = mesh_distances(ply.vertices, ply.faces, reference.vertices, reference.faces)
    assert distances.v2s_recon_to_scan_mm < 0.05 and distances.v2s_scan_to_recon_mm < 0.05

    for suffix in (".obj", ".glb"):
        path = tmp_path / f"hand{suffix}"
        result = run(app, ["mesh", files["a"], "--res", 40, "--padding", PADDING, "--model",
                           files["model"], "--out", path])
        assert "cannot hold skinning weights" in result.output
        other = load_mesh(path)
        assert other.num_vertices == ply.num_vertices and other.skin_weights is None
        np.testing.assert_allclose(other.vertices, ply.vertices, atol=1e-6)
        assert np.abs(other.colors.astype(int) - ply.colors.astype(int)).max() <= 1


def test_render_orbit_then_cameras(app, files, tmp_path):
    out = tmp_path / "orbit"
    result = run(app, ["render", files["a"], "--orbit", 3, "--resolution", "40x32",
                       "--out", out, "--fps", 5])
    assert "turntable: " in result.output
    for index in range(3):
        rgb = iio.imread(out / f"orbit{index:03d}_rgb.png")
        mask = iio.imread(out / f"orbit{index:03d}_mask.png")
        normals = iio.imread(out / f"orbit{index:03d}_normals.png")
        depth = np.load(out / f"orbit{index:03d}_depth.npy")
        assert rgb.shape == (32, 40, 3) and mask.shape == (32, 40) and normals.shape == rgb.shape
        assert depth.shape == (32, 40)
        hand = mask > 0
        assert hand[10:22, 17:23].any() and 0.05 < hand.mean() < 0.8
        border = np.concatenate([hand[0], hand[-1], hand[:, 0], hand[:, -1]])
        assert not border.any()
        # Black background (edge pixels under half opacity keep some colour), a lit hand.
        assert (rgb[[0, -1]] == 0).all() and (rgb[:, [0, -1]] == 0).all()
        assert rgb[~hand].mean() < 10 and (rgb[hand].max(axis=1) > 40).mean() > 0.9
        # Metres along the ray: the camera stands back to frame the ~25 cm blob in a 30 degree
        # field of view (~1 m); nothing on the border.
        assert (np.abs(depth[hand] - np.median(depth[hand])) < 0.15).all()
        assert 0.5 < np.median(depth[hand]) < 1.5 and (depth[[0, -1]] == 0).all()
    gif = iio.imread(out / "turntable.gif", index=None)
    assert gif.shape[:3] == (3, 32, 40)

    # The cameras it wrote render again (intrinsics scaled to another size, white background).
    again = tmp_path / "again"
    run(app, ["render", files["a"], "--camera", out / "cameras.json", "--resolution", "20x16",
              "--out", again, "--background", "white", "--no-normals"])
    small = iio.imread(again / "orbit000_rgb.png")
    assert small.shape == (16, 20, 3) and (small[0, 0] == 255).all()
    assert not (again / "orbit000_normals.png").exists() and not (again / "turntable.gif").exists()
    small_mask = iio.imread(again / "orbit000_mask.png") > 0
    big_mask = iio.imread(out / "orbit000_mask.png") > 0
    # The same view at half the size: the masks agree on most 2x2 blocks.
    pooled = big_mask.reshape(16, 2, 20, 2).mean(axis=(1, 3)) >= 0.5
    assert (pooled == small_mask).mean() > 0.9


def test_animate_motion_and_sequence(app, files, tmp_path):
    out = tmp_path / "fist"
    result = run(app, ["animate", files["a"], "--motion", "fist", "--frames-per-segment", 1,
                       "--res", 24, "--resolution", "32x32", "--out", out])
    assert "3 meshes, 3 frames" in result.output
    meshes = [load_mesh(out / "meshes" / f"frame_{i:03d}.ply") for i in range(3)]
    for item in meshes:
        assert item.colors is not None and item.skin_weights.shape[1] == 16
    # Frames 0 and 2 are the hand's own pose; frame 1 the fist.
    np.testing.assert_allclose(meshes[0].vertices, meshes[2].vertices, atol=1e-5)
    moved = mesh_distances(meshes[1].vertices, meshes[1].faces, meshes[0].vertices,
                           meshes[0].faces)
    assert moved.v2s_recon_to_scan_mm > 2.0
    frames = [iio.imread(out / "frames" / f"frame_{i:03d}.png") for i in range(3)]
    assert all(frame.shape == (32, 32, 3) for frame in frames)
    assert np.abs(frames[1].astype(int) - frames[0].astype(int)).mean() > 1.0
    assert iio.imread(out / "animation.gif", index=None).shape[:3] == (3, 32, 32)
    saved = json.loads((out / "poses.json").read_text())
    assert np.array(saved["poses"]).shape == (3, 48)

    # A 45-D sequence keeps the hand's global rotation; skinning meshes share their faces.
    sequence = tmp_path / "seq.json"
    sequence.write_text(json.dumps({"poses": [[0.0] * 45, [0.3] * 45]}))
    out = tmp_path / "seq"
    run(app, ["animate", files["a"], "--poses", sequence, "--res", 24, "--mesh-mode", "skinning",
              "--no-frames", "--out", out])
    first, second = (load_mesh(out / "meshes" / f"frame_{i:03d}.ply") for i in range(2))
    assert np.array_equal(first.faces, second.faces)
    assert np.abs(first.vertices - second.vertices).max() > 0.01
    assert not (out / "frames").exists()
    poses = np.array(json.loads((out / "poses.json").read_text())["poses"])
    np.testing.assert_allclose(poses[:, :3], [[0.3, -0.2, 0.1]] * 2, atol=1e-6)

    # Frames only, from the camera the first run chose (scaled to 16x16).
    out = tmp_path / "frames"
    run(app, ["animate", files["a"], "--poses", sequence, "--res", 0, "--camera",
              tmp_path / "fist" / "camera.json", "--resolution", "16x16", "--out", out])
    assert not (out / "meshes").exists()
    assert iio.imread(out / "animation.gif", index=None).shape[:3] == (2, 16, 16)


def test_blend_then_mesh(app, files, tmp_path):
    same = tmp_path / "same.json"
    run(app, ["blend", files["a"], files["b"], "--shape", "0", "--color", "A", "--out", same])
    a, b, mixed = read_params(files["a"]), read_params(files["b"]), read_params(same)
    assert torch.equal(mixed.shape_code, a.shape_code) and torch.equal(mixed.color_code,
                                                                      a.color_code)
    assert torch.equal(mixed.rest_joints, a.rest_joints)
    swapped = tmp_path / "swapped.json"
    result = run(app, ["blend", files["a"], files["b"], "--shape", "B", "--color", "0.5",
                       "--out", swapped])
    assert "shape 0 A + 1 B" in result.output
    mixed = read_params(swapped)
    assert torch.equal(mixed.shape_code, b.shape_code) and torch.equal(mixed.rest_joints,
                                                                      b.rest_joints)
    torch.testing.assert_close(mixed.color_code, 0.5 * (a.color_code + b.color_code))
    assert mixed.model == a.model and mixed.extra["blend"]["b"] == str(files["b"])
    run(app, ["mesh", swapped, "--res", 16, "--padding", PADDING, "--out", tmp_path / "m.ply"])


def test_image_sizes_and_camera_files(tmp_path):
    assert parse_image_size("64x48") == (64, 48) and parse_image_size(" 8X4 ") == (8, 4)
    with pytest.raises(ValueError, match="resolution must look like"):
        parse_image_size("512by512")
    with pytest.raises(ValueError, match="--resolution must be between"):
        parse_image_size("0x10", "--resolution")
    path = tmp_path / "cams.json"
    path.write_text(json.dumps([{"name": "c", "K": [[40, 0, 20], [0, 40, 10], [0, 0, 1]],
                                 "R": np.eye(3).tolist(), "t": [0, 0, 1], "width": 40,
                                 "height": 20}]))
    (camera,) = read_cameras(path, (20, 10))
    assert (camera.width, camera.height) == (20, 10)
    torch.testing.assert_close(camera.K, torch.tensor([[20.0, 0, 10], [0, 20, 5], [0, 0, 1]]))
    path.write_text("[]")
    with pytest.raises(ValueError, match="holds no camera"):
        read_cameras(path)


@pytest.fixture()
def lisa():
    """The ``lisa`` entry point (errors become one line and exit status 2)."""
    return main.main


@pytest.mark.parametrize("case", [
    "missing_params", "wrong_shape_code", "bad_resolution", "camera_missing_field",
    "unknown_motion", "bad_suffix", "camera_and_orbit", "bad_blend_weight",
])
def test_bad_inputs_are_one_line_errors(lisa, files, tmp_path, capsys, case):
    out = tmp_path / "out"
    wrong = tmp_path / "wrong.json"
    data = json.loads(files["a"].read_text())
    data["shape_code"] = [0.0] * 5
    wrong.write_text(json.dumps(data))
    cameras = tmp_path / "cams.json"
    cameras.write_text(json.dumps([{"name": "c", "K": np.eye(3).tolist(), "R": np.eye(3).tolist(),
                                    "width": 8, "height": 8}]))
    args, expected = {
        "missing_params": (["mesh", tmp_path / "nope.json", "--out", out / "m.ply"],
                           ["nope.json", "no such file"]),
        "wrong_shape_code": (["render", wrong, "--orbit", 2, "--out", out],
                             ["wrong.json", "shape_code has 5 entries"]),
        "bad_resolution": (["render", files["a"], "--orbit", 2, "--resolution", "40by30",
                            "--out", out], ["--resolution", "40by30"]),
        "camera_missing_field": (["render", files["a"], "--camera", cameras, "--out", out],
                                 ["cams.json", "camera 0", "t"]),
        "unknown_motion": (["animate", files["a"], "--motion", "wave", "--out", out],
                           ["--motion", "wave", "fist"]),
        "bad_suffix": (["mesh", files["a"], "--out", out / "m.stl"], ["--out", ".stl"]),
        "camera_and_orbit": (["render", files["a"], "--orbit", 2, "--camera", cameras,
                              "--out", out], ["--camera", "--orbit"]),
        "bad_blend_weight": (["blend", files["a"], files["b"], "--shape", "C", "--out",
                              out / "p.json"], ["--shape", "'C'"]),
    }[case]
    with pytest.raises(SystemExit) as info:
        lisa([str(a) for a in args])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lisa: error: ") and "\n" not in err and "Traceback" not in err
    for piece in expected:
        assert piece in err
    assert not out.exists()  # nothing written


def test_mesh_removes_specks_unless_kept(app, files, tmp_path):
    from lisa_hand.geometry.pieces import MIN_PIECE_FRACTION, surface_pieces

    args = ["mesh", files["a"], "--res", 40, "--padding", PADDING, "--out"]
    kept = run(app, [*args, tmp_path / "kept.ply", "--keep-specks"])
    assert "removed" not in kept.output
    every, total = surface_pieces(load_mesh(tmp_path / "kept.ply"))
    specks = every[every < MIN_PIECE_FRACTION * total]
    assert len(specks) > 0  # the untrained blob leaves some: the case is real
    result = run(app, [*args, tmp_path / "clean.ply"])
    assert (f"note: the mesh: {len(specks)} speck(s) below 0.1 % of the surface removed "
            f"({1e4 * specks.sum():.3g} cm^2 in all) (--keep-specks keeps them)") in result.output
    left, left_total = surface_pieces(load_mesh(tmp_path / "clean.ply"))
    np.testing.assert_allclose(left, every[every >= MIN_PIECE_FRACTION * total], rtol=1e-6)
    assert left_total == pytest.approx(total - specks.sum(), rel=1e-6)
