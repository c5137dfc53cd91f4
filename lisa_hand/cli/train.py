"""``lisa train-prior`` and ``lisa train``: LISA's two training stages (paper Section 4.2)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

_TORCHRUN = (
    "Several GPUs or nodes: launch through torchrun, e.g. 'torchrun --standalone "
    "--nproc_per_node 4 -m lisa_hand.cli.main {command}' (one process per GPU; add --nnodes, "
    "--node-rank and --rdzv-endpoint for several nodes, with RUN on a shared filesystem). Every "
    "process draws the same global batch and trains on its share of the frames; rank 0 writes "
    "the files."
)
_PROGRESS = (
    "A progress bar shows the losses (a line every trainer.print_every steps when not on a "
    "terminal); Ctrl-C stops after the current step with a checkpoint, and the same command "
    "resumes."
)
PRIOR_HELP = "\n\n".join([
    "Train LISA's geometric prior (SDF and skinning MLPs, one shape code per subject) on the 3D "
    "scans of DATA: losses L_surf, L_N, L_Eik, L_w and L_reg (paper Section 4.2).",
    _PROGRESS,
    _TORCHRUN.format(command="train-prior DATA --out RUN"),
])
TRAIN_HELP = "\n\n".join([
    "Train LISA (shape, colour and skinning MLPs, shape and colour codes, per-camera gain and "
    "bias, pose refinement after the first 10% of the steps) on the multi-view images of DATA: "
    "losses L_col (VolSDF rendering of rays through the masks), L_Eik, L_w and L_reg (paper "
    "Section 4.2). With --prior the geometry starts from a 'lisa train-prior' run.",
    _PROGRESS,
    _TORCHRUN.format(command="train DATA --out RUN --prior PRIOR"),
])

DataArg = Annotated[Path, typer.Argument(
    metavar="DATA", help="Dataset folder ('lisa synth' layout: split.json, s000/f000/...).")]
OutOpt = Annotated[Path, typer.Option(
    "--out", help="Run folder: config.json, log.jsonl and checkpoints (last.pt) go here.")]
StepsOpt = Annotated[int | None, typer.Option(
    "--steps", help="Number of training steps (sets trainer.steps).")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", metavar="KEY=VALUE",
    help="Override a config value, e.g. --set trainer.lr=1e-4 --set field.sdf_hidden=64 "
         "--set lambda_eik=0.05 (repeatable; keys as in RUN/config.json).")]
ConfigOpt = Annotated[Path | None, typer.Option(
    "--config", help="Start from this JSON config (e.g. another run's config.json) instead of "
                     "the defaults; --set and --steps apply on top.")]
DeviceOpt = Annotated[str | None, typer.Option(
    "--device", help="auto (CUDA when available), cpu, cuda or cuda:N (sets trainer.device).")]
ResumeOpt = Annotated[bool, typer.Option(
    "--resume/--no-resume",
    help="Continue from RUN/last.pt if it exists (default), or start afresh.")]


def _resolve(config_cls, config_path: Path | None, overrides: list[str] | None,
             steps: int | None, device: str | None):
    from ..utils.config import apply_overrides, load_config

    config = load_config(config_cls, config_path) if config_path is not None else config_cls()
    items = list(overrides or [])
    if steps is not None:
        items.append(f"trainer.steps={steps}")
    if device is not None:
        items.append(f"trainer.device={device}")
    return apply_overrides(config, items)


def _report(result, out: Path) -> None:
    if os.environ.get("RANK", "0") != "0":
        return
    losses = " ".join(f"{name}={value:.4g}" for name, value in result.losses.items())
    ran = result.steps_done - result.start_step
    typer.echo(f"{result.status}: {result.steps_done} steps ({ran} in this call, "
               f"{result.seconds:.1f} s)" + (f"; last losses: {losses}" if losses else ""))
    if result.checkpoint is not None:
        typer.echo(f"checkpoint: {result.checkpoint}")
    typer.echo(f"run folder: {out} (config.json, log.jsonl)")


def train_prior(
    data: DataArg,
    out: OutOpt,
    init: Annotated[Path | None, typer.Option(
        "--init", help="Start from this prior instead of the geometric initialisation: a "
                       "'lisa train-prior' run folder (or checkpoint), an exported model or a "
                       "shipped model's name (e.g. 'geometry_v3'), to go on training it on "
                       "more or other hands. Its field's architecture is taken; subjects it "
                       "has not seen start from its mean shape code. Ignored when the run "
                       "resumes from its own checkpoint.")] = None,
    steps: StepsOpt = None,
    overrides: SetOpt = None,
    config: ConfigOpt = None,
    device: DeviceOpt = None,
    resume: ResumeOpt = True,
) -> None:
    """Train LISA's geometric prior on the 3D scans of DATA (help: PRIOR_HELP)."""
    from ..training.prior import PriorConfig
    from ..training.prior import train_prior as run

    resolved = _resolve(PriorConfig, config, overrides, steps, device)
    _report(run(data, out, resolved, resume=resume, init=init), out)


def train(
    data: DataArg,
    out: OutOpt,
    prior: Annotated[Path | None, typer.Option(
        "--prior", help="A 'lisa train-prior' run folder (or checkpoint), an exported model, or "
                        "a shipped model's name ('geometry': the 203-subject prior) to start the "
                        "geometry from; without it the model trains from images only (LISA-im).")
    ] = None,
    steps: StepsOpt = None,
    overrides: SetOpt = None,
    config: ConfigOpt = None,
    device: DeviceOpt = None,
    resume: ResumeOpt = True,
) -> None:
    """Train LISA on the multi-view images of DATA (help: TRAIN_HELP)."""
    from ..training.images import ImageTrainConfig, train_images

    resolved = _resolve(ImageTrainConfig, config, overrides, steps, device)
    _report(train_images(data, out, resolved, prior=prior, resume=resume), out)


def register(app: typer.Typer) -> None:
    app.command("train-prior", help=PRIOR_HELP)(train_prior)
    app.command("train", help=TRAIN_HELP)(train)
