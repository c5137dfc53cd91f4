"""The dataset generator (``lisa synth``): layout, loaders, determinism, split, errors, CLI."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from lisa_hand.cli.synth import register
from lisa_hand.data.datasets import RayFrames, ScanFrames, read_frame_table
from lisa_hand.data.layout import (
    FORMAT_NAME,
    FramePaths,
    read_depth,
    read_image,
    read_mask,
    read_split,
)
from lisa_hand.data.meshio import load_mesh
from lisa_hand.data.scans import ScanConfig
from lisa_hand.data.synth.dataset import (
    SynthConfig,
    dataset_rig,
    parse_resolution,
    split_subjects,
    synthesize,
    write_preview,
)
from lisa_hand.geometry.cameras import load_cameras
from lisa_hand.skeleton import KEYPOINT_NAMES, forward_kinematics

TINY = SynthConfig(num_subjects=3, num_poses=2, num_views=2, resolution=(64, 48), seed=0,
                   scan=ScanConfig(num_points=400), num_sdf_samples=300, voxels_per_length=40,
                   named_pose_fraction=0.5, num_workers=1)
NUM_TINY_FRAMES = 6


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "data"
    summary = synthesize(root, TINY, progress=False)
    assert summary.num_frames == NUM_TINY_FRAMES and summary.num_images == 12
    assert summary.seconds > 0 and summary.stage_seconds["mesh"] > 0
    return root


def _frames(root: Path) -> list[FramePaths]:
    return [FramePaths(p) for p in sorted(root.glob("s*/f*"))]


def _files(root: Path) -> dict[str, Path]:
    return {str(p.relative_to(root)): p for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_files_and_keys(tiny):
    dataset = json.loads((tiny / "dataset.json").read_text())
    assert dataset["format"] == FORMAT_NAME and dataset["num_frames"] == NUM_TINY_FRAMES
    assert dataset["camera_names"] == ["cam000", "cam001"]
    assert dataset["config"]["resolution"] == [64, 48] and "num_workers" not in dataset["config"]
    frames = _frames(tiny)
    assert len(frames) == NUM_TINY_FRAMES
    for index in range(3):
        subject = json.loads((tiny / f"s{index:03d}" / "subject.json").read_text())
        assert subject["id"] == f"s{index:03d}" and subject["side"] == "right"
        assert np.array(subject["rest_joints"]).shape == (16, 3)
        assert np.array(subject["template_betas"]).shape == (10,)
        assert np.array(subject["template_rest_joints"]).shape == (16, 3)
        assert 0.16 <= subject["shape"]["hand_length"] <= 0.22
        assert "skin_tone" in subject["appearance"] and isinstance(subject["detail_seed"], int)
        # The fitted template's skeleton is close to the hand's own (MANO-like fit, ~1 mm).
        gap = np.abs(np.array(subject["template_rest_joints"]) - subject["rest_joints"]).max()
        assert gap < 0.004

    for paths in frames:
        params = json.loads(paths.params.read_text())
        assert np.array(params["pose"]).shape == (48,)
        assert np.array(params["translation"]).shape == (3,)
        assert np.array(params["joints"]).shape == (16, 3)
        assert np.array(params["keypoints"]).shape == (21, 3)
        assert params["pose_name"] is None or isinstance(params["pose_name"], str)
        assert set(params["camera_gain"]) == set(params["camera_bias"]) == {"cam000", "cam001"}
        with np.load(paths.scan) as scan:
            assert scan["points"].shape == scan["normals"].shape == (400, 3)
            assert scan["weights"].shape == scan["template_weights"].shape == (400, 16)
            assert scan["sdf_points"].shape == (300, 3) and scan["sdf"].shape == (300,)
            np.testing.assert_allclose(scan["weights"].sum(1), 1.0, atol=1e-5)
            np.testing.assert_allclose(scan["template_weights"].sum(1), 1.0, atol=1e-5)
            np.testing.assert_allclose(np.linalg.norm(scan["normals"], axis=1), 1.0, atol=1e-4)
        mesh = load_mesh(paths.mesh)
        assert mesh.colors is not None and mesh.skin_weights.shape == (mesh.num_vertices, 16)
        cameras = load_cameras(paths.cameras)
        assert [c.name for c in cameras] == ["cam000", "cam001"]
        for camera in cameras:
            image = read_image(paths.image(camera.name))
            mask = read_mask(paths.mask(camera.name))
            depth = read_depth(paths.depth(camera.name))
            assert image.shape == (48, 64, 3) and mask.shape == depth.shape == (48, 64)
            assert 20 < mask.sum() < mask.size // 2  # the hand is in view, not filling it
            np.testing.assert_array_equal(depth > 0, mask)
            assert (image[~mask] == 0).all()  # black background, gain/bias on the hand only
        keypoints = json.loads(paths.keypoints.read_text())
        assert keypoints["names"] == list(KEYPOINT_NAMES)
        for view in keypoints["views"].values():
            assert np.array(view["keypoints"]).shape == (21, 2) and len(view["visible"]) == 21


def test_loaders_read_the_dataset(tiny):
    split = read_split(tiny)
    table = read_frame_table(tiny, "train")
    assert table.num_subjects == len(split["train"]) and table.num_frames == 2 * len(
        split["train"])
    scans = ScanFrames(tiny, "train")
    batch = scans.sample(2, 16, 8, torch.Generator().manual_seed(0))
    assert batch.surface_weights.shape == (2, 16, 16) and batch.near_sdf.shape == (2, 4)
    rays = RayFrames(tiny, "test")
    assert rays.camera_names == ["cam000", "cam001"]
    ray_batch = rays.sample_rays(32, torch.Generator().manual_seed(0))
    assert ray_batch.in_mask.any() and ray_batch.rgb.shape == (1, 32, 3)


def _check_frame_geometry(paths: FramePaths) -> None:
    """Depth back-projects onto the mesh, SDF samples match winding-number distances, keypoints
    project as the cameras say and land on the hand, and the template skeleton and weights,
    posed with the frame's parameters, follow the hand (what LISA is conditioned on)."""
    import point_cloud_utils as pcu

    mesh = load_mesh(paths.mesh)
    vertices = mesh.vertices.astype(np.float64)
    params = json.loads(paths.params.read_text())
    keypoints = json.loads(paths.keypoints.read_text())["views"]
    num_visible = 0
    for camera in load_cameras(paths.cameras, dtype=torch.float64):
        depth = read_depth(paths.depth(camera.name)).astype(np.float64)
        rows, cols = np.nonzero(depth)
        pixels = np.stack([cols + 0.5, rows + 0.5, np.ones_like(cols, float)], axis=1)
        K, R, t = (x.numpy() for x in (camera.K, camera.R, camera.t))
        x_cam = (pixels @ np.linalg.inv(K).T) * depth[rows, cols, None]
        x_world = (x_cam - t) @ R
        distance, _, _ = pcu.closest_points_on_mesh(x_world, vertices, mesh.faces)
        assert np.abs(distance).max() < 2e-4  # 0.1 mm depth units, float32

        view = keypoints[camera.name]
        world = np.array(params["keypoints"])
        projected = (world @ R.T + t) @ K.T
        projected = projected[:, :2] / projected[:, 2:]
        np.testing.assert_allclose(view["keypoints"], projected, atol=1e-3)
        padded = np.pad(read_mask(paths.mask(camera.name)), 1)
        for (u, v), visible in zip(view["keypoints"], view["visible"], strict=True):
            if visible:  # joint centres lie inside the hand: on the mask, up to a pixel
                num_visible += 1
                assert padded[int(v):int(v) + 3, int(u):int(u) + 3].any()
    assert num_visible >= 10

    with np.load(paths.scan) as scan:
        sdf_points, sdf = scan["sdf_points"].astype(np.float64), scan["sdf"]
        weights, template_weights = scan["weights"], scan["template_weights"]
    reference, _, _ = pcu.signed_distance_to_mesh(sdf_points, vertices, mesh.faces)
    far = np.abs(reference) > 1e-4  # the sign of points on the surface is a coin toss
    np.testing.assert_allclose(sdf[far], reference[far], atol=1e-5, rtol=5e-3)
    # The posed template sits on the hand: its nearest-vertex weights mostly pick the same bone.
    assert (weights.argmax(1) == template_weights.argmax(1)).mean() > 0.75

    subject = json.loads((paths.root.parent / "subject.json").read_text())
    assert subject["side"] == params["side"]
    kinematics = forward_kinematics(
        torch.tensor(params["pose"], dtype=torch.float64)[None],
        torch.tensor(subject["template_rest_joints"], dtype=torch.float64),
        torch.tensor(params["translation"], dtype=torch.float64)[None])
    gap = (kinematics.joints[0] - torch.tensor(params["joints"])).norm(dim=-1).max()
    assert gap < 0.005


