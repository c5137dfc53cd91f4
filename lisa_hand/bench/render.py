"""Render benchmark: a whole 1024x667 image of a hand, fast path against uniform sampling.

``python -m lisa_hand.bench render [--field NAME] [--model PATH] [--resolution WxH] [--json FILE]``

The scene is a posed hand (:func:`lisa_hand.bench.field.bench_pose`) seen palm-on from 0.6 m
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
  for a trained model: :func:`lisa_scene` takes any model, pose and codes (the callbacks are
  ``model.field_fn(state)`` and ``model.sdf_fn(state)``).
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

import torch

from ..geometry.cameras import Camera, intrinsics_from_fov, look_at
from ..render import LaplaceDensity, RenderConfig, ray_sphere_bounds, render_rays
from ..render.image import ImageRenderConfig, image_to_uint8, render_image

__all__ = [
    "TARGET_SECONDS",
    "PAPER_SECONDS_P100",
    "BenchScene",
    "lisa_scene",
    "capsule_scene",
    "trained_scene",
    "SCENES",
    "make_scene",
    "run_render_benchmark",
    "main",
]

TARGET_SECONDS = 15.0
"""The issue's target for a 1024x667 render on 2 CPU cores."""
PAPER_SECONDS_P100 = 60.0
"""LISA paper, Section 5: a 1024x667 novel view in "approximately one minute" on a P100."""

_CAMERA_DISTANCE = 0.6
_FOV_DEG = 40.0
# Capsule radii of the analytic hand, metres: palm segments and finger segments.
_PALM_RADIUS = 0.013
_FINGER_RADIUS = 0.0085


@dataclass
class BenchScene:
    """A field and a camera to render it with.

    field_fn: points [N, 3] metres, directions [N, 3] -> (sdf [N] metres, rgb [N, 3]).
    sdf_fn: points [N, 3] metres -> sdf [N] metres. camera: the view.
    center: [3] metres and radius (metres) of a sphere holding the surface.
    lipschitz: bound on the SDF's overestimation (1 for an exact SDF).
    description: one line for the log.
    beta: the field's own Laplace scale, metres (a trained model's), or None.
    """

    field_fn: Callable
    sdf_fn: Callable
    camera: Camera
    center: torch.Tensor
    radius: float
    lipschitz: float
    description: str
    beta: float | None = None


def _posed_segments(pose: torch.Tensor, rest_joints: torch.Tensor, tip_extension: float):
    """World segments of the posed hand: (start [20, 3], end [20, 3], owner bone ids, rotation of
    the root [3, 3]). pose: [1, 48] radians; rest_joints: [16, 3] metres."""
    from ..fields.bones import SEGMENT_BONES, bone_segments
    from ..skeleton import forward_kinematics

    kinematics = forward_kinematics(pose, rest_joints[None])
    start, end = bone_segments(rest_joints[None], tip_extension)
    transforms = kinematics.transforms[0, list(SEGMENT_BONES)]
    rot, trans = transforms[:, :3, :3], transforms[:, :3, 3]
    start = (rot @ start[0, :, :, None])[..., 0] + trans
    end = (rot @ end[0, :, :, None])[..., 0] + trans
    return start, end, list(SEGMENT_BONES), kinematics.transforms[0, 0, :3, :3]


def _palm_camera(
    center: torch.Tensor, root_rotation: torch.Tensor, width: int, height: int
) -> Camera:
    """A camera 0.6 m in front of the palm (rest palm normal -y), fingers (rest -x) up."""
    palm_normal = root_rotation @ torch.tensor([0.0, -1.0, 0.0])
    fingers = root_rotation @ torch.tensor([-1.0, 0.0, 0.0])
    eye = center + _CAMERA_DISTANCE * palm_normal
    rotation, translation = look_at(eye, center, fingers)
    K = intrinsics_from_fov(_FOV_DEG, width, height)
    return Camera(K=K, R=rotation, t=translation, width=width, height=height, name="bench")


def _bounding_sphere(start, end, radii) -> tuple[torch.Tensor, float]:
    ends = torch.cat([start, end])
    center = 0.5 * (ends.amin(dim=0) + ends.amax(dim=0))
    reach = torch.maximum((start - center).norm(dim=-1), (end - center).norm(dim=-1)) + radii
    return center, float(reach.max()) * 1.02


