"""The training engine on the toy problem: against a hand-written loop, logs, checkpoints,
resume, the NaN/inf guard, Ctrl-C, bad inputs."""

from __future__ import annotations

import io
import json
import math
import os
import signal

import pytest
import torch

from lisa_hand.model.checkpoint import load_checkpoint
from lisa_hand.training.checkpoint import NonFiniteError
from lisa_hand.training.config import TrainerConfig, lr_factor
from lisa_hand.training.engine import CONFIG_FILE, Trainer, train
from lisa_hand.training.progress import LOG_FILE
from lisa_hand.utils.config import load_config

from .toy import GLOBAL_BATCH, REG_WEIGHT, make_model, make_step_fn, target_fn


def _config(**kwargs) -> TrainerConfig:
    base = dict(steps=20, lr=1e-2, checkpoint_every=5, device="cpu", progress=False, seed=5)
    base.update(kwargs)
    return TrainerConfig(**base)


def _params(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def _max_diff(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> float:
    return max(float((a[k] - b[k]).abs().max()) for k in a)


def _log(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / LOG_FILE).read_text().splitlines()]


def _reference_loop(config: TrainerConfig) -> dict[str, torch.Tensor]:
    """The same training written out by hand: Adam, closed-form LR, torch's own clipping."""
    model = make_model(0)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, betas=config.betas)
    gen = torch.Generator().manual_seed(config.seed)
    for step in range(config.steps):
        warm = (step + 1) / config.warmup_steps if step < config.warmup_steps else 1.0
        progress = step / (config.steps - 1)
        final = config.lr_final_factor
        decay = {"constant": 1.0, "exponential": final ** progress,
                 "cosine": final + (1 - final) * 0.5 * (1 + math.cos(math.pi * progress))}
        for group in optimizer.param_groups:
            group["lr"] = config.lr * warm * decay[config.lr_schedule]
        x = torch.rand(GLOBAL_BATCH, 3, generator=gen, dtype=torch.float64) * 2 - 1
        y = target_fn(x).float()
        optimizer.zero_grad()
        loss = ((model(x.float()) - y) ** 2).mean()
        loss = loss + REG_WEIGHT * sum(p.pow(2).sum() for p in model.parameters())
        loss.backward()
        if config.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
        optimizer.step()
    return _params(model)


@pytest.mark.parametrize(
    "options",
    [dict(lr_schedule="cosine"),
     dict(lr_schedule="exponential", warmup_steps=4, grad_clip=0.5, lr_final_factor=0.3)],
)
def test_matches_a_hand_written_loop(tmp_path, options):
    config = _config(**options)
    model = make_model(0)
    result = train(model, make_step_fn(), config, tmp_path)
    assert result.status == "completed" and result.steps_done == 20 and result.start_step == 0
    assert _max_diff(_params(model), _reference_loop(config)) < 1e-6
    assert result.losses["total"] == pytest.approx(
        result.losses["data"] + result.losses["reg"], rel=1e-6)


def test_lr_factor_closed_forms():
    cos = TrainerConfig(steps=11, lr_schedule="cosine", lr_final_factor=0.2)
    assert lr_factor(0, cos) == pytest.approx(1.0)
    assert lr_factor(5, cos) == pytest.approx(0.6)  # halfway: (1 + 0.2) / 2
    assert lr_factor(10, cos) == pytest.approx(0.2)
    exp = TrainerConfig(steps=11, lr_schedule="exponential", lr_final_factor=0.25)
    assert lr_factor(5, exp) == pytest.approx(0.5)
    assert lr_factor(10, exp) == pytest.approx(0.25)
    warm = TrainerConfig(steps=11, warmup_steps=4)
    assert [lr_factor(s, warm) for s in range(5)] == pytest.approx([0.25, 0.5, 0.75, 1, 1])


