"""Point-cloud fitting benchmark: time for a fit to reach V2S 1 mm, against the paper's loop.

``python -m benchmarks fit [--json FILE] [--model CKPT] [--points N] [--seed S]``

The target is the model itself (self-consistency, so 1 mm is reachable): the hand of a
training subject's shape code, random template betas, the 'relaxed' finger pose, a random global
rotation and translation, meshed at 128^3 (:func:`lisa_hand.inference.mesh_hand`) and scanned
(:func:`lisa_hand.data.scans.simulate_scan`, ``--points`` points, ``--noise-mm`` normal noise).
The model is ``--model`` (a file, run or shipped name), else what ``lisa fit-points`` uses
without one (the shipped geometric prior). Without a trained model the model is a geometric
initialisation on the template's skeleton (a blob hand; its shape code does nothing).

Accuracy along the way is the mean ``|G(x)|`` of the current fit over 4000 scan points, the
vertex-to-surface distance from the scan to the fitted surface when ``G`` is a distance (checked
at the end against the true V2S of the 128^3 meshes, both ways).

* ``seconds``: :func:`lisa_hand.fitting.points.fit.fit_points` with its defaults (candidate
  orientations, articulated proxy, then the field on 512 random points per iteration with
  culled bones, a few candidates pruned to one), from the start until the accuracy first
  reaches ``--target-mm`` (evaluated after the run from per-iteration snapshots, so the check
  costs the fit nothing).
* ``reference_seconds``: the same initialisation (its time included), then the paper's plain
  loop: ``torch.optim.Adam`` on the 48-D pose, translation and shape code, the loss
  ``mean_i |G(x_i)| + w |beta+|^2`` over ALL points every iteration, every point through every
  bone (``cull=False``), one candidate. Its loss is the accuracy itself. It stops at the target
  or after ``--reference-budget`` seconds (``reference_reached`` says which).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from lisa_hand.data.webxr_hand import WEBXR_WRISTS
from lisa_hand.utils.threads import cpu_threads

from . import write_results
from ._webxr import run_webxr_fits
from ._webxr_scenes import run_scene_fits

__all__ = ["FitBenchmark", "run_webxr_fits", "run_fit_benchmark", "main"]

_EVAL_POINTS = 4000


@dataclass
class FitBenchmark:
    """Numbers of one run (JSON via :meth:`to_dict`); times in seconds, distances in mm."""

    model: str
    device: str
    threads: int
    num_points: int
    noise_mm: float
    target_mm: float
    seconds: float | None
    """Optimised fit: time until the accuracy reached ``target_mm`` (None: never)."""
    reference_seconds: float | None
    """Paper loop (same start): time until the target, or the budget when not reached."""
    reference_reached: bool
    speedup: float | None
    init_seconds: float
    """Initialisation shared by both (proxy, candidate orientations, articulated proxy)."""
    fit_seconds: float
    """The optimised fit's whole run."""
    accuracy_mm: float
    """Final mean |G| over the evaluation points (optimised fit)."""
    reference_accuracy_mm: float
    """The reference's last mean |G| over all points."""
    reference_iterations: int
    reference_seconds_per_iteration: float
    fit_seconds_per_iteration: float
    """Field stage of the optimised fit, per iteration."""
    v2s_scan_to_recon_mm: float
    v2s_recon_to_scan_mm: float
    v2v_scan_to_recon_mm: float
    v2v_recon_to_scan_mm: float
    reference_v2s_scan_to_recon_mm: float
    reference_v2s_recon_to_scan_mm: float
    rotation_error_deg: float
    stage_seconds: dict

    def to_dict(self) -> dict:
        return asdict(self)


def _bench_model(path, device):
    from lisa_hand.fields.config import FieldConfig
    from lisa_hand.fitting.points.io import default_point_model
    from lisa_hand.handmodel.template import load_template
    from lisa_hand.model.lisa import LisaModel
    from lisa_hand.model.trained import TrainedModel, load_trained, shipped_model_path

    if path is None and shipped_model_path(default_point_model()).is_file():
        path = default_point_model()  # what 'lisa fit-points' uses without --model
    if path is not None:
        model = load_trained(path, device)
        return model, model.source
    template = load_template().to(dtype=torch.float32)
    rest = template.rest_joints(torch.zeros(1, template.num_betas))[0]
    field = LisaModel(FieldConfig(use_color=False), init_rest_joints=rest).eval()
    shape_dim = field.config.shape_dim
    model = TrainedModel(field=field, shape_codes=torch.zeros(4, shape_dim), color_codes=None,
                         subject_ids=["s0", "s1", "s2", "s3"], beta=0.002, gain=torch.ones(3),
                         bias=torch.zeros(3), source="geometric-init")
    return model.to(device), "geometric-init (no trained model: a blob hand)"