def lisa_scene(
    width: int,
    height: int,
    seed: int = 0,
    *,
    model=None,
    pose: torch.Tensor | None = None,
    rest_joints: torch.Tensor | None = None,
    shape_code: torch.Tensor | None = None,
    color_code: torch.Tensor | None = None,
    lipschitz: float = 1.2,
) -> BenchScene:
    """The LISA field of ``model`` (default: a fresh ``LisaModel()`` at its geometric
    initialisation) for one frame, with the palm camera.

    model: a :class:`lisa_hand.model.LisaModel` (a trained one for real renders).
    pose: [1, 48] radians (default :func:`lisa_hand.bench.field.bench_pose`). rest_joints: [16, 3]
    metres (default ``BENCH_REST_JOINTS``). shape_code: [1, shape_dim] (default zeros);
    color_code: [1, color_dim] (default 0.5 N(0, 1), seeded).
    lipschitz: allowance for the learned SDF overestimating distances.
    """
    from ..fields import FieldConfig
    from ..model.lisa import LisaModel
    from .field import BENCH_REST_JOINTS, bench_pose

    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(BENCH_REST_JOINTS) if rest_joints is None else rest_joints
    if model is None:
        model = LisaModel(FieldConfig(), init_rest_joints=rest_joints).eval()
    config = model.config
    pose = bench_pose(generator) if pose is None else pose
    if shape_code is None:
        shape_code = torch.zeros(1, config.shape_dim)
    if color_code is None:
        color_code = 0.5 * torch.randn(1, config.color_dim, generator=generator)
    with torch.no_grad():
        state = model.prepare(pose, None, rest_joints[None], shape_code, color_code)
    start, end, owners, root = _posed_segments(pose, rest_joints, config.tip_extension)
    radii = torch.tensor(
        [config.palm_region_radius if o == 0 else config.finger_region_radius for o in owners]
    )
    center, radius = _bounding_sphere(start, end, radii)
    return BenchScene(
        field_fn=model.field_fn(state),
        sdf_fn=model.sdf_fn(state),
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=lipschitz,
        description=f"LISA field ({config.composition}, geometric init), bone regions as bounds",
    )


def _capsule_sdf_fn(pose: torch.Tensor, rest_joints: torch.Tensor):
    """The union of the posed bone capsules: (sdf_fn, start [20, 3], end [20, 3], radii [20])."""
    start, end, owners, root = _posed_segments(pose, rest_joints, tip_extension=0.8)
    radii = torch.tensor([_PALM_RADIUS if o == 0 else _FINGER_RADIUS for o in owners])
    axis = end - start
    length = axis.norm(dim=-1)
    axis = axis / length[:, None]

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        dtype = points.dtype
        rel = points[:, None, :] - start.to(dtype)
        along = (rel * axis.to(dtype)).sum(-1).clamp(min=0.0)
        along = torch.minimum(along, length.to(dtype))
        offset = rel - along[..., None] * axis.to(dtype)
        return (offset.norm(dim=-1) - radii.to(dtype)).amin(dim=-1)

    return sdf_fn, start, end, radii, root


def _capsule_colour(points: torch.Tensor) -> torch.Tensor:
    """Skin tone with a smooth pattern (a few mm wavelength), [N, 3] in [0, 1]."""
    skin = torch.tensor([0.85, 0.62, 0.5], dtype=points.dtype)
    pattern = 0.12 * torch.sin(150.0 * points) * torch.cos(90.0 * points.roll(1, dims=-1))
    return (skin + pattern).clamp(0.0, 1.0)


def capsule_scene(width: int, height: int, seed: int = 0) -> BenchScene:
    """The union of the posed skeleton's bone capsules (an exact SDF) with a colour pattern."""
    from .field import BENCH_REST_JOINTS, bench_pose

    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(BENCH_REST_JOINTS)
    pose = bench_pose(generator)
    sdf_fn, start, end, radii, root = _capsule_sdf_fn(pose, rest_joints)

    def field_fn(points: torch.Tensor, directions: torch.Tensor):
        return sdf_fn(points), _capsule_colour(points)

    center, radius = _bounding_sphere(start, end, radii)
    return BenchScene(
        field_fn=field_fn,
        sdf_fn=sdf_fn,
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=1.0,
        description="union of 20 bone capsules (exact SDF), patterned colour",
    )


