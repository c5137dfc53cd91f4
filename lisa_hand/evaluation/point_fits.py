"""Fit a model to the scans of held-out frames and measure the fitted meshes (paper Table 1).

``python -m lisa_hand.evaluation.point_fits DATA [--model M] [--split test] [--frames N]``

For each frame of the split (subjects never seen in training), ``scan.npz``'s points and normals
are fitted (:func:`lisa_hand.fitting.points.io.fit_point_file`: global pose from scratch, then pose,
skeleton and shape code), the fitted surface is meshed, and V2V and V2S are measured both ways
against the frame's ground-truth ``mesh.ply`` (millimetres, :mod:`lisa_hand.metrics`). Prints a
line per frame and the means; ``--json`` writes them.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..data.layout import list_frames, read_split
from ..utils.io import write_json

__all__ = ["PointFitSummary", "evaluate_point_fits", "main"]

METRIC_KEYS = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
               "v2s_scan_to_recon_mm")


@dataclass
class PointFitSummary:
    """Per-frame metrics (``frames``: list of dicts with ``frame``, ``seconds`` and the four
    distances in mm) and their means (``mean``)."""

    frames: list[dict]
    mean: dict[str, float]

    def to_dict(self) -> dict:
        return {"frames": self.frames, "mean": self.mean}


def evaluate_point_fits(
    data_dir: str | os.PathLike,
    model_path: str | os.PathLike | None = None,
    split: str = "test",
    max_frames: int | None = None,
    resolution: int = 128,
    config=None,
    out_dir: str | os.PathLike | None = None,
    log=print,
) -> PointFitSummary:
    """Fit every frame (or the first ``max_frames``, spread over the subjects) of ``split``.

    out_dir: where each frame's fit goes (``out_dir/s006_f000/``); None: a temporary folder.
    """
    from ..fitting.points.io import fit_point_file

    data_dir = Path(data_dir)
    subjects = read_split(data_dir)[split]
    if not subjects:
        raise ValueError(f"{data_dir}: split {split!r} has no subjects")
    # Frame f000 of every subject first, then f001, ...: any prefix covers all subjects.
    frames = sorted(list_frames(data_dir, subjects),
                    key=lambda paths: (paths.root.name, paths.root.parent.name))
    if max_frames is not None:
        frames = frames[:max_frames]
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(out_dir) if out_dir is not None else Path(scratch)
        for paths in frames:
            name = f"{paths.root.parent.name}_{paths.root.name}"
            start = time.perf_counter()
            report = fit_point_file(paths.scan, root / name, model_path=model_path,
                                    gt_path=paths.mesh, units="m", resolution=resolution,
                                    config=config)
            row = {"frame": name, "seconds": time.perf_counter() - start, **report.metrics}
            results.append(row)
            log(f"{name}: " + ", ".join(f"{k} {row[k]:.3f}" for k in METRIC_KEYS)
                + f" ({row['seconds']:.1f} s)")
    mean = {key: float(sum(r[key] for r in results) / len(results)) for key in METRIC_KEYS}
    mean["seconds"] = float(sum(r["seconds"] for r in results) / len(results))
    if any(not math.isfinite(v) for v in mean.values()):
        raise ValueError("a fit produced non-finite distances")
    return PointFitSummary(frames=results, mean=mean)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m lisa_hand.evaluation.point_fits",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("data", help="dataset folder (lisa synth layout)")
    parser.add_argument("--model", default=None, help="model (default: the shipped one)")
    parser.add_argument("--split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=None, help="at most this many frames")
    parser.add_argument("--res", type=int, default=128, help="marching-cubes resolution")
    parser.add_argument("--out", default=None, help="keep each frame's fit here")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args(argv)
    summary = evaluate_point_fits(args.data, args.model, args.split, args.frames, args.res,
                                  out_dir=args.out)
    print("mean: " + ", ".join(f"{k} {v:.3f}" for k, v in summary.mean.items()))
    if args.json:
        write_json(args.json, summary.to_dict())


if __name__ == "__main__":
    main()
