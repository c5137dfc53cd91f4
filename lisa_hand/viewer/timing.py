"""How long the viewer waits for a mesh: ``python -m lisa_hand.viewer.timing``.

The seconds from a request (a changed control) to its coarse and to its fine mesh, through the
viewer's :class:`~.meshing.Remesher`, for the model's mean hand in four poses, on 1 and 2 torch
threads.
"""

from __future__ import annotations

import time

from ..model.trained import TrainedModel
from ..skeleton.params import HandParams
from .meshing import MeshUpdate, RemeshConfig, Remesher

__all__ = ["measure_remesh", "main"]


def measure_remesh(model: TrainedModel, hands: list[HandParams], config: RemeshConfig | None = None
                   ) -> dict[str, list[float]]:
    """Seconds from each request to its coarse and to its fine mesh, through a
    :class:`Remesher` (each hand meshed alone). -> {"coarse": [...], "fine": [...]}"""
    start: dict[int, float] = {}
    seconds: dict[str, list[float]] = {"coarse": [], "fine": []}

    def on_mesh(update: MeshUpdate) -> None:
        seconds[update.level].append(time.perf_counter() - start[update.generation])

    remesher = Remesher(model, on_mesh, config)
    try:
        for params in hands:
            start[remesher.generation + 1] = time.perf_counter()
            remesher.request(params)
            remesher.wait_idle(600.0)
    finally:
        remesher.close()
    return seconds


def main(argv: list[str] | None = None) -> None:
    """``python -m lisa_hand.viewer.timing [--model M] [--threads 1 2]``: how long the viewer
    waits for the coarse and the fine mesh of the shipped model's mean hand in four poses."""
    import argparse
    import statistics

    from ..model.trained import load_trained
    from ..utils.threads import cpu_threads
    from .state import CodeSpaces, NamedHand, PoseEdit, ViewState, mean_hand, view_params

    parser = argparse.ArgumentParser(prog="python -m lisa_hand.viewer.timing",
                                     description=main.__doc__.split(":")[0])
    parser.add_argument("--model", default=None)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--coarse-res", type=int, default=RemeshConfig.coarse_resolution)
    parser.add_argument("--fine-res", type=int, default=RemeshConfig.fine_resolution)
    args = parser.parse_args(argv)
    model = load_trained(args.model)
    hands = [NamedHand("mean", mean_hand(model))]
    spaces = CodeSpaces.from_model(model)
    poses = [None, "relaxed", "fist", "point"]
    params = [view_params(ViewState(pose=PoseEdit(named=name)), hands, spaces) for name in poses]
    config = RemeshConfig(coarse_resolution=args.coarse_res, fine_resolution=args.fine_res)
    for threads in args.threads:
        with cpu_threads(threads):
            measure_remesh(model, params[:1], config)  # warm-up
            seconds = measure_remesh(model, params, config)
        resolutions = {"coarse": config.coarse_resolution, "fine": config.fine_resolution}
        line = ", ".join(f"{level} {resolutions[level]}^3 median "
                         f"{statistics.median(values):.2f} s (max {max(values):.2f})"
                         for level, values in seconds.items() if values)
        print(f"{threads} thread(s), {len(params)} poses: {line}")


if __name__ == "__main__":
    main()
