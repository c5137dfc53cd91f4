"""``lisa eval``: the paper's tables on held-out subjects (:mod:`lisa_hand.evaluation.tables`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _parse_models(values: list[str] | None) -> dict[str, str]:
    from ..evaluation.methods import METHODS
    from ..model.trained import shipped_name

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
        if not Path(path).exists() and shipped_name(path) is None:
            raise FileNotFoundError(f"{path}: no such model file, run folder or shipped model "
                                    f"({method})")
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
    real: Annotated[bool, typer.Option(
        "--real", help="DATA is an imported real split ('lisa import freihand' or "
                       "'interhand2.6m'): fit each frame's photo with its own camera (the "
                       "'lisa fit-photo' fit) and score it as the dataset's benchmark does "
                       "(FreiHAND: MPJPE, PA-MPJPE, PA-MPVPE, F@5 mm, F@15 mm; InterHand2.6M: "
                       "MPJPE root- and Procrustes-aligned); writes OUT/results.json.")] = False,
    split: Annotated[str, typer.Option(help="--real: the split of DATA to score.")] = "test",
    keypoints: Annotated[str, typer.Option(
        help="--real: 'given' (the dataset's 2D keypoints) or 'detect' (MediaPipe).")]
    = "given",
    frames: Annotated[int | None, typer.Option(
        "--frames", min=1, help="--real: at most this many frames.")] = None,
    fit_model: Annotated[Path | None, typer.Option(
        "--fit-model", help="--real: the trained model that fits (default: the shipped one).")
    ] = None,
) -> None:
    """Build the paper's Tables 1-3 on the held-out (test) subjects of DATA: shape from point
    clouds (V2V, V2S in mm, both ways; many subjects, and one subject in many poses), shape
    and colour from 1, 2 and 4 views (V2V, V2S, PSNR in novel views) and colour (PSNR, SSIM,
    LPIPS), for the MANO-like template and every --model. Writes OUT/results.md,
    OUT/results.json and OUT/pictures/; every number is computed by the run. Fits run in
    --workers processes; an interrupted run resumes from OUT/jobs/."""
    import dataclasses

    if real:
        return _eval_real(data, out, split, keypoints, frames, fit_model, device)
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


def _eval_real(data: Path | None, out: Path, split: str, keypoints: str, frames: int | None,
               model: Path | None, device: str) -> None:
    """``lisa eval DATA --real``: the photo fit scored on an imported real split."""
    from ..evaluation.real_formats import evaluate_split, photo_fit_predictor

    if data is None:
        raise ValueError("--real needs DATA: a split imported by 'lisa import'")
    predict = photo_fit_predictor(out / "fits", keypoints=keypoints, model_path=model,
                                  device=device)
    scores = evaluate_split(data, split, predict, out=out / "results.json", max_frames=frames,
                            log=typer.echo)
    if not scores.frames:
        first = f"; the first: {scores.failed[0]}" if scores.failed else ""
        raise ValueError(f"{data}: no frame of split {split!r} was scored ({len(scores.failed)} "
                         f"failed{first}); see {out / 'results.json'}")
    means = ", ".join(f"{key} {value:.4g}" for key, value in scores.means.items())
    typer.echo(f"{scores.dataset}: {len(scores.frames)} frames scored, {len(scores.failed)} "
               f"failed; means: {means}")
    typer.echo(f"wrote {out / 'results.json'}")


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
