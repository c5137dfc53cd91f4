"""``lisa animate``: re-pose a fitted hand along a pose sequence (meshes and frames)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from .options import DeviceOpt, ModelOpt, ParamsArg, parse_image_size, read_cameras


class MeshFormat(str, Enum):
    """Mesh file format of the frames."""

    ply = "ply"
    obj = "obj"
    glb = "glb"


class MeshMode(str, Enum):
    """How each frame's mesh is made."""

    field = "field"
    skinning = "skinning"


def _check_motion_options(
    poses: Path | None, motion: str | None, frames_per_segment: int, res: int, frames: bool
) -> None:
    """One of --poses and --motion (a known one), the counts in range, something to write."""
    if (poses is None) == (motion is None):
        raise ValueError("give exactly one of --poses SEQ.json and --motion NAME")
    if motion is not None:
        from ..handmodel.poses import POSE_NAMES

        if motion not in POSE_NAMES:
            raise ValueError(f"--motion: unknown motion {motion!r}; known: "
                             f"{', '.join(POSE_NAMES)}")
    if not 1 <= frames_per_segment <= 1000:
        raise ValueError(f"--frames-per-segment must be in [1, 1000], got {frames_per_segment}")
    if res != 0 and not 8 <= res <= 1024:
        raise ValueError(f"--res must be 0 (no meshes) or in [8, 1024], got {res}")
    if res == 0 and not frames:
        raise ValueError("nothing to write: --res 0 and --no-frames")


def animate(
    params: ParamsArg,
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: meshes/frame_000.ply..., frames/frame_000.png..., "
                      "animation.gif, camera.json, poses.json.")],
    poses: Annotated[Path | None, typer.Option(
        "--poses", help="Pose sequence JSON: a list of poses of 48 numbers (global rotation "
                        "and 15 joints, axis-angle radians, MANO order) or 45 (finger joints "
                        "only: the hand's global rotation is kept), or {\"poses\": [...], "
                        "\"translations\": [[x, y, z], ...]} (metres; default the hand's); "
                        "at most 10000 poses.")
    ] = None,
    motion: Annotated[str | None, typer.Option(
        "--motion", help="A named motion: from the hand's pose to the named pose and back "
                         "(flat, relaxed, fist, point, pinch, ok).")] = None,
    frames_per_segment: Annotated[int, typer.Option(
        "--frames-per-segment", help="--motion: poses from the hand's pose to the named one "
                                     "(the motion has 2 N + 1).")] = 8,
    res: Annotated[int, typer.Option(
        "--res", help="Mesh grid samples per side (0: no meshes).")] = 96,
    mesh_format: Annotated[MeshFormat, typer.Option(
        "--mesh-format", help="ply (with skinning weights), obj or glb.")] = MeshFormat.ply,
    mesh_mode: Annotated[MeshMode, typer.Option(
        "--mesh-mode", help="field: marching cubes of the field in every pose; skinning: the "
                            "first mesh re-posed by its skinning weights (same vertices and "
                            "faces in every frame).")] = MeshMode.field,
    render_frames: Annotated[bool, typer.Option(
        "--frames/--no-frames", help="Render the frames and animation.gif.")] = True,
    camera: Annotated[Path | None, typer.Option(
        "--camera", help="Camera JSON (a list; the first is used); default: a palm-side view "
                         "framing every pose.")] = None,
    resolution: Annotated[str | None, typer.Option(
        "--resolution", help="WIDTHxHEIGHT of the frames: default 512x512, or the --camera's "
                             "own size (its intrinsics are scaled when given).")] = None,
    fps: Annotated[float, typer.Option("--fps", help="GIF frames per second.")] = 12.0,
    model: ModelOpt = None,
    device: DeviceOpt = "auto",
) -> None:
    """Re-pose the hand of PARAMS along --poses SEQ.json or a --motion: one mesh and one frame
    per pose from a fixed camera, with the hand's shape and colour codes (mix them first with
    'lisa blend')."""
    from ..inference import (
        MeshConfig,
        animate_hand,
        load_hand,
        motion_poses,
        read_pose_sequence,
        resolve_poses,
    )
    from ..utils.device import resolve_device

    _check_motion_options(poses, motion, frames_per_segment, res, render_frames)
    size = parse_image_size(resolution, "--resolution") if resolution is not None else None
    if not fps > 0:
        raise ValueError(f"--fps must be > 0, got {fps}")
    sequence = read_pose_sequence(poses) if poses is not None else None
    fixed_camera = read_cameras(camera, size)[0] if camera is not None else None
    from ..utils.io import check_output_dir

    check_output_dir(out)  # before the work: a file or an unwritable place fails now
    trained, hand = load_hand(params, model, resolve_device(device))
    if sequence is not None:
        pose_seq, translations = resolve_poses(hand, sequence)
    else:
        pose_seq, translations = motion_poses(hand, motion, frames_per_segment), None
    result = animate_hand(
        trained, hand, pose_seq, translations, out,
        mesh_resolution=res or None, mesh_suffix=f".{mesh_format.value}",
        mesh_mode=mesh_mode.value, mesh_config=MeshConfig(), frames=render_frames,
        camera=fixed_camera, width=size[0] if size else 512, height=size[1] if size else 512,
        fps=fps, log=typer.echo,
    )  # fmt: skip
    typer.echo(f"animated {result.poses.shape[0]} poses in {result.seconds:.1f} s into {out}: "
               f"{len(result.mesh_paths)} meshes, {len(result.frame_paths)} frames"
               + (f", {result.gif_path}" if result.gif_path is not None else ""))


def register(app: typer.Typer) -> None:
    app.command("animate")(animate)
