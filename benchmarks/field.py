"""Field benchmark: points per second of the LISA field against a straightforward reference.

``python -m benchmarks field [--json FILE]``

The reference is what one writes first: 16 separate ``nn.Sequential`` per-bone MLPs run in a
Python loop, every point through every bone, the pose features and latent codes concatenated to
every point's input, float32, ``torch.nn.Softplus``. It applies the same bone regions (masking)
as the model, so both compute the same function; the weights are copied from the model and the
outputs compared (max abs error printed; points on a region's boundary, in the region for one
and not for the other by rounding, are left out and counted: ``region_ties``).

The optimised field is measured step by step, each step adding one idea to the previous:

1. ``stacked``: stacked weights ``[J, in, out]`` (one einsum a layer), every point through every
   bone, the conditioning folded into a per-frame bias (``cull=False``).
2. ``culled``: each bone's MLPs run only on the points inside its region, the skinning MLP only
   on points in two or more regions (``cull=True``).
3. ``culled_mixed`` and ``culled_bf16``: as 2 with the colour MLPs' (or all MLPs') hidden
   products in bfloat16.
4. ``culled_fused``: as 2 with each row chunk's layer chain compiled (``torch.compile``,
   :mod:`lisa_hand.fields.fused`): bias, a polynomial Softplus and the SDF's output dot product
   fused into one pass after each product. Its compilation time is reported beside it and the
   number of calls that amortise it; where compilation is unavailable it runs eagerly (and says
   so). ``--no-fused`` leaves it out.

The headline is the fastest step within the tolerances. The training side is timed too
(``backward``): a step of the loss ``mean(sdf^2)`` back to every weight (conditioning included),
and an Eikonal step (the SDF's gradient with its graph, then ``mean(sdf^2) + mean((|grad| -
1)^2)`` back to the weights: the double backward), both on the culled field in float32, with
nominal GFLOP/s (:data:`benchmarks._timing.BACKWARD_FLOP_FACTOR`). The share of the
forward spent inside the MLPs (``mlp_share``) tells how much is left outside them.

Beside the model, the ways of running the stacked MLP on the culled (point, bone) pairs are
timed on the same pairs (``pair_strategies``, :mod:`benchmarks._pairs`): the sorted pairs
with a loop over the bones in row chunks (what the model does), the same without chunks,
``torch.nn.functional.grouped_mm``, a padded bmm, and per-bone ``index_select``/``index_copy``
from the unsorted points.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lisa_hand.fields import FieldConfig, bone_segments
from lisa_hand.fields.bones import SEGMENT_BONES
from lisa_hand.fields.fused import fused_inference, fused_stats
from lisa_hand.model.lisa import FieldOutput, FrameState, LisaModel
from lisa_hand.skeleton import AVERAGE_REST_JOINTS, NUM_JOINTS
from lisa_hand.utils.device import describe_device, resolve_device
from tests.model.reference_field import ReferenceField

from . import write_results
from ._pairs import time_pair_strategies
from ._timing import (
    interleaved_best,
    large_matmul,
    mlp_flops,
    mlp_share,
    time_training_steps,
)

__all__ = [
    "FieldBenchmark",
    "bench_pose",
    "sample_bench_points",
    "run_field_benchmark",
    "main",
]

# Accepted differences between the optimised field and the float32 reference: 0.1 mm on the SDF
# (a tenth of the best fitting errors the paper reports), 2e-3 on colour and weights.
SDF_TOLERANCE_M = 1e-4
COLOR_TOLERANCE = 2e-3
WEIGHT_TOLERANCE = 2e-3


def bench_pose(generator: torch.Generator) -> torch.Tensor:
    """A moderately flexed hand with a random global orientation. -> [1, 48] radians"""
    pose = 0.15 * torch.randn(1, NUM_JOINTS, 3, generator=generator)
    pose[:, 1:, 2] += 0.35  # flex the fingers about their lateral (z) axes
    pose[:, 0] = torch.randn(3, generator=generator)
    return pose.reshape(1, 3 * NUM_JOINTS)


def sample_bench_points(
    model: LisaModel, state: FrameState, num_points: int, generator: torch.Generator
) -> torch.Tensor:
    """Points around the posed hand: half uniform in its bounding box (2 cm padding), half near
    the bones (uniform along a random region segment, plus 1 cm Gaussian noise).

    -> [1, num_points, 3] world metres
    """
    config = model.config
    start, end = bone_segments(state.rest_joints, config.tip_extension)
    transforms = state.kinematics.transforms[:, list(SEGMENT_BONES)]
    rot, trans = transforms[..., :3, :3], transforms[..., :3, 3]
    start = (rot @ start[..., None])[..., 0] + trans
    end = (rot @ end[..., None])[..., 0] + trans
    ends = torch.cat([start, end], dim=1)[0]
    low, high = ends.amin(dim=0) - 0.02, ends.amax(dim=0) + 0.02
    num_box = num_points // 2
    box = low + (high - low) * torch.rand(num_box, 3, generator=generator)
    num_near = num_points - num_box
    segment = torch.randint(0, start.shape[1], (num_near,), generator=generator)
    along = torch.rand(num_near, 1, generator=generator)
    near = start[0, segment] + along * (end[0, segment] - start[0, segment])
    near = near + 0.01 * torch.randn(num_near, 3, generator=generator)
    return torch.cat([box, near], dim=0)[None]


@dataclass
class FieldBenchmark:
    """Numbers of one benchmark run (see :func:`run_field_benchmark`)."""

    num_points: int
    points_per_s: float
    reference_points_per_s: float
    speedup: float
    gflops: float
    matmul_gflops: float
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        values = {
            "num_points": self.num_points,
            "points_per_s": self.points_per_s,
            "reference_points_per_s": self.reference_points_per_s,
            "speedup": self.speedup,
            "gflops": self.gflops,
            "matmul_gflops": self.matmul_gflops,
        }
        values.update(self.extra)
        return values


def _max_error(a: torch.Tensor | None, b: torch.Tensor | None) -> float:
    if a is None or b is None:
        return float("nan")
    return float((a.double() - b.double()).abs().max())


_STEPS = {
    # name: (cull, inference precision, fused, what it adds)
    "stacked": (False, "float32", False,
                "stacked weights, conditioning folded into a per-frame bias"),
    "culled": (True, "float32", False, "bone culling (regions), skinning MLP only where 2+ bones"),
    "culled_mixed": (True, "mixed", False, "colour MLPs' hidden products in bfloat16"),
    "culled_bf16": (True, "bfloat16", False, "all MLPs' hidden products in bfloat16"),
    "culled_fused": (True, "float32", True,
                     "culled, chunk chains compiled: bias + polynomial Softplus in one pass"),
}  # fmt: skip


@dataclass
class _BenchHand:
    """The benchmark's field and query: a perturbed model, one posed frame, the points."""

    model: LisaModel
    state: FrameState
    pose: torch.Tensor
    """[1, 48] radians."""
    rest_joints: torch.Tensor
    """[16, 3] metres."""
    shape_code: torch.Tensor
    color_code: torch.Tensor
    points: torch.Tensor
    """[1, N, 3] world metres."""
    translation: torch.Tensor
    """[1, 3] metres."""

    def prepare(self) -> FrameState:
        """The frame's state again (with autograd recording, for training steps)."""
        return self.model.prepare(
            self.pose, self.translation, self.rest_joints[None], self.shape_code, self.color_code
        )


