"""Render benchmark: a whole 1024x667 image of a hand, fast path against uniform sampling.

``python -m benchmarks render [--field NAME] [--model PATH] [--resolution WxH] [--json FILE]``

The scene is a posed hand (:func:`benchmarks.field.bench_pose`) seen palm-on from 0.6 m
through a 40 degree lens (the hand spans about 450 of the 667 rows, as in InterHand2.6M's
1024x667 views). The fields (``--field``; the default ``auto`` is ``trained`` when a trained
model exists, the shipped one or ``--model``, else ``lisa-capsules``; the output says which):

* ``trained``: a trained LISA model (``--model``, default the shipped
  ``lisa_hand/assets/lisa_pretrained.pt``) as ``lisa render`` renders it
  (:mod:`lisa_hand.inference`: the model's mean codes and colour calibration, its ``beta``,
  Lipschitz allowance 1.5), on the average skeleton;
* ``lisa-capsules`` (default): the union of the skeleton's bone capsules (a hand-shaped surface
  that covers the fingers, as a trained LISA's does) plus a 0.5 mm perturbation and 40 % of the
  colour from the LISA model, which runs on every query: LISA's cost on a realistic surface.
* ``lisa``: the LISA model alone (:class:`lisa_hand.model.LisaModel`, default
  :class:`~lisa_hand.fields.FieldConfig`) at its geometric initialisation, a blob of a hand
  whose fingers are mostly missing (fewer surface pixels than a trained model). This is the hook
  for a trained model: :func:`benchmarks._scenes.lisa_scene` takes any model, pose and
  codes (the callbacks are ``model.field_fn(state)`` and ``model.sdf_fn(state)``).
* ``capsules``: the capsule hand alone (an exact SDF), cheap, for checking accuracy.

Timed in one run, on the same rays and density (Laplace scale ``--beta``):

* **reference**: :func:`~lisa_hand.render.render_rays` with uniform sampling, 128 samples on
  every ray that meets the bounding sphere (the rest cost nothing there too);
* **fast**: :func:`~lisa_hand.render.image.render_image` in volume mode (occupancy-grid culling,
  sphere-traced samples, colour only where the weight matters), including the grid build, RGB
  only (no normal map);
* with ``--variants``: the fast path with sphere or box culling instead of the grid, with colour
  at every sample (``color_weight_threshold=0``, i.e. ``render_rays`` unchanged), the surface
  mode (one shaded point per pixel), and with the normal map (autograd).

Accuracy: PSNR of each image against the reference image, and on ``--dense-pixels`` random
pixels of the hand (and its edge), PSNR of both the fast and the reference image against a dense
render (uniform, 1024 samples a ray), since 128 uniform samples are themselves not exact when
``beta`` is small.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from lisa_hand.render import LaplaceDensity, RenderConfig, ray_sphere_bounds, render_rays
from lisa_hand.render.image import ImageRenderConfig, render_image
from lisa_hand.render.saving import image_to_uint8
from lisa_hand.utils.device import describe_device, resolve_device, synchronize
from lisa_hand.utils.threads import cpu_threads

from . import write_results
from ._scenes import SCENES, BenchScene, make_scene

__all__ = [
    "TARGET_SECONDS",
    "PAPER_SECONDS_P100",
    "run_render_benchmark",
    "main",
]

TARGET_SECONDS = 15.0
"""The target for a 1024x667 render on 2 CPU cores."""
PAPER_SECONDS_P100 = 60.0
"""LISA paper, Section 5: a 1024x667 novel view in "approximately one minute" on a P100."""


class _Counted:
    """Wrap a callback and count the points it is called on."""

    def __init__(self, fn: Callable) -> None:
        self.fn = fn
        self.points = 0

    def __call__(self, points, *args):
        self.points += points.shape[0]
        return self.fn(points, *args)


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.double() - b.double()) ** 2).mean())
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def _fast(scene: BenchScene, config: ImageRenderConfig, density: LaplaceDensity):
    field_fn, sdf_fn = _Counted(scene.field_fn), _Counted(scene.sdf_fn)
    synchronize()
    start = time.perf_counter()
    out = render_image(field_fn, sdf_fn, scene.camera, scene.center, scene.radius, config, density)
    synchronize()
    seconds = time.perf_counter() - start
    counts = {"field_points": field_fn.points, "sdf_points": sdf_fn.points}
    return out, seconds, counts


@dataclass
class _Reference:
    """The reference render (uniform samples) and the rays it was rendered on."""

    output: Any
    """``render_rays``' output on every pixel's ray."""
    rgb: torch.Tensor
    """[H, W, 3] in [0, 1]."""
    seconds: float
    samples: int
    """Uniform samples a ray."""
    field_points: int
    """Field evaluations."""
    origins: torch.Tensor
    directions: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor
    hit: torch.Tensor
    """[H*W] whether the ray meets the bounding sphere."""


def _render_reference(scene: BenchScene, density: LaplaceDensity, samples: int,
                      background: tuple[float, float, float], log: Callable[[str], None]
                      ) -> _Reference:
    """Uniform samples on every ray through the bounding sphere (``render_rays``)."""
    from lisa_hand.geometry.cameras import pixel_rays

    camera = scene.camera
    with torch.no_grad():
        field_ref = _Counted(scene.field_fn)
        synchronize()
        start = time.perf_counter()
        origins, directions = pixel_rays(camera)
        near, far, hit = ray_sphere_bounds(origins, directions, scene.center, scene.radius)
        ref_config = RenderConfig(
            sampler="uniform", num_samples=samples, chunk_size=2048, background=background
        )
        reference = render_rays(
            field_ref, None, origins, directions, near, far, ref_config, density, hit=hit
        )
        synchronize()
        seconds = time.perf_counter() - start
    log(
        f"reference (uniform, {samples} samples a ray, render_rays): "
        f"{seconds:.2f} s, {int(hit.sum())} rays in the bounding sphere, "
        f"{field_ref.points / 1e6:.1f} M field evaluations"
    )
    rgb = reference.rgb.reshape(camera.height, camera.width, 3)
    return _Reference(reference, rgb, seconds, samples, field_ref.points, origins, directions,
                      near, far, hit)


def _fast_results(scene: BenchScene, density: LaplaceDensity, reference: _Reference,
                  background: tuple[float, float, float], log: Callable[[str], None]):
    """The fast path (volume mode, RGB only) against the reference. -> (its output, the
    numbers for the results)."""
    height, width = reference.rgb.shape[:2]
    ref_rgb = reference.rgb
    config = ImageRenderConfig(lipschitz=scene.lipschitz, background=background, normals="none")
    fast, seconds, counts = _fast(scene, config, density)
    psnr = _psnr(fast.rgb, ref_rgb)
    union = fast.mask | (reference.output.opacity.reshape(height, width) > 0.5)
    psnr_fg = _psnr(fast.rgb[union], ref_rgb[union])
    log(
        f"fast (volume, grid culling, sphere-traced samples): {seconds:.2f} s "
        f"(reference {reference.seconds:.2f} s, x{reference.seconds / seconds:.1f}), "
        f"{fast.num_rays_rendered} rays rendered, {counts['sdf_points'] / 1e6:.2f} M sdf and "
        f"{counts['field_points'] / 1e6:.2f} M field evaluations; PSNR vs reference "
        f"{psnr:.1f} dB (hand pixels {psnr_fg:.1f} dB); target {TARGET_SECONDS:.0f} s"
    )
    log(
        "  stages: "
        + ", ".join(
            f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in fast.stats.items()
        )
    )
    num_in_bound = int(reference.hit.sum())
    return fast, {
        "seconds": seconds,
        "reference_seconds": reference.seconds,
        "speedup": reference.seconds / seconds,
        "psnr_vs_reference_db": psnr,
        "psnr_vs_reference_hand_db": psnr_fg,
        "rays": width * height,
        "rays_in_bound": num_in_bound,
        "rays_rendered": fast.num_rays_rendered,
        "reference_rays_rendered": num_in_bound,
        "reference_samples_per_ray": reference.samples,
        "mask_pixels": int(fast.mask.sum()),
        "evaluations": {
            "fast": counts,
            "reference": {"field_points": reference.field_points, "sdf_points": 0},
        },
        "stages": fast.stats,
        "config": {
            "samples_in_band": config.render.num_samples,
            "uniform_samples": config.render.num_samples_extra,
            "color_weight_threshold": config.color_weight_threshold,
            "grid_resolution": config.grid_resolution,
            "lipschitz": config.lipschitz,
        },
    }


def _variant_results(scene: BenchScene, density: LaplaceDensity, ref_rgb: torch.Tensor,
                     images: dict, log: Callable[[str], None]) -> dict:
    """The fast path with sphere or box culling, colour everywhere, the surface mode and the
    normal map; their images go into ``images``."""
    lipschitz = scene.lipschitz
    variant_configs = {
        "cull_sphere": ImageRenderConfig(lipschitz=lipschitz, culling="sphere", normals="none"),
        "cull_box": ImageRenderConfig(lipschitz=lipschitz, culling="box", normals="none"),
        "color_everywhere": ImageRenderConfig(
            lipschitz=lipschitz, color_weight_threshold=0.0, normals="none"
        ),
        "surface": ImageRenderConfig(lipschitz=lipschitz, mode="surface", normals="none"),
        "with_normals": ImageRenderConfig(lipschitz=lipschitz),
    }
    variants = {}
    for name, variant in variant_configs.items():
        out, var_seconds, var_counts = _fast(scene, variant, density)
        var_psnr = _psnr(out.rgb, ref_rgb)
        images[name] = out.rgb
        variants[name] = {
            "seconds": var_seconds,
            "psnr_vs_reference_db": var_psnr,
            "rays_rendered": out.num_rays_rendered,
            "evaluations": var_counts,
            "stages": out.stats,
        }
        log(
            f"variant {name:16s}: {var_seconds:6.2f} s, {out.num_rays_rendered} rays, "
            f"{var_counts['sdf_points'] / 1e6:.2f} M sdf + "
            f"{var_counts['field_points'] / 1e6:.2f} M field evaluations, PSNR vs "
            f"reference {var_psnr:.1f} dB"
        )
    return variants


def run_render_benchmark(
    field: str = "auto",
    width: int = 1024,
    height: int = 667,
    *,
    beta: float | None = None,
    reference_samples: int = 128,
    variants: bool = False,
    dense_pixels: int = 2000,
    seed: int = 0,
    save_dir: str | None = None,
    model_path: str | None = None,
    device: torch.device | str = "cpu",
    log: Callable[[str], None] = print,
) -> dict:
    """Render the scene with the fast path and the uniform reference; return the numbers.

    beta: Laplace scale, metres (None: a trained model's own, else 1 mm).
    model_path: the trained model of the 'trained' and 'auto' fields.
    device: where the trained field renders ("cpu", "cuda", "cuda:N"; GPU work is waited for
        before each clock read).
    """
    torch.manual_seed(seed)
    device = resolve_device(device)
    scene = make_scene(field, width, height, seed, model_path, device)
    if beta is None:
        beta = scene.beta if scene.beta is not None else 1e-3
    density = LaplaceDensity(beta_init=beta, beta_min=0.0).to(device)
    background = (0.0, 0.0, 0.0)
    log(
        f"render benchmark: {width}x{height}, field: {scene.description}; beta {beta * 1e3:.2f} "
        f"mm, bound radius {scene.radius * 100:.1f} cm, torch threads {torch.get_num_threads()}, "
        f"device {describe_device(device)}"
    )
    results: dict = {
        "field": field,
        "field_description": scene.description,
        "width": width,
        "height": height,
        "resolution": f"{width}x{height}",
        "threads": torch.get_num_threads(),
        "device": describe_device(device),
        "beta_m": beta,
        "target_seconds": TARGET_SECONDS,
        "paper_seconds_p100": PAPER_SECONDS_P100,
        # The machine may be shared: the load says how much the timings can be trusted.
        "load_average_at_start": os.getloadavg()[0],
    }
    reference = _render_reference(scene, density, reference_samples, background, log)
    fast, numbers = _fast_results(scene, density, reference, background, log)
    results.update(numbers)
    images = {"fast": fast.rgb, "reference": reference.rgb}
    if variants:
        results["variants"] = _variant_results(scene, density, reference.rgb, images, log)
    results["load_average_at_end"] = os.getloadavg()[0]
    log(
        f"load average (1 min) at start {results['load_average_at_start']:.1f}, at end "
        f"{results['load_average_at_end']:.1f} (on {os.cpu_count()} cores)"
    )
    if dense_pixels > 0:
        results["dense_check"] = _dense_check(
            scene, density, reference.output, fast, dense_pixels, seed, reference.origins,
            reference.directions, reference.near, reference.far, log,
        )  # fmt: skip
    if save_dir is not None:
        _save_images(save_dir, images, width, height)
    return results


def _dense_check(
    scene, density, reference, fast, num_pixels, seed, origins, directions, near, far, log
) -> dict:
    """PSNR of the fast and the reference image against 1024 uniform samples on hand pixels."""
    foreground = (reference.opacity > 0.01) | (fast.opacity.reshape(-1) > 0.01)
    candidates = torch.nonzero(foreground).squeeze(-1)
    generator = torch.Generator().manual_seed(seed)
    pick = torch.randperm(candidates.shape[0], generator=generator)[:num_pixels]
    pixels = candidates[pick]
    config = RenderConfig(sampler="uniform", num_samples=1024, chunk_size=256)
    with torch.no_grad():
        dense = render_rays(
            scene.field_fn,
            None,
            origins[pixels],
            directions[pixels],
            near[pixels],
            far[pixels],
            config,
            density,
        )
    fast_rgb = fast.rgb.reshape(-1, 3)[pixels]
    psnr_fast = _psnr(fast_rgb, dense.rgb)
    psnr_ref = _psnr(reference.rgb[pixels], dense.rgb)
    log(
        f"dense check on {pixels.shape[0]} hand/edge pixels (uniform, 1024 samples): PSNR fast "
        f"{psnr_fast:.1f} dB, reference {psnr_ref:.1f} dB"
    )
    return {
        "pixels": int(pixels.shape[0]),
        "psnr_fast_db": psnr_fast,
        "psnr_reference_db": psnr_ref,
    }


def _save_images(save_dir: str, images: dict, width: int, height: int) -> None:
    import imageio.v3 as iio

    from lisa_hand.utils.io import atomic_path

    folder = Path(save_dir)
    folder.mkdir(parents=True, exist_ok=True)
    for name, rgb in images.items():
        path = folder / f"render_{name}_{width}x{height}.png"
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, image_to_uint8(rgb), extension=".png")


def _parse_resolution(text: str) -> tuple[int, int]:
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--resolution must look like 1024x667, got {text!r}") from None
    if width < 1 or height < 1:
        raise ValueError(f"--resolution must be positive, got {text!r}")
    return width, height


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks render [options]``; returns the results."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks render", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--field",
        choices=SCENES,
        default=SCENES[0],
        help="auto (default): trained if a trained model exists, else lisa-capsules; trained: "
        "a trained model as 'lisa render' renders it; lisa-capsules: the capsule hand at "
        "LISA's cost; lisa: the LISA model alone (geometric init); capsules: the analytic hand",
    )
    parser.add_argument(
        "--model", default=None, help="trained model for --field trained/auto (default: shipped)"
    )
    parser.add_argument("--resolution", default="1024x667", help="WxH pixels")
    parser.add_argument(
        "--beta", type=float, default=None,
        help="Laplace scale, metres (default: a trained model's own, else 0.001)",
    )  # fmt: skip
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (default: unchanged)")
    parser.add_argument(
        "--variants",
        action="store_true",
        help="also time sphere/box culling, colour everywhere, surface mode",
    )
    parser.add_argument(
        "--dense-pixels",
        type=int,
        default=2000,
        help="pixels of the dense accuracy check (0: skip)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--device", default="cpu",
        help="where the trained field renders: cpu (default), cuda or cuda:N",
    )  # fmt: skip
    parser.add_argument(
        "--save-images",
        default=None,
        metavar="DIR",
        help="write the rendered images as PNG into DIR",
    )
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    width, height = _parse_resolution(args.resolution)
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    if args.beta is not None and not args.beta > 0:
        raise ValueError(f"--beta must be > 0 (metres), got {args.beta}")
    with cpu_threads(args.threads):
        results = run_render_benchmark(
            args.field,
            width,
            height,
            beta=args.beta,
            variants=args.variants,
            dense_pixels=args.dense_pixels,
            seed=args.seed,
            save_dir=args.save_images,
            model_path=args.model,
            device=args.device,
        )
    write_results(args.json, json.loads(json.dumps(results, default=float)))
    return results


if __name__ == "__main__":
    main()
