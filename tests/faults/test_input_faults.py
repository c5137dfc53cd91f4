"""The commands' inputs, hostile or wrong: a model file, a point cloud, params.json, a camera file,
a depth image, a pose sequence. Each is refused with one line naming the file and the problem
(exit 2), never a traceback, never advice to turn a safety off, never a silently wrong result.
Every bad input is made here, in ``tmp_path``; each case stops before any fit or training."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from lisa_hand.cli.main import main
from lisa_hand.evaluation.real_formats import SplitScores
from lisa_hand.inference.sequences import MAX_POSES, read_pose_sequence
from lisa_hand.model.trained import load_trained
from lisa_hand.skeleton import AVERAGE_REST_JOINTS
from lisa_hand.skeleton.params import HandParams, read_params, write_params
from lisa_hand.utils.io import read_json

CAMERA = {"name": "cam0", "K": [[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]],
          "R": np.eye(3).tolist(), "t": [0.0, 0.0, 0.0], "width": 64, "height": 48}
SINGULAR_K = [[60.0, 60.0, 32.0], [60.0, 60.0, 24.0], [0.0, 0.0, 1.0]]  # fx, fy > 0; det 0
SAFETY_OFF = ("weights_only", "allow_pickle", "pip install", "Traceback")


def run(capsys, *args) -> tuple[int, str]:
    """``lisa ARGS`` -> (exit status, what it printed to stderr, stripped)."""
    capsys.readouterr()
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    return code, capsys.readouterr().err.strip()


def assert_one_line(code: int, error: str, *expected: str) -> None:
    assert code == 2, error
    assert error.startswith("lisa: error: ") and "\n" not in error, error
    for text in expected:
        assert text in error, (text, error)
    for text in SAFETY_OFF:
        assert text not in error, (text, error)


def write_cameras(path, *cameras) -> str:
    path.write_text(json.dumps(list(cameras)))
    return str(path)


def hand_params(folder, name="params.json", **changes):
    """A valid params.json (the bench skeleton, 40 cm before the camera), changed in ``changes``
    (JSON values) -> its path."""
    params = HandParams(pose=torch.zeros(48), translation=torch.tensor([0.0, 0.0, 0.4]),
                        rest_joints=torch.tensor(AVERAGE_REST_JOINTS), shape_code=torch.zeros(8))
    path = write_params(folder / name, params)
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))
    return path


def cloud(count=300, seed=0) -> np.ndarray:
    """[count, 3] points of a hand's size (about 0.17 m across), metres."""
    return np.random.default_rng(seed).uniform(-0.05, 0.05, (count, 3))


# --- model files ---------------------------------------------------------------------------


