"""``lisa eval``: the paper's tables on held-out subjects (:mod:`lisa_hand.evaluation.tables`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _parse_models(values: list[str] | None) -> dict[str, str]:
    from ..evaluation.methods import METHODS

    models: dict[str, str] = {}
    for value in values or []:
        method, sep, path = value.partition("=")
        if not sep or not path:
            raise ValueError(f"--model {value!r}: expected METHOD=PATH, e.g. nasa=runs/nasa")
        if method not in METHODS or not METHODS[method].takes_model:
            raise ValueError(f"--model {value!r}: unknown method {method!r}; choose from "
                             f"{', '.join(m for m in METHODS if METHODS[m].takes_model)} (the "
                             "MANO-like template is always evaluated)")
        if method in models:
            raise ValueError(f"--model: {method} given twice")
        if not Path(path).exists():
            raise FileNotFoundError(f"{path}: no such model file or run folder ({method})")
        models[method] = path
    return models


def _parse_views(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--views {text!r}: expected a comma-separated list such as 1,2,4") \
            from None


def eval_command(
    data: Annotated[Path | None, typer.Argument(
        help="Dataset folder ('lisa synth' layout) whose test split is evaluated. Optional "
             "with --quick (a tiny one is made).", metavar="DATA")] = None,
    out: Annotated[Path, typer.Option("--out", help="Folder for results.md, results.json, "
                                      "pictures/, the fits and jobs/ (resumable).")]
    = Path("lisa_eval"),
    model: Annotated[list[str] | None, typer.Option(
        "--model", metavar="METHOD=PATH",
        help="Repeatable: a trained run or exported model per method "
             "(volsdf, nasa, narf, lisa_im, lisa_geom, lisa_full). The MANO-like "
                        "template is always in.")] = None,
    quick: Annotated[bool, typer.Option(
        "--quick", help="Toy sizes for a check in minutes (CI). Without DATA and --model, it "
                        "synthesizes a tiny dataset and trains every method for a few steps "
                        "first.")] = False,
    subjects: Annotated[int | None, typer.Option(
        help="Table 1: held-out subjects, one scan each (default: all).")] = None,
    poses: Annotated[int, typer.Option(help="Table 1: scans of one held-out subject.")] = 6,
    image_subjects: Annotated[int, typer.Option(
        "--image-subjects", help="Tables 2-3: held-out subjects fitted from images.")] = 4,
    views: Annotated[str, typer.Option(help="Tables 2-3: input view counts.")] = "1,2,4",
    resolution: Annotated[int, typer.Option(
        help="Marching-cubes resolution of every implicit method.")] = 256,
    tables: Annotated[str, typer.Option(
        help="Which fits: 'points' (Table 1), 'images' (Tables 2, 3) or both.")]
    = "points,images",
    workers: Annotated[int, typer.Option(help="Fits run at once (one CPU thread each).")] = 2,
    device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = "cpu",
) -> None:
    """Build the paper's Tables 1-3 on the held-out (test) subjects of DATA: shape from point
    clouds (V2V, V2S in mm, both ways; many subjects, and one subject in many poses), shape
    and colour from 1, 2 and 4 views (V2V, V2S, PSNR in novel views) and colour (PSNR, SSIM,
    LPIPS), for the MANO-like template and every --model. Writes OUT/results.md,
    OUT/results.json and OUT/pictures/; every number is computed by the run. Fits run in
    --workers processes; an interrupted run resumes from OUT/jobs/."""
    import dataclasses

    from ..evaluation.config import EvalConfig
    from ..evaluation.quick import QUICK_EVAL, quick_models
    from ..evaluation.tables import run_eval

    models = _parse_models(model)
    if data is None:
        if not quick or models:
            raise ValueError("DATA is required (a 'lisa synth' dataset), except with --quick "
                             "and no --model")
        data, models = quick_models(out / "quick", log=typer.echo)
    elif not models and not quick:
        typer.echo("no --model given: only the MANO-like template is evaluated")
    table_names = tuple(t.strip() for t in tables.split(",") if t.strip())
    if quick:
        config = dataclasses.replace(QUICK_EVAL, tables=table_names, device=device)
    else:
        config = EvalConfig(num_subjects=subjects, num_poses=poses,
                            image_subjects=image_subjects, views=_parse_views(views),
                            resolution=resolution, tables=table_names, workers=workers,
                            device=device)
    run_eval(data, models, out, config, log=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
