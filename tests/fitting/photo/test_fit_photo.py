"""The photo fit below the command line: the --keypoints formats, the crop the fit sees, the 3D
keypoints every fit writes, several photos of one hand (cameras placed by the hand), the side
chosen by fitting both, all-or-nothing writing, and a real photo (``tests/assets/photos``; needs
MediaPipe)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from lisa_hand.data.keypoints import write_keypoints
from lisa_hand.data.photo import photo_camera, read_photo
from lisa_hand.fitting.outputs import (
    FIT_FILES,
    hand_keypoints_3d,
    keypoints_3d_record,
    write_fit_outputs,
)
from lisa_hand.fitting.photo.fit import FitPhotoConfig, fit_photo_folder, photo_fit_defaults
from lisa_hand.fitting.photo.inputs import PhotoHand, crop_view, read_given_hands
from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.skeleton import KEYPOINT_NAMES, forward_kinematics, mirror_points
from lisa_hand.skeleton.params import read_params
from tests.assets import PHOTOS
from tests.fitting.image_scene import load_float_template, tiny_model
from tests.fitting.photo.photo_scene import (
    FOCAL,
    hand_keypoints,
    photo_hand,
    render_photo,
    save_jpeg,
    save_keypoints,
)
from tests.fitting.photo.photo_scene import (
    photo_camera as true_camera,
)


def fast_config(**overrides) -> FitPhotoConfig:
    fit = photo_fit_defaults(**{"keypoint_iters": 100, "color_iters": 3, "num_rays": 64,
                                "rotation_pool": 512, "restarts": 6, **overrides})
    return FitPhotoConfig(fit=fit, mesh_resolution=32, render_max_side=64)


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    from lisa_hand.model.trained import export_trained

    model = tiny_model()
    path, _ = export_trained(model, tmp_path_factory.mktemp("model") / "model.pt")
    return model, path


@pytest.fixture(scope="module")
def big_photo(tmp_path_factory):
    """A 2000 x 1000 photo, read downscaled to 1600 x 800 (0.8 image pixels per original)."""
    path = save_jpeg(tmp_path_factory.mktemp("big") / "big.jpg",
                     np.full((1000, 2000, 3), 0.5, np.float32))
    return read_photo(path)


def hand_points(offset=(1000.0, 500.0), size=300.0) -> np.ndarray:
    """21 plausible keypoints (the template's flat hand seen from the palm), pixels."""
    template = load_float_template()
    keypoints = template.forward(torch.zeros(1, 48), torch.zeros(1, template.num_betas)
                                 ).keypoints[0].double().numpy()
    return np.stack([keypoints[:, 2], keypoints[:, 0]], 1) / 0.18 * size + offset


def test_keypoints_files_in_every_accepted_form(big_photo, tmp_path):
    points = hand_points()
    expected = points * 0.8  # original -> image pixels
    confidence = np.ones(21)
    confidence[[4, 8]] = 0.0
    openpose = np.concatenate([points, confidence[:, None]], 1).reshape(-1)
    write_keypoints(tmp_path / "frame.json", {"big": {"keypoints": points,
                                                      "visible": [True] * 21}})
    forms = {
        "list.json": (points.tolist(), None, 21),
        "dict.json": ({"keypoints": points.tolist(), "side": "left"}, "left", 21),
        "scored.json": ({"keypoints": np.concatenate([points, confidence[:, None]], 1).tolist()},
                        None, 19),
        "hands.json": ({"hands": [{"keypoints": points.tolist(), "side": "right"}]}, "right",
                       21),
        "fitted.json": ({"names": list(KEYPOINT_NAMES), "keypoints_2d_detected":
                         points.tolist(), "side": "right"}, "right", 21),
        "openpose.json": ({"people": [{"hand_left_keypoints_2d": openpose.tolist(),
                                       "hand_right_keypoints_2d": [0.0] * 63}]}, "left", 19),
    }
    for name, (data, side, visible) in forms.items():
        (tmp_path / name).write_text(json.dumps(data))
        hands = read_given_hands(tmp_path / name, big_photo)
        assert len(hands) == 1, name
        hand = hands[0]
        assert hand.side == side and int(hand.visible.sum()) == visible, name
        np.testing.assert_allclose(hand.keypoints[hand.visible], expected[hand.visible],
                                   atol=1e-9)
        assert np.isfinite(hand.keypoints).all()  # hidden ones hold stand-ins
    frame = read_given_hands(tmp_path / "frame.json", big_photo)[0]
    np.testing.assert_allclose(frame.keypoints, expected, atol=1e-9)
    (tmp_path / "two.json").write_text(json.dumps([{"keypoints": points.tolist()},
                                                   {"keypoints": (points + 5).tolist()}]))
    assert len(read_given_hands(tmp_path / "two.json", big_photo)) == 2


@pytest.mark.parametrize("data, message", [
    ([[0.4, 0.6]] * 21, "the keypoints look normalised to [0, 1]"),
    ({"keypoints": [[10.0, 20.0, 0.0]] * 21}, "only 0 visible keypoint(s); at least 8"),
    ({"keypoints": [[10.0, 5000.0]] * 21}, "21 visible keypoint(s) lie outside the photo "
                                           "(2000x1000 pixels, upright)"),
    ({"keypoints": [[10.0, "x"]] * 21}, "keypoints must be numbers"),
    ({"hands": []}, "'hands' must be a non-empty list"),
    ({"keypoints": [[10.0, 20.0]] * 21, "side": "middle"}, "'side' must be 'right' or 'left'"),
    ({"views": {"cam000": {"keypoints": [[10.0, 20.0]] * 21}}, "other": 1}, None),
    ({"views": {"a": {"keypoints": [[1.0, 2.0]] * 21}, "b": {}}}, "no view named 'big'"),
    ({"pose": [0.0] * 48}, "no keypoints found; expected a list of 21 [u, v]"),
])  # fmt: skip
def test_malformed_keypoints_files_are_one_line_errors(big_photo, tmp_path, data, message):
    path = tmp_path / "kp.json"
    path.write_text(json.dumps(data))
    if message is None:  # a frame's keypoints.json with one view: that view is the photo's
        assert len(read_given_hands(path, big_photo)) == 1
        return
    with pytest.raises(ValueError) as info:
        read_given_hands(path, big_photo)
    assert str(info.value).startswith(str(path)) and message in str(info.value)
    assert "\n" not in str(info.value)


def test_crop_view_is_the_photo_seen_through_a_shifted_scaled_camera(big_photo):
    camera, source = photo_camera(big_photo, focal_px=1500.0)
    assert source == "focal-px"
    points = hand_points(offset=(1400.0, 300.0), size=500.0) * 0.8
    hand = PhotoHand(keypoints=points, visible=np.ones(21, bool), side=None, score=None,
                     source="test")
    mask = np.zeros(big_photo.image.shape[:2], bool)
    mask[200:400, 1000:1300] = True
    crop = crop_view(big_photo, camera, hand, mask, "big", margin=0.5, max_side=200)
    view = crop.view
    assert max(view.width, view.height) == 200 and view.mask is not None
    world = torch.tensor([[0.03, -0.02, 0.4], [-0.05, 0.01, 0.6]])
    full, _ = camera.project(world)
    cropped, _ = view.camera.project(world)
    np.testing.assert_allclose(crop.to_image(cropped.numpy()), full.numpy(), atol=1e-3)
    np.testing.assert_allclose(crop.to_image(view.keypoints.numpy()), points, atol=1e-3)
    x0, y0, x1, y1 = crop.box
    assert x0 <= points[:, 0].min() and x1 >= points[:, 0].max() and y0 >= 0
    assert view.mask.float().mean() > 0


def test_every_fit_writes_the_fitted_3d_keypoints(tmp_path):
    template = load_float_template().to(dtype=torch.float64)
    generator = torch.Generator().manual_seed(3)
    betas = 0.5 * torch.randn(template.num_betas, generator=generator, dtype=torch.float64)
    from lisa_hand.handmodel.poses import sample_pose
    from lisa_hand.skeleton.params import HandParams

    pose = sample_pose(generator, 1, global_orient=True)[0].double()
    hand = HandParams(pose=pose, translation=torch.tensor([0.1, -0.05, 0.4]),
                      rest_joints=template.rest_joints(betas[None])[0], betas=betas,
                      shape_code=torch.zeros(4))
    truth = template.forward(hand.pose[None].double(), hand.betas[None].double(),
                             hand.translation[None].double()).keypoints[0].numpy()
    np.testing.assert_allclose(hand_keypoints_3d(hand), truth, atol=1e-6)
    left = mirror_hand(hand)  # a left hand's keypoints are the mirror image
    np.testing.assert_allclose(hand_keypoints_3d(left), mirror_points(
        torch.from_numpy(truth)).numpy(), atol=1e-6)
    # a fixed skeleton (no betas): the joints are its forward kinematics
    fixed = HandParams(pose=pose, translation=torch.zeros(3),
                       rest_joints=1.1 * template.rest_joints(betas[None])[0],
                       shape_code=torch.zeros(4))
    joints = forward_kinematics(fixed.pose.double()[None], fixed.rest_joints.double()[None]
                                ).joints[0].numpy()
    keypoints = hand_keypoints_3d(fixed)
    np.testing.assert_allclose(keypoints[[0, 5, 9, 13, 17]], joints[[0, 1, 4, 10, 7]],
                               atol=1e-6)
    assert np.linalg.norm(keypoints[12] - keypoints[0]) > 0.15  # a fingertip, not a joint

    assert "keypoints.json" in FIT_FILES
    mesh = Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]]))
    written = write_fit_outputs(tmp_path / "fit", hand, mesh, {"psnr_db": 30.0})
    assert [path.name for path in written] == ["params.json", "mesh.ply", "keypoints.json",
                                               "metrics.json"]
    record = json.loads((tmp_path / "fit" / "keypoints.json").read_text())
    assert record["names"] == list(KEYPOINT_NAMES) and record["frame"] == "world"
    assert record["units"] == "m" and "world frame of the input" in record["note"]
    np.testing.assert_allclose(record["keypoints_3d"], truth, atol=1e-6)
    assert record == json.loads(json.dumps(keypoints_3d_record(hand)))


