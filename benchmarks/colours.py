"""Colour benchmark: how well ``lisa fit-points`` puts a coloured scan's colours on the fitted
mesh (:mod:`lisa_hand.fitting.points.colours`), on the surface the scan saw and on the rest.

``python -m benchmarks colours [--hands 4] [--model M] [--threads 1] [--json FILE]``

Hands the shipped geometric prior never saw (the first ``--hands`` test subjects of its split of
hand model v2's 290 subjects), each in a pose of the pose sampler, scanned all round and from
one side (8000 points, 0.3 mm noise along the normals), every point coloured with the subject's
true albedo (:mod:`lisa_hand.handmodel.appearance`: skin tone, lighter palms, nails, creases),
written as a coloured PLY and fitted as ``lisa fit-points SCAN.ply --side right`` does
(:func:`lisa_hand.fitting.points.io.fit_point_file`, its defaults: the support, other pieces and
the sensor searched for; each fit's V2S both ways against the true mesh is printed, a check of
those defaults on hands in sampled poses). Measured at the true mesh's vertices within
3 mm of the fitted surface: the mean absolute colour error in 8-bit levels and the PSNR (dB) of
``mesh.ply``'s colour at the nearest fitted vertex, over the vertices the scan saw (within 3 mm
of one of its points) and over those it did not (the hidden side of a one-sided scan). In the
same run, two references at the same vertices: the grey a geometric prior's mesh has without
the scan's colours (``--colours none``, :data:`lisa_hand.inference.hand_field.
GEOMETRY_ONLY_GREY`) and one colour everywhere (the scan's mean).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from lisa_hand.metrics.colours import colour_errors
from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["coloured_scan", "run_colour_benchmark", "main"]

_SPLIT_SUBJECTS = 290  # the geometric prior's dataset (hand model v2), split with seed 0
_POSE_SEED = 100


def coloured_scan(index: int, subject: str, partial: bool, folder: Path, hand_model: str = "v2"):
    """Write subject ``subject``'s hand in pose ``index`` (seed 100 + index) as a coloured scan
    ``folder/NAME.ply`` -> (the path, the true mesh, the scan's points [N, 3] metres)."""
    import torch
    import trimesh

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.data.synth import SynthConfig, make_subject
    from lisa_hand.geometry.meshing import colors_to_uint8
    from lisa_hand.handmodel import sample_pose

    record = make_subject(SynthConfig(seed=0, hand_model=hand_model), int(subject[1:]),
                          fit_template=False)
    pose = sample_pose(torch.Generator().manual_seed(_POSE_SEED + index), 1, side="right")[0]
    posed = record.hand.posed(pose.double())
    truth = posed.mesh(colors=True)
    scan = simulate_scan(truth.vertices, truth.faces, ScanConfig(
        num_points=8000, partial=partial, noise_normal_std=3e-4), seed=index)
    points = np.asarray(scan.points, np.float64)
    albedo = posed.albedo(torch.from_numpy(points)).numpy()
    path = folder / f"{subject}_{'one_side' if partial else 'all_round'}.ply"
    trimesh.PointCloud(points, colors=colors_to_uint8(albedo)).export(path)
    return path, truth, points


def run_colour_benchmark(hands: int, folder: Path, model: str | None = None) -> dict:
    """Fit ``hands`` held-out hands' coloured scans, all round and from one side -> the
    results: {"rows": [per scan], "mean": {kind: {guess: means}}}."""
    from lisa_hand.data.meshio import load_mesh, save_mesh
    from lisa_hand.data.synth import split_subjects
    from lisa_hand.fitting.points.io import fit_point_file
    from lisa_hand.inference.hand_field import GEOMETRY_ONLY_GREY

    held_out = split_subjects(_SPLIT_SUBJECTS, seed=0)["test"]
    if not 1 <= hands <= len(held_out):
        raise ValueError(f"--hands must be in 1..{len(held_out)} (the held-out subjects)")
    subjects, rows = held_out[:hands], []
    for index, subject in enumerate(subjects):
        for partial in (False, True):
            path, truth, points = coloured_scan(index, subject, partial, folder)
            save_mesh(folder / f"{path.stem}_truth.ply", truth)
            start = time.perf_counter()
            report = fit_point_file(path, folder / path.stem, model_path=model, side="right",
                                    viewpoint="auto", support="auto", others="auto",
                                    gt_path=folder / f"{path.stem}_truth.ply")
            seconds = time.perf_counter() - start
            fitted = load_mesh(folder / path.stem / "mesh.ply")
            references = {"scan_mean": np.asarray(report.cloud.colors, np.float64).mean(0),
                          "grey": np.full(3, GEOMETRY_ONLY_GREY)}
            errors = colour_errors(truth, np.asarray(fitted.vertices, np.float64),
                                   fitted.colors, points, references,
                                   _interpolated(report, fitted))
            row = {"subject": subject, "scan": "one side" if partial else "all round",
                   "seconds": seconds, "v2s_mm": report.metrics, **errors}
            rows.append(row)
            print(_line(row), flush=True)
    return {"rows": rows, "mean": _means(rows)}


def _interpolated(report, fitted) -> dict[str, np.ndarray]:
    """When the model's colour guessed the unseen surface: the scan's colours interpolated over
    it instead (:func:`lisa_hand.fitting.points.colours.transfer_colours` without a base), on the
    same mesh, for comparison; else nothing."""
    from lisa_hand.fitting.points.colours import transfer_colours
    from lisa_hand.fitting.points.io import hand_points

    if not report.fit.params.extra["input"]["colours"].get("colour_code_fitted"):
        return {}
    kept = hand_points(report.cloud, report.fit)
    found = transfer_colours(fitted.vertices, fitted.faces, report.cloud.points[kept],
                             report.cloud.colors[kept])
    return {} if found is None else {"interpolated": found.colors}


def _means(rows: list[dict]) -> dict:
    means: dict[str, dict] = {}
    for kind in ("all round", "one side"):
        chosen = [row for row in rows if row["scan"] == kind]
        guesses = [key for key in chosen[0] if isinstance(chosen[0][key], dict)
                   and key != "v2s_mm"] if chosen else []
        means[kind] = {guess: {key: float(np.nanmean([row[guess][key] for row in chosen]))
                               for key in chosen[0][guess]} for guess in guesses}
    return means


def _line(row: dict) -> str:
    to_recon, to_scan = (row["v2s_mm"][f"v2s_{way}_mm"] for way in ("scan_to_recon",
                                                                      "recon_to_scan"))
    parts = [f"{row['subject']} {row['scan']:>9}: {row['seconds']:.1f} s, V2S "
             f"{to_recon:.2f} / {to_scan:.2f} mm"]
    for guess in ("fit", "interpolated", "scan_mean", "grey"):
        if guess in row:
            value = row[guess]
            parts.append(f"{guess} seen {value['seen_mae']:.1f} / hidden "
                         f"{value['hidden_mae']:.1f} levels ({value['seen_psnr']:.1f} / "
                         f"{value['hidden_psnr']:.1f} dB)")
    return "; ".join(parts)


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks colours [options]``; returns the results."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks colours",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--hands", type=int, default=4, help="held-out hands (default 4)")
    parser.add_argument("--model", default=None, help="trained model (default: the point "
                        "fit's, the shipped geometric prior)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="keep the scans and fits here (default: a temporary folder)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    if args.hands < 1 or args.threads < 1:
        raise ValueError("--hands and --threads must be >= 1")
    with cpu_threads(args.threads), tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.out) if args.out is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"colour benchmark: {args.hands} held-out hands, all round and one side, "
              f"{args.threads} torch thread(s)")
        results = run_colour_benchmark(args.hands, folder, args.model)
    for kind, guesses in results["mean"].items():
        for guess, value in guesses.items():
            print(f"mean, {kind:>9}, {guess:>9}: seen {value['seen_mae']:.1f} / hidden "
                  f"{value['hidden_mae']:.1f} levels, {value['seen_psnr']:.1f} / "
                  f"{value['hidden_psnr']:.1f} dB")
    write_results(args.json, results)
    return results


if __name__ == "__main__":
    main()
