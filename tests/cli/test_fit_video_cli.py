"""``lisa fit-video`` end to end on the real clip of ``tests/assets/videos`` (MediaPipe, the
photo extra, finds its right hand in every frame; the shipped default model): 15 frames fitted
once, every output file checked; and its one-line errors for bad input, after which nothing is
written."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from lisa_hand.cli import main
from lisa_hand.data.detect import photo_extra_missing
from lisa_hand.skeleton.params import read_params
from tests.assets import ASSETS

cv2 = pytest.importorskip("cv2")

CLIP = ASSETS / "videos" / "hand_landmarker_test_video.mp4"  # 640 x 360, 25 fps, 202 frames
VIDEO_FILES = ["hand.glb", "mesh.ply", "metrics.json", "overlay.mp4", "params.json",
               "report.html", "track.json"]
FAST = ["--no-progress", "--device", "cpu", "--threads", "1"]
needs_mediapipe = pytest.mark.skipif(photo_extra_missing() is not None,
                                     reason="the photo extra (MediaPipe) is not installed")


def run(argv: list[str]) -> tuple[int, str, str]:
    """``lisa ARGV`` in this process -> (exit code, stdout, stderr as Python wrote them)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main.main(argv)
            code = 0
        except SystemExit as exit_:
            code = exit_.code or 0
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """One fit of 6.0-6.6 s of the clip (15 frames, rows 150-164): (exit code, stdout, stderr,
    the output folder)."""
    folder = tmp_path_factory.mktemp("fit_video") / "out"
    code, out, err = run(["fit-video", str(CLIP), "--out", str(folder), "--start", "6",
                          "--end", "6.6", *FAST])
    return code, out, err, folder


@pytest.fixture(scope="module")
def track(fitted):
    return json.loads((fitted[3] / "track.json").read_text())


@needs_mediapipe
def test_fit_writes_every_file(fitted):
    code, out, err, folder = fitted
    assert code == 0, err
    assert sorted(path.name for path in folder.iterdir()) == VIDEO_FILES
    assert all((folder / name).stat().st_size > 0 for name in VIDEO_FILES)
    assert "hand 0 (right): fitted in 15 of 15 frames" in out
    assert out.count("wrote ") == len(VIDEO_FILES)
    assert (folder / "hand.glb").read_bytes()[:4] == b"glTF"
    assert "<html" in (folder / "report.html").read_text().lower()
    assert not list(folder.parent.glob(".*"))  # no lock or staging folder left beside it


