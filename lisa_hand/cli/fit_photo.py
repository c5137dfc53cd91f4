"""``lisa fit-photo``: fit LISA to uncalibrated photographs of a hand, write the hand."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .options import (
    AutoSide,
    DeviceOpt,
    FitModelOpt,
    GuardOpt,
    ShapeFit,
    ShapeFitOpt,
    ThreadsOpt,
    ViewCalibrationOpt,
    image_fit_overrides,
    set_option,
    with_settings,
)

SetOpt = set_option("FitPhotoConfig (lisa_hand/fitting/photo/config.py; the image fit's "
                    "FitImagesConfig under fit.)",
                    "--set fit.keypoint_iters=600 --set fit.code_lr=0.02 "
                    "--set view_max_side=480")


def fit_photo(
    photos: Annotated[list[Path], typer.Argument(
        metavar="PHOTO",
        help="The photo (JPEG, PNG, ...; EXIF orientation applied), or several photos of the "
             "same hand in the same pose (shape, colour and pose shared; each photo its own "
             "camera, placed by the hand's pose in it).")],
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: params.json, mesh.ply, keypoints.json, camera.json, "
                      "mask.png, overlay.png, report.html, metrics.json (DIR/handN/ per hand "
                      "when a photo holds several, fitted alone and then together, with "
                      "DIR/hands.json, hands.ply and overlay.png of all).")],
    side: Annotated[AutoSide, typer.Option(
        "--side", help="auto (the detector's side; else both are tried), right or left.")
    ] = AutoSide.auto,
    camera: Annotated[list[Path] | None, typer.Option(
        "--camera", metavar="CAM.json",
        help="Calibrated camera (cameras.json convention: K, width, height): once for all "
             "photos, or once per photo in their order.")] = None,
    focal_px: Annotated[float | None, typer.Option(
        "--focal-px", min=1e-6, help="Focal length in pixels of the original photo.")] = None,
    fov: Annotated[float | None, typer.Option(
        "--fov", min=1e-6, max=179.9,
        help="Field of view along the photo's long side, degrees (default: EXIF, else 67).")
    ] = None,
    keypoints: Annotated[list[Path] | None, typer.Option(
        "--keypoints", metavar="KP.json",
        help="The hand's 21 keypoints instead of detection, in pixels of the ORIGINAL photo "
             "(upright), OpenPose order: [[u, v] x 21], {\"keypoints\": ..., \"side\": ...}, "
             "{\"hands\": [...]}, a frame's keypoints.json, an OpenPose JSON or a fit-photo "
             "keypoints.json. Once for all photos or once per photo.")] = None,
    mask: Annotated[list[Path] | None, typer.Option(
        "--mask", metavar="MASK.png",
        help="The hand's mask (white = hand) at the photo's size, instead of the automatic "
             "one; once per photo.")] = None,
    hand: Annotated[int | None, typer.Option(
        "--hand", min=0, metavar="N",
        help="Fit only hand N (0 = leftmost detected, or the file's first) into OUT; default: "
             "every hand, into OUT/hand0, OUT/hand1, ...")] = None,
    model: FitModelOpt = None,
    device: DeviceOpt = "auto",
    keypoint_iters: Annotated[int | None, typer.Option(
        "--keypoint-iters", min=0, help="Iterations of the keypoint stage (default 300).")
    ] = None,
    color_iters: Annotated[int | None, typer.Option(
        "--color-iters", min=0,
        help="Iterations of the pose, shape and colour stage (default 40; 0 skips it).")
    ] = None,
    rays: Annotated[int | None, typer.Option(
        "--rays", min=1, help="Rays rendered per colour iteration (default 256).")] = None,
    res: Annotated[int, typer.Option(
        "--res", min=16, max=1024, help="Marching-cubes samples per axis of the mesh.")] = 128,
    threads: ThreadsOpt = 1,
    shape_fit: ShapeFitOpt = ShapeFit.space,
    guard: GuardOpt = True,
    view_calibration: ViewCalibrationOpt = True,
    seed: Annotated[int, typer.Option(help="Seed of the restarts and of the rays.")] = 0,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
    settings: SetOpt = None,
) -> None:
    """Fit the LISA hand to photos: detect the 21 keypoints (MediaPipe: pip install -e
    '.[photo]'; or give them with --keypoints), choose the camera (--camera, --focal-px,
    --fov, EXIF, or a default field of view), mask the hand, fit pose, shape and colour, and
    write OUT/params.json, mesh.ply, keypoints.json (2D detected and fitted in the photo's
    pixels, 3D in the camera frame), camera.json, mask.png, overlay.png and report.html.
    Several hands in one photo are each fitted alone, then together so that they touch
    without passing through each other (--set fit.joint.iters=0: alone only); OUT/hands.json
    gives their sides, the right-to-left wrist offset and the deepest penetration."""
    from ..fitting.photo.fit import FitPhotoConfig, fit_photo_folder, photo_fit_defaults

    overrides = image_fit_overrides(seed=seed, threads=threads, shape_fit=shape_fit,
                                    guard=guard, keypoint_iters=keypoint_iters,
                                    color_iters=color_iters, rays=rays,
                                    view_calibration=view_calibration)
    config = with_settings(FitPhotoConfig(fit=photo_fit_defaults(**overrides),
                                          mesh_resolution=res), settings)
    reports = fit_photo_folder(
        photos, out, side=side.value, camera_json=camera or None, focal_px=focal_px,
        fov_deg=fov, keypoints_json=keypoints or None, mask_path=mask or None, hand=hand,
        model_path=model, device=device, progress=progress, log=typer.echo, config=config)
    for report in reports:
        guard = report.guard
        verdict = "n/a" if guard is None else (
            f"{guard.pieces} piece(s), area x{guard.area_ratio:.3f}, "
            + ("passed" if guard.passed else "FAILED"))
        errors = ", ".join(f"{error:.2f}" for error in report.keypoint_error_px)
        typer.echo(f"fitted a {report.side} hand to {len(report.photos)} photo(s) in "
                   f"{report.seconds:.1f} s: keypoint error {errors} px; surface {verdict}")
        for path in report.written:
            typer.echo(f"wrote {path}")


def register(app: typer.Typer) -> None:
    app.command("fit-photo")(fit_photo)
