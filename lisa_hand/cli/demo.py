"""``lisa demo``: the main job, end to end on what exists so far."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def demo(
    out: Annotated[Path, typer.Option("--out", help="Folder for the demo's outputs.")] = Path(
        "lisa_demo"
    ),
    seed: Annotated[int, typer.Option(help="Random seed of the synthesized hand.")] = 0,
) -> None:
    """Run the end-to-end demo and write its outputs to OUT."""
    from ..demo import run_demo

    run_demo(out_dir=out, seed=seed)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
