"""Run tiny prior and/or image trainings (the configs of ``conftest``) as a script, for torchrun::

    torchrun --standalone --nproc_per_node 2 -m tests.training.run_tiny --data DATA --out RUN \
        --kinds prior,images --steps 3 --grad-sync allreduce

Each kind trains into ``RUN/<kind>``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lisa_hand.training.distributed import cleanup, end_process, group_was_created, init_distributed
from lisa_hand.training.images import train_images
from lisa_hand.training.prior import train_prior
from lisa_hand.utils.threads import single_thread_worker

from .conftest import tiny_image_config, tiny_prior_config, tiny_trainer


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--kinds", default="prior,images")
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--grad-sync", default="allreduce")
    args = parser.parse_args(argv)
    single_thread_worker()  # this whole process: one torch thread
    trainer = tiny_trainer(steps=args.steps, grad_sync=args.grad_sync,
                           find_unused_parameters=args.grad_sync == "ddp")
    dist = init_distributed("cpu")
    try:
        for kind in args.kinds.split(","):
            if kind == "prior":
                train_prior(args.data, args.out / kind, tiny_prior_config(trainer=trainer),
                            resume=False, dist=dist)
            else:
                train_images(args.data, args.out / kind, tiny_image_config(trainer=trainer),
                             resume=False, dist=dist)
    finally:
        cleanup(dist)
    if group_was_created():  # a torchrun worker (see end_process)
        end_process(0)


if __name__ == "__main__":
    main()