@needs_mediapipe
def test_track_json_frames(fitted, track):
    assert fitted[0] == 0, fitted[2]
    assert track["fps"] == 25.0 and (track["width"], track["height"]) == (640, 360)
    frames = track["frames"]
    assert [frame["index"] for frame in frames] == list(range(150, 165))
    times = np.array([frame["time_s"] for frame in frames])
    np.testing.assert_allclose(times, np.arange(150, 165) / 25.0, atol=1e-3)
    assert (np.diff(times) > 0).all()
    assert [hand["side"] for hand in track["hands"]] == ["right"]
    # The hand's shape and colour come from a few of its best-seen frames across the 15: the
    # best-seen one and the best of the other two thirds (it is large in every frame).
    (record,) = track["hands"]
    keyframes = [key["index"] for key in record["keyframes"]]
    assert record["keyframe"]["index"] in keyframes and len(keyframes) == 3
    assert keyframes == sorted(set(keyframes)) and 150 <= keyframes[0] < keyframes[-1] < 165
    thirds = [(index - 150) // 5 for index in keyframes]
    assert thirds == [0, 1, 2]
    for frame in frames:
        (hand,) = frame["hands"]
        assert hand["side"] == "right" and hand["identity"] == 0 and hand["detected"]
        assert len(hand["pose"]) == 48 and len(hand["translation"]) == 3
        points_3d, points_2d = np.array(hand["keypoints_3d"]), np.array(hand["keypoints_2d"])
        assert points_3d.shape == (21, 3) and points_2d.shape == (21, 2)
        assert (points_3d[:, 2] > 0.05).all() and np.isfinite(points_3d).all()
        assert (points_2d > -20).all() and (points_2d[:, 0] < 660).all()
        assert (points_2d[:, 1] < 380).all()


@needs_mediapipe
def test_track_json_2d_keypoints_are_the_3d_ones_projected(fitted, track):
    """keypoints_2d are keypoints_3d seen by the file's own camera (K in the clip's pixels)."""
    assert fitted[0] == 0, fitted[2]
    K = np.array(track["camera"]["K"])
    assert K.shape == (3, 3) and K[0, 2] == pytest.approx(320.0) and K[1, 2] == pytest.approx(180)
    for frame in track["frames"]:
        (hand,) = frame["hands"]
        points = np.array(hand["keypoints_3d"]) @ K.T
        np.testing.assert_allclose(points[:, :2] / points[:, 2:], hand["keypoints_2d"],
                                   atol=0.1)


@needs_mediapipe
def test_params_overlay_and_metrics(fitted):
    code, _, err, folder = fitted
    assert code == 0, err
    params = read_params(folder / "params.json")
    assert params.side == "right" and params.pose.shape == (48,)
    video = params.extra["video"]
    assert video["keyframe"] in video["keyframes"] and len(video["keyframes"]) == 3
    assert 0.1 < float(params.translation[2]) < 2.0
    capture = cv2.VideoCapture(str(folder / "overlay.mp4"))
    count = 0
    while True:
        ok, bgr = capture.read()
        if not ok:
            break
        assert bgr.shape == (360, 640, 3)
        count += 1
    capture.release()
    assert count == 15
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["frames"] == 15
    (hand,) = metrics["hands"]
    assert hand["side"] == "right" and hand["frames_fitted"] == 15
    assert hand["keyframes"] == sorted(key["index"] for key in
                                       json.loads((folder / "track.json").read_text())["hands"][0]
                                       ["keyframes"])
    assert hand["agreement_px"] < 6.0  # measured 1.4 px
    assert np.isfinite(hand["jitter_mm_per_frame2"])


@needs_mediapipe
def test_params_skeleton_is_the_tracks(fitted, track):
    """One skeleton through the clip: params.json's, posed at each frame's pose and
    translation, gives that frame's keypoints in track.json (the motion fitted them with it)."""
    from dataclasses import replace

    import torch

    from lisa_hand.fitting.outputs import hand_keypoints_3d

    assert fitted[0] == 0, fitted[2]
    params = read_params(fitted[3] / "params.json")
    for frame in track["frames"][::7]:
        (hand,) = frame["hands"]
        posed = replace(params, pose=torch.tensor(hand["pose"], dtype=params.pose.dtype),
                        translation=torch.tensor(hand["translation"],
                                                 dtype=params.translation.dtype))
        np.testing.assert_allclose(hand_keypoints_3d(posed), hand["keypoints_3d"], atol=2e-5)


# --- bad input: one line, exit code 2, nothing written -------------------------------------


def refuse_the_model(monkeypatch):
    import lisa_hand.model.trained

    def refuse(*args, **kwargs):
        raise AssertionError("the model was loaded before the input was checked")

    monkeypatch.setattr(lisa_hand.model.trained, "load_trained", refuse)


def check_refused(argv: list[str], tmp_path, message: str) -> None:
    before = sorted(path.name for path in tmp_path.iterdir())
    code, _, err = run(argv)
    assert code == 2, err
    assert err.startswith("lisa: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert sorted(path.name for path in tmp_path.iterdir()) == before  # no folder, no lock


def test_not_a_video(tmp_path, monkeypatch):
    refuse_the_model(monkeypatch)
    (tmp_path / "x.mp4").write_text("these are not frames\n")
    check_refused(["fit-video", str(tmp_path / "x.mp4"), "--out", str(tmp_path / "out"),
                   *FAST], tmp_path, "x.mp4: not a video")


def test_start_after_the_end_of_the_clip(tmp_path, monkeypatch):
    refuse_the_model(monkeypatch)
    check_refused(["fit-video", str(CLIP), "--out", str(tmp_path / "out"), "--start", "20",
                   *FAST], tmp_path, "hand_landmarker_test_video.mp4: no frame after 20 s")


@needs_mediapipe
def test_frames_without_a_hand(tmp_path, monkeypatch):
    from PIL import Image

    refuse_the_model(monkeypatch)
    frames = tmp_path / "grey"
    frames.mkdir()
    for number in range(5):
        Image.new("RGB", (160, 120), (128, 128, 128)).save(frames / f"frame{number}.png")
    out = tmp_path / "out"
    check_refused(["fit-video", str(frames), "--out", str(out), *FAST], tmp_path,
                  "grey: no hand found in any of its 5 frames")
    # An output folder that exists is left as it was (empty).
    out.mkdir()
    check_refused(["fit-video", str(frames), "--out", str(out), *FAST], tmp_path,
                  "no hand found")
    assert list(out.iterdir()) == []
