"""``lisa fit-images`` on a tiny exported model and a frame folder rendered from it (48 x 36
pixels, 3 views), and its one-line errors for bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from lisa_hand.cli import main
from lisa_hand.data.layout import write_image
from lisa_hand.data.meshio import load_mesh, save_mesh
from lisa_hand.inference import mesh_hand
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton.params import read_params
from tests.fitting.image_scene import render_frame, tiny_model, true_hand, write_frame

FAST = ["--keypoint-iters", "60", "--color-iters", "4", "--rays", "64", "--res", "32",
        "--device", "cpu", "--no-progress"]


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture()
def lisa():
    """``lisa_hand.cli.main.main`` (it registers every verb, fit-images included)."""
    return main.main


def run_ok(lisa, argv):
    """Run a command that must succeed (typer exits with status 0)."""
    try:
        lisa(argv)
    except SystemExit as exit_:
        assert exit_.code in (0, None)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit_images")
    model = tiny_model()
    truth = true_hand(model)
    frame = write_frame(folder / "f000", render_frame(model, truth))
    model_path, _ = export_trained(model, folder / "model.pt")
    gt = save_mesh(frame / "mesh.ply", mesh_hand(model, truth, 48))
    return {"folder": folder, "frame": frame, "model": model_path, "gt": gt}


def test_writes_params_mesh_and_metrics(lisa, files, tmp_path, capsys):
    out = tmp_path / "out"
    run_ok(lisa, ["fit-images", str(files["frame"]), "--out", str(out), "--model",
                  str(files["model"]), "--gt", str(files["gt"]), *FAST])
    printed = capsys.readouterr().out
    assert "fitted 3 view(s)" in printed and f"wrote {out / 'metrics.json'}" in printed
    params = read_params(out / "params.json")
    assert params.side == "right" and params.color_code is not None
    assert params.model == str(files["model"].resolve()) and params.betas.shape == (10,)
    mesh = load_mesh(out / "mesh.ply")
    assert mesh.colors is not None and mesh.num_faces > 100
    assert mesh.skin_weights is not None and np.allclose(mesh.skin_weights.sum(1), 1, atol=1e-4)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["views"] == ["cam000", "cam001", "cam002"]
    assert metrics["keypoint_error_px"] < 2.0  # few iterations, noiseless keypoints
    assert metrics["psnr_db"] > 20.0 and metrics["psnr_mask_db"] > 15.0
    assert set(metrics["psnr_per_view"]) == {"cam000", "cam001", "cam002"}
    for key in ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
                "v2s_scan_to_recon_mm"):
        assert 0.0 < metrics[key] < 20.0
    assert metrics["v2s_recon_to_scan_mm"] <= metrics["v2v_recon_to_scan_mm"]
    # The surface guard: its verdict (at guard_resolution) and the written mesh's figures.
    guard = metrics["guard"]
    assert guard["passed"] and guard["fallback"] == "none" and guard["pieces"] >= 1
    assert abs(guard["area_ratio"] - 1.0) <= 0.10
    surface = metrics["surface"]
    assert surface["resolution"] == 32 and surface["pieces"] >= 1
    assert abs(surface["area_ratio"] - 1.0) <= 0.10
    assert params.extra["guard"]["attempts"]["color"]["passed"]


def test_one_view_without_keypoints_or_psnr(lisa, files, tmp_path, capsys):
    frame = tmp_path / "frame"
    shutil.copytree(files["frame"], frame)
    (frame / "keypoints.json").unlink()
    out = tmp_path / "out"
    run_ok(lisa, ["fit-images", str(frame), "--out", str(out), "--model", str(files["model"]),
                  "--views", "cam001", "--no-psnr", *FAST])
    printed = capsys.readouterr().out
    assert "no keypoints: the pose comes from the masks alone" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["views"] == ["cam001"] and metrics["keypoint_error_px"] is None
    assert "psnr_db" not in metrics and "v2v_recon_to_scan_mm" not in metrics
    assert read_params(out / "params.json").extra["views"] == ["cam001"]


def test_keypoints_far_outside_the_image_are_dropped(lisa, files, tmp_path, capsys):
    frame = tmp_path / "frame"
    shutil.copytree(files["frame"], frame)
    data = json.loads((frame / "keypoints.json").read_text())
    for index in (4, 8):  # two finger tips marked visible, thousands of pixels away
        data["views"]["cam000"]["keypoints"][index] = [31000.0, -9000.0]
    (frame / "keypoints.json").write_text(json.dumps(data))
    out = tmp_path / "out"
    run_ok(lisa, ["fit-images", str(frame), "--out", str(out), "--model", str(files["model"]),
                  "--no-psnr", *FAST])
    printed = capsys.readouterr().out
    assert "view cam000: 2 keypoint(s) marked visible lie more than 10% of the image" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["keypoint_error_px"] < 2.0  # the other keypoints, fitted as before
    notes = read_params(out / "params.json").extra["input"]["notes"]
    assert any(note.endswith("are left out (thumb_tip, index_tip)") for note in notes)


def _corrupt_model(files, tmp_path):
    path = tmp_path / "broken.pt"
    path.write_bytes(b"not a model")
    return ["--model", str(path)], "broken.pt: not a LISA model file"


def _small_image(files, tmp_path):
    frame = tmp_path / "frame"
    shutil.copytree(files["frame"], frame)
    write_image(frame / "images" / "cam002.png", np.zeros((30, 40, 3), np.uint8))
    return ["--frame", str(frame)], "images/cam002.png: image is 40x30 but camera 'cam002'"


def _no_camera_field(files, tmp_path):
    frame = tmp_path / "frame"
    shutil.copytree(files["frame"], frame)
    cameras = json.loads((frame / "cameras.json").read_text())
    del cameras[0]["t"]
    (frame / "cameras.json").write_text(json.dumps(cameras))
    return ["--frame", str(frame)], "cameras.json: camera 0: missing camera field(s): t"


def _unknown_view(files, tmp_path):
    return ["--views", "cam000,cam7"], "cameras.json: no camera named 'cam7'"


def _missing_gt(files, tmp_path):
    return ["--gt", str(tmp_path / "nope.ply")], "nope.ply: no such file"


def _out_is_a_file(files, tmp_path):
    path = tmp_path / "taken"
    path.write_text("x")
    return ["--out", str(path)], "taken: --out must be a folder"


@pytest.mark.parametrize("case", [_corrupt_model, _small_image, _no_camera_field,
                                  _unknown_view, _missing_gt, _out_is_a_file])
def test_bad_inputs_are_one_line_errors(lisa, files, tmp_path, capsys, case):
    extra, message = case(files, tmp_path)
    options = {"--frame": str(files["frame"]), "--out": str(tmp_path / "out"),
               "--model": str(files["model"])}
    rest = []
    for key, value in zip(extra[::2], extra[1::2], strict=True):
        if key in options:
            options[key] = value
        else:
            rest += [key, value]
    frame = options.pop("--frame")
    argv = ["fit-images", frame, *[x for pair in options.items() for x in pair], *rest, *FAST]
    with pytest.raises(SystemExit) as info:
        lisa(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lisa: error: ") and "\n" not in err and message in err
    assert not (tmp_path / "out").exists()


def test_fit_images_help_lists_the_options(lisa, capsys):
    with pytest.raises(SystemExit) as info:
        lisa(["fit-images", "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for option in ("--views", "--model", "--keypoint-iters", "--color-iters", "--rays",
                   "--device", "--res", "--gt", "--side"):
        assert option in text


@pytest.mark.parametrize("flags, shape_fit, guard", [
    ([], "space", True), (["--shape-fit", "free", "--no-guard"], "free", False),
    (["--shape-fit", "fixed"], "fixed", True)])
def test_shape_fit_and_guard_flags_reach_the_fit(lisa, files, tmp_path, monkeypatch, flags,
                                                 shape_fit, guard):
    import lisa_hand.fitting.images.folder as folder

    seen = {}

    def capture(*args, config=None, **kwargs):
        seen["config"] = config
        raise ValueError("captured")

    monkeypatch.setattr(folder, "fit_image_folder", capture)
    with pytest.raises(SystemExit):
        lisa(["fit-images", str(files["frame"]), "--out", str(tmp_path / "out"), *flags])
    assert (seen["config"].shape_fit, seen["config"].guard) == (shape_fit, guard)


@pytest.mark.parametrize("frames, sides, message", [
    (2, ["right"], "2 frame folder(s) and 1 side(s): give one --side per folder, in order"),
    (2, [], "give one --side per folder, in order"),  # the one default side is not two
    (1, ["right", "left"], "2 --side options for one frame folder: give one"),
])
def test_sides_must_match_the_frame_folders(lisa, files, tmp_path, capsys, frames, sides,
                                            message):
    second = tmp_path / "second"
    shutil.copytree(files["frame"], second)
    folders = [str(files["frame"]), str(second)][:frames]
    out = tmp_path / "out"
    argv = ["fit-images", *folders, "--out", str(out), "--model", str(files["model"]), *FAST]
    for side in sides:
        argv += ["--side", side]
    with pytest.raises(SystemExit) as info:
        lisa(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lisa: error: ") and "\n" not in err and message in err, err
    assert "Traceback" not in err and not out.exists()