def rotation_about(axis: str, degrees: float) -> torch.Tensor:
    vector = torch.zeros(3)
    vector["xyz".index(axis)] = math.radians(degrees)
    return axis_angle_to_matrix(vector)


def test_several_photos_of_one_hand_place_their_cameras(model_file, tmp_path):
    model, path = model_file
    hand = photo_hand(model)
    centre = hand_keypoints(hand).mean(0)
    rotation = rotation_about("y", 30.0)  # camera B: turned 30 degrees about the hand
    shift = centre - rotation @ centre
    photos = [render_photo(model, [hand]),
              render_photo(model, [hand], true_camera(rotation=rotation, shift=shift))]
    paths, keypoints = [], []
    for index, photo in enumerate(photos):
        paths.append(save_jpeg(tmp_path / f"view{index}.jpg", photo.image))
        keypoints.append(save_keypoints(tmp_path / f"view{index}.json", photo.keypoints[0],
                                        "right"))
    out = tmp_path / "out"
    reports = fit_photo_folder(paths, out, keypoints_json=keypoints, focal_px=FOCAL,
                               model_path=path, device="cpu", progress=False, log=None,
                               config=fast_config())
    assert len(reports) == 1 and reports[0].folder == out
    assert max(reports[0].keypoint_error_px) < 2.0
    assert sorted(p.name for p in out.iterdir()) == [
        "cameras.json", "keypoints.json", "mesh.ply", "metrics.json", "params.json", "photo0",
        "photo1", "report.html"]
    assert sorted(p.name for p in (out / "photo1").iterdir()) == [
        "camera.json", "keypoints.json", "mask.png", "overlay.png"]
    cameras = json.loads((out / "cameras.json").read_text())
    placed = torch.tensor(cameras[1]["R"], dtype=torch.float64)
    angle = math.degrees(math.acos(float(((placed.T @ rotation.double()).trace() - 1) / 2)))
    assert angle < 6.0  # placed by the hand alone (measured 3.3 deg; 2.1 without OpenCV)
    assert np.allclose(cameras[0]["R"], np.eye(3), atol=1e-6)
    record = json.loads((out / "keypoints.json").read_text())
    assert len(record["photos"]) == 2
    for entry, photo in zip(record["photos"], photos, strict=True):
        error = np.linalg.norm(np.asarray(entry["keypoints_2d_fitted"]) - photo.keypoints[0],
                               axis=1).mean()
        assert error < 2.0
    # cameras placed by the hand keep one view's scale ambiguity: the depth comes from the
    # hand-size prior as with one photo (measured: 3 cm too far for this larger-than-mean hand)
    assert abs(record["keypoints_3d"][0][2] - photos[0].keypoints_3d[0][0, 2]) < 0.06


