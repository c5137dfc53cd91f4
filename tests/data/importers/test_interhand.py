"""``lisa import interhand2.6m`` on a fixture in InterHand2.6M's exact format: cameras, keypoint
order and units, projections, poses by inverse kinematics and from MANO, bad frames skipped."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import read_frame_table
from lisa_hand.data.importers.common import ImportReport
from lisa_hand.data.importers.interhand import (
    InterHandConfig,
    import_interhand,
    interhand_records,
)
from lisa_hand.data.keypoints import read_keypoints
from lisa_hand.data.layout import read_image, read_sources
from lisa_hand.geometry.cameras import load_cameras
from lisa_hand.skeleton import forward_kinematics
from lisa_hand.utils.io import read_json
from tests.data.importers.fixtures import OPENPOSE_OF_INTERHAND, cam2pixel_mm, interhand_fixture
from tests.skeleton.synthetic_mano import write_synthetic_mano

MM = 1e-3


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ih")
    info = interhand_fixture(root / "InterHand2.6M")
    out = root / "DATA"
    report = import_interhand(InterHandConfig(root=str(root / "InterHand2.6M")), out,
                              progress=False)
    return root / "InterHand2.6M", out, info, report


def frames_by_source(out):
    frames = {}
    for params_path in sorted(out.glob("s*/f*/params.json")):
        params = read_json(params_path)
        source = params["source"]
        frames[(source["capture"], source["frame_idx"], params["side"])] = params_path.parent
    return frames


def test_counts_and_skips(dataset):
    _, out, _, report = dataset
    # 10 annotated instants: 4 right, 2 left, 1 interacting (2 hands), 1 right with 2 views,
    # minus the frame without annotation and the frame with an invalid joint.
    assert report.num_frames == 4 + 2 + 2 + 1
    assert report.skipped == {"missing annotation": 1, "invalid joints": 1, "missing image": 1}
    assert any("image0009.jpg: image of an annotated frame is missing" in m
               for m in report.messages)
    assert any("frame 7: no 3D joint annotation" in m for m in report.messages)
    assert any("frame 8: right hand has 1 invalid joint(s)" in m for m in report.messages)
    assert report.num_subjects == 2  # subject 0 right and left
    assert (out / "dataset.json").is_file()
    assert read_json(out / "split.json")["train"] == ["s000", "s001"]


def test_keypoints_roundtrip_and_projection(dataset):
    _, out, info, _ = dataset
    frames = frames_by_source(out)
    worst_mm, worst_px = 0.0, 0.0
    for (capture, frame, side), folder in frames.items():
        params = read_json(folder / "params.json")
        world = info["world_mm"][(capture, frame)]
        offset = 0 if side == "right" else 21
        # InterHand joint i of the hand is OpenPose keypoint OPENPOSE_OF_INTERHAND[i].
        expected_m = np.zeros((21, 3))
        expected_m[OPENPOSE_OF_INTERHAND] = world[offset:offset + 21] * MM
        worst_mm = max(worst_mm, np.abs(np.asarray(params["keypoints"]) - expected_m).max() / MM)
        keypoints = read_keypoints(folder / "keypoints.json")
        cameras = {c.name: c for c in load_cameras(folder / "cameras.json", dtype=torch.float64)}
        for name, view in keypoints.items():
            cam = name.removeprefix("cam")
            p = info["cameras"][capture]
            theirs = cam2pixel_mm(world[offset:offset + 21], np.asarray(p["campos"][cam]),
                                  np.asarray(p["camrot"][cam]), np.asarray(p["focal"][cam]),
                                  np.asarray(p["princpt"][cam]))
            ours = view.keypoints[OPENPOSE_OF_INTERHAND] - 0.5  # our pixel centres are at +0.5
            worst_px = max(worst_px, np.abs(ours - theirs).max())
            # The written camera projects the written 3D keypoints to the same pixels.
            projected, _ = cameras[name].project(torch.tensor(params["keypoints"],
                                                              dtype=torch.float64))
            assert np.abs(projected.numpy() - view.keypoints).max() < 1e-6
    assert worst_mm < 0.01  # joints round-trip within 0.01 mm
    assert worst_px < 0.01  # projections within 0.01 px of the dataset's own


def test_poses_reproduce_the_joints(dataset):
    _, out, _, report = dataset
    for split_frames in (read_frame_table(out, "train"),):
        for i, paths in enumerate(split_frames.frames):
            params = read_json(paths.params)
            joints = forward_kinematics(split_frames.pose[i:i + 1].double(),
                                        split_frames.rest_joints[split_frames.frame_subject[i]]
                                        .double(), split_frames.translation[i:i + 1].double())
            error = (joints.joints[0] - torch.tensor(params["joints"])).norm(dim=-1).max()
            assert float(error) < 1.0 * MM, paths.root
            assert params["pose_source"] == "inverse_kinematics"
    assert max(report.ik_error_mm) < 1.0


def test_images_are_referred_to_not_copied(dataset):
    _, out, info, _ = dataset
    folder = frames_by_source(out)[(0, 9, "right")]
    assert not (folder / "images").exists()
    sources = read_sources(folder)["images"]
    assert sorted(sources) == ["cam400002", "cam400006"]  # cam400004's image is missing
    assert sources["cam400002"].resolve() == info["images"][(0, 9, "400002")].resolve()
    from lisa_hand.data.layout import FramePaths

    image = read_image(FramePaths(folder).image("cam400002"))
    assert image.shape == (512, 334, 3)


def test_options_select_hands_cameras_and_frames(dataset):
    root, _, _, _ = dataset
    report = ImportReport(root=root, dataset="InterHand2.6M")
    config = InterHandConfig(root=str(root), hand="left", cameras=("cam400002",), every=2)
    records = list(interhand_records(config, report, set()))
    # Left hands at frames 4, 5 (left) and 6 (interacting); every 2nd frame of each sequence:
    # sequence one has frames 0-4 -> 0, 2, 4; sequence two 5-9 -> 5, 7, 9.
    assert sorted(r.source["frame_idx"] for r in records) == [4, 5]
    assert all([c.name for c in r.cameras] == ["cam400002"] for r in records)
    limited = list(interhand_records(InterHandConfig(root=str(root), max_frames=3), report,
                                     set()))
    assert len(limited) == 3


def test_missing_annotation_file_is_one_clear_error(tmp_path):
    (tmp_path / "annotations" / "train").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match="InterHand2.6M_train_data.json: missing"):
        import_interhand(InterHandConfig(root=str(tmp_path)), tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_mano_fits_give_the_pose(tmp_path):
    mano_dir = tmp_path / "mano"
    mano_dir.mkdir()
    write_synthetic_mano(mano_dir / "MANO_RIGHT.pkl", "right", seed=1)
    write_synthetic_mano(mano_dir / "MANO_LEFT.pkl", "left", seed=1)
    root = tmp_path / "ih"
    info = interhand_fixture(root, mano_dir=mano_dir)
    out = tmp_path / "DATA"
    report = import_interhand(InterHandConfig(root=str(root), captures=(1,), mano=str(mano_dir)),
                              out, progress=False)
    assert report.num_frames == 8 and report.pose_source == {"mano": 8}
    table = read_frame_table(out, "train")
    for i, paths in enumerate(table.frames):
        params = read_json(paths.params)
        entry = info["mano"][(1, params["source"]["frame_idx"], params["side"])]
        from lisa_hand.skeleton import ManoLayer

        layer = ManoLayer(mano_dir / f"MANO_{params['side'].upper()}.pkl", dtype=torch.float64)
        pose = torch.tensor(entry["pose"], dtype=torch.float64)
        full = torch.cat([pose[:3], pose[3:] + layer.hand_mean])
        assert torch.allclose(torch.tensor(params["pose"], dtype=torch.float64), full,
                              atol=1e-12)
        joints = forward_kinematics(table.pose[i:i + 1].double(),
                                    table.rest_joints[table.frame_subject[i]].double(),
                                    table.translation[i:i + 1].double()).joints[0]
        # The subject's skeleton is J(betas) (one shape per hand here): joints exact (float32
        # storage of the table aside).
        assert float((joints - torch.tensor(params["joints"])).norm(dim=-1).max()) < 1e-3 * MM


def test_what_lisa_train_reads(tmp_path):
    """With --masks, the imported split loads as lisa train's rays (images referred to) and its
    skinning pseudo ground truth (scan.npz: posed template points and weights)."""
    from lisa_hand.data.datasets import RayFrames, ScanFrames

    root = tmp_path / "ih"
    interhand_fixture(root, masks=True)
    out = tmp_path / "DATA"
    import_interhand(InterHandConfig(root=str(root), masks=str(root / "masks"),
                                     skinning_points=500), out, progress=False)
    rays = RayFrames(out, "train", background_per_view=64)
    assert rays.num_frames == 9 and rays.camera_names == ["cam400002", "cam400004", "cam400006"]
    batch = rays.sample_rays(256, torch.Generator().manual_seed(0), num_frames=2)
    assert 0.5 < float(batch.in_mask.float().mean()) < 1.0
    scans = ScanFrames(out, "train")
    sample = scans.sample(3, 100, 0, torch.Generator().manual_seed(1))
    assert torch.allclose(sample.surface_weights.sum(-1), torch.ones(3, 100), atol=1e-3)
    for k, frame in enumerate(sample.frame_index.tolist()):
        keypoints = torch.tensor(read_json(scans.table.frames[frame].params)["keypoints"])
        distance = torch.cdist(sample.surface_points[k], keypoints).min(dim=1).values
        # Template surface points lie around the hand's skeleton (the palm's centre is a few cm
        # from the nearest keypoint).
        assert float(distance.max()) < 0.06 and float(distance.mean()) < 0.03
