"""Timing and FLOP counting shared by the field benchmark's parts (``field``, ``_pairs``).

The leading underscore keeps this module out of :func:`benchmarks.benchmark_names`: it is
not a benchmark.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator

import torch

from lisa_hand.utils.device import synchronize

__all__ = [
    "BACKWARD_FLOP_FACTOR",
    "EIKONAL_FLOP_FACTOR",
    "interleaved_best",
    "large_matmul",
    "mlp_flops",
    "mlp_share",
    "time_training_steps",
    "timed_methods",
]

# Nominal FLOPs of a training step as multiples of the forward's (every layer ``y = x W``):
# a loss's backward computes ``dL/dW = x^T dy`` and ``dL/dx = dy W^T``, one forward's worth each
# (3x in all with the forward; the first layers' input gradients are not needed, so this is an
# upper bound by their few FLOPs). An Eikonal step adds the input gradient with its graph
# (``dx = dy W^T``, 1x) and the backward through it (its weight and incoming gradients, 2x):
# 6x in all.
BACKWARD_FLOP_FACTOR = 3.0
EIKONAL_FLOP_FACTOR = 6.0


def interleaved_best(
    fns: dict[str, Callable[[], object]],
    rounds: int,
    slow: tuple[str, ...] = (),
    slow_rounds: int = 2,
) -> dict[str, float]:
    """Best wall time of each function over ``rounds`` rounds (``slow_rounds`` for the names in
    ``slow``), the functions interleaved in each round, so that a burst of load from other
    processes hits all of them alike. One warm-up call each first. GPU work is waited for
    (:func:`~lisa_hand.utils.device.synchronize`) before each clock read. -> {name: seconds}"""
    for fn in fns.values():
        fn()
    best = dict.fromkeys(fns, math.inf)
    for index in range(max(rounds, slow_rounds)):
        for name, fn in fns.items():
            if index >= (slow_rounds if name in slow else rounds):
                continue
            synchronize()
            start = time.perf_counter()
            fn()
            synchronize()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def large_matmul(device: torch.device) -> tuple[Callable[[], object], float, str]:
    """The machine's reference pace: a float32 matmul large for ``device`` (2048^3 on a CPU,
    8192^3 on a GPU, whose 2048^3 ends before its launch cost is paid back), on random data.
    -> (a call that runs it, its FLOPs, its name for the logs)"""
    size = 8192 if torch.device(device).type == "cuda" else 2048
    generator = torch.Generator().manual_seed(0)
    mat_a = torch.randn(size, size, generator=generator).to(device)
    mat_b = torch.randn(size, size, generator=generator).to(device)
    return (lambda: mat_a @ mat_b), 2.0 * size**3, f"{size}^3"


def mlp_flops(mlp, rows: int, with_cond: bool) -> float:
    """Multiply-add FLOPs (2 per MAC) of ``rows`` points through one group of ``mlp`` (a
    :class:`lisa_hand.fields.mlp.StackedMLP`; ``with_cond``: the conditioning in the input)."""
    first_in = mlp.point_dim + (mlp.cond_dim if with_cond else 0)
    macs = first_in * mlp.hidden + (mlp.depth - 1) * mlp.hidden**2 + mlp.hidden * mlp.out_dim
    return 2.0 * rows * macs


@contextlib.contextmanager
def timed_methods(objects: list, name: str, totals: dict[str, float]) -> Iterator[None]:
    """Within the block, accumulate the wall time of ``obj.<name>(...)`` calls of every object
    in ``totals[name]`` (an instance attribute shadows the method; removed afterwards)."""
    totals.setdefault(name, 0.0)

    def wrap(bound: Callable) -> Callable:
        def timed(*args, **kwargs):
            synchronize()
            start = time.perf_counter()
            try:
                return bound(*args, **kwargs)
            finally:
                synchronize()
                totals[name] += time.perf_counter() - start

        return timed

    for obj in objects:
        setattr(obj, name, wrap(getattr(obj, name)))
    try:
        yield
    finally:
        for obj in objects:
            delattr(obj, name)


def mlp_share(run: Callable[[], object], mlps: list, rounds: int) -> float:
    """Share of the wall time of ``run()`` spent in the ``forward_grouped`` calls of ``mlps``
    (in its fastest of ``rounds`` runs, without gradients): what is left to gain outside."""
    best = (math.inf, 0.0)
    with torch.no_grad():
        for _ in range(rounds):
            totals: dict[str, float] = {}
            with timed_methods(mlps, "forward_grouped", totals):
                synchronize()
                start = time.perf_counter()
                run()
                synchronize()
                elapsed = time.perf_counter() - start
            best = min(best, (elapsed, totals["forward_grouped"]))
    return best[1] / best[0]


def time_training_steps(
    model,
    prepare: Callable[[], object],
    points: torch.Tensor,
    forward_flops: float,
    rounds: int,
    log: Callable[[str], None],
) -> dict:
    """Training steps on the culled float32 field of ``model`` (a LisaModel; autograd records, so
    its MLPs run eagerly): the forward alone, the loss ``mean(sdf^2)`` back to every weight, and
    an Eikonal step (the SDF's gradient with its graph, then ``mean(sdf^2) + mean((|grad| -
    1)^2)`` back to the weights: double backward). Each calls ``prepare()`` (the frame state)
    again, so the conditioning weights get gradients too.

    points: [1, N, 3] world metres; forward_flops: the culled geometry forward's MLP FLOPs.
    -> {"forward"|"backward"|"eikonal": {"ms", "points_per_s", "gflops_nominal",
    "over_forward"}, "matmul_gflops" (:func:`large_matmul`, timed in the same rounds), "flop_model"}
    """
    num = points.shape[1]

    def forward() -> None:
        with torch.no_grad():
            model.field(prepare(), points, with_color=False, cull=True)

    def backward() -> None:
        model.zero_grad(set_to_none=True)
        out = model.field(prepare(), points, with_color=False, cull=True)
        out.sdf.square().mean().backward()

    def eikonal() -> None:
        model.zero_grad(set_to_none=True)
        out = model.field(prepare(), points, with_color=False, with_gradient=True,
                          create_graph=True, cull=True)  # fmt: skip
        loss = out.sdf.square().mean() + (out.sdf_grad.norm(dim=-1) - 1.0).square().mean()
        loss.backward()

    # a large matmul in the same rounds: the machine's pace while these ran
    matmul, matmul_flops, _ = large_matmul(points.device)
    best = interleaved_best({"forward": forward, "backward": backward, "eikonal": eikonal,
                             "matmul": matmul}, rounds)  # fmt: skip
    model.zero_grad(set_to_none=True)
    matmul_gflops = matmul_flops / best.pop("matmul") / 1e9
    factors = {"forward": 1.0, "backward": BACKWARD_FLOP_FACTOR, "eikonal": EIKONAL_FLOP_FACTOR}
    result: dict = {
        name: {
            "ms": seconds * 1e3,
            "points_per_s": num / seconds,
            "gflops_nominal": factors[name] * forward_flops / seconds / 1e9,
            "over_forward": seconds / best["forward"],
        }
        for name, seconds in best.items()
    }
    result["matmul_gflops"] = matmul_gflops
    result["flop_model"] = (
        f"forward MLP FLOPs x {BACKWARD_FLOP_FACTOR:g} (loss backward: weight and input "
        f"gradients), x {EIKONAL_FLOP_FACTOR:g} (Eikonal: double backward)"
    )
    for name in best:
        step = result[name]
        log(f"  train {name:8s}: {step['ms']:8.1f} ms, {step['points_per_s']:>10,.0f} points/s, "
            f"{step['gflops_nominal']:5.1f} GFLOP/s nominal "
            f"({step['gflops_nominal'] / matmul_gflops:.0%} of the large matmul's "
            f"{matmul_gflops:.1f} in the same rounds), x{step['over_forward']:.2f} forward")
    return result