def test_unknown_side_is_chosen_by_fitting_both(model_file, tmp_path):
    model, path = model_file
    photo = render_photo(model, [photo_hand(model)])
    mirrored = photo.image[:, ::-1]  # the same picture of a left hand
    width = photo.image.shape[1]
    cases = {"right": (photo.image, photo.keypoints[0]),
             "left": (mirrored, photo.keypoints[0] * [-1.0, 1.0] + [width, 0.0])}
    for side, (image, points) in cases.items():
        jpeg = save_jpeg(tmp_path / f"{side}.jpg", np.ascontiguousarray(image))
        keypoints = save_keypoints(tmp_path / f"{side}.json", points)  # no side given
        lines = []
        reports = fit_photo_folder(jpeg, tmp_path / side, keypoints_json=keypoints,
                                   focal_px=FOCAL, model_path=path, device="cpu",
                                   progress=False, log=lines.append,
                                   config=fast_config(color_iters=0))
        report = reports[0]
        assert report.side == side and report.side_source == "fitted"
        assert any(line.startswith(f"side unknown: fitted as both, {side} won") for line in
                   lines)
        assert report.keypoint_error_px[0] < 2.0 and report.guard is None  # no colour stage


def test_detected_hands_and_an_unsure_side(model_file, tmp_path, monkeypatch):
    from lisa_hand.data import detect

    model, path = model_file
    photo = render_photo(model, [photo_hand(model)])
    jpeg = save_jpeg(tmp_path / "hand.jpg", photo.image)
    points = photo.keypoints[0]
    box = (*points.min(0), *points.max(0))
    # The detector's convention: its wrist a fraction of the way to the middle knuckle.
    shift = detect.MEDIAPIPE_WRIST_SHIFT
    detector = points.copy()
    detector[0] = points[0] + shift * (points[9] - points[0])
    monkeypatch.setattr(detect, "photo_extra_missing", lambda: None)
    notes = {}
    for score, votes, side, source in ((0.98, (3, 0), "right", "detected"),
                                       (0.6, (0, 3), "right", "fitted"),
                                       (0.9, (3, 1), "right", "detected")):
        found = [detect.DetectedHand(keypoints=detector, score=score, side="left" if
                                     score < 0.75 else "right", box=box, side_votes=votes)]
        monkeypatch.setattr(detect, "detect_hands", lambda image, max_hands=4, found=found:
                            found)
        lines = []
        config = dataclasses.replace(fast_config(color_iters=0), detector_wrist_shift=shift)
        report = fit_photo_folder(jpeg, tmp_path / f"out{score}", focal_px=FOCAL,
                                  model_path=path, device="cpu", progress=False,
                                  log=lines.append, config=config)[0]
        assert (report.side, report.side_source) == (side, source)
        assert report.keypoint_error_px[0] < 2.0  # against the wrist moved back
        assert any("1 hand(s) found" in line for line in lines)
        record = json.loads((tmp_path / f"out{score}" / "keypoints.json").read_text())
        np.testing.assert_allclose(record["keypoints_2d_detector"], detector, atol=1e-6)
        np.testing.assert_allclose(record["keypoints_2d_detected"], points, atol=1e-6)
        notes[score] = lines
    assert any("the detector is unsure of the side (left 0.60, below 0.75)" in line
               for line in notes[0.6])
    # A split vote: the side is kept, with a note.
    split = "the detector's estimates disagree on the side (right 3 right : 1 left"
    assert any(split in line for line in notes[0.9])
    assert not any(split[:40] in line for line in notes[0.98] + notes[0.6])
    assert any("split vote 3 right : 1 left" in line for line in notes[0.9])


