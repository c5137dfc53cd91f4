"""kill -9 in the middle of a run, resume in a new process: same result as an uninterrupted run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import torch

from lisa_hand.model.checkpoint import load_checkpoint
from lisa_hand.training.config import TrainerConfig
from lisa_hand.training.engine import train
from lisa_hand.training.progress import LOG_FILE

from .toy import make_model, make_step_fn

REPO = Path(__file__).resolve().parents[2]


def _run_toy(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "tests.training.toy", *args], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=120)


def test_kill_9_then_resume_equals_an_uninterrupted_run(tmp_path):
    run = tmp_path / "run"
    common = ["--out", str(run), "--steps", "40", "--checkpoint-every", "10", "--global-rngs"]
    killed = _run_toy(*common, "--kill-at", "27")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert load_checkpoint(run / "last.pt").step == 20
    logged = [json.loads(line)["step"] for line in (run / LOG_FILE).read_text().splitlines()]
    assert logged == list(range(27))  # steps 20..26 are logged but not in the checkpoint

    resumed = _run_toy(*common)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming from" in resumed.stderr and "at step 20" in resumed.stderr
    final = torch.load(run / "final.pt")

    # The uninterrupted reference, in this process (same settings as the toy script; the
    # training folder's autouse fixture runs every test on one thread, as the script does).
    config = TrainerConfig(steps=40, lr=1e-2, lr_schedule="cosine", checkpoint_every=10,
                           device="cpu", progress=False, seed=5)
    model = make_model(0)
    train(model, make_step_fn(global_rngs=True), config, tmp_path / "whole")
    for key, value in model.state_dict().items():
        torch.testing.assert_close(final[key], value, rtol=0, atol=1e-7)

    def entries(path):
        return [{k: v for k, v in json.loads(line).items() if k != "seconds"}
                for line in (path / LOG_FILE).read_text().splitlines()]

    ours, reference = entries(run), entries(tmp_path / "whole")
    assert [e["step"] for e in ours] == list(range(40))
    for mine, theirs in zip(ours, reference, strict=True):
        assert mine["lr"] == theirs["lr"]
        for name, value in theirs["losses"].items():
            assert abs(mine["losses"][name] - value) <= 1e-6 * max(1.0, abs(value))
