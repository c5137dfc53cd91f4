"""The photo benchmark's pieces: synthetic photos with ground truth, the figures it reads from a
fit's files, and its plumbing with a stand-in fit (the real fit is measured by the benchmark)."""

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from PIL import Image

from lisa_hand.bench._photo_scenes import (
    PhotoSceneConfig,
    held_out_subjects,
    make_photo,
    photo_orientation,
)
from lisa_hand.bench.photo import (
    detector_wrist_shift,
    keypoint_error_px,
    reference_keypoints,
    run_photo_benchmark,
)
from lisa_hand.geometry.rotations import axis_angle_to_matrix
from lisa_hand.handmodel import OpenHand
from lisa_hand.metrics import pa_mpjpe

# Small, coarse photos: the same scenes, cheap to make.
SMALL = PhotoSceneConfig(width=320, height=240, voxels_per_length=60.0)


def test_held_out_subjects_are_not_the_shipped_models():
    from lisa_hand.model.trained import load_trained

    trained = load_trained(None, "cpu")
    geometry = load_trained("geometry", "cpu")
    held_out = {f"s{index:03d}" for index in held_out_subjects()}
    assert len(held_out) == 6 and len(trained.subject_ids) == 51
    assert held_out.isdisjoint(trained.subject_ids)
    assert held_out.isdisjoint(geometry.subject_ids)


def test_training_subjects_photos_are_not_the_benchmarks():
    from lisa_hand.fitting.photo.detect import to_skeleton_wrist

    train = held_out_subjects("train")
    assert len(train) == 6 and set(train).isdisjoint(held_out_subjects())
    with pytest.raises(ValueError, match="subjects"):
        PhotoSceneConfig(subjects="val")
    # The wrist offset the bench reports is the one to_skeleton_wrist undoes.
    rng = np.random.default_rng(1)
    true = rng.uniform(0, 500, size=(21, 2))
    detected = true.copy()
    detected[0] = true[0] + 0.2 * (true[9] - true[0]) + 3.0 * np.array(
        [true[9, 1] - true[0, 1], true[0, 0] - true[9, 0]]) / np.linalg.norm(true[9] - true[0])
    assert detector_wrist_shift(detected, true) == pytest.approx(0.2)  # across: not counted
    along = true.copy()
    along[0] = true[0] + 0.2 * (true[9] - true[0])
    np.testing.assert_allclose(to_skeleton_wrist(along, 0.2), true, atol=1e-9)


@pytest.mark.parametrize("side", ["right", "left"])
def test_orientation_fingers_up_palm_to_camera(side):
    config = PhotoSceneConfig(max_turn_deg=0.0, max_tilt_deg=0.0, max_roll_deg=0.0)
    rotation = axis_angle_to_matrix(torch.from_numpy(
        photo_orientation(np.random.default_rng(0), side, False, config))).numpy()
    keypoints = OpenHand(side=side).posed().keypoints.numpy() @ rotation.T
    wrist, thumb_tip, middle_tip, pinky_tip = keypoints[[0, 4, 12, 20]]
    # Fingers up in the image (camera y points down), the palm facing the camera (-z): a hand
    # held up to a phone, its thumb on the right for a right hand (on the left for a left one).
    assert middle_tip[1] - wrist[1] < -0.15
    assert abs(middle_tip[0] - wrist[0]) < 0.02 and abs(middle_tip[2] - wrist[2]) < 0.02
    thumb_right = thumb_tip[0] > pinky_tip[0]
    assert thumb_right == (side == "right")
    back = axis_angle_to_matrix(torch.from_numpy(
        photo_orientation(np.random.default_rng(0), side, True, config))).numpy()
    back_keypoints = OpenHand(side=side).posed().keypoints.numpy() @ back.T
    assert (back_keypoints[4, 0] > back_keypoints[20, 0]) != thumb_right


def test_make_photo_ground_truth(tmp_path):
    photo = make_photo(SMALL, 0, tmp_path)
    assert photo.path == tmp_path / "photo_000.jpg" and photo.side == "right"
    assert photo.subject == f"s{held_out_subjects()[0]:03d}"
    with Image.open(photo.path) as image:
        assert image.format == "JPEG" and image.size == (320, 240)
        assert len(image.getexif()) == 0  # no EXIF: no focal length for the fit
        pixels = np.asarray(image.convert("RGB"), np.float64) / 255.0
    # The 2D keypoints are the pinhole projections of the 3D ones (camera frame = world).
    projected = photo.keypoints_3d @ photo.K.T
    np.testing.assert_allclose(photo.keypoints_2d, projected[:, :2] / projected[:, 2:], atol=1e-3)
    assert 60.0 <= photo.fov_deg <= 70.0
    assert photo.K[0, 0] == pytest.approx(160.0 / math.tan(math.radians(photo.fov_deg) / 2))
    centre = 0.5 * (photo.keypoints_3d.min(0) + photo.keypoints_3d.max(0))
    assert 0.4 <= centre[2] <= 0.6
    assert (photo.keypoints_2d > 0).all() and (photo.keypoints_2d < [320, 240]).all()
    assert photo.visible.sum() >= 12
    # A plain background: the corners agree; the hand at the middle knuckle differs from it.
    corners = pixels[[2, 2, -3, -3], [2, -3, 2, -3]]
    assert np.abs(corners - corners.mean(0)).max() < 0.1
    u, v = photo.keypoints_2d[9].astype(int)
    assert np.abs(pixels[v - 1:v + 2, u - 1:u + 2].mean((0, 1)) - corners.mean(0)).max() > 0.05
    # Every other photo is a left hand; the next pair has a textured background.
    second = make_photo(SMALL, 1, tmp_path)
    assert second.side == "left" and not second.textured and make_photo(SMALL, 2, tmp_path).textured
    # The same index gives the same photo.
    again = make_photo(SMALL, 0, tmp_path / "again")
    np.testing.assert_array_equal(again.keypoints_3d, photo.keypoints_3d)