def _target(model, seed: int):
    """The true hand: HandParams of a training subject in a random placement."""
    from lisa_hand.handmodel.poses import named_pose
    from lisa_hand.handmodel.template import load_template
    from lisa_hand.skeleton.params import HandParams

    generator = torch.Generator().manual_seed(seed)
    template = load_template().to(dtype=torch.float32)
    betas = 0.7 * torch.randn(template.num_betas, generator=generator)
    pose = named_pose("relaxed").clone()
    # A uniform random rotation: a uniform unit quaternion (w, v) as axis-angle.
    quaternion = torch.randn(4, generator=generator, dtype=torch.float64)
    quaternion = quaternion * torch.sign(quaternion[0]) / quaternion.norm()
    sin_half = quaternion[1:].norm()
    pose[:3] = (2.0 * torch.atan2(sin_half, quaternion[0]) * quaternion[1:] / sin_half).float()
    subject = int(torch.randint(model.shape_codes.shape[0], (1,), generator=generator))
    return HandParams(
        pose=pose,
        translation=0.1 * torch.randn(3, generator=generator),
        rest_joints=template.rest_joints(betas[None])[0],
        shape_code=model.shape_codes[subject].cpu(),
        color_code=None if model.color_codes is None else model.color_codes[subject].cpu(),
        betas=betas,
    )


def _mean_abs_sdf(model, params, points: torch.Tensor) -> float:
    from lisa_hand.inference import hand_field

    with torch.no_grad():
        return float(hand_field(model, params).sdf_fn()(points).abs().mean())


def _reference_loop(model, start, points: torch.Tensor, target_m: float, budget: float,
                    shape_weight: float):
    """The paper's loop (see the module docstring). -> (params, seconds, reached, iters, acc)"""
    field = model.field
    device, dtype = field.device, field.dtype
    pose = start.pose[None].to(device, dtype).clone().requires_grad_(True)
    translation = start.translation[None].to(device, dtype).clone().requires_grad_(True)
    code = start.shape_code[None].to(device, dtype).clone().requires_grad_(True)
    rest = start.rest_joints[None].to(device, dtype)
    color = None
    if field.color_mlp is not None:
        color = model.mean_color_code()[None].to(device, dtype)
    optimizer = torch.optim.Adam([
        {"params": [pose], "lr": 0.01},
        {"params": [translation], "lr": 0.001},
        {"params": [code], "lr": 0.01},
    ])
    for weight in field.parameters():
        weight.requires_grad_(False)
    begin = time.perf_counter()
    iterations, accuracy, reached = 0, math.inf, False
    while time.perf_counter() - begin < budget:
        state = field.prepare(pose, translation, rest, code, color)
        data = field.field(state, points[None], with_color=False, cull=False).sdf.abs().mean()
        accuracy = float(data.detach())
        iterations += 1
        if accuracy <= target_m:
            reached = True
            break
        loss = data + shape_weight * code.square().sum()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    seconds = time.perf_counter() - begin
    for weight in field.parameters():
        weight.requires_grad_(True)
    params = start.with_pose(pose[0].detach().cpu(), translation[0].detach().cpu())
    params.shape_code = code[0].detach().cpu()
    return params, seconds, reached, iterations, accuracy


def run_fit_benchmark(model_path=None, *, num_points: int = 20000, noise_mm: float = 0.0,
                      target_mm: float = 1.0, seed: int = 0, device: str = "cpu",
                      threads: int = 1, reference_budget: float = 120.0) -> FitBenchmark:
    """Run both fits on one target (see the module docstring), with ``threads`` torch CPU
    threads (the previous count is given back afterwards)."""
    with cpu_threads(threads):
        return _fit_benchmark(model_path, num_points, noise_mm, target_mm, seed, device, threads,
                              reference_budget)