def _bench_hand(config: FieldConfig, num_points: int, seed: int,
                device: torch.device | str = "cpu") -> _BenchHand:
    """The model (weights perturbed as some way into training), pose, codes and points, drawn
    on the CPU (the same numbers on every device) and moved to ``device``."""
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(AVERAGE_REST_JOINTS)
    model = LisaModel(config, init_rest_joints=rest_joints).eval()
    with torch.no_grad():  # a model some way into training: perturb the initial weights
        for param in model.parameters():
            param.add_(0.02 * torch.randn(param.shape, generator=generator))
    pose = bench_pose(generator)
    translation = 0.05 * torch.randn(1, 3, generator=generator)
    shape_code = 0.1 * torch.randn(1, config.shape_dim, generator=generator)
    color_code = 0.1 * torch.randn(1, config.color_dim, generator=generator)
    with torch.no_grad():
        state = model.prepare(pose, translation, rest_joints[None], shape_code, color_code)
        points = sample_bench_points(model, state, num_points, generator)
    if torch.device(device).type != "cpu":
        model = model.to(device)
        pose, translation, rest_joints, shape_code, color_code, points = (
            t.to(device) for t in (pose, translation, rest_joints, shape_code, color_code, points)
        )
        with torch.no_grad():
            state = model.prepare(pose, translation, rest_joints[None], shape_code, color_code)
    return _BenchHand(
        model, state, pose, rest_joints, shape_code, color_code, points, translation
    )