def test_keypoints_json_fits_the_detection_again(model_file, tmp_path, monkeypatch):
    """A fit's keypoints.json keeps the detector's 3D landmarks; given back with --keypoints it
    gives the detection's fit again (the landmarks lean the fingers: without them the fit
    differs)."""
    from lisa_hand.data import detect

    model, path = model_file
    photo = render_photo(model, [photo_hand(model)])
    jpeg = save_jpeg(tmp_path / "hand.jpg", photo.image)
    points, landmarks = photo.keypoints[0], photo.keypoints_3d[0]
    # The landmarks lean every finger the other way along its camera ray than the true hand.
    landmarks = landmarks * [1.0, 1.0, -1.0]
    found = [detect.DetectedHand(keypoints=points, score=0.98, side="right",
                                 box=(*points.min(0), *points.max(0)), side_votes=(3, 0),
                                 landmarks_3d=landmarks)]
    monkeypatch.setattr(detect, "photo_extra_missing", lambda: None)
    monkeypatch.setattr(detect, "detect_hands", lambda image, max_hands=4: found)
    options = dict(focal_px=FOCAL, model_path=path, device="cpu", progress=False, log=None,
                   config=fast_config(color_iters=0))
    fit_photo_folder(jpeg, tmp_path / "detected", **options)
    written = tmp_path / "detected" / "keypoints.json"
    np.testing.assert_allclose(json.loads(written.read_text())["landmarks_3d"], landmarks,
                               atol=1e-12)
    fit_photo_folder(jpeg, tmp_path / "again", keypoints_json=written, **options)
    plain = save_keypoints(tmp_path / "plain.json", points, "right")
    fit_photo_folder(jpeg, tmp_path / "plain", keypoints_json=plain, **options)
    pose = {name: read_params(tmp_path / name / "params.json").pose
            for name in ("detected", "again", "plain")}
    torch.testing.assert_close(pose["again"], pose["detected"], atol=1e-5, rtol=0)
    assert (pose["plain"] - pose["detected"]).abs().max() > 0.05
    numbers = json.loads((tmp_path / "detected" / "metrics.json").read_text())["per_photo"][0]
    # The hand is its own model's render: its silhouette covers the keypoints' first mask
    # (measured IoU 0.72: that mask is coarse) and its colours match it (30 dB).
    assert numbers["silhouette_iou"] > 0.6 and numbers["psnr_in_mask_db"] > 25.0