def test_run_folder_config_log_and_checkpoints(tmp_path):
    config = _config(keep_every=10, lr_schedule="cosine", log_every=2)
    model = make_model(0)
    x_test = torch.rand(500, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    with torch.no_grad():
        error_before = float(((model(x_test) - target_fn(x_test)) ** 2).mean())
    result = train(model, make_step_fn(), config, tmp_path)
    with torch.no_grad():
        error_after = float(((model(x_test) - target_fn(x_test)) ** 2).mean())
    assert error_after < 0.5 * error_before  # it learns (2.5 -> 0.7)
    assert load_config(TrainerConfig, tmp_path / CONFIG_FILE) == config
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [CONFIG_FILE, "last.pt", LOG_FILE, "step_00000010.pt", "step_00000020.pt"]
    assert result.checkpoint == tmp_path / "last.pt"
    ckpt = load_checkpoint(tmp_path / "last.pt")
    assert ckpt.step == 20 and ckpt.trainer == json.loads((tmp_path / CONFIG_FILE).read_text())
    assert load_checkpoint(tmp_path / "step_00000010.pt").step == 10
    log = _log(tmp_path)
    assert [e["step"] for e in log] == list(range(1, 20, 2))  # every 2nd step, the last one
    for entry in log:
        assert entry["lr"] == pytest.approx(1e-2 * lr_factor(entry["step"], config))
        assert set(entry["losses"]) == {"total", "data", "reg"}
    assert log[-1]["losses"] == pytest.approx(result.losses)


def test_run_config_is_saved_and_checkpointed(tmp_path):
    from ..utils.test_config import RunCfg

    run_config = RunCfg(name="toy", training=_config(steps=3))
    train(make_model(0), make_step_fn(), run_config.training, tmp_path, run_config=run_config,
          extra_state=lambda: {"norm": torch.tensor([1.5])})
    assert load_config(RunCfg, tmp_path / CONFIG_FILE) == run_config
    ckpt = load_checkpoint(tmp_path / "last.pt")
    assert ckpt.config["name"] == "toy" and float(ckpt.extra["norm"]) == 1.5
    trainer = Trainer(make_model(0), make_step_fn(), _config(steps=4), tmp_path,
                      run_config=run_config)
    assert trainer.step == 3 and float(trainer.resumed_extra["norm"]) == 1.5


def test_resume_in_process_equals_an_uninterrupted_run(tmp_path):
    config = _config(lr_schedule="cosine", checkpoint_every=4)
    whole = make_model(0)
    train(whole, make_step_fn(global_rngs=True), config, tmp_path / "whole")

    part = tmp_path / "part"
    first = train(make_model(0), make_step_fn(global_rngs=True), config, part,
                  hooks=[lambda info: _stop_at(info, 10)])
    assert first.status == "interrupted" and first.steps_done == 11
    assert load_checkpoint(part / "last.pt").step == 11  # written at the stop, off-schedule
    resumed = make_model(7)  # other initial weights: the checkpoint must overwrite them
    second = train(resumed, make_step_fn(global_rngs=True), config, part)
    assert second.start_step == 11 and second.resumed_from == part / "last.pt"
    assert _max_diff(_params(resumed), _params(whole)) == 0.0
    drop_time = [{k: v for k, v in e.items() if k != "seconds"} for e in _log(part)]
    assert drop_time == [{k: v for k, v in e.items() if k != "seconds"}
                         for e in _log(tmp_path / "whole")]


def _stop_at(info, step):
    if info.step == step:
        os.kill(os.getpid(), signal.SIGINT)  # a Ctrl-C: the trainer finishes the step


def test_ctrl_c_checkpoints_and_restores_the_handler(tmp_path):
    before = signal.getsignal(signal.SIGINT)
    result = train(make_model(0), make_step_fn(), _config(), tmp_path,
                   hooks=[lambda info: _stop_at(info, 6)])
    assert result.status == "interrupted" and result.steps_done == 7
    assert result.checkpoint == tmp_path / "last.pt"
    assert load_checkpoint(tmp_path / "last.pt").step == 7
    assert signal.getsignal(signal.SIGINT) is before


def test_finished_run_does_nothing_and_resume_false_restarts(tmp_path):
    calls = []
    step_fn = make_step_fn()

    def counting(ctx):
        calls.append(ctx.step)
        return step_fn(ctx)

    train(make_model(0), counting, _config(steps=6), tmp_path)
    assert calls == list(range(6))
    again = train(make_model(0), counting, _config(steps=6), tmp_path)
    assert again.status == "completed" and again.steps_done == 6 and len(calls) == 6
    longer = train(make_model(0), counting, _config(steps=8), tmp_path)
    assert longer.start_step == 6 and calls[6:] == [6, 7]
    fresh = train(make_model(0), counting, _config(steps=3), tmp_path, resume=False)
    assert fresh.start_step == 0 and calls[8:] == [0, 1, 2]
    assert [e["step"] for e in _log(tmp_path)] == [0, 1, 2]
    other = tmp_path / "other"
    explicit = train(make_model(0), counting, _config(steps=4), other,
                     resume=tmp_path / "last.pt")
    assert explicit.start_step == 3
    with pytest.raises(FileNotFoundError, match="nope.pt: no such checkpoint"):
        Trainer(make_model(0), counting, _config(), other, resume=tmp_path / "nope.pt")


def test_nan_loss_stops_naming_the_step_and_term_and_keeps_the_last_good_checkpoint(tmp_path):
    config = _config()
    with pytest.raises(NonFiniteError, match=r"diverged at step 13: loss 'reg' is nan "
                                             r"\(also non-finite: total=nan\)") as info:
        train(make_model(0), make_step_fn(nan_at=13), config, tmp_path / "bad")
    assert str(tmp_path / "bad" / "last.pt") in str(info.value)
    ckpt = load_checkpoint(tmp_path / "bad" / "last.pt")
    assert ckpt.step == 10
    assert all(torch.isfinite(v).all() for v in ckpt.model.values())
    assert [e["step"] for e in _log(tmp_path / "bad")] == list(range(13))
    clean = make_model(0)
    train(clean, make_step_fn(), _config(steps=10), tmp_path / "clean")
    assert _max_diff(ckpt.model, _params(clean)) == 0.0


def test_nan_gradient_with_finite_losses_is_caught(tmp_path):
    with pytest.raises(NonFiniteError, match=r"step 7: the gradient is non-finite .* in "
                                             r"'layers.0.weight'.*no checkpoint was written"):
        train(make_model(0), make_step_fn(grad_nan_at=7), _config(checkpoint_every=0),
              tmp_path)
    assert not (tmp_path / "last.pt").exists()


def test_progress_bar_on_a_terminal(tmp_path, monkeypatch):
    class FakeTerminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = FakeTerminal()
    monkeypatch.setattr("sys.stderr", terminal)
    train(make_model(0), make_step_fn(), _config(progress=True, steps=6), tmp_path)
    text = terminal.getvalue()
    assert "6/6" in text and "total=" in text and "reg=" in text and "lr=" in text


def test_progress_lines_when_not_a_terminal(tmp_path, capsys):
    train(make_model(0), make_step_fn(), _config(progress=True, steps=6, print_every=3),
          tmp_path)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("step")]
    assert [line.split()[1] for line in lines] == ["3/6", "6/6"]


