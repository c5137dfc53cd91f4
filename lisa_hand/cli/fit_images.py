"""``lisa fit-images``: fit LISA to 1..N calibrated views (paper Section 4.3), write the hand."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from .options import (
    DeviceOpt,
    FitModelOpt,
    GuardOpt,
    ShapeFit,
    ShapeFitOpt,
    Side,
    ThreadsOpt,
    Units,
    ViewCalibrationOpt,
    image_fit_overrides,
    set_option,
    with_settings,
)

SetOpt = set_option("FitImagesConfig (lisa_hand/fitting/images/config.py)",
                    "--set keypoint_iters=1000 --set code_lr=0.02 --set render.num_samples=32")


def fit_images(
    frames: Annotated[list[Path], typer.Argument(
        metavar="DIR...",
        help="Frame folder: cameras.json, images/NAME.png, and optionally masks/NAME.png and "
             "keypoints.json (the layout 'lisa synth' writes). Several folders: one hand each, "
             "seen by the same cameras (an interacting frame of 'lisa import interhand2.6m'), "
             "fitted alone and then together, into OUT/hand0, OUT/hand1, ... with "
             "OUT/hands.json and OUT/hands.ply; give one --side per folder.")],
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: params.json, mesh.ply and metrics.json.")],
    views: Annotated[str | None, typer.Option(
        "--views", help="Comma-separated camera names to use, e.g. cam000 or "
                        "cam000,cam002,cam004,cam006 (default: all).")] = None,
    model: FitModelOpt = None,
    gt: Annotated[Path | None, typer.Option(
        "--gt", help="Ground-truth mesh (or points), e.g. the frame's mesh.ply: adds V2V and "
                     "V2S distances (mm), both ways, to metrics.json.")] = None,
    units: Annotated[Units, typer.Option(
        "--units", help="Unit of GT: m, cm, mm, or auto (from the size of a hand: 0.1-0.3 m, "
                        "10-30 cm or 100-300 mm across).")] = Units.auto,
    keypoint_iters: Annotated[int | None, typer.Option(
        "--keypoint-iters", min=0,
        help="Iterations of the pose stage (default 400; the paper uses 1000).")] = None,
    color_iters: Annotated[int | None, typer.Option(
        "--color-iters", min=0,
        help="Iterations of the pose, shape and colour stage (default 300; the paper uses "
             "5000; 0 skips it).")] = None,
    rays: Annotated[int | None, typer.Option(
        "--rays", min=1, help="Rays rendered per colour iteration (default 512).")] = None,
    side: Annotated[list[Side] | None, typer.Option(
        "--side", help="right or left hand (default right); several folders: one each, in "
                       "order.")] = None,
    res: Annotated[int, typer.Option(
        "--res", min=16, max=1024, help="Marching-cubes samples per axis of the mesh.")] = 128,
    device: DeviceOpt = "auto",
    threads: ThreadsOpt = 1,
    shape_fit: ShapeFitOpt = ShapeFit.space,
    guard: GuardOpt = True,
    view_calibration: ViewCalibrationOpt = True,
    seed: Annotated[int, typer.Option(help="Seed of the restarts and of the rays.")] = 0,
    psnr: Annotated[bool, typer.Option(
        "--psnr/--no-psnr", help="Re-render the input views for the PSNR in metrics.json.")
    ] = True,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
    settings: SetOpt = None,
) -> None:
    """Fit the LISA hand to the calibrated views of DIR: the pose from the 2D keypoints and
    masks, then pose, shape and colour with volume rendering; write OUT/params.json,
    OUT/mesh.ply and OUT/metrics.json."""
    from ..fitting.images.config import FitImagesConfig
    from ..fitting.images.folder import fit_image_folder

    names = None
    if views is not None:
        names = [name.strip() for name in views.split(",") if name.strip()]
        if not names:
            raise ValueError(f"--views {views!r}: no camera name given")
    overrides = image_fit_overrides(seed=seed, threads=threads, shape_fit=shape_fit,
                                    guard=guard, keypoint_iters=keypoint_iters,
                                    color_iters=color_iters, rays=rays,
                                    view_calibration=view_calibration)
    config = with_settings(FitImagesConfig(**overrides), settings)
    sides = _sides(frames, side)
    if len(frames) > 1:
        _fit_hands(frames, out, sides, gt=gt, views=names, model_path=model, resolution=res,
                   config=config, device=device, progress=progress)
        return
    report = fit_image_folder(frames[0], out, views=names, model_path=model, gt_path=gt,
                              units=units.value, resolution=res, config=config,
                              side=sides[0], device=device, psnr=psnr, progress=progress,
                              log=typer.echo)
    fit, metrics = report.fit, report.metrics

    def shown(value, unit: str) -> str:
        return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) \
            else f"{value:.3f} {unit}"

    typer.echo(f"fitted {len(metrics['views'])} view(s) in {fit.seconds:.1f} s "
               f"(keypoints {fit.stage_seconds['keypoints']:.1f} s, colour "
               f"{fit.stage_seconds['color']:.1f} s): keypoint error "
               f"{shown(metrics['keypoint_error_px'], 'px')}")
    for key in ("psnr_db", "psnr_mask_db", "v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm",
                "v2v_scan_to_recon_mm", "v2s_scan_to_recon_mm"):
        if key in metrics:
            unit = "dB" if key.startswith("psnr") else "mm"
            typer.echo(f"  {key}: {shown(metrics[key], unit)}")
    for path in report.written:
        typer.echo(f"wrote {path}")


def _sides(frames: list[Path], side: list | None) -> list[str]:
    """The side of each frame folder: ``--side`` once per folder (one folder: right by
    default)."""
    sides = [one.value for one in side] if side else ["right"]
    if len(frames) > 1 and not side:
        raise ValueError(f"{len(frames)} frame folders: give one --side per folder, in order "
                         "(e.g. --side right --side left)")
    if len(frames) == 1 and len(sides) > 1:
        raise ValueError(f"{len(sides)} --side options for one frame folder: give one")
    return sides


def _fit_hands(frames: list[Path], out: Path, sides: list[str], *, gt, **options) -> None:
    """Several frame folders: one hand each, fitted alone and together
    (:func:`lisa_hand.fitting.images.hands.fit_image_folders`)."""
    from ..fitting.images.hands import fit_image_folders

    if gt is not None:
        raise ValueError("--gt compares one hand: fit one frame folder with it")
    for path in fit_image_folders(frames, out, sides, log=typer.echo, **options):
        typer.echo(f"wrote {path}")


def register(app: typer.Typer) -> None:
    app.command("fit-images")(fit_images)
