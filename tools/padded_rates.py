"""Same-run comparison of image-training steps per second with
:meth:`~lisa_hand.fields.mlp.StackedMLP.forward_grouped`'s loop over the groups
(``GPU_PADDED_ROWS = 0``) against its padded batched product (the default on a GPU).

``python -m tools.padded_rates DATA [--device cuda] [--held-out CAM]`` (from the repository
root): DATA is a dataset in the ``lisa synth`` layout (``python -m benchmarks train``'s, say).
Both configurations of the training benchmark (reference and fast), each with both ways,
interleaved: 3 rounds of 5 steps, best round's median. On a CPU the padded way is never taken
by default (padding costs more than the launches it saves there); this script times it there
too.
"""

import argparse
import statistics
import tempfile
from pathlib import Path

import lisa_hand.fields.mlp as mlp_module
from benchmarks.train import held_out_copy, prior_from_trained, step_runs
from lisa_hand.geometry.cameras import load_cameras
from lisa_hand.utils.device import resolve_device


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--held-out", default=None, help="camera left out (default: the last)")
    args = parser.parse_args()
    device = resolve_device(args.device)
    first = sorted(args.data.glob("s*/f*/cameras.json"))
    if not first:
        raise SystemExit(f"{args.data}: no frame with cameras.json (not a dataset)")
    held_out = args.held_out or load_cameras(first[0])[-1].name
    data = held_out_copy(args.data, Path(tempfile.mkdtemp()) / "views", held_out)
    runs = step_runs(data, prior_from_trained(None), args.device)
    default_rows = mlp_module.GPU_PADDED_ROWS

    def step(name: str, padded: bool) -> float:
        mlp_module.GPU_PADDED_ROWS = default_rows if padded else 0
        original = mlp_module.StackedMLP.forward_grouped
        if device.type == "cpu" and padded:  # the CPU never pads by default: ask for it
            mlp_module.StackedMLP.forward_grouped = (
                lambda self, *a, **k: original(self, *a, **{**k, "padded": True}))
        try:
            return runs[name].step()
        finally:
            mlp_module.StackedMLP.forward_grouped = original
            mlp_module.GPU_PADDED_ROWS = default_rows

    variants = [(name, padded) for name in runs for padded in (False, True)]
    for variant in variants:
        step(*variant)
    best = dict.fromkeys(variants, float("inf"))
    for _ in range(3):
        for variant in variants:
            best[variant] = min(best[variant], statistics.median(step(*variant)
                                                                 for _ in range(5)))
    for (name, padded), seconds in best.items():
        print(f"{name:9s} {'padded' if padded else 'loop  '}: {1 / seconds:6.2f} steps/s "
              f"({seconds * 1e3:.0f} ms)")
    for name in runs:
        print(f"{name}: padded x{best[(name, False)] / best[(name, True)]:.2f} over the loop "
              f"({device})")


if __name__ == "__main__":
    main()
