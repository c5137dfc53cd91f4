"""Image-training benchmark: steps per second and novel-view PSNR of the default step and a
reference step.

``python -m benchmarks train [--data DIR] [--work DIR] [--budget-s S] [--json FILE]``

``python -m benchmarks train --steps N [--set KEY=VALUE ...]``: one run of the fast step
with the overrides, its PSNR and surface error (what a training setting buys, from the same
start as every other such run).

Two configurations of ``lisa train`` (:class:`~lisa_hand.training.images.ImageTrainConfig`):

* **reference**: the straightforward step: frame after frame (``batched_step=false``), the
  sphere-traced sampler with 48 samples in the band ``[-8 beta, +16 beta]`` around the surface
  plus 16 uniform ones a ray, 64 marching steps; per frame 256 + 256 Eikonal points (ray
  samples, uniform) and 512 skinning points;
* **fast** (the default): every frame of the step rendered in one pass (one sphere trace
  and one field evaluation for the batch, no gradient pass for the skinning points), 12 band
  samples in ``[-4 beta, +8 beta]`` plus 4 uniform ones, 12 marching steps; 64 + 64 Eikonal
  and 128 skinning points a frame.

Both start from the same geometry (the shipped model's SDF and skinning networks as the prior,
its mean shape code for every subject; the colour networks start fresh) and train on the same
frames: the training subjects of a small dataset (``--data``, default a dataset synthesised into
``--work``: 6 subjects x 2 poses x 7 views at 384x250, seed 11) with one camera of each frame
held out (``--held-out``, default the last one), constant learning rate.

1. **Steps per second**, measured in one process, the two steps interleaved (``--rate-steps``
   each, best of the rounds' medians), so that load from other processes hits both alike.
2. **Equal wall-clock**: the budget ``--budget-s`` converted into steps with each rate
   (``budget x steps_per_s``); each configuration trains that many steps. **Equal steps**: the
   fast configuration is also evaluated after the reference's number of steps (the same run,
   checkpointed there).
3. **PSNR** of the held-out camera of every training frame (rendered as ``lisa render`` does,
   with the model's mean colour calibration: the camera is unseen), inside the mask (the
   demo's figure) and over the whole image, at ``--eval-scale`` of the resolution; and the
   **geometry**: the mean |SDF| of the trained field at each frame's true surface points
   (``scan.npz``), mm, so that a cheaper step cannot buy speed with a worse surface.
4. ``--shaded``: the fast step is also trained with headlight shading
   (:mod:`lisa_hand.render.shading`, ``shading="headlight"``) for the fast run's steps, and its
   held-out PSNR reported (``psnr_shaded``): what modelling the camera-side light buys.

The JSON (``--json``) holds ``steps_per_s``, ``reference_steps_per_s``, ``speedup``, ``psnr``
(fast, equal time), ``reference_psnr``, ``psnr_equal_steps``, ``psnr_shaded`` (None without
``--shaded``), ``surface_error_mm``, ``reference_surface_error_mm``,
``surface_error_mm_equal_steps`` and the details.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from lisa_hand.data.datasets import RayFrames, ScanFrames
from lisa_hand.data.layout import read_image, read_mask
from lisa_hand.geometry.cameras import load_cameras, save_cameras
from lisa_hand.inference.hand_field import hand_field
from lisa_hand.inference.render import render_hand, scale_camera
from lisa_hand.metrics.image import psnr
from lisa_hand.model.trained import load_trained, trained_from_checkpoint
from lisa_hand.render import RenderConfig
from lisa_hand.skeleton.params import HandParams
from lisa_hand.training.config import TrainerConfig
from lisa_hand.training.images import (
    ImageTrainConfig,
    build_image_model,
    load_image_data,
    resolve_prior,
    sample_image_batch,
    train_images,
)
from lisa_hand.training.prior import PriorModel
from lisa_hand.training.prior import prior_from_trained as prior_of_subjects
from lisa_hand.utils.config import apply_overrides
from lisa_hand.utils.device import describe_device, resolve_device, synchronize
from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["reference_config", "fast_config", "prior_from_trained", "held_out_copy",
           "StepRun", "step_runs", "measure_rates", "main"]


def reference_config(steps: int, seed: int = 0, device: str = "auto") -> ImageTrainConfig:
    """The reference image step (see the module docstring), ``steps`` steps on ``device``."""
    render = RenderConfig(sampler="sphere_traced", num_samples=48, num_samples_extra=16,
                          stratified=True, sphere_num_steps=64, sphere_band_outside=8.0,
                          sphere_band_inside=16.0)
    return ImageTrainConfig(render=render, batched_step=False, eikonal_ray_points=256,
                            eikonal_uniform_points=256, skinning_points=512,
                            trainer=_trainer(steps, seed, device))


def fast_config(steps: int, seed: int = 0, device: str = "auto") -> ImageTrainConfig:
    """Today's default image step (``ImageTrainConfig()``'s render and step), ``steps`` steps on
    ``device``."""
    return ImageTrainConfig(trainer=_trainer(steps, seed, device))


def _trainer(steps: int, seed: int, device: str) -> TrainerConfig:
    base = ImageTrainConfig().trainer
    return dataclasses.replace(base, steps=steps, lr_schedule="constant", seed=seed,
                               checkpoint_every=0, print_every=0, progress=False, device=device)


def prior_from_trained(model_path: str | Path | None = None) -> PriorModel:
    """A prior (geometry networks, one mean shape code) from a trained model file: the shipped
    model by default. Its subjects are unknown to any dataset, so image runs start every
    subject from its mean code."""
    subjects = prior_of_subjects(load_trained(model_path))
    prior = PriorModel(subjects.field.config, ["mean"])
    prior.field.load_state_dict(subjects.field.state_dict())
    with torch.no_grad():
        prior.shape_codes.weight[0] = subjects.shape_codes.weight.float().mean(dim=0)
    return prior.float()


def held_out_copy(data: Path, out: Path, held_out: str) -> Path:
    """A copy of the dataset ``data`` without camera ``held_out`` in any frame (links to the
    files; each frame's ``cameras.json`` rewritten). -> ``out``."""
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for item in data.iterdir():
        if item.is_file():
            (out / item.name).symlink_to(item.resolve())
    for cameras_file in sorted(data.glob("s*/f*/cameras.json")):
        frame = cameras_file.parent
        target = out / frame.relative_to(data)
        target.mkdir(parents=True)
        for item in frame.iterdir():
            if item.name != "cameras.json":
                (target / item.name).symlink_to(item.resolve())
        cameras = [c for c in load_cameras(cameras_file) if c.name != held_out]
        if not cameras:
            raise ValueError(f"{cameras_file}: no camera left without {held_out!r}")
        save_cameras(target / "cameras.json", cameras)
        subject = frame.parent / "subject.json"
        if subject.is_file() and not (target.parent / "subject.json").exists():
            (target.parent / "subject.json").symlink_to(subject.resolve())
    return out


def _synthesize(work: Path) -> Path:
    from lisa_hand.data.synth.config import SynthConfig
    from lisa_hand.data.synth.dataset import synthesize

    data = work / "data"
    if (data / "dataset.json").is_file():
        return data
    config = SynthConfig(num_subjects=6, num_poses=2, num_views=7, resolution=(384, 250),
                         seed=11)
    print(f"synthesising the benchmark's dataset into {data} (about a minute)", flush=True)
    synthesize(data, config, progress=False, overwrite=data.exists())
    return data


@dataclasses.dataclass
class StepRun:
    """One configuration's image-training state, to time single steps (:func:`step_runs`)."""

    config: ImageTrainConfig
    rays: RayFrames
    scans: ScanFrames | None
    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    generator: torch.Generator
    device: torch.device

    def step(self) -> float:
        """One training step (sample, render, losses, backward, Adam) -> its wall seconds,
        GPU work waited for before each clock read."""
        config = self.config
        synchronize()
        start = time.perf_counter()
        batch = sample_image_batch(self.rays, self.scans, config, self.generator).to(self.device)
        terms = self.model(batch, render=config.render, batched=config.batched_step,
                           background=config.background)
        total = sum(weight * terms[key] for key, weight in config.loss_weights().items())
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        synchronize()
        return time.perf_counter() - start


def step_runs(data: Path, prior: PriorModel | None, device: str = "cpu") -> dict[str, StepRun]:
    """The reference and the fast configuration on ``data``, from ``prior``, on ``device``, each
    ready to time steps: {"reference": run, "fast": run}."""
    device = resolve_device(device)
    runs = {}
    for name, config in {"reference": reference_config(1), "fast": fast_config(1)}.items():
        config, prior_model, _ = resolve_prior(config, prior)
        rays, scans = load_image_data(data, config)
        torch.manual_seed(0)
        model, _ = build_image_model(rays, config, prior_model)
        model = model.to(device).train()
        optimizer = torch.optim.Adam(model.parameters(), lr=config.trainer.lr)
        runs[name] = StepRun(config, rays, scans, model, optimizer,
                             torch.Generator().manual_seed(0), device)
    return runs


def measure_rates(data: Path, prior: PriorModel | None, rounds: int, steps: int,
                  device: str = "cpu") -> dict[str, float]:
    """Seconds per step of both configurations on ``device``, interleaved: ``rounds`` rounds of
    ``steps`` steps each (GPU work waited for before each clock read); -> {"reference": s,
    "fast": s} (best of the rounds' medians)."""
    runs = step_runs(data, prior, device)
    for run in runs.values():  # warm-up
        run.step()
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(rounds):
        for name, run in runs.items():
            best[name] = min(best[name], statistics.median(run.step() for _ in range(steps)))
    return best


def evaluate(run: Path, data: Path, held_out: str, scale: float,
             checkpoint: Path | None = None, surface_points: int = 4000,
             device: str = "cpu") -> dict[str, float]:
    """PSNR of the held-out camera of every training frame of ``data`` (the full dataset),
    rendered by the run's model (its subject codes, mean calibration) on ``device``, and the
    geometry: the mean |SDF| of the model at the frame's true surface points (``scan.npz``
    points, the first ``surface_points``), mm. -> {"psnr_mask", "psnr_image",
    "surface_error_mm", "frames", "seconds"}"""
    from lisa_hand.model.checkpoint import load_checkpoint

    start = time.perf_counter()
    trained = (trained_from_checkpoint(load_checkpoint(checkpoint)) if checkpoint is not None
               else load_trained(run)).to(resolve_device(device))
    table = RayFrames(data, "train", max_band_px=0, background_per_view=0).table
    inside, whole, surface = [], [], []
    for frame, paths in enumerate(table.frames):
        camera = next(c for c in load_cameras(paths.cameras) if c.name == held_out)
        width, height = round(camera.width * scale), round(camera.height * scale)
        small = scale_camera(camera, width, height)
        subject = table.subject_ids[int(table.frame_subject[frame])]
        row = trained.subject_ids.index(subject)
        params = HandParams(pose=table.pose[frame], translation=table.translation[frame],
                            rest_joints=table.rest_joints[int(table.frame_subject[frame])],
                            shape_code=trained.shape_codes[row].float(),
                            color_code=trained.color_codes[row].float())
        image = render_hand(trained, params, [small])[0]
        with np.load(paths.scan) as scan:
            points = torch.as_tensor(scan["points"][:surface_points], dtype=torch.float32,
                                     device=trained.field.device)
        with torch.no_grad():
            sdf = hand_field(trained, params).sdf_fn()(points)
        surface.append(1000.0 * float(sdf.abs().mean()))
        target = _resized(read_image(paths.image(held_out)), width, height)
        mask = _resized(read_mask(paths.mask(held_out)).astype(np.float32), width, height) > 0.5
        predicted = image.rgb.cpu().numpy()
        inside.append(psnr(predicted, target, mask))
        whole.append(psnr(predicted, target))
    return {"psnr_mask": float(np.mean(inside)), "psnr_image": float(np.mean(whole)),
            "surface_error_mm": float(np.mean(surface)), "frames": len(inside),
            "seconds": round(time.perf_counter() - start, 1)}


def _resized(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-average ``image`` [H, W(, C)] to ``width x height`` (integer factors, else nearest)."""
    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image
    if h % height == 0 and w % width == 0:
        fy, fx = h // height, w // width
        shape = (height, fy, width, fx) + image.shape[2:]
        return image.reshape(shape).mean(axis=(1, 3))
    rows = (np.arange(height) * h / height).astype(int)
    cols = (np.arange(width) * w / width).astype(int)
    return image[rows][:, cols]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m benchmarks train",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None,
                        help="a dataset (lisa synth layout); default: synthesised into --work")
    parser.add_argument("--work", type=Path, default=Path("runs/bench_train"),
                        help="folder for the dataset, the held-out copy and the runs")
    parser.add_argument("--held-out", default=None,
                        help="camera held out of training (default: the last of the rig)")
    parser.add_argument("--budget-s", type=float, default=180.0,
                        help="the equal wall-clock budget, seconds (converted into steps with "
                             "each measured rate)")
    parser.add_argument("--rate-rounds", type=int, default=3,
                        help="rounds of the interleaved step timing (best round's median)")
    parser.add_argument("--rate-steps", type=int, default=5,
                        help="steps of each configuration per round of the timing")
    parser.add_argument("--eval-scale", type=float, default=0.5,
                        help="resolution of the held-out renders, as a fraction of the images'")
    parser.add_argument("--model", type=Path, default=None,
                        help="trained model whose geometry is the prior (default: the shipped "
                             "LISA-full; 'geometry': the shipped 203-subject prior)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (default: torch's; 1 on a shared machine)")
    parser.add_argument("--device", default="cpu",
                        help="where both configurations train and render: cpu (default), cuda "
                             "or cuda:N (GPU work is waited for before each clock read)")
    parser.add_argument("--shaded", action="store_true",
                        help="also train the fast step with headlight shading "
                             "(shading=headlight) for the fast run's steps: PSNR 'psnr_shaded'")
    parser.add_argument("--steps", type=int, default=None,
                        help="one run instead of the comparison: the fast step with the --set "
                             "overrides for this many steps, then its PSNR and surface error "
                             "(no timing, no reference)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="with --steps: a config override of the fast step, as in 'lisa "
                             "train --set' (repeatable), e.g. lambda_surface=100")
    parser.add_argument("--json", type=Path, default=None, help="write the numbers here")
    return parser


def run_variant(train_data: Path, data: Path, work: Path, held_out: str, prior: PriorModel | None,
                steps: int, overrides: list[str], scale: float, device: str = "cpu") -> dict:
    """``--steps``: the fast step with ``overrides`` trained ``steps`` steps (constant learning
    rate, from ``prior``) into ``work/run_<overrides>``, resumed if there, then evaluated. ->
    :func:`evaluate`'s numbers plus "steps", "overrides", "train_seconds"."""
    config = apply_overrides(fast_config(steps, device=device), overrides)
    name = "_".join(o.replace("=", "-").replace(".", "") for o in overrides) or "default"
    run = work / f"run_{name}"
    start = time.perf_counter()
    train_images(train_data, run, config, prior=prior, resume=True)
    result = evaluate(run, data, held_out, scale, device=device)
    result.update(steps=steps, overrides=list(overrides),
                  train_seconds=round(time.perf_counter() - start, 1))
    print(f"{' '.join(overrides) or 'defaults'}: {steps} steps, PSNR held-out views "
          f"{result['psnr_mask']:.2f} dB in the mask, {result['psnr_image']:.2f} dB whole image, "
          f"surface |SDF| {result['surface_error_mm']:.3f} mm", flush=True)
    return result


def main(argv: list[str] | None = None) -> dict:
    args = _parser().parse_args(argv)
    cpu_threads(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    data = args.data if args.data is not None else _synthesize(args.work)
    first = sorted(data.glob("s*/f*/cameras.json"))
    if not first:
        raise ValueError(f"{data}: no frame with cameras.json (not a dataset)")
    held_out = args.held_out or load_cameras(first[0])[-1].name
    train_data = held_out_copy(data, args.work / "train_views", held_out)
    prior = prior_from_trained(args.model)
    device = str(resolve_device(args.device))
    if args.steps is not None:
        result = run_variant(train_data, data, args.work, held_out, prior, args.steps,
                             args.overrides, args.eval_scale, device)
        write_results(args.json, result)
        return result
    if args.overrides:
        raise SystemExit("--set needs --steps (one run with the overrides)")

    rates = measure_rates(train_data, prior, args.rate_rounds, args.rate_steps, device)
    ref_rate, fast_rate = 1.0 / rates["reference"], 1.0 / rates["fast"]
    where = (describe_device(device) if device != "cpu"
             else f"{torch.get_num_threads()} threads")
    print(f"steps per second (interleaved, {where}): reference "
          f"{ref_rate:.2f}, fast {fast_rate:.2f} (x{fast_rate / ref_rate:.2f})", flush=True)
    ref_steps = max(1, round(args.budget_s * ref_rate))
    fast_steps = max(ref_steps, round(args.budget_s * fast_rate))

    results: dict = {}
    run_ref, run_fast = args.work / "run_reference", args.work / "run_fast"
    timings = {}
    runs = [("reference", run_ref, reference_config(ref_steps, device=device)),
            ("fast_equal_steps", run_fast, fast_config(ref_steps, device=device)),
            ("fast", run_fast, fast_config(fast_steps, device=device))]
    if args.shaded:
        runs.append(("fast_shaded", args.work / "run_fast_shaded",
                     dataclasses.replace(fast_config(fast_steps, device=device),
                                         shading="headlight")))
    for name, run, config in runs:
        start = time.perf_counter()
        resume = name == "fast"  # continues the equal-steps run up to its own budget
        if name == "fast_shaded" and run.exists():
            shutil.rmtree(run)
        train_images(train_data, run, config, prior=prior, resume=resume)
        timings[name] = round(time.perf_counter() - start, 1)
        results[name] = evaluate(run, data, held_out, args.eval_scale, device=device)
        results[name]["steps"] = config.trainer.steps
        print(f"{name:17s}: {config.trainer.steps:5d} steps, PSNR held-out views "
              f"{results[name]['psnr_mask']:.2f} dB in the mask, "
              f"{results[name]['psnr_image']:.2f} dB whole image, surface |SDF| "
              f"{results[name]['surface_error_mm']:.3f} mm (train {timings[name]} s)",
              flush=True)
    summary = {
        "steps_per_s": fast_rate, "reference_steps_per_s": ref_rate,
        "speedup": fast_rate / ref_rate,
        "psnr": results["fast"]["psnr_mask"], "reference_psnr": results["reference"]["psnr_mask"],
        "psnr_equal_steps": results["fast_equal_steps"]["psnr_mask"],
        "surface_error_mm": results["fast"]["surface_error_mm"],
        "reference_surface_error_mm": results["reference"]["surface_error_mm"],
        "surface_error_mm_equal_steps": results["fast_equal_steps"]["surface_error_mm"],
        "psnr_shaded": results["fast_shaded"]["psnr_mask"] if args.shaded else None,
        "budget_s": args.budget_s, "held_out_camera": held_out, "threads": torch.get_num_threads(),
        "device": describe_device(device),
        "train_seconds": timings, "results": results,
        "reference_config": dataclasses.asdict(reference_config(ref_steps).render),
        "fast_config": dataclasses.asdict(fast_config(fast_steps).render),
    }
    if args.shaded:
        print(f"with headlight shading (same steps as fast): {summary['psnr_shaded']:.2f} dB in "
              f"the mask vs {summary['psnr']:.2f} dB without")
    print(f"headline: x{summary['speedup']:.2f} steps/s; PSNR at equal time "
          f"{summary['psnr']:.2f} dB vs reference {summary['reference_psnr']:.2f} dB; at equal "
          f"steps {summary['psnr_equal_steps']:.2f} dB; surface |SDF| "
          f"{summary['surface_error_mm']:.3f} mm vs reference "
          f"{summary['reference_surface_error_mm']:.3f} mm (equal steps "
          f"{summary['surface_error_mm_equal_steps']:.3f} mm)")
    write_results(args.json, summary)
    return summary


if __name__ == "__main__":
    main()