def _region_counts(hand: _BenchHand, extra: dict, log: Callable[[str], None]) -> tuple[int, int]:
    """(active (point, bone) pairs, points in 2+ regions); their ratios go into ``extra``."""
    num_points = hand.points.shape[1]
    with torch.no_grad():
        active = hand.model.field(hand.state, hand.points, with_color=False).region_mask
    pairs = int(active.sum())
    multi = int((active.sum(-1) >= 2).sum())
    extra["active_bones_per_point"] = pairs / num_points
    extra["points_in_no_region"] = float((active.sum(-1) == 0).float().mean())
    extra["points_in_2plus_regions"] = multi / num_points
    log(
        f"points: {num_points}, active bones per point {pairs / num_points:.2f}, in no region "
        f"{extra['points_in_no_region']:.1%}, in 2+ regions {multi / num_points:.1%}; "
        f"torch threads: {torch.get_num_threads()}; device: {extra['device']}"
    )
    return pairs, multi


def _time_steps(hand: _BenchHand, config: FieldConfig, repeats: int, steps: dict, log):
    """Best times of the reference and of every step (geometry, and with colour), interleaved,
    and of a large matmul; then each one's outputs. The fused step is compiled (its first
    calls, timed) before. -> (best {name: s}, reference outputs (geometry, colour), {step:
    (geometry, colour) outputs}, matmul GFLOP/s, compilation {...} or None, run_step)."""
    model, state, points = hand.model, hand.state, hand.points
    reference = ReferenceField(model).eval()

    def run_reference(color: bool) -> FieldOutput:
        color_input = hand.color_code if color else None
        return reference(
            points, hand.pose, state.kinematics, hand.rest_joints[None], hand.shape_code,
            color_input, model.pose_mask,
        )  # fmt: skip

    models = {
        name: dataclasses.replace(config, inference_precision=precision)
        for name, (_, precision, _, _) in steps.items()
    }

    def run_step(name: str, color: bool) -> FieldOutput:
        model.config = models[name]
        try:
            with fused_inference(steps[name][2]):
                return model.field(state, points, with_color=color, cull=steps[name][0])
        finally:
            model.config = config

    compilation = None
    if "culled_fused" in steps:
        with torch.no_grad():
            before, start = fused_stats()["compile_seconds"], time.perf_counter()
            run_step("culled_fused", False)
            run_step("culled_fused", True)
            first = time.perf_counter() - start
        stats = fused_stats()
        compilation = {"first_calls_s": first,
                       "compile_s": stats["compile_seconds"] - before,
                       "compiled": stats["disabled_reason"] is None,
                       "disabled_reason": stats["disabled_reason"]}  # fmt: skip
        log(f"culled_fused: first calls (geometry, colour; compiling) {first:.1f} s"
            + ("" if compilation["compiled"] else
               f"; compilation unavailable, runs eagerly: {stats['disabled_reason']}"))

    matmul, matmul_flops, matmul_name = large_matmul(points.device)
    fns: dict[str, Callable[[], object]] = {"matmul": matmul}
    for color in (False, True):
        suffix = "_color" if color else ""
        fns["reference" + suffix] = lambda c=color: run_reference(c)
        for name in steps:
            fns[name + suffix] = lambda n=name, c=color: run_step(n, c)
    with torch.no_grad():
        slow = ("reference", "reference_color", "stacked", "stacked_color")
        best = interleaved_best(fns, repeats, slow=slow, slow_rounds=max(1, min(repeats, 2)))
        ref_outputs = run_reference(False), run_reference(True)
        outputs = {name: (run_step(name, False), run_step(name, True)) for name in steps}
    peak = matmul_flops / best["matmul"] / 1e9
    return best, ref_outputs, outputs, (peak, matmul_name), compilation, run_step


