"""``train_prior`` on the tiny dataset: it learns, checkpoints what rebuilds it, resumes exactly,
and refuses bad settings."""

from __future__ import annotations

import dataclasses
import json
import os
import signal

import pytest
import torch

from lisa_hand.fields.config import FieldConfig
from lisa_hand.model.checkpoint import PRIOR_KIND, load_checkpoint
from lisa_hand.training.distributed import DistContext
from lisa_hand.training.prior import PriorConfig, PriorModel, load_prior, train_prior
from lisa_hand.training.runs import batch_mean
from lisa_hand.utils.config import apply_overrides, load_config

from .conftest import tiny_prior_config, tiny_trainer


def _log(run) -> list[dict]:
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


def _mean(entries: list[dict], key: str) -> float:
    return sum(entry["losses"][key] for entry in entries) / len(entries)


def _probe_points() -> torch.Tensor:
    generator = torch.Generator().manual_seed(11)
    return torch.rand(1, 64, 3, generator=generator) * torch.tensor([0.16, 0.06, 0.1]) \
        + torch.tensor([0.0, -0.03, -0.05])


def _probe_sdf(prior, table, frame: int = 0) -> torch.Tensor:
    subject = table.frame_subject[frame : frame + 1]
    with torch.no_grad():
        state = prior.field.prepare(table.pose[frame : frame + 1],
                                    table.translation[frame : frame + 1],
                                    table.rest_joints[subject], prior.shape_codes(subject))
        return prior.field.field(state, _probe_points(), with_color=False).sdf


def test_tiny_prior_lowers_its_losses_and_checkpoints_a_rebuildable_model(tiny_data, tmp_path):
    from lisa_hand.data.datasets import read_frame_table

    table = read_frame_table(tiny_data, "train")
    config = tiny_prior_config(trainer=tiny_trainer(steps=40))
    captured = {}

    def capture(info):
        if info.step + 1 == config.trainer.steps:
            model = info.trainer.model
            model.eval()
            captured["sdf"] = _probe_sdf(model, table)
            model.train()

    result = train_prior(tiny_data, tmp_path, config, hooks=[capture])
    assert result.status == "completed" and result.steps_done == 40
    log = _log(tmp_path)
    assert set(log[0]["losses"]) == {"total", "surf", "normal", "eik", "w", "reg"}
    first, last = log[:5], log[-5:]
    assert _mean(last, "total") < 0.65 * _mean(first, "total")
    assert _mean(last, "surf") < 0.6 * _mean(first, "surf")
    assert _mean(last, "normal") < _mean(first, "normal")

    assert load_config(PriorConfig, tmp_path / "config.json") == config
    ckpt = load_checkpoint(tmp_path / "last.pt")
    assert ckpt.extra["kind"] == PRIOR_KIND and ckpt.extra["subject_ids"] == ["s000", "s001"]
    prior = load_prior(tmp_path)
    assert prior.field.config == config.field and prior.subject_ids == ["s000", "s001"]
    assert not prior.training
    assert torch.equal(_probe_sdf(prior, table), captured["sdf"])
    assert prior.shape_codes.weight.shape == (2, config.field.shape_dim)


def test_an_exported_prior_loads_as_the_same_prior(tiny_data, tmp_path):
    from lisa_hand.data.datasets import read_frame_table
    from lisa_hand.model.trained import export_trained, load_trained

    table = read_frame_table(tiny_data, "train")
    run = tmp_path / "run"
    train_prior(tiny_data, run, tiny_prior_config(trainer=tiny_trainer(steps=3)))
    exported, _ = export_trained(load_trained(run), tmp_path / "prior.pt")
    direct, again = load_prior(run), load_prior(exported)
    assert again.subject_ids == direct.subject_ids and not again.training
    assert not again.field.config.use_color
    assert torch.equal(again.shape_codes.weight, direct.shape_codes.weight)
    assert torch.allclose(_probe_sdf(again, table), _probe_sdf(direct, table), atol=1e-7)
    # a file that is neither a checkpoint nor an exported model is refused, naming it
    bad = tmp_path / "notes.pt"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="notes.pt"):
        load_prior(bad)


def test_a_prior_started_from_another_takes_its_networks_codes_and_architecture(tiny_data,
                                                                                 tmp_path):
    from lisa_hand.data.datasets import read_frame_table

    table = read_frame_table(tiny_data, "train")
    first = tiny_prior_config(trainer=tiny_trainer(steps=6))
    train_prior(tiny_data, tmp_path / "first", first)
    before = load_prior(tmp_path / "first")
    # Another architecture asked for: the start's is taken (its weights would not fit).
    wider = dataclasses.replace(first.field, sdf_hidden=first.field.sdf_hidden * 2)
    config = tiny_prior_config(field=wider, trainer=tiny_trainer(steps=1, lr=1e-12))
    train_prior(tiny_data, tmp_path / "second", config, init=tmp_path / "first")
    second = load_prior(tmp_path / "second")
    assert second.field.config == first.field
    assert load_config(PriorConfig, tmp_path / "second/config.json").field == first.field
    assert load_checkpoint(tmp_path / "second/last.pt").extra["init"] == str(tmp_path / "first")
    # lr 1e-12: one step moves nothing measurable; the same field and codes as the start.
    assert torch.allclose(second.shape_codes.weight, before.shape_codes.weight, atol=1e-9)
    assert torch.allclose(_probe_sdf(second, table), _probe_sdf(before, table), atol=1e-7)

    # The val split's subject is new to the start: it begins at the start's mean code.
    third = load_prior(tmp_path / "first")
    fresh = PriorModel(first.field, ["s000", "s999"])
    assert fresh.start_from(third) == ["s999"]
    assert torch.equal(fresh.shape_codes.weight[0], third.shape_codes.weight[0])
    assert torch.allclose(fresh.shape_codes.weight[1], third.shape_codes.weight.mean(0))