def test_geometry_is_consistent(tiny):
    for paths in _frames(tiny)[:3]:
        _check_frame_geometry(paths)


def test_left_hands(tmp_path):
    root = tmp_path / "left"
    synthesize(root, dataclasses.replace(TINY, num_subjects=1, num_poses=1, left_fraction=1.0),
               progress=False)
    subject = json.loads((root / "s000" / "subject.json").read_text())
    assert subject["side"] == "left"
    # A left hand's fingers start on the +x side of the wrist (mirror of the right hand's -x).
    assert np.array(subject["rest_joints"])[1:, 0].min() > 0
    _check_frame_geometry(FramePaths(root / "s000" / "f000"))


def test_hands_are_upright_and_centred(tiny):
    for paths in _frames(tiny):
        keypoints = np.array(json.loads(paths.params.read_text())["keypoints"])
        up = keypoints[9] - keypoints[0]  # wrist to middle MCP
        tilt = np.degrees(np.arccos(up[1] / np.linalg.norm(up)))
        assert tilt < TINY.max_tilt_deg + 15.0  # the palm's axis is not exactly the rest -x
        centre = 0.5 * (keypoints.min(0) + keypoints.max(0))
        assert np.abs(centre).max() < 5 * TINY.translation_std


@pytest.mark.slow  # two worker processes start (importing torch): ~5-10 s
def test_same_seed_same_files_any_worker_count_or_size(tiny, tmp_path):
    """Frame k/f depends on (seed, k, f) only: a smaller dataset written by 2 worker processes
    holds the very same files for the subjects and frames it shares with the in-process one."""
    small = tmp_path / "small"
    summary = synthesize(small, dataclasses.replace(TINY, num_subjects=2, num_poses=1,
                                                    num_workers=2), progress=False)
    assert summary.num_workers == 2
    shared = {name: path for name, path in _files(small).items()
              if name.startswith(("s000/", "s001/")) and "f001" not in name}
    assert len(shared) == 2 * (1 + 5 + 3 * 2)  # subject.json; 5 frame files; 3 PNGs per view
    for name, path in shared.items():
        reference = tiny / name
        if name.endswith(".npz"):  # the ZIP container stores the write time; compare arrays
            with np.load(path) as a, np.load(reference) as b:
                assert a.files == b.files
                for key in a.files:
                    np.testing.assert_array_equal(a[key], b[key], err_msg=f"{name}: {key}")
        else:
            assert path.read_bytes() == reference.read_bytes(), name


