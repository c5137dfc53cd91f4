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