def _fit_benchmark(model_path, num_points: int, noise_mm: float, target_mm: float, seed: int,
                   device: str, threads: int, reference_budget: float) -> FitBenchmark:
    """:func:`run_fit_benchmark`'s work, on the thread count it set."""
    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import FitPointsConfig, fit_points
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances

    model, model_name = _bench_model(model_path, device)
    truth = _target(model, seed)
    plain = MeshConfig(colors=False, skin_weights=False)
    gt_mesh = mesh_hand(model, truth, 128, plain)
    scan = simulate_scan(gt_mesh.vertices, gt_mesh.faces,
                         ScanConfig(num_points=num_points, noise_normal_std=noise_mm * 1e-3),
                         seed=seed)
    points = torch.from_numpy(scan.points).to(device=model.field.device, dtype=model.field.dtype)
    pick = np.random.default_rng(seed).permutation(len(points))[:_EVAL_POINTS]
    eval_points = points[torch.from_numpy(pick).to(points.device)]

    config = FitPointsConfig(num_threads=threads)
    snapshots: list[tuple[str, float, object]] = []

    def record(step) -> None:
        if step.stage == "field" or (step.stage == "pose"
                                     and step.iteration == step.num_iterations - 1):
            snapshots.append((step.stage, step.seconds, step.params()))

    fit = fit_points(model, scan.points, None, config, callback=record)
    init_seconds = sum(fit.stage_seconds.get(k, 0.0) for k in ("proxy", "align", "pose", "size"))
    seconds = None
    for stage, when, params in snapshots:
        if stage == "field" and _mean_abs_sdf(model, params, eval_points) <= target_mm * 1e-3:
            seconds = when
            break
    accuracy = _mean_abs_sdf(model, fit.params, eval_points)

    start = next(params for stage, _, params in snapshots if stage == "pose")
    reference, loop_seconds, reached, iterations, reference_accuracy = _reference_loop(
        model, start, points, target_mm * 1e-3, reference_budget, config.shape_weight)
    reference_seconds = init_seconds + loop_seconds

    recon = mesh_hand(model, fit.params, 128, plain)
    distances = mesh_distances(recon.vertices, recon.faces, gt_mesh.vertices, gt_mesh.faces)
    reference_mesh = mesh_hand(model, reference, 128, plain)
    reference_distances = mesh_distances(reference_mesh.vertices, reference_mesh.faces,
                                         gt_mesh.vertices, gt_mesh.faces)
    rotation = axis_angle_to_matrix(fit.params.pose[:3].double())
    true_rotation = axis_angle_to_matrix(truth.pose[:3].double())
    cosine = (torch.trace(rotation.T @ true_rotation) - 1.0) / 2.0
    field_iterations = max(config.field_iters, 1)
    return FitBenchmark(
        model=model_name,
        device=str(device),
        threads=threads,
        num_points=num_points,
        noise_mm=noise_mm,
        target_mm=target_mm,
        seconds=seconds,
        reference_seconds=reference_seconds,
        reference_reached=reached,
        speedup=None if seconds is None else reference_seconds / seconds,
        init_seconds=init_seconds,
        fit_seconds=fit.seconds,
        accuracy_mm=accuracy * 1e3,
        reference_accuracy_mm=reference_accuracy * 1e3,
        reference_iterations=iterations,
        reference_seconds_per_iteration=loop_seconds / max(iterations, 1),
        fit_seconds_per_iteration=fit.stage_seconds["field"] / field_iterations,
        v2s_scan_to_recon_mm=distances.v2s_scan_to_recon_mm,
        v2s_recon_to_scan_mm=distances.v2s_recon_to_scan_mm,
        v2v_scan_to_recon_mm=distances.v2v_scan_to_recon_mm,
        v2v_recon_to_scan_mm=distances.v2v_recon_to_scan_mm,
        reference_v2s_scan_to_recon_mm=reference_distances.v2s_scan_to_recon_mm,
        reference_v2s_recon_to_scan_mm=reference_distances.v2s_recon_to_scan_mm,
        rotation_error_deg=math.degrees(math.acos(max(-1.0, min(1.0, float(cosine))))),
        stage_seconds=dict(fit.stage_seconds),
    )