def test_landmarks_in_a_keypoints_file_are_checked(big_photo, tmp_path):
    points = hand_points().tolist()
    for landmarks, message in (([[0.0, 0.0, 0.5]] * 20, "must be [21, 3] finite metres"),
                               ([[0.0, 0.0, 0.0]] * 20 + [[0.0, 0.0, 2.0]], "must be metres")):
        path = tmp_path / "kp.json"
        path.write_text(json.dumps({"keypoints": points, "landmarks_3d": landmarks}))
        with pytest.raises(ValueError) as info:
            read_given_hands(path, big_photo)
        assert str(info.value).startswith(str(path)) and message in str(info.value)
    given = np.random.default_rng(0).normal(0.0, 0.03, (21, 3))
    path.write_text(json.dumps({"hands": [{"keypoints": points, "landmarks_3d": given.tolist()}]}))
    np.testing.assert_allclose(read_given_hands(path, big_photo)[0].landmarks_3d, given)


def test_a_failure_while_writing_leaves_the_previous_fit(model_file, tmp_path, monkeypatch):
    model, path = model_file
    photo = render_photo(model, [photo_hand(model)])
    jpeg = save_jpeg(tmp_path / "hand.jpg", photo.image)
    keypoints = save_keypoints(tmp_path / "hand.json", photo.keypoints[0], "right")
    out = tmp_path / "out"
    options = dict(keypoints_json=keypoints, focal_px=FOCAL, model_path=path, device="cpu",
                   progress=False, log=None, config=fast_config(color_iters=0))
    fit_photo_folder(jpeg, out, **options)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    import lisa_hand.data.layout

    def broken(path, rgb):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(lisa_hand.data.layout, "write_image", broken)
    with pytest.raises(OSError, match="disk full"):
        fit_photo_folder(jpeg, out, **{**options, "config": fast_config(color_iters=0,
                                                                         seed=1)})
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hand.jpg", "hand.json", "out"]


