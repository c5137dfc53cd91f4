"""``lisa demo``: the main job, end to end (see :mod:`lisa_hand.evaluation.demo`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def demo(
    out: Annotated[Path, typer.Option("--out", help="Folder for the demo's outputs (input "
                                      "data, fits, meshes, renders, report.html).")]
    = Path("lisa_demo"),
    seed: Annotated[int, typer.Option(help="Which unseen hand to synthesize.")] = 0,
    model: Annotated[Path | None, typer.Option(
        "--model", help="Model file or training run (default: the shipped model).")] = None,
    fit_scale: Annotated[float, typer.Option(
        "--fit-scale", help="Multiply the fits' iteration counts (e.g. 0.5: faster, rougher).")]
    = 1.0,
    device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = "auto",
    hand_model: Annotated[str, typer.Option(
        "--hand-model", metavar="v1|v2",
        help="Version of the open hand model the unseen hand is drawn from: v1 (default; what "
             "the shipped model was trained on) or v2 (for a model trained on v2 hands, "
             "--model RUN).")] = "v1",
) -> None:
    """Run the end-to-end demo: synthesize a hand the shipped model never saw, fit it from its
    point cloud, from 1 view and from 4 views, mesh the fits, render novel views and a
    turntable, print V2V, V2S (mm) and PSNR, and write OUT/report.html. A few minutes on 2 CPU
    cores."""
    from ..evaluation.demo import DemoConfig, run_demo

    if not fit_scale > 0:
        raise ValueError(f"--fit-scale must be > 0, got {fit_scale}")
    config = DemoConfig(seed=seed, model=None if model is None else str(model),
                        fit_scale=fit_scale, device=device, hand_model=hand_model)
    run_demo(out, config, log=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
