"""``lisa demo``: the main job, end to end on what exists so far."""

from __future__ import annotations

from pathlib import Path

import typer


def demo(
    out: Path = typer.Option(Path("lisa_demo"), "--out", help="Folder for the demo's outputs."),
    seed: int = typer.Option(0, help="Random seed of the synthesized hand."),
) -> None:
    """Run the end-to-end demo and write its outputs to OUT."""
    from ..demo import run_demo

    run_demo(out_dir=out, seed=seed)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