def test_model_files_that_are_not_models_are_refused_without_unsafe_advice(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("a text file\nwith lines\n")
    pickled = tmp_path / "objects.pt"
    torch.save({"format": "lisa_hand.trained", "hook": ValueError("runs code")}, pickled)
    cut = tmp_path / "cut.pt"
    torch.save({"x": torch.zeros(1000)}, cut)
    cut.write_bytes(cut.read_bytes()[:300])
    params = hand_params(tmp_path)
    for path, reason in ((text, "not a torch file"), (pickled, "holds Python objects"),
                         (cut, "truncated or corrupted")):
        with pytest.raises(ValueError, match="not a LISA model file") as info:
            load_trained(path)
        assert reason in str(info.value) and "weights_only" not in str(info.value)
        code, error = run(capsys, "mesh", params, "--model", path, "--out", tmp_path / "m.ply")
        assert_one_line(code, error, f"{path}: not a LISA model file", reason)


# --- point clouds and meshes ---------------------------------------------------------------


def _bad_arrays(folder) -> dict[str, tuple[str, str]]:
    """{file name: (what the error says)} for .npy/.npz files no reader may take."""
    np.savez(folder / "whole.npz", points=cloud())
    data = (folder / "whole.npz").read_bytes()
    (folder / "truncated.npz").write_bytes(data[: len(data) // 2])
    (folder / "corrupted.npz").write_bytes(data[:40] + bytes(200) + data[240:])
    np.save(folder / "whole.npy", cloud())
    (folder / "truncated.npy").write_bytes((folder / "whole.npy").read_bytes()[:500])
    np.save(folder / "objects.npy", np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    np.savez(folder / "objects.npz", points=np.array([{"a": 1}, None], dtype=object))
    np.save(folder / "complex.npy", cloud().astype(np.complex128) + 1e-3j)
    return {
        "truncated.npz": "truncated or corrupted",
        "corrupted.npz": "truncated or corrupted",
        "truncated.npy": "truncated or corrupted",
        "objects.npy": "holds Python objects",
        "objects.npz": "holds Python objects",
        "complex.npy": "must be real numbers, got dtype complex128",
    }


def test_bad_arrays_in_fit_points_and_metrics(tmp_path, capsys):
    cases = _bad_arrays(tmp_path)
    np.save(tmp_path / "good.npy", cloud())
    for name, expected in cases.items():
        path = tmp_path / name
        code, error = run(capsys, "fit-points", path, "--out", tmp_path / "out", "--model",
                          tmp_path / "no_model.pt")
        assert_one_line(code, error, f"{path}: ", expected)
        code, error = run(capsys, "metrics", tmp_path / "good.npy", path)
        assert_one_line(code, error, f"{path}: ", expected)
    assert not (tmp_path / "out").exists()


def test_bad_ground_truth_of_a_point_fit(tmp_path, capsys):
    _bad_arrays(tmp_path)
    np.save(tmp_path / "scan.npy", cloud())
    code, error = run(capsys, "fit-points", tmp_path / "scan.npy", "--out", tmp_path / "out",
                      "--gt", tmp_path / "truncated.npz", "--model", tmp_path / "no_model.pt",
                      "--side", "right")
    assert_one_line(code, error, f"{tmp_path / 'truncated.npz'}: ", "truncated or corrupted")


def test_a_cloud_far_from_the_origin_is_refused(tmp_path, capsys):
    np.save(tmp_path / "far.npy", cloud() + [1e6, 0.0, 0.0])
    code, error = run(capsys, "fit-points", tmp_path / "far.npy", "--out", tmp_path / "out",
                      "--model", tmp_path / "no_model.pt")
    assert_one_line(code, error, "far.npy: the cloud lies 1e+06 m from the origin")


def test_metrics_on_a_huge_point_set_subsample_it_and_say_so(tmp_path, capsys, monkeypatch):
    import lisa_hand.metrics.mesh as mesh_metrics

    monkeypatch.setattr(mesh_metrics, "MAX_POINT_SET", 500)
    np.save(tmp_path / "recon.npy", cloud(400, seed=1))
    np.save(tmp_path / "scan.npy", cloud(2000, seed=2))
    with pytest.raises(SystemExit) as info:
        main(["metrics", str(tmp_path / "recon.npy"), str(tmp_path / "scan.npy")])
    assert info.value.code in (0, None)
    printed = capsys.readouterr().out
    assert f"{tmp_path / 'scan.npy'}: compared through 500 of its 2000 points" in printed
    assert "recon.npy: compared" not in printed


# --- camera files --------------------------------------------------------------------------


@pytest.mark.parametrize(("change", "expected"), [
    ({"K": SINGULAR_K}, "K is singular"),
    ({"width": 100000, "height": 100000}, "width must be at most 16384 pixels"),
    ({"K": [[1e12, 0.0, 32.0], [0.0, 1e12, 24.0], [0.0, 0.0, 1.0]]},
     "focal length fx = 1e+12 px is implausible"),
])
def test_bad_cameras_in_render_fit_images_fit_photo_and_depth(tmp_path, capsys, change,
                                                               expected):
    cameras = write_cameras(tmp_path / "cameras.json", {**CAMERA, **change})
    code, error = run(capsys, "render", tmp_path / "params.json", "--camera", cameras, "--out",
                      tmp_path / "render")
    assert_one_line(code, error, f"{cameras}: camera 0: ", expected)

    frame = tmp_path / "frame"
    frame.mkdir()
    write_cameras(frame / "cameras.json", {**CAMERA, **change})
    code, error = run(capsys, "fit-images", frame, "--out", tmp_path / "fit")
    assert_one_line(code, error, f"{frame / 'cameras.json'}: camera 0: ", expected)

    iio.imwrite(tmp_path / "photo.png", np.zeros((48, 64, 3), np.uint8))
    single = tmp_path / "camera.json"
    single.write_text(json.dumps({**CAMERA, **change}))
    code, error = run(capsys, "fit-photo", tmp_path / "photo.png", "--camera", single, "--out",
                      tmp_path / "photo_fit")
    assert_one_line(code, error, f"{single}: ", expected)

    iio.imwrite(tmp_path / "depth.png", np.full((48, 64), 500, np.uint16))
    code, error = run(capsys, "fit-points", tmp_path / "depth.png", "--camera", cameras,
                      "--out", tmp_path / "depth_fit")
    assert_one_line(code, error, f"{cameras}: camera 0: ", expected)


def test_an_implausible_focal_length_of_a_photo(tmp_path, capsys):
    iio.imwrite(tmp_path / "photo.png", np.zeros((48, 64, 3), np.uint8))
    code, error = run(capsys, "fit-photo", tmp_path / "photo.png", "--focal-px", "1e12",
                      "--out", tmp_path / "fit")
    assert_one_line(code, error, "focal_px 1e+12 is implausible", "photo.png")


def test_deeply_nested_json_names_the_file(tmp_path, capsys):
    nested = tmp_path / "nested.json"
    nested.write_text("[" * 200_000 + "]" * 200_000)
    code, error = run(capsys, "render", tmp_path / "params.json", "--camera", nested, "--out",
                      tmp_path / "render")
    assert_one_line(code, error, f"{nested}: not valid JSON (nested too deeply)")
    with pytest.raises(ValueError, match="nested too deeply"):
        read_json(nested)


@pytest.mark.parametrize("name", ["../outside", "/etc/passwd", "sub/cam", "..", "a\\b"])
def test_camera_names_must_stay_inside_the_frame_folder(tmp_path, capsys, name):
    frame = tmp_path / "frame"
    frame.mkdir()
    cameras = write_cameras(frame / "cameras.json", CAMERA, {**CAMERA, "name": name})
    code, error = run(capsys, "fit-images", frame, "--out", tmp_path / "fit")
    assert_one_line(code, error, f"{cameras}: camera 1 is named {name!r}",
                    "not a plain file name")


# --- params.json ---------------------------------------------------------------------------


@pytest.mark.parametrize(("changes", "expected"), [
    ({"version": 99}, "version 99 is not one this code reads"),
    ({"version": True}, "version True"),
    ({"pose": [True] * 48}, "pose must hold numbers only, found True"),
    ({"shape_code": ["0"] * 8}, "shape_code must hold numbers only"),
    ({"translation": [1e6, 0.0, 0.0]}, "translation is 1e+06 m from the origin"),
    ({"rest_joints": [[0.0, 0.0, 0.0]] * 16}, "rest_joints is degenerate"),
    ({"model": ["a"]}, "model must be a shipped model's name or a path"),
])
def test_params_json_that_is_no_hand(tmp_path, capsys, changes, expected):
    path = hand_params(tmp_path, **changes)
    with pytest.raises(ValueError) as info:
        read_params(path)
    assert str(info.value).startswith(f"{path}: ") and expected in str(info.value)
    code, error = run(capsys, "mesh", path, "--out", tmp_path / "mesh.ply")
    assert_one_line(code, error, f"{path}: ", expected)


def test_params_json_may_not_name_a_model_outside_its_folder(tmp_path, capsys):
    folder = tmp_path / "fit"
    folder.mkdir()
    (tmp_path / "elsewhere.pt").write_bytes(b"")
    for model in ("../elsewhere.pt", "sub/../../elsewhere.pt"):
        path = hand_params(folder, model=model)
        code, error = run(capsys, "mesh", path, "--out", tmp_path / "mesh.ply")
        assert_one_line(code, error, f"{path}: its model {model!r} leaves the file's folder",
                        f"--model {tmp_path / 'elsewhere.pt'}")
    assert not (tmp_path / "mesh.ply").exists()


# --- depth images --------------------------------------------------------------------------


def test_empty_depth_images_say_so(tmp_path, capsys):
    cameras = write_cameras(tmp_path / "cam.json", CAMERA)
    for name in ("empty.png", "empty.tiff"):
        (tmp_path / name).write_bytes(b"")
        code, error = run(capsys, "fit-points", tmp_path / name, "--camera", cameras, "--out",
                          tmp_path / "out")
        assert_one_line(code, error,
                        f"{tmp_path / name}: cannot read this depth image: the file is empty")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG junk")
    code, error = run(capsys, "fit-points", tmp_path / "junk.png", "--camera", cameras, "--out",
                      tmp_path / "out")
    assert_one_line(code, error, "junk.png: cannot read this depth image: unreadable")


def test_a_wrong_depth_scale_is_named_not_the_mask(tmp_path, capsys):
    cameras = write_cameras(tmp_path / "cam.json", CAMERA)
    depth = np.zeros((48, 64), np.uint16)
    depth[14:34, 22:42] = 500  # the hand at 500 units
    iio.imwrite(tmp_path / "depth.png", depth)
    iio.imwrite(tmp_path / "mask.png", np.where(depth > 0, 255, 0).astype(np.uint8))
    code, error = run(capsys, "fit-points", tmp_path / "depth.png", "--camera", cameras,
                      "--mask", tmp_path / "mask.png", "--depth-scale", "1", "--out",
                      tmp_path / "out", "--model", tmp_path / "no_model.pt")
    assert_one_line(code, error, "inside the mask", "check --depth-scale", "(now 1;")
    assert "pass --mask" not in error
    code, error = run(capsys, "fit-points", tmp_path / "depth.png", "--camera", cameras,
                      "--depth-scale", "1e-7", "--out", tmp_path / "out", "--model",
                      tmp_path / "no_model.pt")
    assert_one_line(code, error, "check --depth-scale")


# --- pose sequences, evaluation, training data -------------------------------------------


def test_pose_sequences_are_capped(tmp_path, capsys):
    path = tmp_path / "poses.json"
    path.write_text(json.dumps([[0.0] * 45] * (MAX_POSES + 1)))
    with pytest.raises(ValueError, match=f"{MAX_POSES + 1} poses, more than the {MAX_POSES}"):
        read_pose_sequence(path)
    code, error = run(capsys, "animate", tmp_path / "params.json", "--poses", path, "--out",
                      tmp_path / "anim")
    assert_one_line(code, error, f"{path}: {MAX_POSES + 1} poses")
    far = tmp_path / "far.json"
    far.write_text(json.dumps({"poses": [[0.0] * 45], "translations": [[0.0, 0.0, 1e6]]}))
    with pytest.raises(ValueError, match="a translation is 1e\\+06 m from the origin"):
        read_pose_sequence(far)


def test_eval_real_that_scored_no_frame_fails(tmp_path, capsys, monkeypatch):
    import lisa_hand.evaluation.real_formats as real_formats

    def nothing_scored(data, split, predict, out=None, max_frames=None, log=None):
        return SplitScores(dataset="FreiHAND", failed=["f000: no hand found"])

    monkeypatch.setattr(real_formats, "evaluate_split", nothing_scored)
    monkeypatch.setattr(real_formats, "photo_fit_predictor", lambda *args, **kwargs: None)
    code, error = run(capsys, "eval", tmp_path / "data", "--real", "--out", tmp_path / "eval")
    assert_one_line(code, error, "no frame of split 'test' was scored (1 failed",
                    "f000: no hand found")


def test_train_prior_on_a_file_says_it_is_not_a_folder(tmp_path, capsys):
    data = tmp_path / "data.npz"
    np.savez(data, points=cloud())
    code, error = run(capsys, "train-prior", data, "--out", tmp_path / "run")
    assert_one_line(code, error, f"{data}: is a file, not a dataset folder")
