"""``lisa fit-photo`` end to end on synthetic photos (a tiny exported model's hands rendered into
an uncalibrated camera, saved as JPEG, their true 2D keypoints given with --keypoints: no
MediaPipe needed), every output file checked; several hands; and its one-line errors for bad
input, after which nothing is written."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pytest

from lisa_hand.cli import main
from lisa_hand.data.layout import read_mask, write_mask
from lisa_hand.data.meshio import load_mesh
from lisa_hand.metrics import mpjpe, pa_mpjpe
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton import KEYPOINT_NAMES
from lisa_hand.skeleton.params import read_params
from tests.fitting.image_scene import tiny_model
from tests.fitting.photo.photo_scene import (
    FOCAL,
    HEIGHT,
    WIDTH,
    photo_camera,
    photo_hand,
    render_photo,
    save_jpeg,
    save_keypoints,
)

FAST = ["--keypoint-iters", "100", "--color-iters", "3", "--rays", "64", "--res", "32",
        "--device", "cpu", "--no-progress"]
PHOTO_FILES = ["camera.json", "keypoints.json", "mask.png", "mesh.ply", "metrics.json",
               "overlay.png", "params.json", "report.html"]


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture()
def lisa():
    """``lisa_hand.cli.main.main`` (it registers every verb, fit-photo included)."""
    return main.main


def run(lisa, argv, capsys) -> tuple[int, str, str]:
    try:
        lisa(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code or 0
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit_photo")
    model = tiny_model()
    model_path, _ = export_trained(model, folder / "model.pt")
    photo = render_photo(model, [photo_hand(model)])
    two = render_photo(model, [photo_hand(model, (-0.075, 0.0, 0.36), seed=1),
                               photo_hand(model, (0.075, 0.0, 0.36), seed=2)],
                       photo_camera(width=176))
    return {
        "model": model_path, "photo": photo, "two": two,
        "jpeg": save_jpeg(folder / "hand.jpg", photo.image),
        "keypoints": save_keypoints(folder / "hand.keypoints.json", photo.keypoints[0],
                                    side="right"),
        "two_jpeg": save_jpeg(folder / "two.jpg", two.image),
        "two_keypoints": save_keypoints(folder / "two.keypoints.json", two.keypoints,
                                        side="right"),
        "folder": folder,
    }


def fit_args(files, jpeg="jpeg", keypoints="keypoints"):
    return [str(files[jpeg]), "--keypoints", str(files[keypoints]), "--focal-px", str(FOCAL),
            "--model", str(files["model"]), *FAST]


def test_writes_every_output(lisa, files, tmp_path, capsys):
    out = tmp_path / "out"
    code, printed, err = run(lisa, ["fit-photo", *fit_args(files), "--out", str(out)], capsys)
    assert code == 0, err
    assert "fitted a right hand to 1 photo(s)" in printed
    assert f"wrote {out / 'report.html'}" in printed
    assert sorted(p.name for p in out.iterdir()) == PHOTO_FILES
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging left
    truth = files["photo"]

    params = read_params(out / "params.json")
    assert params.side == "right" and params.color_code is not None
    assert params.model == str(files["model"].resolve())
    assert params.extra["input"]["camera_sources"] == ["focal-px"]
    mesh = load_mesh(out / "mesh.ply")
    assert mesh.colors is not None and mesh.num_faces > 100
    assert mesh.skin_weights is not None and np.allclose(mesh.skin_weights.sum(1), 1, atol=1e-4)

    keypoints = json.loads((out / "keypoints.json").read_text())
    assert keypoints["names"] == list(KEYPOINT_NAMES) and keypoints["side"] == "right"
    assert keypoints["image_size"] == [WIDTH, HEIGHT] and keypoints["frame"] == "camera"
    detected = np.asarray(keypoints["keypoints_2d_detected"])
    fitted = np.asarray(keypoints["keypoints_2d_fitted"])
    points_3d = np.asarray(keypoints["keypoints_3d"])
    assert detected.shape == fitted.shape == (21, 2) and points_3d.shape == (21, 3)
    np.testing.assert_allclose(detected, truth.keypoints[0], atol=1e-6)
    error = np.linalg.norm(fitted - truth.keypoints[0], axis=1).mean()
    assert error < 1.5 and keypoints["keypoint_error_px"] == pytest.approx(error)
    projected = points_3d @ truth.camera.K.double().numpy().T
    np.testing.assert_allclose(projected[:, :2] / projected[:, 2:], fitted, atol=1e-3)
    # one view, 100 iterations: the 3D hand roughly (the size from the hand-size prior);
    # measured: MPJPE 11 mm, PA-MPJPE 8 mm, wrist depth 2.4 cm too far
    assert mpjpe(points_3d, truth.keypoints_3d[0]) < 20.0
    assert pa_mpjpe(points_3d, truth.keypoints_3d[0]) < 15.0
    assert abs(points_3d[0, 2] - truth.keypoints_3d[0][0, 2]) < 0.06

    cameras = json.loads((out / "camera.json").read_text())
    assert [entry["image"] for entry in cameras] == ["fitted", "original"]
    assert cameras[1]["K"][0][0] == pytest.approx(FOCAL) and cameras[1]["source"] == "focal-px"
    mask = read_mask(out / "mask.png")
    silhouette = truth.opacity > 0.5
    assert mask.shape == (HEIGHT, WIDTH)
    assert (mask & silhouette).sum() / (mask | silhouette).sum() > 0.6

    from PIL import Image

    overlay = Image.open(out / "overlay.png")
    assert overlay.height >= HEIGHT and overlay.width > 3 * overlay.height * 0.9
    report = (out / "report.html").read_text()
    assert report.count("data:image/png;base64,") == 2  # self-contained: nothing linked
    assert not re.search(r'(src|href)="(?!data:)', report) and "<script" not in report
    for src in re.findall(r'src="data:image/png;base64,([^"]+)"', report):
        assert base64.b64decode(src)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "keypoint error" in report and "focal-px" in report
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["keypoint_error_px"] == pytest.approx(error)
    assert metrics["guard"]["passed"] in (True, False) and metrics["guard"]["pieces"] >= 1
    assert metrics["surface"]["resolution"] == 32 and metrics["surface"]["pieces"] >= 1
    assert metrics["per_photo"][0]["focal_px"] == pytest.approx(FOCAL)
    assert metrics["side_source"] == "--keypoints" and metrics["seconds"] > 0


def test_several_hands_each_into_its_folder_or_one_with_hand(lisa, files, tmp_path, capsys):
    out = tmp_path / "out"
    args = fit_args(files, "two_jpeg", "two_keypoints")
    code, printed, err = run(lisa, ["fit-photo", *args, "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["hand0", "hand1", "hands.json",
                                                      "hands.ply", "overlay.png"]
    hands = json.loads((out / "hands.json").read_text())
    assert [(hand["folder"], hand["side"]) for hand in hands["hands"]] == [
        ("hand0", "right"), ("hand1", "right")]
    assert hands["right_to_left_m"] is None  # two right hands: no right-to-left offset
    assert 0.0 <= hands["penetration_mm"] < 1.0  # hands apart
    assert "2 right hands in one photo" in printed
    two = files["two"]
    for index in (0, 1):
        folder = out / f"hand{index}"
        assert sorted(p.name for p in folder.iterdir()) == PHOTO_FILES
        keypoints = json.loads((folder / "keypoints.json").read_text())
        fitted = np.asarray(keypoints["keypoints_2d_fitted"])
        assert np.linalg.norm(fitted - two.keypoints[index], axis=1).mean() < 2.0
    assert printed.count("fitted a right hand") == 2

    single = tmp_path / "single"
    code, _, err = run(lisa, ["fit-photo", *args, "--out", str(single), "--hand", "1"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in single.iterdir()) == PHOTO_FILES
    keypoints = json.loads((single / "keypoints.json").read_text())
    np.testing.assert_allclose(keypoints["keypoints_2d_detected"], two.keypoints[1], atol=1e-6)
    # a reused folder is replaced as a whole: hand folders of the first fit go
    code, _, err = run(lisa, ["fit-photo", *args, "--out", str(out), "--hand", "0"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == PHOTO_FILES


def test_a_given_mask_is_used_and_written_as_it_is(lisa, files, tmp_path, capsys):
    truth = files["photo"]
    given = write_mask(tmp_path / "given.png", truth.opacity > 0.5)
    plain = tmp_path / "plain.json"  # a bare 21 x 2 list, the side from --side
    plain.write_text(json.dumps(truth.keypoints[0].tolist()))
    out = tmp_path / "out"
    code, printed, err = run(lisa, ["fit-photo", str(files["jpeg"]), "--out", str(out),
                                    "--keypoints", str(plain), "--mask", str(given),
                                    "--side", "right", "--model", str(files["model"]), *FAST],
                             capsys)
    assert code == 0, err
    assert "side: right (--side)" in printed
    assert np.array_equal(read_mask(out / "mask.png"), truth.opacity > 0.5)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["mask"] == "--mask" and metrics["side_source"] == "--side"
    assert metrics["per_photo"][0]["camera_source"] == "default"  # no --focal-px this time
    assert metrics["keypoint_error_px"] < 2.0


# Bad inputs: (name, arguments replacing the defaults, setup(files, tmp_path, monkeypatch) ->
# extra args, message).


def _not_an_image(files, tmp_path, monkeypatch):
    path = tmp_path / "notes.jpg"
    path.write_text("these are not pixels")
    return {"photo": path}, "notes.jpg: not an image file"


def _truncated_jpeg(files, tmp_path, monkeypatch):
    path = tmp_path / "cut.jpg"
    data = files["jpeg"].read_bytes()
    path.write_bytes(data[:int(0.6 * len(data))])  # the pixel data cut short
    return {"photo": path}, "cut.jpg: truncated or corrupt image file"


def _no_hand_found(files, tmp_path, monkeypatch):
    from lisa_hand.data import detect

    monkeypatch.setattr(detect, "photo_extra_missing", lambda: None)
    monkeypatch.setattr(detect, "detect_hands", lambda image, max_hands=4: [])
    return {"keypoints": None}, "hand.jpg: no hand found"


def _photo_extra_missing(files, tmp_path, monkeypatch):
    from lisa_hand.data import detect

    monkeypatch.setattr(detect, "photo_extra_missing", lambda: detect.PHOTO_EXTRA_HINT)
    return {"keypoints": None}, "pip install -e '.[photo]'; or give the 21 keypoints with " \
                                "--keypoints"


def _hand_too_small(files, tmp_path, monkeypatch):
    points = files["photo"].keypoints[0]
    small = points.mean(0) + 0.08 * (points - points.mean(0))
    return ({"keypoints": save_keypoints(tmp_path / "small.json", small, "right")},
            "the hand is too small to fit")


def _keypoints_malformed(files, tmp_path, monkeypatch):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"keypoints": [[1.0, 2.0]] * 20}))
    return {"keypoints": path}, r"bad.json: keypoints must be [21, 2] pixels (u, v)"


def _keypoints_not_json(files, tmp_path, monkeypatch):
    path = tmp_path / "bad.json"
    path.write_text("{'keypoints': ")
    return {"keypoints": path}, "bad.json: not valid JSON"


def _keypoints_normalised(files, tmp_path, monkeypatch):
    points = files["photo"].keypoints[0] / [WIDTH, HEIGHT]
    return ({"keypoints": save_keypoints(tmp_path / "unit.json", points)},
            "the keypoints look normalised to [0, 1]")


def _hand_out_of_range(files, tmp_path, monkeypatch):
    return {"extra": ["--hand", "3"]}, "--hand 3, but 1 hand(s) were found"


def _mask_wrong_size(files, tmp_path, monkeypatch):
    path = write_mask(tmp_path / "mask.png", np.ones((10, 12), bool))
    return {"extra": ["--mask", str(path)]}, "mask.png: mask is 12x10 but the photo hand.jpg"


def _out_is_a_file(files, tmp_path, monkeypatch):
    path = tmp_path / "out"
    path.write_text("x")
    return {}, "out: --out must be a folder"


def _out_holds_other_files(files, tmp_path, monkeypatch):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    return {}, "output folder holds files a fit does not write (notes.txt)"


@pytest.mark.parametrize("case", [_not_an_image, _truncated_jpeg, _no_hand_found,
                                  _photo_extra_missing, _hand_too_small, _keypoints_malformed,
                                  _keypoints_not_json, _keypoints_normalised,
                                  _hand_out_of_range, _mask_wrong_size, _out_is_a_file,
                                  _out_holds_other_files])
def test_bad_inputs_are_one_line_errors_and_write_nothing(lisa, files, tmp_path, capsys,
                                                          monkeypatch, case):
    import lisa_hand.model.trained

    changes, message = case(files, tmp_path, monkeypatch)

    def refuse(*args, **kwargs):
        raise AssertionError("the model was loaded before the input was checked")

    monkeypatch.setattr(lisa_hand.model.trained, "load_trained", refuse)
    photo = changes.get("photo", files["jpeg"])
    keypoints = changes.get("keypoints", files["keypoints"])
    argv = ["fit-photo", str(photo), "--out", str(tmp_path / "out"), "--model",
            str(files["model"]), *FAST, *changes.get("extra", [])]
    if keypoints is not None:
        argv += ["--keypoints", str(keypoints)]
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run(lisa, argv, capsys)
    assert code == 2, err
    assert err.startswith("lisa: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written
    if (tmp_path / "out").is_dir():
        assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["notes.txt"]


def test_help_explains_the_options(lisa, capsys):
    code, text, _ = run(lisa, ["fit-photo", "--help"], capsys)
    assert code == 0
    for option in ("--out", "--side", "--camera", "--focal-px", "--fov", "--keypoints",
                   "--mask", "--hand", "--model", "--device", "--shape-fit", "--no-guard",
                   "ORIGINAL", "pip install"):
        assert option in text, option