def test_different_seed_differs(tiny, tmp_path):
    other = tmp_path / "other"
    synthesize(other, dataclasses.replace(TINY, num_subjects=1, num_poses=1, seed=1),
               progress=False)
    for name in ("s000/subject.json", "s000/f000/params.json", "s000/f000/images/cam000.png",
                 "s000/f000/scan.npz"):
        assert (tiny / name).read_bytes() != (other / name).read_bytes(), name


def test_dataset_rig_cannot_be_changed_by_a_caller():
    cameras, gain_bias = dataset_rig(TINY)
    names, gains = [camera.name for camera in cameras], gain_bias.gain.copy()
    cameras.clear()
    gain_bias.gain[:] = 0.0
    again_cameras, again = dataset_rig(TINY)
    assert [camera.name for camera in again_cameras] == names
    np.testing.assert_array_equal(again.gain, gains)


def test_split_rule():
    counts = {n: {k: len(v) for k, v in split_subjects(n, seed=3).items()}
              for n in (1, 2, 3, 5, 10, 20)}
    assert counts[1] == {"train": 1, "val": 0, "test": 0}
    assert counts[2] == {"train": 1, "val": 0, "test": 1}
    assert counts[3] == {"train": 2, "val": 0, "test": 1}
    assert counts[5] == {"train": 3, "val": 1, "test": 1}
    assert counts[10] == {"train": 7, "val": 1, "test": 2}
    assert counts[20] == {"train": 14, "val": 2, "test": 4}
    split = split_subjects(20, seed=3)
    everyone = split["train"] + split["val"] + split["test"]
    assert sorted(everyone) == [f"s{i:03d}" for i in range(20)]  # disjoint and complete
    assert split_subjects(20, seed=3) == split and split_subjects(20, seed=4) != split
    assert all(v == sorted(v) for v in split.values())


