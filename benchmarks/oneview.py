"""One-view benchmark: where the keypoint stage of ``lisa fit-images`` puts a hand seen by one
calibrated camera, with its depth restarts and without them (the reference, in the same run).

``python -m benchmarks oneview [--hands 10] [--view cam000] [--json FILE]``

The hands are the demo's unseen hands (``lisa demo --seed k`` for k = 0 .. hands - 1: synth seed
1000 + k, one subject the shipped models never saw, 8 views at 384 x 250), written to a temporary
folder (or ``--data DIR``, kept). Each is fitted from the view ``--view`` alone (its 2D keypoints
and mask; :func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`, default
:class:`~lisa_hand.fitting.images.config.FitImagesConfig`), then again with
``depth_factors=()`` (no depth restarts: the fit before them). Measured against the frame's
true keypoints (``params.json``): the MPJPE of the 21 keypoints in world coordinates (no
alignment: one view's depth counts) and the error of the wrist's distance from the camera, mm.
No LISA model is needed: the keypoint stage fits the mesh template.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["unseen_hands", "one_view_errors", "run_oneview_benchmark", "main"]

_DEMO_SEED_OFFSET = 1000  # lisa demo's hands (lisa_hand.evaluation.demo)


def unseen_hands(folder: str | Path, count: int, resolution: tuple[int, int] = (384, 250)
                 ) -> list[Path]:
    """Synthesize the demo's first ``count`` unseen hands (synth seeds 1000 + k, 8 views) into
    ``folder/hand{k}`` -> their frame folders."""
    from lisa_hand.data.synth.dataset import SynthConfig, synthesize

    frames = []
    for index in range(count):
        root = Path(folder) / f"hand{index}"
        synthesize(root, SynthConfig(num_subjects=1, num_poses=1, num_views=8,
                                     resolution=resolution, seed=_DEMO_SEED_OFFSET + index),
                   progress=False, overwrite=True)
        frames.append(root / "s000" / "f000")
    return frames


def one_view_errors(frame: str | Path, view: str, config, template=None) -> dict[str, float]:
    """Fit the keypoint stage to the view ``view`` of ``frame`` with ``config`` (a
    :class:`~lisa_hand.fitting.images.config.FitImagesConfig`) and the mesh ``template`` (None:
    the package's, on the CPU) -> {"mpjpe_mm": mean keypoint distance to the truth, world
    frame; "wrist_depth_mm": the fitted wrist's distance from the camera minus the true one;
    "seconds"}."""
    from lisa_hand.fitting.images.keypoint_stage import fit_keypoints
    from lisa_hand.fitting.images.views import read_views
    from lisa_hand.fitting.stages import template_on

    frame = Path(frame)
    views = read_views(frame, [view])
    template = template_on(template, torch.device("cpu"))
    began = time.perf_counter()
    hand, _ = fit_keypoints(views, config, template)
    seconds = time.perf_counter() - began
    with torch.no_grad():
        fitted = template.forward(hand.pose[None], hand.betas[None],
                                  hand.translation[None]).keypoints[0].double().numpy()
    truth = np.asarray(json.loads((frame / "params.json").read_text())["keypoints"], np.float64)
    camera = views[0].camera
    centre = -(camera.R.double().T @ camera.t.double()).numpy()
    depth = np.linalg.norm(fitted[0] - centre) - np.linalg.norm(truth[0] - centre)
    return {"mpjpe_mm": float(np.linalg.norm(fitted - truth, axis=-1).mean() * 1e3),
            "wrist_depth_mm": float(depth * 1e3), "seconds": seconds}


def run_oneview_benchmark(frames: list[Path], view: str = "cam000",
                          log: Callable[[str], None] = print) -> dict:
    """Both fits of every frame (module docstring) -> the JSON-ready results: per hand and
    their means, ``mpjpe_mm`` / ``reference_mpjpe_mm`` (mean over the hands) and
    ``wrist_depth_mm`` / ``reference_wrist_depth_mm`` (mean absolute), and the lists
    ``per_hand``."""
    from lisa_hand.fitting.images.config import FitImagesConfig
    from lisa_hand.fitting.stages import template_on

    config = FitImagesConfig()
    reference = replace(config, depth_factors=())
    template = template_on(None, torch.device("cpu"))
    rows = []
    for index, frame in enumerate(frames):
        new = one_view_errors(frame, view, config, template)
        old = one_view_errors(frame, view, reference, template)
        rows.append({"hand": index, "mpjpe_mm": new["mpjpe_mm"], "wrist_depth_mm":
                     new["wrist_depth_mm"], "seconds": new["seconds"],
                     "reference_mpjpe_mm": old["mpjpe_mm"],
                     "reference_wrist_depth_mm": old["wrist_depth_mm"],
                     "reference_seconds": old["seconds"]})
        log(f"  hand {index} (lisa demo --seed {index}): MPJPE {new['mpjpe_mm']:.1f} mm, wrist "
            f"depth {new['wrist_depth_mm']:+.0f} mm, {new['seconds']:.1f} s; without depth "
            f"restarts {old['mpjpe_mm']:.1f} mm, {old['wrist_depth_mm']:+.0f} mm, "
            f"{old['seconds']:.1f} s")
    results: dict = {"benchmark": "oneview", "view": view, "hands": len(rows), "per_hand": rows}
    for key in ("mpjpe_mm", "reference_mpjpe_mm", "seconds", "reference_seconds"):
        results[key] = float(np.mean([row[key] for row in rows]))
    for key in ("wrist_depth_mm", "reference_wrist_depth_mm"):
        results[key] = float(np.mean([abs(row[key]) for row in rows]))
    results["worst_mpjpe_mm"] = float(max(row["mpjpe_mm"] for row in rows))
    results["reference_worst_mpjpe_mm"] = float(max(row["reference_mpjpe_mm"] for row in rows))
    log("")
    log("| one view | MPJPE mm (mean, worst) | wrist depth error mm (mean abs) | s a fit |")
    log("| --- | --- | --- | --- |")
    for label, prefix in (("depth restarts (default)", ""), ("without", "reference_")):
        log(f"| {label} | {results[prefix + 'mpjpe_mm']:.1f}, "
            f"{results[prefix + 'worst_mpjpe_mm']:.1f} | {results[prefix + 'wrist_depth_mm']:.0f}"
            f" | {results[prefix + 'seconds']:.1f} |")
    return results


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks oneview [options]``; returns the results."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks oneview",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--hands", type=int, default=10, help="unseen hands (default 10)")
    parser.add_argument("--view", default="cam000", help="the one camera fitted")
    parser.add_argument("--data", default=None, metavar="DIR",
                        help="write and keep the hands here (default: a temporary folder)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    if args.hands < 1:
        raise ValueError(f"--hands must be >= 1, got {args.hands}")
    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    with cpu_threads(args.threads), tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.data) if args.data is not None else Path(scratch)
        print(f"one-view benchmark: {args.hands} unseen hands, view {args.view}, "
              f"{args.threads} torch thread(s)")
        results = run_oneview_benchmark(unseen_hands(folder, args.hands), args.view)
    write_results(args.json, results)
    return results


if __name__ == "__main__":
    main()