def _flop_counts(model: LisaModel, num_points: int, pairs: int, multi: int
                 ) -> dict[str, tuple[float, float]]:
    """{variant: (geometry FLOPs, with colour)} of the MLPs: every point through every bone
    with the conditioning in the input (reference) or in a bias (stacked); the culled pairs."""
    sdf_mlp, color_mlp, skin_mlp = model.sdf_mlp, model.color_mlp, model.skinning_mlp
    ref_flops = 16 * mlp_flops(sdf_mlp, num_points, True) + mlp_flops(skin_mlp, num_points, False)
    ref_flops_color = ref_flops + 16 * mlp_flops(color_mlp, num_points, True)
    dense_flops = 16 * mlp_flops(sdf_mlp, num_points, False) + mlp_flops(
        skin_mlp, num_points, False
    )
    dense_flops_color = dense_flops + 16 * mlp_flops(color_mlp, num_points, False)
    culled_flops = mlp_flops(sdf_mlp, pairs, False) + mlp_flops(skin_mlp, multi, False)
    culled_flops_color = culled_flops + mlp_flops(color_mlp, pairs, False)
    flops = {"reference": (ref_flops, ref_flops_color), "stacked": (dense_flops, dense_flops_color)}
    for name in _STEPS:
        flops.setdefault(name, (culled_flops, culled_flops_color))
    return flops


def _step_results(best: dict[str, float], ref_outputs, outputs, flops, num_points: int,
                  steps: dict, log: Callable[[str], None]) -> dict[str, dict]:
    """Speed, GFLOP/s and the largest errors against the reference of every step (logged)."""
    ref_geo, ref_col = ref_outputs
    ref_time, ref_time_color = best["reference"], best["reference_color"]
    log(
        f"{'reference':17s}: geometry {num_points / ref_time:>10,.0f} points/s "
        f"({flops['reference'][0] / ref_time / 1e9:5.1f} GFLOP/s), with colour "
        f"{num_points / ref_time_color:>10,.0f} points/s "
        f"({flops['reference'][1] / ref_time_color / 1e9:5.1f} GFLOP/s)  "
        "[16 nn.Sequential in a loop, conditioning concatenated to every point]"
    )
    # Weights are compared where a point is in some region: elsewhere they are one-hot on the
    # nearest region, and equidistant regions (beyond a shared joint) tie, decided by rounding;
    # the SDF is the same either way. A point on a region's boundary (|excess| ~1e-8 m) is in
    # the region or not by rounding, and the field steps there (a bone joins the blend): such
    # points are left out of the comparison and counted ("region_ties"; 4 of 2^20 bench points,
    # 4 cm off the surface, on the CPU and on a GPU alike).
    inside = ref_geo.region_mask.any(-1)
    results = {}
    for name, (_, _, _, adds) in steps.items():
        geo, col = outputs[name]
        agree = (geo.region_mask == ref_geo.region_mask).all(-1)
        agree_color = (col.region_mask == ref_col.region_mask).all(-1)
        inside_agree = inside & agree
        geo_time, col_time = best[name], best[name + "_color"]
        errors = {
            "sdf_m": _max_error(geo.sdf[agree], ref_geo.sdf[agree]),
            "weights": _max_error(geo.weights[inside_agree], ref_geo.weights[inside_agree]),
            "sdf_with_color_m": _max_error(col.sdf[agree_color], ref_col.sdf[agree_color]),
            "rgb": _max_error(col.rgb[agree_color], ref_col.rgb[agree_color]),
        }
        ok = errors["sdf_m"] <= SDF_TOLERANCE_M and errors["weights"] <= WEIGHT_TOLERANCE
        ok_color = (
            errors["sdf_with_color_m"] <= SDF_TOLERANCE_M and errors["rgb"] <= COLOR_TOLERANCE
        )
        results[name] = {
            "adds": adds,
            "points_per_s": num_points / geo_time,
            "points_per_s_color": num_points / col_time,
            "speedup": ref_time / geo_time,
            "speedup_color": ref_time_color / col_time,
            "gflops": flops[name][0] / geo_time / 1e9,
            "gflops_color": flops[name][1] / col_time / 1e9,
            "max_abs_error": errors,
            "region_ties": int((~agree).sum()),
            "within_tolerance": ok,
            "within_tolerance_color": ok_color,
        }
        log(
            f"{name:17s}: geometry {num_points / geo_time:>10,.0f} points/s "
            f"(x{ref_time / geo_time:5.1f}, {flops[name][0] / geo_time / 1e9:5.1f} GFLOP/s), "
            f"with colour {num_points / col_time:>10,.0f} points/s "
            f"(x{ref_time_color / col_time:5.1f})  [+ {adds}]"
        )
        log(
            f"{'':17s}  max abs error vs reference: sdf {errors['sdf_m']:.1e} m, weights "
            f"{errors['weights']:.1e}, rgb {errors['rgb']:.1e} ({int((~agree).sum())} region "
            f"ties left out): geometry "
            f"{'within' if ok else 'OUTSIDE'} tolerance, colour "
            f"{'within' if ok_color else 'OUTSIDE'}"
        )
    return results


