"""``lisa import`` on hostile or wrong input: one line naming the file and the entry (exit 2),
a bad frame or view skipped and named, or the input converted with a note; never a traceback,
never a silently wrong dataset. Every bad input is made here, in ``tmp_path``."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
import torch

from lisa_hand.data.importers.common import ImportReport
from lisa_hand.data.importers.freihand import FreiHandConfig, import_freihand
from lisa_hand.data.importers.scans import ScanImportConfig, import_scans
from lisa_hand.data.meshio import save_mesh
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.handmodel.template import load_template
from lisa_hand.skeleton.mano_file import load_mano_pkl
from tests.cli.test_import_cli import run
from tests.data.importers.fixtures import freihand_fixture, interhand_fixture
from tests.skeleton.synthetic_mano import (
    FakeCscMatrix,
    official_layout,
    synthetic_mano_arrays,
    write_pickle_py2,
)

F64 = torch.float64
IH_ARGS = ("--hand", "right", "--captures", "0", "--skinning-points", "0", "--quiet")


def one_line_refusal(code, output, *needles):
    assert code == 2, output
    assert output.err.startswith("lisa: error: ") and output.err.count("\n") == 1, output.err
    assert "Traceback" not in output.err
    for needle in needles:
        assert needle in output.err, output.err


def edit_json(path, change):
    content = json.loads(path.read_text())
    content = change(content) or content
    path.write_text(json.dumps(content))


def annotation(root, name):
    return root / "annotations" / "train" / f"InterHand2.6M_train_{name}.json"


# --------------------------------------------------------------------------------------------
# InterHand2.6M


def test_interhand_file_names_cannot_leave_the_dataset(tmp_path, capsys):
    root = tmp_path / "ih"
    interhand_fixture(root)

    def escape(data):
        data["images"][0]["file_name"] = "../../../../etc/passwd"  # frame 0, cam400002
        data["images"][1]["file_name"] = "/etc/passwd"  # frame 0, cam400004

    edit_json(annotation(root, "data"), escape)
    code, output = run(capsys, "import", "interhand2.6m", root, "--out", tmp_path / "D",
                       *IH_ARGS)
    assert code == 0, output.err
    # 6 frames as without the change; frame 0 keeps its third view only (17 - 2 views).
    assert "6 frames (15 views)" in output.out and "2 bad path" in output.out
    report = json.loads((tmp_path / "D" / "import_report.json").read_text())
    messages = "\n".join(report["skip_messages"])
    assert ("InterHand2.6M_train_data.json: images[0] (id 0): file_name "
            "'../../../../etc/passwd' leaves the dataset folder") in messages
    assert "images[1] (id 1): file_name '/etc/passwd' leaves the dataset folder" in messages
    for sources in (tmp_path / "D").glob("s*/f*/sources.json"):
        assert "passwd" not in sources.read_text()


def test_interhand_camera_file_that_is_a_list_is_one_line(tmp_path, capsys):
    root = tmp_path / "ih"
    interhand_fixture(root)
    annotation(root, "camera").write_text("[1, 2]")
    code, output = run(capsys, "import", "interhand2.6m", root, "--out", tmp_path / "D",
                       *IH_ARGS)
    one_line_refusal(code, output, "InterHand2.6M_train_camera.json: expected a JSON object")
    assert not (tmp_path / "D").exists()


def test_interhand_malformed_image_entries_are_skipped_and_named(tmp_path, capsys):
    root = tmp_path / "ih"
    interhand_fixture(root)

    def damage(data):
        del data["images"][0]["file_name"]
        data["images"][1]["id"] = "x"
        data["images"][2] = [1, 2]
        data["annotations"][3] = "junk"

    edit_json(annotation(root, "data"), damage)
    code, output = run(capsys, "import", "interhand2.6m", root, "--out", tmp_path / "D",
                       *IH_ARGS)
    assert code == 0, output.err
    # Frame 0 lost all three views; frames 1-3, 6 and 9 remain.
    assert "5 frames" in output.out
    assert "3 bad image entry" in output.out and "1 bad annotation" in output.out
    report = json.loads((tmp_path / "D" / "import_report.json").read_text())
    messages = "\n".join(report["skip_messages"])
    assert "images[0]: no file_name" in messages
    assert "images[1]: id, capture, frame_idx, width and height must be integers" in messages
    assert "images[2]: not an object" in messages
    assert "annotations[3]: an object with an integer image_id needed" in messages


def test_interhand_joint_file_with_a_list_entry_names_the_first_skip(tmp_path, capsys):
    root = tmp_path / "ih"
    interhand_fixture(root)
    edit_json(annotation(root, "joint_3d"), lambda joints: {"0": [1, 2]})
    code, output = run(capsys, "import", "interhand2.6m", root, "--out", tmp_path / "D",
                       *IH_ARGS)
    one_line_refusal(code, output, "no frame could be imported",
                     "InterHand2.6M_train_joint_3d.json: Capture0 frame 0: no 3D joint")


def test_interhand_cameras_that_are_not_cameras_are_refused(tmp_path, capsys):
    """camrot of zeros is not a rotation (it used to become the identity); campos of 1e30 mm
    puts the camera 1e27 m from the hand; a camera behind the hand sees nothing of it."""
    root = tmp_path / "ih"
    interhand_fixture(root)

    def damage(cameras):
        cameras["0"]["camrot"]["400002"] = np.zeros((3, 3)).tolist()
        cameras["0"]["campos"]["400004"] = [1e30, 1e30, 1e30]
        # cam400006 turned around: the hand is behind it.
        camrot = np.asarray(cameras["0"]["camrot"]["400006"])
        cameras["0"]["camrot"]["400006"] = (np.diag([-1.0, 1.0, -1.0]) @ camrot).tolist()

    edit_json(annotation(root, "camera"), damage)
    code, output = run(capsys, "import", "interhand2.6m", root, "--out", tmp_path / "D",
                       *IH_ARGS)
    one_line_refusal(code, output, "no frame could be imported",
                     "InterHand2.6M_train_camera.json: Capture0: camera 400002: camrot is not a "
                     "rotation")
    report = ImportReport(root=tmp_path, dataset="InterHand2.6M")
    from lisa_hand.data.importers.interhand import InterHandConfig, interhand_records

    records = list(interhand_records(InterHandConfig(root=str(root), hand="right"), report,
                                     set()))
    assert records == []
    messages = "\n".join(report.messages)
    assert "camera cam400004 is 1.732e+27 m from the hand" in messages
    assert "camera cam400006: 21 of 21 keypoints are behind the camera" in messages
    # 6 right-hand frames with annotations and valid joints, 3 cameras (one image missing).
    assert report.skipped == {"bad camera": 17, "no view": 6, "missing annotation": 1,
                              "invalid joints": 1, "missing image": 1}


# --------------------------------------------------------------------------------------------
# FreiHAND


def test_freihand_millimetres_are_converted_and_said(tmp_path, capsys):
    root = tmp_path / "fh"
    info = freihand_fixture(root, num=3)
    edit_json(root / "training_xyz.json", lambda xyz: (np.asarray(xyz) * 1e3).tolist())
    code, output = run(capsys, "import", "freihand", root, "--out", tmp_path / "D",
                       "--skinning-points", "0", "--quiet")
    assert code == 0, output.err
    assert "note: " in output.out and "training_xyz.json: the keypoints are in millimetres, " \
        "not metres" in output.out
    report = json.loads((tmp_path / "D" / "import_report.json").read_text())
    assert report["ik_error_mm_max"] < 1.0 and len(report["notes"]) == 1
    for params in (tmp_path / "D").glob("s*/f*/params.json"):
        params = json.loads(params.read_text())
        expected = info["xyz"][params["source"]["sample"]]
        assert np.abs(np.asarray(params["keypoints"]) - expected).max() < 1e-9


def test_freihand_keypoints_of_no_unit_are_refused(tmp_path, capsys):
    root = tmp_path / "fh"
    freihand_fixture(root, num=2)
    edit_json(root / "training_xyz.json", lambda xyz: (np.asarray(xyz) * 1e6).tolist())
    code, output = run(capsys, "import", "freihand", root, "--out", tmp_path / "D", "--quiet")
    one_line_refusal(code, output, "training_xyz.json: the median sample's keypoints",
                     "too large for a hand")


def test_freihand_keypoints_behind_the_camera_and_singular_K_are_skipped(tmp_path):
    root = tmp_path / "fh"
    freihand_fixture(root, num=4)  # sample 1 has NaN keypoints

    def behind(xyz):
        xyz[0] = (np.asarray(xyz[0]) * [1.0, 1.0, -1.0]).tolist()

    def singular(K):
        K[2] = [[480.0, 480.0, 112.0], [480.0, 480.0, 111.0], [0.0, 0.0, 1.0]]

    edit_json(root / "training_xyz.json", behind)
    edit_json(root / "training_K.json", singular)
    report = import_freihand(FreiHandConfig(root=str(root), skinning_points=0),
                             tmp_path / "D", progress=False)
    assert report.num_frames == 1
    assert report.skipped == {"bad camera": 2, "invalid joints": 1}
    messages = "\n".join(report.messages)
    assert "training_xyz.json: sample 0: camera cam0: 21 of 21 keypoints are behind" in messages
    assert "training_xyz.json: sample 2: K is singular" in messages


# --------------------------------------------------------------------------------------------
# Scans


def posed_template(seed=0, translation=(0.0, 0.1, 0.5)):
    template = load_template().to(dtype=F64)
    pose = sample_pose(torch.Generator().manual_seed(seed), 1, global_orient=True).to(F64)
    out = template(pose, torch.zeros(1, template.num_betas, dtype=F64),
                   torch.tensor([translation], dtype=F64))
    return out.vertices[0].numpy(), template.faces.numpy(), out.keypoints[0].numpy()


def write_scan(folder, name, *, mesh_scale=1.0, keypoint_scale=1.0, offset=(0.0, 0.0, 0.0),
               keypoints=None, seed=0):
    vertices, faces, true_keypoints = posed_template(seed)
    folder.mkdir(parents=True, exist_ok=True)
    save_mesh(folder / f"{name}.ply", Mesh(vertices=vertices * mesh_scale, faces=faces))
    if keypoints is None:
        keypoints = {"keypoints": ((true_keypoints + offset) * keypoint_scale).tolist()}
    (folder / f"{name}.keypoints3d.json").write_text(json.dumps(keypoints))
    return true_keypoints


def test_scan_keypoints_file_that_is_a_list_is_named(tmp_path, capsys):
    write_scan(tmp_path / "scans" / "p", "a", keypoints=[1, 2])
    code, output = run(capsys, "import", "scans", tmp_path / "scans", "--out", tmp_path / "D",
                       "--no-pose-search", "--quiet")
    one_line_refusal(code, output, "no frame could be imported",
                     "a.keypoints3d.json: expected a JSON object, got a list")


def test_scan_keypoints_off_the_scan_are_skipped(tmp_path):
    write_scan(tmp_path / "scans" / "p", "good")
    write_scan(tmp_path / "scans" / "p", "shifted", offset=(0.5, 0.0, 0.0))
    report = import_scans(ScanImportConfig(root=str(tmp_path / "scans"), num_points=500,
                                           num_sdf_samples=100), tmp_path / "D", progress=False)
    assert report.num_frames == 1
    assert report.skipped == {"keypoints off the scan": 1}
    assert "shifted.keypoints3d.json: the keypoints lie up to" in report.messages[0]
    assert "from the scan shifted.ply" in report.messages[0]


def test_scan_keypoints_in_millimetres_beside_a_mesh_in_metres_are_converted(tmp_path):
    true_keypoints = write_scan(tmp_path / "scans" / "p", "a", keypoint_scale=1e3)
    report = import_scans(ScanImportConfig(root=str(tmp_path / "scans"), num_points=500,
                                           num_sdf_samples=100), tmp_path / "D", progress=False)
    assert report.num_frames == 1 and not report.skipped
    assert len(report.notes) == 1 and "the keypoints are in millimetres" in report.notes[0]
    assert max(report.ik_error_mm) < 1.0
    params = json.loads((tmp_path / "D" / "s000" / "f000" / "params.json").read_text())
    assert np.abs(np.asarray(params["keypoints"]) - true_keypoints).max() < 1e-9


# --------------------------------------------------------------------------------------------
# MANO .pkl


def test_mano_sparse_regressor_claiming_a_huge_shape_is_refused_before_allocating(tmp_path,
                                                                                 capsys):
    content = official_layout(synthetic_mano_arrays(0))
    content["J_regressor"]._shape = (200000, 200000)  # 320 GB as dense float64
    (tmp_path / "mano").mkdir()
    path = write_pickle_py2(tmp_path / "mano" / "MANO_RIGHT.pkl", content)
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"MANO_RIGHT\.pkl: key 'J_regressor' .*claims "
                                             r"shape \(200000, 200000\), expected \(16, 778\)"):
            load_mano_pkl(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100e6
    (tmp_path / "scans").mkdir()
    code, output = run(capsys, "import", "scans", tmp_path / "scans", "--out", tmp_path / "D",
                       "--mano", tmp_path / "mano", "--quiet")
    one_line_refusal(code, output, "MANO_RIGHT.pkl: key 'J_regressor'")


def test_mano_sparse_regressor_with_an_index_outside_its_shape_is_refused(tmp_path):
    arrays = synthetic_mano_arrays(0)
    content = official_layout(arrays)
    regressor = FakeCscMatrix(arrays["J_regressor"])
    regressor.indices = regressor.indices.copy()
    regressor.indices[0] = -1  # would wrap around to the last row silently
    content["J_regressor"] = regressor
    path = write_pickle_py2(tmp_path / "MANO_RIGHT.pkl", content)
    with pytest.raises(ValueError, match="an index is outside the shape"):
        load_mano_pkl(path)
