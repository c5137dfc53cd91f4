"""A tiny problem for the engine tests: an MLP regressing a fixed smooth function of 3 inputs.

Also a script, so that tests can run it in subprocesses (kill -9, torchrun)::

    python -m tests.training.toy --out RUN --steps 40 [--kill-at 27] [--global-rngs]
    torchrun --standalone --nproc_per_node 2 -m tests.training.toy --out RUN --grad-sync ddp

It writes the final weights to ``RUN/final.pt`` (rank 0).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
from pathlib import Path

import numpy as np
import torch
from torch import nn

from lisa_hand.training.config import TrainerConfig
from lisa_hand.training.distributed import (
    cleanup,
    end_process,
    global_mean,
    group_was_created,
    init_distributed,
    shard,
    unwrap,
)
from lisa_hand.training.engine import StepContext, StepInfo, train
from lisa_hand.utils.threads import single_thread_worker

GLOBAL_BATCH = 25
"""Odd on purpose: two ranks get 12 and 13 items, which exercises ``global_mean``'s scaling."""
REG_WEIGHT = 1e-3


def target_fn(x: torch.Tensor) -> torch.Tensor:
    """x: [N, 3] -> [N, 1], the function the MLP learns."""
    return (torch.sin(2.0 * x[:, :1]) + x[:, 1:2] * x[:, 2:3] - 0.5 * x[:, 2:3] ** 2)


class ToyMLP(nn.Module):
    """3 -> hidden -> 1 with tanh."""

    def __init__(self, hidden: int = 16) -> None:
        super().__init__()
        self.layers = nn.Sequential(nn.Linear(3, hidden), nn.Tanh(), nn.Linear(hidden, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


def make_model(seed: int = 0, dtype: torch.dtype = torch.float32, hidden: int = 16) -> ToyMLP:
    """A deterministic initialisation that does not touch the global RNG."""
    model = ToyMLP(hidden)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for param in model.parameters():
            param.copy_(0.5 * torch.randn(param.shape, generator=gen))
    return model.to(dtype)


def make_step_fn(
    batch: int = GLOBAL_BATCH, global_rngs: bool = False, nan_at: int | None = None,
    grad_nan_at: int | None = None,
):
    """The toy step: the data come from ``ctx.generator``; optionally also from the global RNGs
    (torch, numpy, python), to check that a resume restores them; optionally a NaN loss (or a
    NaN gradient with finite losses) at one step."""

    def step_fn(ctx: StepContext) -> dict[str, torch.Tensor]:
        model = unwrap(ctx.model)
        dtype = next(model.parameters()).dtype
        x = torch.rand(batch, 3, generator=ctx.generator, dtype=torch.float64) * 2 - 1
        if global_rngs:
            x = x + 0.01 * torch.randn(batch, 3, dtype=torch.float64)
            x = x * (1.0 + 0.01 * np.random.rand()) + 0.01 * random.random()
        y = target_fn(x)
        x_local, y_local = shard((x.to(dtype), y.to(dtype)), ctx.dist)
        pred = ctx.model(x_local.to(ctx.device))
        if grad_nan_at is not None and ctx.step == grad_nan_at:
            pred.register_hook(lambda grad: grad * float("nan"))
        data = global_mean(((pred - y_local.to(ctx.device)) ** 2).sum(-1), batch, ctx.dist)
        reg = REG_WEIGHT * sum(p.pow(2).sum() for p in model.parameters())
        if nan_at is not None and ctx.step == nan_at:
            reg = reg * float("nan")
        return {"total": data + reg, "data": data, "reg": reg}

    return step_fn


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--checkpoint-every", type=int, default=10)
    parser.add_argument("--kill-at", type=int, default=0,
                        help="SIGKILL this process after this many steps are done")
    parser.add_argument("--grad-sync", default="ddp",
                        help="comma-separated modes; one run per mode into OUT/<mode>")
    parser.add_argument("--dtype", default="float32")
    parser.add_argument("--global-rngs", action="store_true")
    parser.add_argument("--lr", type=float, default=1e-2)
    args = parser.parse_args(argv)
    single_thread_worker()  # this whole process: one torch thread
    dtype = getattr(torch, args.dtype)
    dist = init_distributed("cpu")
    try:
        modes = args.grad_sync.split(",")
        for mode in modes:
            out = args.out / mode if len(modes) > 1 else args.out
            config = TrainerConfig(steps=args.steps, lr=args.lr, lr_schedule="cosine",
                                   checkpoint_every=args.checkpoint_every, device="cpu",
                                   progress=False, grad_sync=mode, seed=5)
            model = make_model(0, dtype)

            def kill_hook(info: StepInfo) -> None:
                if args.kill_at and info.step + 1 == args.kill_at:
                    os.kill(os.getpid(), signal.SIGKILL)

            train(model, make_step_fn(global_rngs=args.global_rngs), config, out,
                  hooks=[kill_hook], dist=dist)
            if dist.is_main:
                torch.save(model.state_dict(), out / "final.pt")
    finally:
        cleanup(dist)
    if group_was_created():  # a torchrun worker (see end_process)
        end_process(0)


if __name__ == "__main__":
    main()
