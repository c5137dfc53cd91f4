"""``lisa import``: the three verbs end to end, and bad input as one line."""

from __future__ import annotations

import pytest

from lisa_hand.cli.main import main
from lisa_hand.data.datasets import read_frame_table
from tests.data.importers.fixtures import freihand_fixture, interhand_fixture


def run(capsys, *args):
    code = 0
    try:
        main([str(a) for a in args])
    except SystemExit as exc:
        code = exc.code or 0
    return code, capsys.readouterr()


def test_interhand_cli(tmp_path, capsys):
    interhand_fixture(tmp_path / "ih")
    code, output = run(capsys, "import", "interhand2.6m", tmp_path / "ih", "--out",
                       tmp_path / "DATA", "--split", "train", "--hand", "right", "--captures",
                       "Capture0", "--quiet")
    assert code == 0, output.err
    assert "imported InterHand2.6M: 6 frames" in output.out  # frames 0-3, 6, 9
    assert "skipped: 1 invalid joints, 1 missing annotation, 1 missing image" in output.out
    assert read_frame_table(tmp_path / "DATA", "train").num_frames == 6
    # Again into the same folder: refused in one line.
    code, output = run(capsys, "import", "interhand2.6m", tmp_path / "ih", "--out",
                       tmp_path / "DATA", "--quiet")
    assert code == 2 and output.err.count("\n") == 1 and "not empty" in output.err


def test_freihand_cli(tmp_path, capsys):
    freihand_fixture(tmp_path / "fh", num=3)
    code, output = run(capsys, "import", "freihand", tmp_path / "fh", "--out", tmp_path / "D",
                       "--versions", "0,1", "--quiet")
    assert code == 0, output.err
    assert "imported FreiHAND: 4 frames" in output.out


@pytest.mark.parametrize("verb", ["interhand2.6m", "freihand", "scans"])
def test_missing_input_is_one_line(tmp_path, capsys, verb):
    code, output = run(capsys, "import", verb, tmp_path / "nothing", "--out", tmp_path / "o")
    assert code == 2
    assert output.err.startswith("lisa: error: ") and output.err.count("\n") == 1
    assert "Traceback" not in output.err


def test_help_explains(capsys):
    code, output = run(capsys, "import", "interhand2.6m", "--help")
    assert code == 0 and "--mano" in output.out and "--every" in output.out


def test_scans_cli_pose_search_or_skip(tmp_path, capsys, monkeypatch):
    """A scan with no keypoints or MANO file: fitted by the point-cloud pose search (here a
    stand-in for the fit that returns the template's keypoints), or skipped and counted with
    --no-pose-search."""
    import torch

    import lisa_hand.cli.import_data as import_data
    from lisa_hand.data.meshio import save_mesh
    from lisa_hand.geometry.meshing import Mesh
    from lisa_hand.handmodel.template import load_template

    template = load_template().to(dtype=torch.float64)
    posed = template(torch.zeros(1, 48, dtype=torch.float64),
                     torch.zeros(1, template.num_betas, dtype=torch.float64),
                     torch.tensor([[0.0, 0.0, 0.4]], dtype=torch.float64))
    (tmp_path / "scans").mkdir()
    save_mesh(tmp_path / "scans" / "bare.ply", Mesh(vertices=posed.vertices[0].numpy(),
                                                    faces=template.faces.numpy()))
    models = []

    def stand_in(model_path):
        models.append(model_path)
        return lambda points, normals, side: posed.keypoints[0].numpy()

    monkeypatch.setattr(import_data, "scan_pose_search", stand_in)
    code, output = run(capsys, "import", "scans", tmp_path / "scans", "--out", tmp_path / "D",
                       "--points", "1000", "--sdf-samples", "200", "--quiet")
    assert code == 0, output.err
    assert "1 frames" in output.out and models == [None]
    code, output = run(capsys, "import", "scans", tmp_path / "scans", "--out", tmp_path / "E",
                       "--no-pose-search", "--quiet")
    assert code == 2 and "no frame could be imported" in output.err