@pytest.mark.slow
def test_a_real_photo_with_detection(tmp_path):
    pytest.importorskip("mediapipe", reason="detection needs the photo extra (MediaPipe)")
    photo = PHOTOS / "hand_thumb_up.jpg"
    config = FitPhotoConfig(fit=photo_fit_defaults(keypoint_iters=150, color_iters=10,
                                                   num_rays=128), mesh_resolution=64)
    reports = fit_photo_folder(photo, tmp_path / "out", device="cpu", progress=False,
                               log=None, config=config)
    report = reports[0]
    assert len(reports) == 1 and report.side_source == "detected"
    assert report.camera_sources == ["default"]
    assert report.guard is not None and report.guard.pieces == 1
    record = json.loads((tmp_path / "out" / "keypoints.json").read_text())
    detected = np.asarray(record["keypoints_2d_detected"])
    size = np.linalg.norm(detected[0] - detected[9])  # ~170 px from wrist to knuckles
    assert report.keypoint_error_px[0] < 0.08 * size  # measured ~6 px
    from lisa_hand.data.layout import read_mask

    mask = read_mask(tmp_path / "out" / "mask.png")
    assert mask.shape == (521, 640)
    inside = mask[np.clip(detected[:, 1].astype(int), 0, 520),
                  np.clip(detected[:, 0].astype(int), 0, 639)]
    assert inside.mean() > 0.9 and 0.08 < mask.mean() < 0.3  # the hand, not the forearm


def test_the_mesh_ends_past_the_wrist_without_specks(model_file, tmp_path):
    from lisa_hand.data.meshio import load_mesh
    from lisa_hand.geometry.pieces import MIN_PIECE_FRACTION, surface_pieces
    from lisa_hand.skeleton.wrist import WRIST_CLIP_M, wrist_plane

    model, path = model_file
    photo = render_photo(model, [photo_hand(model)])
    jpeg = save_jpeg(tmp_path / "hand.jpg", photo.image)
    keypoints = save_keypoints(tmp_path / "hand.json", photo.keypoints[0], side="right")
    meshes = {}
    for clip in (WRIST_CLIP_M, None):
        out = tmp_path / f"clip{clip}"
        lines = []
        config = dataclasses.replace(fast_config(), wrist_clip_m=clip, mesh_resolution=64)
        (report,) = fit_photo_folder(jpeg, out, keypoints_json=keypoints, focal_px=FOCAL,
                                     model_path=path, device="cpu", progress=False,
                                     log=lines.append, config=config)
        mesh, params = load_mesh(out / "mesh.ply"), read_params(out / "params.json")
        distance = wrist_plane(params).signed_distance(np.asarray(mesh.vertices, np.float64))
        meshes[clip] = (distance, mesh)
        # No speck in the file; what was removed is in metrics.json and said when any.
        metrics = json.loads((out / "metrics.json").read_text())
        areas, total = surface_pieces(mesh)
        assert areas.min() >= MIN_PIECE_FRACTION * total
        removed = metrics["specks_removed"]["count"]
        said = [line for line in lines if " speck(s) below 0.1 % " in line]
        assert len(said) == (removed > 0)  # one line, saying how many
        assert all(f"mesh.ply: {removed} speck(s)" in line for line in said)
        assert metrics["surface"]["pieces"] == len(areas)
    cut, whole = meshes[WRIST_CLIP_M][0], meshes[None][0]
    assert cut.min() > -1e-6  # nothing beyond the cut, 1 cm past the fitted wrist
    assert whole.min() < -0.01  # without it the model's stub runs on