def lisa_capsule_scene(width: int, height: int, seed: int = 0) -> BenchScene:
    """The capsule hand with LISA's cost: every SDF and colour query also runs the LISA model of
    the same skeleton and pose (geometric initialisation), whose output perturbs the surface by
    at most 0.5 mm and gives 40 % of the colour. A trained LISA's surface covers the fingers like
    the capsules do, which the initialised model alone does not."""
    from .field import BENCH_REST_JOINTS, bench_pose

    lisa = lisa_scene(width, height, seed)
    generator = torch.Generator().manual_seed(seed)
    pose = bench_pose(generator)
    capsule_sdf, start, end, radii, root = _capsule_sdf_fn(pose, torch.tensor(BENCH_REST_JOINTS))
    perturbation = 5e-4  # metres; tanh(s / 5 cm) keeps its gradient below ~0.013

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        return capsule_sdf(points) + perturbation * torch.tanh(lisa.sdf_fn(points) / 0.05)

    def field_fn(points: torch.Tensor, directions: torch.Tensor):
        lisa_sdf, lisa_rgb = lisa.field_fn(points, directions)
        sdf = capsule_sdf(points) + perturbation * torch.tanh(lisa_sdf / 0.05)
        return sdf, 0.6 * _capsule_colour(points) + 0.4 * lisa_rgb

    center, radius = _bounding_sphere(start, end, radii + perturbation)
    return BenchScene(
        field_fn=field_fn,
        sdf_fn=sdf_fn,
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=1.05,
        description="capsule hand + LISA model evaluated at every query (LISA's cost)",
    )


def trained_scene(
    width: int, height: int, seed: int = 0, model_path: str | None = None
) -> BenchScene:
    """A trained model (``model_path``, default the shipped one) as ``lisa render`` renders it:
    the benchmark pose on the average skeleton, the model's mean codes, calibrated colours."""
    from ..inference import hand_bounds, hand_render_config, hand_state
    from ..skeleton import forward_kinematics
    from .mesh import bench_hand

    if model_path is None:
        from ..model.trained import default_model_path

        if not default_model_path().is_file():
            raise FileNotFoundError(f"{default_model_path()}: no shipped model; pass --model")
        model_path = str(default_model_path())
    model, params, description = bench_hand(model_path, seed)
    hand = hand_state(model, params)
    center, radius = hand_bounds(params, model.config)
    root = forward_kinematics(params.pose[None], params.rest_joints[None]).transforms[0, 0, :3, :3]
    return BenchScene(
        field_fn=hand.field_fn(),
        sdf_fn=hand.sdf_fn(),
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=hand_render_config(model).lipschitz,
        description=description + " (lisa render's fields)",
        beta=float(model.beta),
    )


SCENES = ("auto", "trained", "lisa-capsules", "lisa", "capsules")


