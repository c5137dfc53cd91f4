"""``lisa train-prior`` and ``lisa train`` through typer's CliRunner on an app with only them."""

from __future__ import annotations

import json

import pytest
import typer
from typer.testing import CliRunner

from lisa_hand.cli import train as train_cli
from lisa_hand.model.checkpoint import load_checkpoint
from lisa_hand.training.images import ImageTrainConfig
from lisa_hand.training.prior import PriorConfig
from lisa_hand.utils.config import config_to_dict, load_config

from .conftest import tiny_image_config, tiny_prior_config


@pytest.fixture(scope="module")
def app():
    app = typer.Typer()

    @app.callback()
    def _root() -> None:
        """test app"""

    train_cli.register(app)
    return app


def _write(path, config) -> str:
    path.write_text(json.dumps(config_to_dict(config)))
    return str(path)


def test_train_prior_then_train_with_the_prior(app, tiny_data, tmp_path):
    runner = CliRunner()
    prior_config = _write(tmp_path / "prior.json", tiny_prior_config())
    prior_run = tmp_path / "prior"
    result = runner.invoke(app, ["train-prior", str(tiny_data), "--out", str(prior_run),
                                 "--config", prior_config, "--steps", "3",
                                 "--set", "lambda_eik=0.2", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert "completed: 3 steps" in result.output and "last.pt" in result.output
    saved = load_config(PriorConfig, prior_run / "config.json")
    assert saved.trainer.steps == 3 and saved.lambda_eik == 0.2
    assert saved.field == tiny_prior_config().field

    # Running again with more steps resumes; --no-resume starts afresh.
    result = runner.invoke(app, ["train-prior", str(tiny_data), "--out", str(prior_run),
                                 "--config", prior_config, "--steps", "4",
                                 "--set", "lambda_eik=0.2"])
    assert result.exit_code == 0, result.output
    assert "completed: 4 steps (1 in this call" in result.output

    image_config = _write(tmp_path / "image.json", tiny_image_config())
    image_run = tmp_path / "image"
    result = runner.invoke(app, ["train", str(tiny_data), "--out", str(image_run), "--prior",
                                 str(prior_run), "--config", image_config, "--steps", "2"])
    assert result.exit_code == 0, result.output
    assert "completed: 2 steps" in result.output
    assert load_checkpoint(image_run / "last.pt").extra["prior"] == str(prior_run)
    assert load_config(ImageTrainConfig, image_run / "config.json").trainer.steps == 2

    again = tmp_path / "prior_again"
    result = runner.invoke(app, ["train-prior", str(tiny_data), "--out", str(again),
                                 "--init", str(prior_run), "--config", prior_config,
                                 "--steps", "1"])
    assert result.exit_code == 0, result.output
    assert load_checkpoint(again / "last.pt").extra["init"] == str(prior_run)

    result = runner.invoke(app, ["train", str(tiny_data), "--out", str(image_run), "--config",
                                 image_config, "--steps", "1", "--no-resume"])
    assert result.exit_code == 0, result.output
    assert "completed: 1 steps (1 in this call" in result.output


def test_bad_options_raise_clear_errors(app, tiny_data, tmp_path):
    runner = CliRunner()
    result = runner.invoke(app, ["train-prior", str(tiny_data), "--out", str(tmp_path / "run"),
                                 "--set", "lambda_surface=3"])
    assert isinstance(result.exception, ValueError)
    assert "unknown key 'lambda_surface'" in str(result.exception)
    result = runner.invoke(app, ["train-prior", str(tiny_data), "--out", str(tmp_path / "run"),
                                 "--init", str(tmp_path / "no_such_prior")])
    assert isinstance(result.exception, (ValueError, FileNotFoundError))
    assert "no_such_prior" in str(result.exception)
    assert not (tmp_path / "run" / "last.pt").exists()
    result = runner.invoke(app, ["train", str(tmp_path / "missing"), "--out",
                                 str(tmp_path / "run"), "--set", "num_rays=7",
                                 "--set", "num_frames=2"])
    assert isinstance(result.exception, ValueError)
    assert "num_rays (7) must be a multiple of num_frames (2)" in str(result.exception)
    result = runner.invoke(app, ["train", str(tmp_path / "missing"), "--out",
                                 str(tmp_path / "run"), "--steps", "1"])
    assert isinstance(result.exception, FileNotFoundError)
    assert "no such dataset folder" in str(result.exception)


def test_help_explains_torchrun(app):
    for verb in ("train-prior", "train"):
        result = CliRunner().invoke(app, [verb, "--help"])
        assert result.exit_code == 0
        assert "torchrun" in result.output and "--nproc_per_node" in result.output
