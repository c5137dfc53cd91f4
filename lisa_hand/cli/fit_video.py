"""``lisa fit-video``: one consistent hand (or two) through a video clip, written as files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .options import AutoSide, DeviceOpt, FitModelOpt, ThreadsOpt, set_option, with_settings

SetOpt = set_option("FitVideoConfig (lisa_hand/fitting/video/config.py; the motion fit's "
                    "MotionConfig under motion., the keyframe's FitPhotoConfig under keyframe.)",
                    "--set motion.acceleration_weight=0.003 --set keyframe.fit.color_iters=80")


def fit_video(
    video: Annotated[Path, typer.Argument(
        metavar="VIDEO", help="A video (MP4, MOV, WebM, AVI, MKV...) or a folder of frames "
                              "(PNG, JPEG; natural order).")],
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: params.json, mesh.ply, hand.glb (one hand; DIR/handN/ "
                      "each when there are several, and hands.json: where they are from each "
                      "other), track.json, overlay.mp4, report.html, metrics.json.")],
    camera: Annotated[Path | None, typer.Option(
        "--camera", metavar="CAM.json",
        help="Calibrated camera (cameras.json convention: K, width, height).")] = None,
    focal_px: Annotated[float | None, typer.Option(
        "--focal-px", min=1e-6, help="Focal length in pixels of the clip.")] = None,
    fov: Annotated[float | None, typer.Option(
        "--fov", min=1e-6, max=179.9,
        help="Field of view along the clip's long side, degrees (default 67).")] = None,
    side: Annotated[AutoSide, typer.Option(
        "--side", help="auto (each hand's detected side), right or left (every hand).")
    ] = AutoSide.auto,
    start: Annotated[float | None, typer.Option(
        "--start", min=0.0, help="Start of the part to fit, seconds.")] = None,
    end: Annotated[float | None, typer.Option(
        "--end", min=0.0, help="End of the part to fit, seconds.")] = None,
    stride: Annotated[int, typer.Option(
        "--stride", min=1, help="Fit every n-th frame.")] = 1,
    fps: Annotated[float | None, typer.Option(
        "--fps", min=1e-3, help="Frames a second of a folder of frames (default 30).")] = None,
    independent: Annotated[bool, typer.Option(
        "--independent", help="Fit every frame alone (no motion prior, no bridging of "
                              "dropouts): the reference the tracked fit is measured against.")
    ] = False,
    model: FitModelOpt = None,
    device: DeviceOpt = "auto",
    threads: ThreadsOpt = 2,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
    settings: SetOpt = None,
) -> None:
    """Fit the LISA hand through a video: detect the hands of every frame (MediaPipe: pip
    install -e '.[photo]'), follow each one through the clip, fit its pose and translation in
    every frame with a motion prior and one skeleton for the clip, then its shape and colour
    once on a few well-seen frames, and write the hand (params.json, mesh.ply), its animation
    (hand.glb), every frame's keypoints (track.json), the clip with the hand over it
    (overlay.mp4) and report.html."""
    from ..fitting.video import FitVideoConfig, fit_video_folder

    config = with_settings(FitVideoConfig(independent=independent, num_threads=threads),
                           settings)
    report = fit_video_folder(
        video, out, camera_json=camera, focal_px=focal_px, fov_deg=fov, side=side.value,
        start_s=start, end_s=end, stride=stride, fps=fps, model_path=model, device=device,
        progress=progress, log=typer.echo, config=config)
    for hand in report.metrics["hands"]:
        typer.echo(f"hand {hand['identity']} ({hand['side']}): fitted in "
                   f"{hand['frames_fitted']} of {report.metrics['frames']} frames, jitter "
                   f"{hand['jitter_mm_per_frame2']:.2f} mm/frame^2, "
                   f"{hand['agreement_px']:.2f} px from the detections")
    typer.echo(f"{report.metrics['frames']} frames in {report.seconds:.1f} s "
               f"({report.frames_per_second:.1f} frames a second)")
    for path in report.written:
        typer.echo(f"wrote {path}")


def register(app: typer.Typer) -> None:
    app.command("fit-video")(fit_video)