def _amortisation(compilation: dict, best: dict[str, float], log: Callable[[str], None]) -> None:
    """Add to ``compilation`` the time its first calls took beyond steady ones and the number of
    calls (geometry) after which the fused step has paid for it against ``culled``."""
    extra_s = compilation["first_calls_s"] - best["culled_fused"] - best["culled_fused_color"]
    saved = best["culled"] - best["culled_fused"]
    compilation["first_calls_extra_s"] = extra_s
    compilation["saved_per_call_s"] = saved
    compilation["break_even_calls"] = math.ceil(extra_s / saved) if saved > 0 else None
    log(f"culled_fused: compilation {compilation['compile_s']:.1f} s ({extra_s:.1f} s beyond "
        f"steady calls), saves {saved * 1e3:.1f} ms a geometry call: pays for itself after "
        f"{compilation['break_even_calls']} calls")


def _headlines(results: dict[str, dict]) -> tuple[str, str]:
    """The fastest step within the tolerances, geometry and with colour (else 'culled')."""

    def pick(ok_key: str, speed_key: str) -> str:
        candidates = [n for n, r in results.items() if r[ok_key]] or ["culled"]
        return max(candidates, key=lambda n: results[n][speed_key])

    return (pick("within_tolerance", "points_per_s"),
            pick("within_tolerance_color", "points_per_s_color"))


