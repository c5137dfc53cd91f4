"""Where padding the per-bone MLPs stops paying on a device: the SDF MLP of
``python -m benchmarks field``'s hand on its culled (point, bone) pairs, with
:meth:`~lisa_hand.fields.mlp.StackedMLP.forward_grouped`'s loop and padded, without gradients and
forward + backward, at growing sizes; then (GPU) the whole render benchmark at three values of
``GPU_PADDED_ROWS``.

``python -m tools.padded_crossover [--device cuda]`` (from the repository root)
"""

import argparse

import torch

import lisa_hand.fields.mlp as mlp_module
from benchmarks._pairs import PairStrategies
from benchmarks._timing import interleaved_best
from benchmarks.field import _bench_hand
from lisa_hand.fields import FieldConfig
from lisa_hand.utils.device import resolve_device


def time_size(points: int, device: torch.device) -> tuple[int, dict, dict]:
    """-> (culled pairs of ``points`` bench points, best seconds without gradients
    {"loop", "padded"}, the same forward and backward)"""
    hand = _bench_hand(FieldConfig(), points, 0, device)
    pairs = PairStrategies(hand.model, hand.state, hand.points)
    enc, sizes = pairs.sorted_pairs()
    bias, mlp = pairs.bias.detach(), pairs.mlp
    leaf = enc.detach().clone().requires_grad_(True)

    def forward(padded: bool) -> None:
        with torch.no_grad():
            mlp.forward_grouped(enc, sizes, bias, padded=padded)

    def backward(padded: bool) -> None:
        mlp.forward_grouped(leaf, sizes, bias, padded=padded).sum().backward()

    ways = {"loop": False, "padded": True}
    return (enc.shape[0],
            interleaved_best({k: lambda p=p: forward(p) for k, p in ways.items()}, 5),
            interleaved_best({k: lambda p=p: backward(p) for k, p in ways.items()}, 5))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cuda")
    device = resolve_device(parser.parse_args().device)
    print("pairs: loop / padded ms, no gradient | forward and backward")
    for points in [2**11, 2**13, 2**15, 2**16, 2**17, 2**18]:
        rows, forward, both = time_size(points, device)
        print(f"{rows:8d}: {forward['loop'] * 1e3:7.2f} / {forward['padded'] * 1e3:7.2f}"
              f" | {both['loop'] * 1e3:7.2f} / {both['padded'] * 1e3:7.2f}", flush=True)
    if device.type == "cuda":
        from benchmarks.render import run_render_benchmark

        default, seconds = mlp_module.GPU_PADDED_ROWS, {}
        try:
            for _ in range(2):
                for rows in (0, 2**16, 2**18):
                    mlp_module.GPU_PADDED_ROWS = rows
                    result = run_render_benchmark("trained", dense_pixels=0, device=device,
                                                  log=lambda line: None)
                    seconds.setdefault(rows, []).append(round(result["seconds"], 3))
        finally:
            mlp_module.GPU_PADDED_ROWS = default
        print("render benchmark, fast path seconds by GPU_PADDED_ROWS:", seconds)


if __name__ == "__main__":
    main()