def _self_consistency(args) -> dict:
    """The self-consistency part of :func:`main`: run, print, -> its numbers."""
    result = run_fit_benchmark(args.model, num_points=args.points, noise_mm=args.noise_mm,
                               target_mm=args.target_mm, seed=args.seed, device=args.device,
                               threads=args.threads, reference_budget=args.reference_budget)

    def shown(value):
        return "not reached" if value is None else f"{value:.2f} s"

    print(f"model: {result.model}; {result.num_points} points, noise {result.noise_mm} mm, "
          f"{result.device}, {result.threads} thread(s)")
    print(f"optimised fit: {shown(result.seconds)} to reach {result.target_mm} mm "
          f"(init {result.init_seconds:.2f} s, whole fit {result.fit_seconds:.2f} s, "
          f"final {result.accuracy_mm:.3f} mm, {1e3 * result.fit_seconds_per_iteration:.1f} "
          "ms per field iteration)")
    reference = shown(result.reference_seconds) if result.reference_reached else \
        f"not reached in {result.reference_seconds:.1f} s"
    print(f"paper loop (same init): {reference} ({result.reference_iterations} iterations, "
          f"{1e3 * result.reference_seconds_per_iteration:.0f} ms each, last "
          f"{result.reference_accuracy_mm:.3f} mm)")
    if result.speedup is not None:
        bound = "" if result.reference_reached else ">= "
        print(f"speed-up: {bound}{result.speedup:.1f}x")
    print(f"V2S scan->recon {result.v2s_scan_to_recon_mm:.3f} mm, recon->scan "
          f"{result.v2s_recon_to_scan_mm:.3f} mm; V2V {result.v2v_scan_to_recon_mm:.3f} / "
          f"{result.v2v_recon_to_scan_mm:.3f} mm; rotation error "
          f"{result.rotation_error_deg:.2f} deg")
    numbers = result.to_dict()
    return numbers


def _add_scene_args(parser: argparse.ArgumentParser) -> None:
    """The bench's flags of WebXR scans with more than the hand in them (table, wall, person):
    each takes auto (the flag alone: as lisa fit-points does by default) or none."""
    scenes = {
        "table": "one-view scans of the WebXR hand lying on a table, palm and back down, the "
                 "table in the scan: auto (the table found and left out, as lisa fit-points "
                 "--support auto) or none (every point fitted)",
        "wall": "a depth camera's whole frame of the WebXR hand 40 cm away, a wall 30 cm behind "
                "it (320 x 240 pixels, 1 mm noise at 40 cm, 3 mm on the wall): auto (the wall "
                "found and left out, as lisa fit-points --support auto) or none",
        "person": "a depth camera's whole frame of a person holding the WebXR hand out 45 cm "
                  "from it, the forearm leading to the body behind: auto (the part nearest the "
                  "sensor kept, as lisa fit-points --others auto) or none (every point fitted)",
    }
    for scene, text in scenes.items():
        parser.add_argument(f"--webxr-{scene}", nargs="?", const="auto", default=None,
                            choices=("auto", "none"),
                            help=f"also fit {text}; their viewpoint as --webxr-viewpoint")


def _sizes(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"sizes must be numbers separated by commas, got "
                                         f"{text!r}") from None


def _proportions(text: str) -> tuple[float, float, float]:
    parts = _sizes(text)
    if len(parts) != 3 or not all(0.7 <= part <= 1.4 for part in parts):
        raise argparse.ArgumentTypeError(f"proportions must be three factors B,T,F in [0.7, 1.4], "
                                         f"got {text!r}")
    return parts


