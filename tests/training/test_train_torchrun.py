"""Both trainers under torchrun (2 CPU processes, gloo), with DistributedDataParallel or a manual
gradient all-reduce, give the weights of one process."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from lisa_hand.model.checkpoint import load_checkpoint
from lisa_hand.training.images import train_images
from lisa_hand.training.prior import train_prior

from .conftest import tiny_image_config, tiny_prior_config, tiny_trainer

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.parametrize("grad_sync", ["ddp", "allreduce"])
def test_two_processes_match_one_process(tiny_data, tmp_path, grad_sync):
    torchrun = shutil.which("torchrun") or str(Path(sys.executable).with_name("torchrun"))
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(name, None)
    proc = subprocess.run(
        [torchrun, "--standalone", "--nproc_per_node", "2", "-m", "tests.training.run_tiny",
         "--data", str(tiny_data), "--out", str(tmp_path / "multi"), "--steps", "3",
         "--grad-sync", grad_sync],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    trainer = tiny_trainer(steps=3, grad_sync="allreduce")
    train_prior(tiny_data, tmp_path / "single/prior", tiny_prior_config(trainer=trainer))
    train_images(tiny_data, tmp_path / "single/images", tiny_image_config(trainer=trainer))
    for kind in ("prior", "images"):
        multi = load_checkpoint(tmp_path / "multi" / kind / "last.pt")
        single = load_checkpoint(tmp_path / "single" / kind / "last.pt")
        assert multi.step == single.step == 3
        for key, value in single.model.items():
            torch.testing.assert_close(multi.model[key], value, rtol=0, atol=1e-5, msg=key)
        # The pose offsets moved (refinement from step 1 of 3), identically.
        if kind == "images":
            assert float(single.model["pose_offsets"].abs().max()) > 0
