"""``lisa import freihand`` on a fixture in FreiHAND's exact format."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import read_frame_table
from lisa_hand.data.importers.freihand import FreiHandConfig, import_freihand
from lisa_hand.data.keypoints import read_keypoints
from lisa_hand.data.layout import read_npz, read_sources
from lisa_hand.skeleton import forward_kinematics
from lisa_hand.utils.io import read_json
from tests.data.importers.fixtures import freihand_fixture, project_points_freihand
from tests.skeleton.synthetic_mano import write_synthetic_mano

MM = 1e-3


def frames(out):
    found = {}
    for path in sorted(out.glob("s*/f*/params.json")):
        params = read_json(path)
        found[(params["source"]["sample"], params["source"]["version"])] = path.parent
    return found


def test_import_training_set(tmp_path):
    info = freihand_fixture(tmp_path / "FreiHAND", num=4)
    out = tmp_path / "DATA"
    report = import_freihand(FreiHandConfig(root=str(tmp_path / "FreiHAND"),
                                            versions=(0, 2)), out, progress=False)
    # 4 samples x 2 versions, minus sample 1 (NaN keypoints) and version 2 of sample 2.
    assert report.num_frames == 5 and report.num_subjects == 3
    assert report.skipped == {"invalid joints": 1, "missing image": 1}
    found = frames(out)
    worst_px, worst_mm = 0.0, 0.0
    for (sample, version), folder in found.items():
        params = read_json(folder / "params.json")
        worst_mm = max(worst_mm, np.abs(np.asarray(params["keypoints"])
                                        - info["xyz"][sample]).max() / MM)
        view = read_keypoints(folder / "keypoints.json")["cam0"]
        theirs = project_points_freihand(info["xyz"][sample], info["K"][sample])
        worst_px = max(worst_px, np.abs(view.keypoints - 0.5 - theirs).max())
        sources = read_sources(folder)
        assert sources["images"]["cam0"].name == f"{sample + version * 4:08d}.jpg"
        assert sources["masks"]["cam0"].name == f"{sample:08d}.jpg"
    assert worst_mm < 0.01 and worst_px < 0.01
    table = read_frame_table(out, "test")
    for i, paths in enumerate(table.frames):
        joints = forward_kinematics(table.pose[i:i + 1].double(),
                                    table.rest_joints[table.frame_subject[i]].double(),
                                    table.translation[i:i + 1].double()).joints[0]
        expected = torch.tensor(read_json(paths.params)["joints"], dtype=torch.float64)
        assert float((joints - expected).norm(dim=-1).max()) < 1.0 * MM


def test_mano_parameters_and_vertices(tmp_path):
    mano_dir = tmp_path / "mano"
    mano_dir.mkdir()
    write_synthetic_mano(mano_dir / "MANO_RIGHT.pkl", "right", seed=2)
    info = freihand_fixture(tmp_path / "FreiHAND", num=3, mano_dir=mano_dir)
    out = tmp_path / "DATA"
    report = import_freihand(FreiHandConfig(root=str(tmp_path / "FreiHAND"), vertices=True,
                                            mano=str(mano_dir)), out, progress=False)
    assert report.pose_source == {"mano": 2}
    for (sample, _), folder in frames(out).items():
        params = read_json(folder / "params.json")
        assert np.allclose(params["pose"], info["full_pose"][sample], atol=1e-12)
        vertices = read_npz(folder / "mano_mesh.npz")["vertices"]
        assert np.abs(vertices - info["verts"][sample]).max() < 1e-12
        subject = read_json(folder.parent / "subject.json")
        joints = forward_kinematics(torch.tensor([params["pose"]], dtype=torch.float64),
                                    torch.tensor(subject["template_rest_joints"],
                                                 dtype=torch.float64),
                                    torch.tensor([params["translation"]],
                                                 dtype=torch.float64)).joints[0]
        expected = torch.tensor(params["joints"], dtype=torch.float64)
        assert float((joints - expected).norm(dim=-1).max()) < 1e-9


def test_missing_annotation_file(tmp_path):
    (tmp_path / "FreiHAND").mkdir()
    with pytest.raises(FileNotFoundError, match="training_K.json: missing FreiHAND"):
        import_freihand(FreiHandConfig(root=str(tmp_path / "FreiHAND")), tmp_path / "out")