def test_keypoint_error_px():
    detected = np.zeros((21, 2))
    fitted = detected + np.array([3.0, 4.0])
    fitted[5] = np.nan  # not fitted: left out
    record = {"keypoints_2d_detected": detected.tolist(),
              "keypoints_2d_fitted": [[None if math.isnan(v) else v for v in row]
                                      for row in fitted]}
    record = json.loads(json.dumps(record).replace("null", "NaN"))
    assert keypoint_error_px(record) == pytest.approx(5.0)
    with pytest.raises(ValueError, match="keypoints.json"):
        keypoint_error_px({"keypoints_2d_detected": [[0, 0]], "keypoints_2d_fitted": [[0, 0, 0]]})


def test_reference_keypoints():
    right, left = reference_keypoints("right"), reference_keypoints("left")
    assert right.shape == (21, 3)
    np.testing.assert_allclose(left, right * np.array([-1.0, 1.0, 1.0]), atol=1e-12)
    length = np.linalg.norm(right[12] - right[0])  # wrist to middle fingertip
    assert 0.15 < length < 0.21
    assert pa_mpjpe(right, right) == pytest.approx(0.0, abs=1e-6)


def _stand_in_fit(calls):
    """A fit that writes the reference hand as its result (and a 3-4-5 px reprojection error)."""

    def fit(photos, out_dir, *, side="auto", keypoints_json=None, progress=True, log=print,
            **options):
        calls.append({"photo": Path(photos[0]).name, "side": side,
                      "keypoints_json": keypoints_json, **options})
        assert progress is False
        if Path(photos[0]).name == "broken.jpg":
            raise ValueError(f"{photos[0]}: no hand found")
        hand = Path(out_dir) / "hand0"
        hand.mkdir(parents=True)
        fitted_side = "right" if side == "auto" else side
        keypoints_3d = reference_keypoints(fitted_side) + np.array([0.0, 0.0, 0.5])
        detected = np.full((21, 2), 100.0)
        (hand / "keypoints.json").write_text(json.dumps({
            "keypoints_3d": keypoints_3d.tolist(), "side": fitted_side,
            "keypoints_2d_detected": detected.tolist(),
            "keypoints_2d_fitted": (detected + [3.0, 4.0]).tolist()}))
        guard = SimpleNamespace(pieces=1, area_ratio=1.04, passed=True)
        return [SimpleNamespace(guard=guard)]

    return fit


def test_benchmark_plumbing_true_keypoints(tmp_path):
    calls = []
    result = run_photo_benchmark(2, shared_dir=tmp_path / "absent", work_dir=tmp_path,
                                 threads=1, detect=False, fit=_stand_in_fit(calls), scene=SMALL,
                                 log=lambda *_: None)
    # Without detection the fit gets the true side and the true 2D keypoints.
    assert [call["side"] for call in calls] == ["right", "left"]
    given = json.loads(Path(calls[1]["keypoints_json"]).read_text())
    assert given["side"] == "left" and len(given["keypoints"]) == 21
    assert result.detection == "true-keypoints" and result.shared == {} and result.failed == 0
    # The stand-in's answer is the reference hand: the same PA-MPJPE as the reference.
    for row in result.synthetic:
        assert row.pa_mpjpe_mm == pytest.approx(row.reference_pa_mpjpe_mm, rel=1e-9)
        assert row.pa_mpjpe_mm > 5.0 and row.mpjpe_mm >= row.pa_mpjpe_mm
    assert result.targets["pa_mpjpe_under_5_mm"] is False
    assert result.targets["one_piece_on_real_photos"] is None
    assert all("config" not in call for call in calls)
    # --set: every fit gets the overridden config.
    from lisa_hand.fitting.photo.fit import FitPhotoConfig
    from lisa_hand.utils.config import apply_overrides

    config = apply_overrides(FitPhotoConfig(), ["fit.color_iters=7"])
    calls = []
    run_photo_benchmark(1, shared_dir=tmp_path / "absent", work_dir=tmp_path / "set", threads=1,
                        detect=False, fit=_stand_in_fit(calls), scene=SMALL, config=config,
                        log=lambda *_: None)
    assert [call["config"].fit.color_iters for call in calls] == [7]
    assert calls[0]["config"].fit.keypoint_iters == FitPhotoConfig().fit.keypoint_iters


def test_benchmark_plumbing_shared_photos(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "hand_thumb_up.jpg").write_bytes(b"stand-in")
    calls = []
    result = run_photo_benchmark(0, shared_dir=shared, work_dir=tmp_path / "work", threads=1,
                                 detect=True, fit=_stand_in_fit(calls), log=lambda *_: None)
    assert [call["photo"] for call in calls] == ["hand_thumb_up.jpg"]
    row = result.shared["hand_thumb_up.jpg"]
    assert (row.pieces, row.area_ratio, row.guard_passed) == (1, 1.04, True)
    assert row.keypoint_error_px == pytest.approx(5.0)
    assert result.targets == {"seconds_per_photo_under_30": True, "pa_mpjpe_under_5_mm": None,
                              "one_piece_on_real_photos": True}
    assert any("thumbs-up.png skipped" in note for note in result.notes)