def make_scene(
    kind: str, width: int, height: int, seed: int = 0, model_path: str | None = None
) -> BenchScene:
    """One of :data:`SCENES` (see the module docstring); ``model_path``: the trained model."""
    if kind == "auto":
        from ..model.trained import default_model_path

        trained = model_path is not None or default_model_path().is_file()
        kind = "trained" if trained else "lisa-capsules"
    if kind == "trained":
        return trained_scene(width, height, seed, model_path)
    if kind == "lisa-capsules":
        return lisa_capsule_scene(width, height, seed)
    if kind == "lisa":
        return lisa_scene(width, height, seed)
    if kind == "capsules":
        return capsule_scene(width, height, seed)
    raise ValueError(f"field must be one of {SCENES}, got {kind!r}")


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
    start = time.perf_counter()
    out = render_image(field_fn, sdf_fn, scene.camera, scene.center, scene.radius, config, density)
    seconds = time.perf_counter() - start
    counts = {"field_points": field_fn.points, "sdf_points": sdf_fn.points}
    return out, seconds, counts


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
    log: Callable[[str], None] = print,
) -> dict:
    """Render the scene with the fast path and the uniform reference; return the numbers.

    beta: Laplace scale, metres (None: a trained model's own, else 1 mm).
    model_path: the trained model of the 'trained' and 'auto' fields.
    """
    torch.manual_seed(seed)
    scene = make_scene(field, width, height, seed, model_path)
    if beta is None:
        beta = scene.beta if scene.beta is not None else 1e-3
    density = LaplaceDensity(beta_init=beta, beta_min=0.0)
    background = (0.0, 0.0, 0.0)
    log(
        f"render benchmark: {width}x{height}, field: {scene.description}; beta {beta * 1e3:.2f} "
        f"mm, bound radius {scene.radius * 100:.1f} cm, torch threads {torch.get_num_threads()}"
    )
    results: dict = {
        "field": field,
        "field_description": scene.description,
        "width": width,
        "height": height,
        "resolution": f"{width}x{height}",
        "threads": torch.get_num_threads(),
        "beta_m": beta,
        "target_seconds": TARGET_SECONDS,
        "paper_seconds_p100": PAPER_SECONDS_P100,
        # The machine may be shared: the load says how much the timings can be trusted.
        "load_average_at_start": os.getloadavg()[0],
    }

    # Reference: uniform samples on every ray through the bounding sphere.
    from ..geometry.cameras import pixel_rays

    with torch.no_grad():
        field_ref = _Counted(scene.field_fn)
        start = time.perf_counter()
        origins, directions = pixel_rays(scene.camera)
        near, far, hit = ray_sphere_bounds(origins, directions, scene.center, scene.radius)
        ref_config = RenderConfig(
            sampler="uniform", num_samples=reference_samples, chunk_size=2048, background=background
        )
        reference = render_rays(
            field_ref, None, origins, directions, near, far, ref_config, density, hit=hit
        )
        reference_seconds = time.perf_counter() - start
    ref_rgb = reference.rgb.reshape(height, width, 3)
    num_in_bound = int(hit.sum())
    log(
        f"reference (uniform, {reference_samples} samples a ray, render_rays): "
        f"{reference_seconds:.2f} s, {num_in_bound} rays in the bounding sphere, "
        f"{field_ref.points / 1e6:.1f} M field evaluations"
    )

    config = ImageRenderConfig(lipschitz=scene.lipschitz, background=background, normals="none")
    fast, seconds, counts = _fast(scene, config, density)
    psnr = _psnr(fast.rgb, ref_rgb)
    union = fast.mask | (reference.opacity.reshape(height, width) > 0.5)
    psnr_fg = _psnr(fast.rgb[union], ref_rgb[union])
    log(
        f"fast (volume, grid culling, sphere-traced samples): {seconds:.2f} s "
        f"(reference {reference_seconds:.2f} s, x{reference_seconds / seconds:.1f}), "
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
    results.update(
        {
            "seconds": seconds,
            "reference_seconds": reference_seconds,
            "speedup": reference_seconds / seconds,
            "psnr_vs_reference_db": psnr,
            "psnr_vs_reference_hand_db": psnr_fg,
            "rays": width * height,
            "rays_in_bound": num_in_bound,
            "rays_rendered": fast.num_rays_rendered,
            "reference_rays_rendered": num_in_bound,
            "reference_samples_per_ray": reference_samples,
            "mask_pixels": int(fast.mask.sum()),
            "evaluations": {
                "fast": counts,
                "reference": {"field_points": field_ref.points, "sdf_points": 0},
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
    )

    images = {"fast": fast.rgb, "reference": ref_rgb}
    if variants:
        variant_configs = {
            "cull_sphere": ImageRenderConfig(
                lipschitz=scene.lipschitz, culling="sphere", normals="none"
            ),
            "cull_box": ImageRenderConfig(lipschitz=scene.lipschitz, culling="box", normals="none"),
            "color_everywhere": ImageRenderConfig(
                lipschitz=scene.lipschitz, color_weight_threshold=0.0, normals="none"
            ),
            "surface": ImageRenderConfig(lipschitz=scene.lipschitz, mode="surface", normals="none"),
            "with_normals": ImageRenderConfig(lipschitz=scene.lipschitz),
        }
        results["variants"] = {}
        for name, variant in variant_configs.items():
            out, var_seconds, var_counts = _fast(scene, variant, density)
            var_psnr = _psnr(out.rgb, ref_rgb)
            images[name] = out.rgb
            results["variants"][name] = {
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

    results["load_average_at_end"] = os.getloadavg()[0]
    log(
        f"load average (1 min) at start {results['load_average_at_start']:.1f}, at end "
        f"{results['load_average_at_end']:.1f} (on {os.cpu_count()} cores)"
    )
    if dense_pixels > 0:
        results["dense_check"] = _dense_check(
            scene, density, reference, fast, dense_pixels, seed, origins, directions, near, far, log
        )
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

    from ..utils.io import atomic_path

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
    """Command line: ``python -m lisa_hand.bench render [options]``; returns the results."""
    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.bench render", description=__doc__.split("\n\n")[0]
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
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads")
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
        "--save-images",
        default=None,
        metavar="DIR",
        help="write the rendered images as PNG into DIR",
    )
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    width, height = _parse_resolution(args.resolution)
    if args.threads is not None:
        if args.threads < 1:
            raise ValueError(f"--threads must be >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    if args.beta is not None and not args.beta > 0:
        raise ValueError(f"--beta must be > 0 (metres), got {args.beta}")
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
    )
    if args.json is not None:
        from ..utils.io import write_json

        write_json(args.json, json.loads(json.dumps(results, default=float)))
        print(f"wrote {args.json}")
    return results


if __name__ == "__main__":
    main()
