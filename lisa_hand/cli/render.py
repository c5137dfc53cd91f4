"""``lisa render``: novel views, normal maps and turntables of a fitted hand."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from .options import DeviceOpt, ModelOpt, ParamsArg, parse_image_size, read_cameras


class Mode(str, Enum):
    """How images are made."""

    volume = "volume"
    surface = "surface"


class Background(str, Enum):
    """Colour behind the hand."""

    black = "black"
    white = "white"


_BACKGROUNDS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}


def render(
    params: ParamsArg,
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: NAME_rgb.png, NAME_normals.png, NAME_mask.png, "
                      "NAME_depth.npy per view, cameras.json, turntable.gif (--orbit).")],
    camera: Annotated[Path | None, typer.Option(
        "--camera", help="Cameras to render: a JSON list of {name, K, R, t, width, height} "
                         "(the cameras.json of datasets and of 'lisa render').")] = None,
    orbit: Annotated[int | None, typer.Option(
        "--orbit", help="Render N views on a circle around the hand's finger axis (the first "
                        "facing the palm) and a turntable GIF (and MP4 when imageio has an "
                        "FFmpeg or PyAV backend).")] = None,
    resolution: Annotated[str | None, typer.Option(
        "--resolution", help="WIDTHxHEIGHT pixels; default 512x512 with --orbit, the cameras' "
                             "own with --camera (intrinsics are scaled when given).")] = None,
    model: ModelOpt = None,
    elevation: Annotated[float, typer.Option(
        "--elevation", help="Orbit: degrees above the palm plane's normal circle.")] = 15.0,
    fov: Annotated[float, typer.Option(
        "--fov", help="Orbit: horizontal field of view, degrees.")] = 30.0,
    fps: Annotated[float, typer.Option("--fps", help="Turntable frames per second.")] = 12.0,
    mode: Annotated[Mode, typer.Option(
        "--mode", help="volume (VolSDF, what LISA renders) or surface (sphere-traced preview).")
    ] = Mode.volume,
    background: Annotated[Background, typer.Option(
        "--background", help="Colour behind the hand.")] = Background.black,
    normals: Annotated[bool, typer.Option(
        "--normals/--no-normals", help="Also write normal maps.")] = True,
    device: DeviceOpt = "auto",
) -> None:
    """Render the hand of PARAMS: from the cameras of CAM.json, or an orbit of N views with a
    turntable. Rays that miss the hand's occupancy grid cost nothing; samples gather in a band
    around the surface; colours use the model's mean gain and bias."""
    from ..inference import (
        hand_render_config,
        load_hand,
        orbit_views,
        prepare_render,
        render_to_folder,
    )
    from ..utils.device import resolve_device

    if (camera is None) == (orbit is None):
        raise ValueError("give exactly one of --camera CAM.json and --orbit N")
    if orbit is not None and not 1 <= orbit <= 720:
        raise ValueError(f"--orbit must be a number of views in [1, 720], got {orbit}")
    size = parse_image_size(resolution, "--resolution") if resolution is not None else None
    if not 0.0 < fov < 180.0:
        raise ValueError(f"--fov must be in (0, 180) degrees, got {fov}")
    if not -90.0 < elevation < 90.0:
        raise ValueError(f"--elevation must be in (-90, 90) degrees, got {elevation}")
    if not fps > 0:
        raise ValueError(f"--fps must be > 0, got {fps}")
    from ..utils.io import check_output_dir

    check_output_dir(out)  # before the work: a file or an unwritable place fails now
    cameras = read_cameras(camera, size) if camera is not None else None
    trained, hand = load_hand(params, model, resolve_device(device))
    config = hand_render_config(
        trained, mode=mode.value, background=_BACKGROUNDS[background.value],
        normals="autograd" if normals else "none",
    )  # fmt: skip
    scene = prepare_render(trained, hand, config)
    if cameras is None:
        width, height = size if size is not None else (512, 512)
        cameras = orbit_views(scene, orbit, width, height, elevation_deg=elevation, fov_deg=fov)
    result = render_to_folder(scene, cameras, out, turntable=orbit is not None, fps=fps,
                              log=typer.echo)
    typer.echo(f"rendered {len(cameras)} view(s) of {cameras[0].width}x{cameras[0].height} in "
               f"{result.seconds:.1f} s into {out} (cameras: {result.cameras_path.name})")
    if result.gif_path is not None:
        typer.echo(f"turntable: {result.gif_path}"
                   + (f", {result.video_path}" if result.video_path is not None else
                      " (no MP4: install 'imageio-ffmpeg' or 'av' for one)"))


def register(app: typer.Typer) -> None:
    app.command("render")(render)