def test_split_file_keeps_test_subjects_out_of_training(tiny):
    split = read_split(tiny)
    assert split["test"] and not set(split["test"]) & set(split["train"])
    assert split == split_subjects(3, TINY.split_fractions, TINY.seed)
    train = read_frame_table(tiny, "train")
    assert not set(train.subject_ids) & set(split["test"])


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="num_subjects"):
        SynthConfig(num_subjects=0)
    with pytest.raises(ValueError, match="resolution"):
        SynthConfig(resolution=(64, 0))
    with pytest.raises(ValueError, match="split_fractions"):
        SynthConfig(split_fractions=(0.5, 0.1, 0.1))
    assert parse_resolution("512x334") == (512, 334) and parse_resolution(" 64X48 ") == (64, 48)
    for text in ("512by334", "512x", "0x10", "-5x5"):
        with pytest.raises(ValueError, match="resolution"):
            parse_resolution(text)
    full = tmp_path / "full"
    full.mkdir()
    (full / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="not empty"):
        synthesize(full, TINY, progress=False)
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(OSError, match="a_file"):
        synthesize(blocker / "data", TINY, progress=False)
    with pytest.raises(OSError, match="a_file"):
        synthesize(blocker, TINY, progress=False)


def test_overwrite_replaces_only_the_dataset(tmp_path):
    root = tmp_path / "data"
    (root / "s007" / "f003").mkdir(parents=True)
    (root / "dataset.json").write_text("{}")
    (root / "notes.txt").write_text("keep me")
    config = dataclasses.replace(TINY, num_subjects=1, num_poses=1, num_views=1)
    synthesize(root, config, progress=False, overwrite=True)
    assert not (root / "s007").exists() and (root / "notes.txt").read_text() == "keep me"
    assert json.loads((root / "dataset.json").read_text())["num_frames"] == 1


@pytest.fixture()
def app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def _root() -> None:
        """Test app."""

    register(app)
    return app


def test_cli_writes_dataset(app, tmp_path):
    out = tmp_path / "cli"
    result = CliRunner().invoke(app, [
        "synth", str(out), "--subjects", "2", "--poses", "1", "--views", "1",
        "--resolution", "40x30", "--seed", "5", "--workers", "1", "--scan-points", "100",
        "--sdf-samples", "50", "--mesh-resolution", "32", "--quiet",
    ])
    assert result.exit_code == 0, result.output
    assert "2 subjects x 1 poses x 1 views" in result.output and "time:" in result.output
    assert read_image(out / "s001" / "f000" / "images" / "cam000.png").shape == (30, 40, 3)
    split = read_split(out)
    assert sorted(split["train"] + split["test"]) == ["s000", "s001"] and len(split["test"]) == 1
    with np.load(out / "s000" / "f000" / "scan.npz") as scan:
        assert scan["points"].shape == (100, 3) and scan["sdf"].shape == (50,)
    assert not (tmp_path / "sheet.png").exists()


def test_cli_preview_alone(app, tmp_path):
    sheet = tmp_path / "sheet.png"
    result = CliRunner().invoke(app, ["synth", "--subjects", "1", "--mesh-resolution", "32",
                                      "--preview", str(sheet)])
    assert result.exit_code == 0, result.output
    assert f"wrote preview {sheet}" in result.output
    preview = read_image(sheet)
    assert preview.shape == (320, 6 * 320 + 5 * 4, 3)  # 1 subject x 6 poses
    assert (preview < 0.9).any() and (preview[0, 0] == 1.0).all()  # hands on white
    assert list(tmp_path.iterdir()) == [sheet]  # no dataset


def test_cli_errors(app, tmp_path):
    result = CliRunner().invoke(app, ["synth"])
    assert isinstance(result.exception, ValueError) and "nothing to write" in str(
        result.exception)
    result = CliRunner().invoke(app, ["synth", str(tmp_path / "x"), "--resolution", "64*48"])
    assert isinstance(result.exception, ValueError) and "64*48" in str(result.exception)
    result = CliRunner().invoke(app, ["synth", str(tmp_path / "x"), "--subjects", "0"])
    assert isinstance(result.exception, ValueError) and "num_subjects" in str(result.exception)


def test_preview_tiles(tmp_path):
    config = dataclasses.replace(TINY, voxels_per_length=32, named_pose_fraction=1.0)
    path = write_preview(tmp_path / "p.png", config, num_subjects=1, num_poses=2, tile_size=48)
    sheet = read_image(path)
    assert sheet.shape == (48, 2 * 48 + 4, 3)
    for tile in (sheet[:, :48], sheet[:, 52:]):
        assert 0.05 < (tile.min(-1) < 0.95).mean() < 0.9  # a hand on a white tile
    with pytest.raises(ValueError, match="png"):
        write_preview(tmp_path / "p.jpg", config)


def test_frame_paths_accept_strings(tiny):
    # docs/data_formats.md builds one from an f-string.
    paths = FramePaths(f"{tiny}/s000/f000")
    assert paths.root == tiny / "s000" / "f000" and paths.params.is_file()
    assert read_image(paths.image("cam000")).shape == (48, 64, 3)
    with pytest.raises(TypeError, match="FramePaths.root"):
        FramePaths(3)
