"""Run a tiny prior or image training (the configs of ``conftest``) as a script, for torchrun::

    torchrun --standalone --nproc_per_node 2 -m tests.training.run_tiny --data DATA --out RUN \
        --kind prior --steps 3 --grad-sync allreduce
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from .conftest import tiny_image_config, tiny_prior_config, tiny_trainer


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--kind", choices=("prior", "images"), default="prior")
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--grad-sync", default="allreduce")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    trainer = tiny_trainer(steps=args.steps, grad_sync=args.grad_sync)
    if args.kind == "prior":
        from lisa_hand.training.prior import train_prior

        train_prior(args.data, args.out, tiny_prior_config(trainer=trainer), resume=False)
        import os, sys; print("done", os.environ.get("RANK"), file=sys.stderr, flush=True)
    else:
        from lisa_hand.training.images import train_images

        train_images(args.data, args.out, tiny_image_config(trainer=trainer), resume=False)


if __name__ == "__main__":
    main()
