"""``lisa synth --hand-model``: the generator's hand model version (v1 by default, unchanged)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from lisa_hand.cli.synth import register
from lisa_hand.data.scans import ScanConfig
from lisa_hand.data.synth.compare import write_model_comparison
from lisa_hand.data.synth.config import _HAND_MODELS
from lisa_hand.data.synth.dataset import SynthConfig
from lisa_hand.data.synth.scene import make_subject
from lisa_hand.handmodel import HAND_MODELS

TINY = SynthConfig(num_subjects=1, num_poses=1, num_views=1, resolution=(40, 30), seed=3,
                   scan=ScanConfig(num_points=100), num_sdf_samples=50, voxels_per_length=32,
                   num_workers=1)


def test_config_default_is_v1_and_v1_configs_are_written_as_before():
    assert _HAND_MODELS == HAND_MODELS
    assert SynthConfig().hand_model == "v1"
    assert "hand_model" not in SynthConfig().to_dict()  # dataset.json of v1 as before versions
    assert SynthConfig(hand_model="v2").to_dict()["hand_model"] == "v2"
    assert SynthConfig(hand_model="v3").to_dict()["hand_model"] == "v3"
    with pytest.raises(ValueError, match="hand_model must be one of v1, v2, v3"):
        SynthConfig(hand_model="v4")


def test_a_v3_dataset_is_made_of_makehuman_hands(tmp_path):
    from lisa_hand.data.synth.dataset import synthesize
    from lisa_hand.handmodel.makehuman import MakeHumanShape

    config = dataclasses.replace(TINY, hand_model="v3")
    synthesize(tmp_path / "v3", config, progress=False)
    subject = json.loads((tmp_path / "v3" / "s000" / "subject.json").read_text())
    assert subject["hand_model"] == "v3"
    assert MakeHumanShape(**subject["shape"]) == make_subject(config, 0, False).hand.shape
    from lisa_hand.data.layout import FramePaths

    frame = FramePaths(tmp_path / "v3" / "s000" / "f000")
    with np.load(frame.scan) as scan:
        assert abs(scan["sdf"]).max() < 0.05 and scan["weights"].shape == (100, 16)
    assert frame.mesh.exists() and frame.image("cam000").exists()


def test_subjects_of_v2_are_v2_hands_and_say_so():
    v1 = make_subject(TINY, 0, fit_template=False)
    v2 = make_subject(dataclasses.replace(TINY, hand_model="v2"), 0, fit_template=False)
    assert v1.hand.model == "v1" and v2.hand.model == "v2"
    assert "hand_model" not in v1.to_json() and v2.to_json()["hand_model"] == "v2"
    assert v1.hand.shape != v2.hand.shape  # drawn from a different distribution


@pytest.fixture()
def app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def _root() -> None:
        """Test app."""

    register(app)
    return app


def test_cli_hand_model_option(app, tmp_path):
    out = tmp_path / "v2"
    result = CliRunner().invoke(app, [
        "synth", str(out), "--subjects", "1", "--poses", "1", "--views", "1", "--resolution",
        "40x30", "--workers", "1", "--scan-points", "100", "--sdf-samples", "50",
        "--mesh-resolution", "32", "--quiet", "--hand-model", "v2",
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads((out / "dataset.json").read_text())["config"]["hand_model"] == "v2"
    assert json.loads((out / "s000" / "subject.json").read_text())["hand_model"] == "v2"
    result = CliRunner().invoke(app, ["synth", str(tmp_path / "x"), "--hand-model", "v9"])
    assert isinstance(result.exception, ValueError) and "v9" in str(result.exception)
    help_text = CliRunner().invoke(app, ["synth", "--help"]).output
    assert "--hand-model" in help_text


def test_comparison_sheet(tmp_path):
    from lisa_hand.data.layout import read_image

    path = write_model_comparison(tmp_path / "c.png", num_subjects=1, tile_size=40,
                                  voxels_per_length=24, progress=False)
    sheet = read_image(path)
    assert sheet.shape == (4 * 40 + 3 * 4, 40, 3)  # rows: v1 rest, v1 posed, v2 rest, v2 posed
    for row in range(4):
        tile = sheet[row * 44 : row * 44 + 40]
        assert 0.05 < (tile.min(-1) < 0.95).mean() < 0.95  # a hand on a white tile
    with pytest.raises(ValueError, match="png"):
        write_model_comparison(tmp_path / "c.jpg")
