"""Point fits of MakeHuman hands from a region of the macro space that no shipped model learnt
from: ``python -m benchmarks heldout [--subjects N] [--ages 66,80] [--model M] [--set KEY=VALUE]
[--json FILE]``.

Hand model v3 subjects (:func:`lisa_hand.handmodel.sample_hand`, MakeHuman's sculpted hand)
aged 66-80 (the priors learnt from 18-65), each in three poses (``flat``, ``relaxed``: the
fingers curled, ``fist``), scanned with 5000 points and 0.3 mm noise from all round (full) and
from one side with its sensor (partial), each in a random placement, and fitted with the model
``lisa fit-points`` takes without ``--model``. Distances as the WebXR benchmark's
(:func:`benchmarks._webxr.measured_fit`): the fit's 128^3 mesh against the subject's exact
mesh, both cut at the fit's wrist plane, so a one-sided fit is measured over the whole hand.
``--refine`` also refines each fit (``lisa fit-points --refine``) and measures it again.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from . import write_results
from ._webxr import measured_fit, refined_row

__all__ = ["run_heldout_fits", "main"]

POSES = ("flat", "relaxed", "fist")
"""The poses of each subject: rest, curled, fist."""


def run_heldout_fits(model, *, subjects: int = 3, ages: tuple[float, float] = (66.0, 80.0),
                     num_points: int = 5000, seed: int = 11, threads: int = 1,
                     config=None, refine=None, log=None) -> list[dict]:
    """Fit ``model`` to full and one-sided scans of ``subjects`` v3 hands aged ``ages`` in
    each pose of :data:`POSES` -> one dict per fit: subject, pose, scan, seconds and the four
    V2S / V2V distances (mm), ``scan_points_to_recon_mm``. config: the
    :class:`~lisa_hand.fitting.points.config.FitPointsConfig` of every fit (None: the defaults
    with seed 0), on ``threads`` threads. refine: a
    :class:`~lisa_hand.fitting.points.refine.RefineConfig`: each fit also refined and measured
    (``refined_*`` keys). log: called with each row."""
    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import FitPointsConfig
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.handmodel import sample_hand
    from lisa_hand.handmodel.poses import named_pose

    config = dataclasses.replace(FitPointsConfig(seed=0) if config is None else config,
                                 num_threads=threads)
    generator = torch.Generator().manual_seed(seed)
    rows = []
    for subject in range(subjects):
        hand = sample_hand(generator, model="v3", ages=ages)
        for pose in POSES:
            posed = hand.posed(named_pose(pose, dtype=torch.float64), dtype=torch.float64)
            vertices, faces = np.asarray(posed.vertices, np.float64), np.asarray(posed.faces)
            turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
            rotation = axis_angle_to_matrix(turn).numpy()
            placed = (vertices - vertices.mean(0)) @ rotation.T + np.array([0.0, 0.0, 0.3])
            for partial in (False, True):
                scan = simulate_scan(placed, faces, ScanConfig(
                    num_points=num_points, partial=partial, noise_normal_std=3e-4),
                    seed=seed + subject)
                fit, measured = measured_fit(model, scan.points, placed, faces, config,
                                             "right", scan.viewpoint if partial else None,
                                             threads)
                rows.append({"subject": subject, "pose": pose,
                             "scan": "partial" if partial else "full",
                             "model": Path(str(model.source)).stem, **measured})
                if refine is not None:
                    rows[-1].update(refined_row(model, fit, scan.points, placed, faces, refine,
                                                threads))
                if log is not None:
                    log(rows[-1])
    return rows


def summary(rows: list[dict]) -> dict:
    """Mean V2S scan->recon and recon->scan (mm) over the full and the partial scans, and the
    worst fit of each."""
    numbers = {}
    for kind in ("full", "partial"):
        mine = [row for row in rows if row["scan"] == kind]
        if not mine:
            continue
        for key in ("v2s_scan_to_recon_mm", "v2s_recon_to_scan_mm",
                    "refined_v2s_scan_to_recon_mm", "refined_v2s_recon_to_scan_mm"):
            values = [row[key] for row in mine if key in row]
            if not values:
                continue
            numbers[f"{kind}_{key}_mean"] = round(float(np.mean(values)), 3)
            numbers[f"{kind}_{key}_worst"] = round(float(np.max(values)), 3)
    return numbers


def _row_line(row: dict) -> None:
    refined = ("" if "refined_v2s_scan_to_recon_mm" not in row else
               f"; refined {row['refined_v2s_scan_to_recon_mm']:.2f}, "
               f"{row['refined_v2s_recon_to_scan_mm']:.2f} mm (+{row['refine_seconds']:.1f} s)")
    print(f"  subject {row['subject']} {row['pose']:>8} {row['scan']:>8}: V2S scan->recon "
          f"{row['v2s_scan_to_recon_mm']:.2f}, recon->scan {row['v2s_recon_to_scan_mm']:.2f} mm "
          f"({row['seconds']:.1f} s){refined}", flush=True)


def _ages(text: str) -> tuple[float, float]:
    try:
        young, old = (float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two ages as A,B, got {text!r}") from None
    if not 0 < young <= old:
        raise argparse.ArgumentTypeError(f"expected 0 < A <= B, got {text!r}")
    return young, old


def _refine_config(seed: int):
    from lisa_hand.fitting.points.refine import RefineConfig

    return RefineConfig(seed=seed)


def main(argv: list[str] | None = None) -> None:
    from lisa_hand.fitting.points.io import default_point_model
    from lisa_hand.model.trained import load_trained

    parser = argparse.ArgumentParser(prog="python -m benchmarks heldout",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--model", default=None,
                        help="trained model (default: what lisa fit-points takes without "
                             "--model)")
    parser.add_argument("--subjects", type=int, default=3, help="v3 subjects (3 poses each)")
    parser.add_argument("--ages", type=_ages, default=(66.0, 80.0),
                        help="their ages, A,B years (default 66,80: older than any training "
                             "subject)")
    parser.add_argument("--points", type=int, default=5000, help="scan points")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (CPU)")
    parser.add_argument("--refine", action="store_true",
                        help="also refine each fit (lisa fit-points --refine) and measure it")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a FitPointsConfig field of every fit, e.g. --set tries=2 "
                             "(repeatable)")
    args = parser.parse_args(argv)
    if args.subjects < 1 or args.points < 100:
        parser.error("--subjects must be >= 1 and --points >= 100")
    from lisa_hand.fitting.points.config import FitPointsConfig
    from lisa_hand.utils.config import apply_overrides

    try:
        config = apply_overrides(FitPointsConfig(seed=0), list(args.overrides))
    except (ValueError, TypeError) as exc:
        parser.error(f"--set: {exc}")
    if args.overrides:
        print(f"fit config overrides: {', '.join(args.overrides)}")
    model = load_trained(args.model or default_point_model(), "cpu")
    print(f"MakeHuman hands aged {args.ages[0]:g}-{args.ages[1]:g} (model: {model.source}):")
    rows = run_heldout_fits(model, subjects=args.subjects, ages=args.ages,
                            num_points=args.points, seed=args.seed, threads=args.threads,
                            refine=_refine_config(args.seed) if args.refine else None,
                            config=config, log=_row_line)
    numbers = {**summary(rows), "ages": list(args.ages), "overrides": list(args.overrides),
               "rows": rows}
    for key, value in numbers.items():
        if key not in ("rows", "ages", "overrides"):
            print(f"{key}: {value}")
    write_results(args.json, numbers)


if __name__ == "__main__":
    main()