def _stop_at(step: int):
    def hook(info):
        if info.step == step:
            os.kill(os.getpid(), signal.SIGINT)  # like Ctrl-C: the step finishes, checkpoint

    return hook


def test_resume_equals_an_uninterrupted_run(tiny_data, tmp_path, capsys):
    config = tiny_prior_config(trainer=tiny_trainer(steps=16, lr_schedule="cosine",
                                                    checkpoint_every=5))
    train_prior(tiny_data, tmp_path / "whole", config)
    first = train_prior(tiny_data, tmp_path / "part", config, hooks=[_stop_at(7)])
    assert first.status == "interrupted" and first.steps_done == 8
    capsys.readouterr()
    second = train_prior(tiny_data, tmp_path / "part", config)
    assert second.start_step == 8 and second.steps_done == 16
    assert "lisa train-prior: resuming" in capsys.readouterr().err
    whole = load_checkpoint(tmp_path / "whole/last.pt").model
    part = load_checkpoint(tmp_path / "part/last.pt").model
    assert whole.keys() == part.keys()
    for key in whole:
        assert torch.allclose(whole[key], part[key], atol=1e-6, rtol=0), key
    # A fresh run from the same seed starts from the same weights and draws the same batches.
    train_prior(tiny_data, tmp_path / "again", config)
    again = load_checkpoint(tmp_path / "again/last.pt").model
    assert all(torch.equal(again[key], whole[key]) for key in whole)


def test_resume_refuses_a_checkpoint_of_other_subjects(tiny_data, tmp_path):
    config = tiny_prior_config(trainer=tiny_trainer(steps=2))
    train_prior(tiny_data, tmp_path, config)
    # The val split has one subject: the code table no longer fits.
    more = tiny_prior_config(trainer=tiny_trainer(steps=4), split="val")
    with pytest.raises(ValueError, match="does not fit the model"):
        train_prior(tiny_data, tmp_path, more)


def test_optional_sdf_term_and_latent_lr(tiny_data, tmp_path):
    config = tiny_prior_config(trainer=tiny_trainer(steps=2), lambda_sdf=10.0, latent_lr=1e-2)
    train_prior(tiny_data, tmp_path, config)
    assert "sdf" in _log(tmp_path)[0]["losses"]
    optimizer = load_checkpoint(tmp_path / "last.pt").optimizer
    assert [group["lr"] for group in optimizer["param_groups"]] == pytest.approx(
        [config.trainer.lr, 1e-2], rel=1e-6)


def test_batch_mean_over_ranks_is_the_global_mean():
    values = torch.tensor([0.3, 1.2, 2.0])  # per-frame means of a global batch of 3 frames
    shares = []
    for rank, part in ((0, values[:1]), (1, values[1:])):
        ctx = DistContext(rank=rank, world_size=2)
        shares.append(batch_mean(part.mean(), part.numel(), 3, ctx))
    assert float(sum(shares) / 2) == pytest.approx(float(values.mean()), rel=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(frames_per_step=0), "frames_per_step must be a positive int"),
        (dict(surface_points=2.5), "surface_points must be a positive int"),
        (dict(lambda_surf=-1.0), "lambda_surf must be a finite number >= 0"),
        (dict(near_fraction=1.5), "near_fraction must be in"),
        (dict(split="training"), "split must be one of"),
        (dict(latent_lr=0.0), "latent_lr must be > 0"),
        (dict(field=FieldConfig()), "use_color must be false"),
    ],
)
def test_bad_config_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PriorConfig(**kwargs)


def test_bad_overrides_name_the_key():
    with pytest.raises(ValueError, match="lambda_eik"):
        apply_overrides(PriorConfig(), ["lambda_eik=-2"])
    with pytest.raises(ValueError, match="unknown key 'lambda_surface'"):
        apply_overrides(PriorConfig(), ["lambda_surface=1"])
    config = apply_overrides(PriorConfig(), ["field.sdf_hidden=64", "trainer.steps=5"])
    assert config.field.sdf_hidden == 64 and config.trainer.steps == 5


def test_missing_dataset_and_all_zero_weights(tiny_data, tmp_path):
    with pytest.raises(FileNotFoundError, match="no such dataset folder"):
        train_prior(tmp_path / "nowhere", tmp_path / "run", tiny_prior_config())
    zero = tiny_prior_config(lambda_surf=0.0, lambda_normal=0.0, lambda_eik=0.0, lambda_w=0.0,
                             lambda_reg=0.0)
    with pytest.raises(ValueError, match="every loss weight is 0"):
        train_prior(tiny_data, tmp_path / "run", zero)
    with pytest.raises(FileNotFoundError, match="no checkpoint in this run folder"):
        load_prior(tmp_path)