def _shown_row(row: dict) -> None:
    """Print one WebXR row as it is measured."""
    print(f"  {row['pose']:>10} {row['wrist']:>7} {row['scan']:>7}: "
          f"{row['v2s_recon_to_scan_mm']:6.2f} {row['v2s_scan_to_recon_mm']:6.2f}  "
          f"{row['v2v_recon_to_scan_mm']:6.2f} {row['v2v_scan_to_recon_mm']:6.2f}  "
          f"({row['seconds']:.1f} s, {row['beyond_wrist_points']} points beyond the "
          f"wrist; scan points {row['scan_points_to_recon_mm']:.2f})", flush=True)
    if "refine_seconds" in row:
        print(f"  {'refined':>26}: {row['refined_v2s_recon_to_scan_mm']:6.2f} "
              f"{row['refined_v2s_scan_to_recon_mm']:6.2f}  "
              f"{row['refined_v2v_recon_to_scan_mm']:6.2f} "
              f"{row['refined_v2v_scan_to_recon_mm']:6.2f}  "
              f"(+{row['refine_seconds']:.1f} s; scan points "
              f"{row['refined_scan_points_to_recon_mm']:.2f})", flush=True)


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks fit [--json FILE] [--model CKPT] ...``"""
    parser = argparse.ArgumentParser(prog="python -m benchmarks fit",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--model", default=None,
                        help="trained model (default: what lisa fit-points takes without "
                             "--model, geometry_v3; else a geometric init)")
    parser.add_argument("--points", type=int, default=20000, help="scan points")
    parser.add_argument("--noise-mm", type=float, default=0.0, help="scan noise along normals")
    parser.add_argument("--target-mm", type=float, default=1.0, help="accuracy to reach")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (CPU)")
    parser.add_argument("--reference-budget", type=float, default=120.0,
                        help="seconds the reference loop may run")
    parser.add_argument("--webxr", type=Path, default=None, metavar="NPZ",
                        help="also fit the WebXR hand (right_hand.npz) in three poses")
    parser.add_argument("--webxr-wrists", default="as-is",
                        help="comma-separated wrist variants of the WebXR scans: "
                             f"{', '.join(WEBXR_WRISTS)} (default as-is)")
    parser.add_argument("--webxr-refine", action="store_true",
                        help="also refine each WebXR fit (lisa fit-points --refine) and measure it")
    parser.add_argument("--webxr-viewpoint", nargs="?", const="true", default="none",
                        choices=("none", "true", "auto"),
                        help="the one-view WebXR scans' sensor position: none (the fit gets "
                             "none), true (the simulated sensor's, as lisa fit-points "
                             "--viewpoint X,Y,Z; the flag alone) or auto (found from the scan, "
                             "as lisa fit-points does by default)")
    parser.add_argument("--webxr-scale", type=float, default=1.0, metavar="S",
                        help="the WebXR hand made S times larger about its wrist (a hand of "
                             "another size: 1.15 is 204 mm long, 0.85 is 151; default 1)")
    parser.add_argument("--webxr-proportions", type=_proportions, default=None,
                        metavar="B,T,F",
                        help="the WebXR hand reshaped before it is posed: its palm B times as "
                             "broad and T times as thick, its fingers F times as long, e.g. "
                             "1.1,1,0.9 (a hand unlike the artist's; default 1,1,1)")
    parser.add_argument("--webxr-sizes", type=_sizes, default=None, metavar="S,S,...",
                        help="the hand sizes the point fit's size search tries, times the mean "
                             "skeleton (default: the config's, 0.85-1.2); 1 turns it off")
    _add_scene_args(parser)
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a FitPointsConfig field of every WebXR fit, e.g. --set "
                             "tries=2 (repeatable)")
    parser.add_argument("--only-webxr", action="store_true",
                        help="skip the self-consistency benchmark")
    args = parser.parse_args(argv)
    if args.points < 100:
        raise ValueError(f"--points must be >= 100, got {args.points}")
    if not 0.5 <= args.webxr_scale <= 2.0:
        parser.error(f"--webxr-scale must be in [0.5, 2], got {args.webxr_scale}")
    numbers = {} if args.only_webxr else _self_consistency(args)
    if args.webxr is not None:
        wrists = tuple(name.strip() for name in args.webxr_wrists.split(",") if name.strip())
        model, name = _bench_model(args.model, args.device)
        print("WebXR hand (mm; V2S recon->scan, scan->recon; V2V recon->scan, scan->recon; "
              f"model: {name}):")

        refine = None
        if args.webxr_refine:
            from lisa_hand.fitting.points.refine import RefineConfig

            refine = RefineConfig(seed=args.seed)
        config = None
        if args.webxr_sizes is not None or args.overrides:
            from lisa_hand.fitting.points.config import FitPointsConfig
            from lisa_hand.utils.config import apply_overrides

            config = FitPointsConfig(seed=args.seed)
            if args.webxr_sizes is not None:
                config = replace(config, sizes=args.webxr_sizes)
            try:
                config = apply_overrides(config, list(args.overrides))
            except (ValueError, TypeError) as exc:
                parser.error(f"--set: {exc}")
            if args.overrides:
                print(f"fit config overrides of the WebXR fits: {', '.join(args.overrides)}")
        numbers["webxr"] = run_webxr_fits(model, args.webxr, seed=args.seed, config=config,
                                          threads=args.threads, wrists=wrists, refine=refine,
                                          viewpoints=args.webxr_viewpoint,
                                          scale=args.webxr_scale,
                                          proportions=args.webxr_proportions, log=_shown_row)
        for scene, choice in (("table", args.webxr_table), ("wall", args.webxr_wall),
                              ("person", args.webxr_person)):
            if choice is not None:
                off = None if choice == "none" else "auto"
                numbers["webxr"] += run_scene_fits(
                    model, args.webxr, scene=scene, seed=args.seed, threads=args.threads,
                    support="auto" if scene == "person" else off,
                    others=off if scene == "person" else "auto",
                    viewpoints=args.webxr_viewpoint, log=_shown_row)
    write_results(args.json, numbers)
