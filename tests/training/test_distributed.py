"""Data parallelism: batch splitting and loss scaling, and 2 gloo processes == 1 process."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from lisa_hand.training.config import TrainerConfig
from lisa_hand.training.distributed import (
    DistContext,
    global_mean,
    init_distributed,
    resolve_device,
    shard,
    shard_slice,
    unwrap,
    wrap_ddp,
)
from lisa_hand.training.engine import train

from .toy import GLOBAL_BATCH, make_model, make_step_fn, target_fn

REPO = Path(__file__).resolve().parents[2]


def _ctx(rank: int, world_size: int) -> DistContext:
    # No process group is needed for the pure slicing/scaling helpers.
    return DistContext(rank=rank, world_size=world_size)


def test_shard_slices_cover_the_batch_once():
    for num_items, world in [(25, 2), (25, 3), (7, 7), (100, 8)]:
        parts = [shard_slice(num_items, _ctx(r, world)) for r in range(world)]
        covered = [i for part in parts for i in range(num_items)[part]]
        assert covered == list(range(num_items))
        assert max(p.stop - p.start for p in parts) - min(p.stop - p.start for p in parts) <= 1
    with pytest.raises(ValueError, match="3 items cannot be split among 4 ranks"):
        shard_slice(3, _ctx(0, 4))


def test_shard_tree_and_errors():
    batch = {"x": torch.arange(10).reshape(5, 2), "y": (torch.arange(5), "label")}
    part = shard(batch, _ctx(1, 2))
    assert part["x"].tolist() == [[4, 5], [6, 7], [8, 9]] and part["y"][0].tolist() == [2, 3, 4]
    assert part["y"][1] == "label"
    assert shard(batch, _ctx(0, 1)) is batch
    columns = shard(torch.arange(12).reshape(2, 6), _ctx(0, 3), dim=1)
    assert columns.tolist() == [[0, 1], [6, 7]]
    with pytest.raises(ValueError, match="disagree on their size along dim 0"):
        shard((torch.zeros(4), torch.zeros(5)), _ctx(0, 2))


@pytest.mark.parametrize("world", [2, 3, 4])
def test_global_mean_gradients_average_to_the_full_batch_gradient(world):
    """What DDP computes (the average over ranks of each rank's gradient) equals the gradient of
    the mean over the global batch, also when the batch does not divide evenly (25 items)."""
    model = make_model(0, torch.float64)
    x = torch.rand(GLOBAL_BATCH, 3, generator=torch.Generator().manual_seed(3),
                   dtype=torch.float64) * 2 - 1
    y = target_fn(x)

    def grads(loss):
        return torch.cat([g.reshape(-1) for g in torch.autograd.grad(loss, model.parameters())])

    full = grads(((model(x) - y) ** 2).mean())
    scaled, naive = [], []
    for rank in range(world):
        ctx = _ctx(rank, world)
        x_local, y_local = shard((x, y), ctx)
        scaled.append(grads(global_mean(((model(x_local) - y_local) ** 2).sum(-1),
                                        GLOBAL_BATCH, ctx)))
        naive.append(grads(((model(x_local) - y_local) ** 2).mean()))
    torch.testing.assert_close(torch.stack(scaled).mean(0), full, rtol=1e-12, atol=1e-14)
    # The per-rank plain mean is biased when the slices differ in size (25 = 12 + 13, ...).
    assert (torch.stack(naive).mean(0) - full).abs().max() > 1e-6


def test_one_process_without_torchrun(monkeypatch):
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK"):
        monkeypatch.delenv(name, raising=False)
    ctx = init_distributed("cpu")
    assert (ctx.rank, ctx.world_size, ctx.backend, ctx.is_main) == (0, 1, None, True)
    assert not ctx.is_distributed and ctx.device == torch.device("cpu")
    model = make_model(0)
    assert wrap_ddp(model, ctx) is model and unwrap(model) is model
    assert resolve_device("cpu") == torch.device("cpu")
    expected = "cuda:0" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto") == torch.device(expected)


def test_bad_torchrun_environment(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    monkeypatch.delenv("MASTER_ADDR", raising=False)
    with pytest.raises(ValueError, match="MASTER_ADDR is not set"):
        init_distributed("cpu")
    monkeypatch.setenv("RANK", "5")
    with pytest.raises(ValueError, match="RANK=5, WORLD_SIZE=2"):
        init_distributed("cpu")
    monkeypatch.setenv("WORLD_SIZE", "two")
    with pytest.raises(ValueError, match="WORLD_SIZE must be an integer"):
        init_distributed("cpu")


def test_two_gloo_processes_match_one_process(tmp_path):
    """torchrun, 2 processes on CPU (gloo), global batch 25 split 12 + 13, float64: the final
    weights equal one process on the same global batch, in both gradient-sync modes."""
    torchrun = shutil.which("torchrun") or str(Path(sys.executable).with_name("torchrun"))
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(name, None)
    steps = 12
    proc = subprocess.run(
        [torchrun, "--standalone", "--nproc_per_node", "2", "-m", "tests.training.toy",
         "--out", str(tmp_path), "--steps", str(steps), "--checkpoint-every", "5",
         "--grad-sync", "ddp,allreduce", "--dtype", "float64"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    config = TrainerConfig(steps=steps, lr=1e-2, lr_schedule="cosine", checkpoint_every=5,
                           device="cpu", progress=False, seed=5)
    single = make_model(0, torch.float64)
    train(single, make_step_fn(), config, tmp_path / "single")
    start = make_model(0, torch.float64).state_dict()
    for mode in ("ddp", "allreduce"):
        final = torch.load(tmp_path / mode / "final.pt")
        for key, value in single.state_dict().items():
            assert not torch.equal(value, start[key])  # the weights did move
            torch.testing.assert_close(final[key], value, rtol=1e-10, atol=1e-12)
        # The log (rank 0) holds the global-batch losses, as in one process.
        single_log = (tmp_path / "single" / "log.jsonl").read_text().splitlines()
        multi_log = (tmp_path / mode / "log.jsonl").read_text().splitlines()
        assert len(multi_log) == len(single_log) == steps