@pytest.mark.parametrize(
    ("returned", "expected"),
    [
        ({"data": torch.tensor(1.0)}, r"step 0: step_fn must return a dict with a 'total'"),
        ({"total": torch.ones(2, requires_grad=True)}, r"'total' must be a scalar tensor"),
        ({"total": torch.tensor(1.0)}, r"'total' does not require grad"),
        ({"total": torch.tensor(1.0, requires_grad=True), "x": "a"}, r"loss 'x' must be"),
    ],
)
def test_bad_step_outputs_are_refused(tmp_path, returned, expected):
    with pytest.raises(ValueError, match=expected):
        train(make_model(0), lambda ctx: returned, _config(), tmp_path)


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        (dict(steps=0), "steps must be a positive int"),
        (dict(lr=float("nan")), "lr must be a positive finite number"),
        (dict(lr_final_factor=0.0), r"lr_final_factor must be in \(0, 1\]"),
        (dict(betas=(0.9, 1.0)), "betas must be two numbers"),
        (dict(grad_clip=-1.0), "grad_clip must be >= 0"),
        (dict(grad_sync="nccl"), "grad_sync must be"),
        (dict(log_every=0), "log_every must be a positive int"),
    ],
)
def test_bad_trainer_configs(kwargs, expected):
    with pytest.raises(ValueError, match=expected):
        TrainerConfig(**kwargs)


def test_bad_device_and_mismatched_checkpoint(tmp_path):
    with pytest.raises(ValueError, match="'tpu' is not a valid device"):
        Trainer(make_model(0), make_step_fn(), _config(device="tpu"), tmp_path)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="CUDA is not available"):
            Trainer(make_model(0), make_step_fn(), _config(device="cuda"), tmp_path)
    train(make_model(0), make_step_fn(), _config(steps=2), tmp_path)
    from .toy import ToyMLP

    with pytest.raises(ValueError, match=rf"{tmp_path / 'last.pt'}: the checkpoint does not "
                                         "fit the model"):
        Trainer(ToyMLP(hidden=5), make_step_fn(), _config(), tmp_path)
