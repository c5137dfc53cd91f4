"""Rebuild the shipped MANO-like template asset (``lisa_hand/assets/template.npz``).

    python -m lisa_hand.handmodel.build_template_asset --out lisa_hand/assets/template.npz

builds the template (:func:`lisa_hand.handmodel.template_build.build_template`, by default 200
subjects of seed 0, 800 vertices, 10 betas; ~15-30 s on one CPU core), measures it on held-out
subjects (:func:`~lisa_hand.handmodel.template_build.evaluate_template`; the report, without
timings, is stored in the file's ``info``, so the file is a deterministic function of the
arguments), writes it atomically and prints its size, explained variance and fit errors.
Exit status 0 on success, 1 (with a one-line ``error:`` message) for a bad argument or an
unwritable output.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from .template import DEFAULT_TEMPLATE_PATH, save_template
from .template_build import build_template, evaluate_template

__all__ = ["main"]

_PROG = "python -m lisa_hand.handmodel.build_template_asset"


def main(argv: list[str] | None = None) -> int:
    """The command line (see the module docstring); ``argv`` defaults to ``sys.argv[1:]``.
    -> the exit status."""
    parser = argparse.ArgumentParser(
        prog=_PROG,
        description="Build the open hand's MANO-like mesh template and report its fit errors.",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_TEMPLATE_PATH, help="output .npz")
    parser.add_argument("--subjects", type=int, default=200, help="subjects of the shape space")
    parser.add_argument("--seed", type=int, default=0, help="seed of the subjects")
    parser.add_argument("--vertices", type=int, default=800, help="mesh vertices")
    parser.add_argument("--betas", type=int, default=10, help="shape components")
    parser.add_argument("--held-out", type=int, default=20, help="held-out subjects to evaluate")
    args = parser.parse_args(argv)
    try:
        start = time.perf_counter()
        template = build_template(args.subjects, args.vertices, args.betas, args.seed)
        built = time.perf_counter() - start
        report = evaluate_template(template, args.held_out, args.seed) if args.held_out else None
        info = dict(template.info)
        if report is not None:  # timings left out: the file is a deterministic function of args
            info["held_out"] = {key: value for key, value in dataclasses.asdict(report).items()
                                if key != "fit_seconds"}  # fmt: skip
        template = dataclasses.replace(template, info=info)
        save_template(template, args.out)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    ratios = template.info["explained_variance_ratio"]
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB): "
          f"{template.num_vertices} vertices, {template.faces.shape[0]} faces, "
          f"{template.num_betas} betas, built in {built:.1f} s")  # fmt: skip
    print(f"explained variance: {sum(ratios):.4f} "
          f"({', '.join(f'{r:.3f}' for r in ratios)})")  # fmt: skip
    if report is not None:
        for name, value in dataclasses.asdict(report).items():
            print(f"  {name}: {value:.4g}" if isinstance(value, float) else f"  {name}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