def run_field_benchmark(
    num_points: int = 65536,
    *,
    config: FieldConfig | None = None,
    repeats: int = 5,
    seed: int = 0,
    compile_mlp: bool = False,
    fused: bool = True,
    backward: bool = True,
    device: torch.device | str = "cpu",
    log: Callable[[str], None] = print,
) -> FieldBenchmark:
    """Measure the field and the reference on ``num_points`` points around a posed hand.

    The headline (``points_per_s``, ``speedup``, ``gflops``) is the fastest step whose outputs
    stay within the tolerances (SDF and weights; with colour under ``*_color``). ``fused``: also
    the compiled step ``culled_fused``; ``backward``: also the training steps (``backward``).
    ``device``: where the field runs ("cpu", "cuda", "cuda:N"; GPU work is waited for before
    each clock read, and the large matmul is 8192^3 there).
    """
    config = FieldConfig() if config is None else config
    if config.composition != "lisa" or not config.use_color:
        raise ValueError("the field benchmark measures the 'lisa' composition with colour")
    device = resolve_device(device)
    hand = _bench_hand(config, num_points, seed, device)
    extra: dict = {"threads": torch.get_num_threads(), "config": config.to_dict(),
                   "device": describe_device(device)}
    pairs, multi = _region_counts(hand, extra, log)
    steps = {name: step for name, step in _STEPS.items() if fused or not step[2]}
    best, ref_outputs, outputs, (peak, matmul_name), compilation, run_step = _time_steps(
        hand, config, repeats, steps, log
    )
    extra["matmul"] = matmul_name
    log(f"large fp32 matmul ({matmul_name}): {peak:.1f} GFLOP/s")
    flops = _flop_counts(hand.model, num_points, pairs, multi)
    results = _step_results(best, ref_outputs, outputs, flops, num_points, steps, log)
    if compilation is not None:
        _amortisation(compilation, best, log)
        results["culled_fused"]["compilation"] = compilation
    extra["mlp_share"] = {
        name: mlp_share(lambda n=name: run_step(n, False),
                        [hand.model.sdf_mlp, hand.model.skinning_mlp], max(2, repeats // 2))
        for name in ("culled", "culled_fused") if name in steps
    }  # fmt: skip
    log("share of the geometry forward inside the MLPs: " + ", ".join(
        f"{name} {share:.0%}" for name, share in extra["mlp_share"].items()))
    headline, headline_color = _headlines(results)
    top, top_color = results[headline], results[headline_color]
    ref_time, ref_time_color = best["reference"], best["reference_color"]
    extra.update(
        {
            "steps": results,
            "headline_step": headline,
            "headline_step_color": headline_color,
            "points_per_s_color": top_color["points_per_s_color"],
            "reference_points_per_s_color": num_points / ref_time_color,
            "speedup_color": top_color["speedup_color"],
            "gflops_color": top_color["gflops_color"],
            "reference_gflops": flops["reference"][0] / ref_time / 1e9,
            "max_abs_error": top["max_abs_error"],
            "tolerance": {
                "sdf_m": SDF_TOLERANCE_M,
                "weights": WEIGHT_TOLERANCE,
                "rgb": COLOR_TOLERANCE,
            },
        }
    )
    extra["pair_strategies"] = time_pair_strategies(
        hand.model, hand.state, hand.points, repeats, log, compile_mlp=compile_mlp, fused=fused
    )
    if backward:
        log("training steps (culled, float32, eager: autograd records):")
        with fused_inference(False):
            train = time_training_steps(
                hand.model, hand.prepare, hand.points, flops["culled"][0], max(2, repeats // 2), log
            )
        extra.update({"backward": train, "backward_gflops": train["backward"]["gflops_nominal"],
                      "backward_points_per_s": train["backward"]["points_per_s"],
                      "eikonal_gflops": train["eikonal"]["gflops_nominal"]})  # fmt: skip
    result = FieldBenchmark(
        num_points=num_points,
        points_per_s=top["points_per_s"],
        reference_points_per_s=num_points / ref_time,
        speedup=top["speedup"],
        gflops=top["gflops"],
        matmul_gflops=peak,
        extra=extra,
    )
    _log_summary(result, log)
    return result


def _log_summary(result: FieldBenchmark, log: Callable[[str], None]) -> None:
    """The headline line, and the training steps' line when they were timed."""
    extra, peak = result.extra, result.matmul_gflops
    log(
        f"headline ({extra['headline_step']}): {result.points_per_s:,.0f} points/s vs reference "
        f"{result.reference_points_per_s:,.0f}: x{result.speedup:.1f}, {result.gflops:.1f} "
        f"GFLOP/s = {result.gflops / peak:.0%} of the large matmul's {peak:.1f}; with colour "
        f"({extra['headline_step_color']}): {extra['points_per_s_color']:,.0f} points/s, "
        f"x{extra['speedup_color']:.1f}"
    )
    if "backward" in extra:
        train = extra["backward"]
        peak = train["matmul_gflops"]  # timed beside the training steps
        log(f"backward (loss of the SDF to the weights): {train['backward']['points_per_s']:,.0f}"
            f" points/s, {train['backward']['gflops_nominal']:.1f} GFLOP/s nominal = "
            f"{train['backward']['gflops_nominal'] / peak:.0%} of the large matmul's {peak:.1f}; "
            f"Eikonal (double backward): {train['eikonal']['points_per_s']:,.0f} points/s, "
            f"{train['eikonal']['gflops_nominal']:.1f} GFLOP/s nominal = "
            f"{train['eikonal']['gflops_nominal'] / peak:.0%}")


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks field [--json FILE] [--points N] [--repeats R]``"""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m benchmarks field", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers to FILE")
    parser.add_argument("--points", type=int, default=65536, help="points per batch")
    parser.add_argument(
        "--repeats", type=int, default=5, help="timed runs per variant, best kept (reference: 2)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--compile", action="store_true",
        help="also time a torch.compile'd MLP with the stock Softplus on the pairs",
    )
    parser.add_argument(
        "--no-fused", action="store_true",
        help="leave out the compiled step culled_fused (its compilation takes tens of seconds)",
    )
    parser.add_argument(
        "--no-backward", action="store_true", help="leave out the training (backward) steps"
    )
    parser.add_argument(
        "--device", default="cpu",
        help="where the field runs: cpu (default), cuda or cuda:N (GPU work is waited for "
        "before each clock read; the large matmul is 8192^3 there)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.points < 1:
        raise ValueError(f"--points must be >= 1, got {args.points}")
    result = run_field_benchmark(
        args.points, repeats=args.repeats, seed=args.seed, compile_mlp=args.compile,
        fused=not args.no_fused, backward=not args.no_backward, device=args.device,
    )  # fmt: skip
    write_results(args.json, result.to_dict())
