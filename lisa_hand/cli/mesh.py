"""``lisa mesh``: a fitted hand's surface as a mesh with colours and skinning weights."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .options import DeviceOpt, ModelOpt, ParamsArg


def mesh(
    params: ParamsArg,
    out: Annotated[Path, typer.Option(
        "--out", help="Mesh file, format by suffix: .ply (colours and 16 skinning weights), "
                      ".obj or .glb (colours).")],
    res: Annotated[int, typer.Option(
        "--res", help="Grid samples along each side of the cube around the hand.")] = 128,
    model: ModelOpt = None,
    padding: Annotated[float, typer.Option(
        "--padding", help="Metres around the posed skeleton's box (the grid grows by itself "
                          "if the surface reaches its side).")] = 0.03,
    dense: Annotated[bool, typer.Option(
        "--dense", help="Evaluate every grid point (the slow reference) instead of coarse to "
                        "fine.")] = False,
    colors: Annotated[bool, typer.Option(
        "--colors/--no-colors", help="Per-vertex colours (model's mean gain and bias).")] = True,
    weights: Annotated[bool, typer.Option(
        "--weights/--no-weights", help="Per-vertex skinning weights (PLY only).")] = True,
    specks: Annotated[bool, typer.Option(
        "--keep-specks", help="Keep the pieces smaller than 0.1 % of the surface that marching "
                              "cubes leaves where the field dips below zero away from the hand "
                              "(removed by default, and said).")] = False,
    device: DeviceOpt = "auto",
) -> None:
    """Extract the hand of PARAMS as a triangle mesh: marching cubes evaluated coarse to fine
    (full resolution only near the surface), vertex colours and skinning weights (dense
    correspondences across poses and subjects)."""
    from ..data.meshio import MESH_SUFFIXES, save_mesh
    from ..geometry.pieces import MIN_PIECE_FRACTION, drop_specks
    from ..inference import MeshConfig, load_hand, mesh_hand_with_stats
    from ..utils.device import resolve_device

    suffix = out.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"--out {out}: unknown mesh format {suffix or '(none)'!r}; use one of "
                         f"{', '.join(MESH_SUFFIXES)}")
    if res < 8 or res > 2048:
        raise ValueError(f"--res must be within [8, 2048] grid samples, got {res}")
    config = MeshConfig(padding=padding, coarse_to_fine=not dense, colors=colors,
                        skin_weights=weights and suffix == ".ply")
    from ..utils.io import check_output_file

    check_output_file(out)  # before the work: a folder or an unwritable place fails now
    trained, hand = load_hand(params, model, resolve_device(device))
    result = mesh_hand_with_stats(trained, hand, res, config)
    written, removed = drop_specks(result.mesh, 0.0 if specks else MIN_PIECE_FRACTION)
    save_mesh(out, written)
    kept = ["colours"] if written.colors is not None else []
    if written.skin_weights is not None:
        kept.append(f"{written.skin_weights.shape[1]} skinning weights")
    elif weights and suffix != ".ply":
        typer.echo(f"note: {suffix} files cannot hold skinning weights; use .ply to keep them")
    grid = result.extraction.num_grid_points
    typer.echo(
        f"wrote {out}: {written.num_vertices} vertices, {written.num_faces} faces"
        + (f" with {' and '.join(kept)}" if kept else "")
        + f"; grid {round(grid ** (1 / 3))}^3, voxel {result.voxel_size * 1e3:.2f} mm, "
        f"{result.extraction.num_evaluations / grid:.1%} of it evaluated, "
        f"{result.seconds_total:.1f} s"
    )
    if removed.count:
        typer.echo(f"note: {removed.note()} (--keep-specks keeps them)")
    if result.grown:
        typer.echo("note: the surface reached the skeleton box; the grid grew to the bone "
                   "regions (raise --padding to avoid the second pass)")


def register(app: typer.Typer) -> None:
    app.command("mesh")(mesh)
