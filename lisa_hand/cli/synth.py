"""``lisa synth``: write a synthetic multi-view dataset of open-model hands, or a preview sheet."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def synth(
    out: Annotated[Path | None, typer.Argument(
        metavar="OUT",
        help="Dataset folder to write (created; must be empty unless --overwrite). May be left "
             "out when --preview is given.")] = None,
    subjects: Annotated[int, typer.Option(
        "--subjects", help="Number of subjects (s000, s001, ...).")] = 20,
    poses: Annotated[int, typer.Option(
        "--poses", help="Frames (poses) per subject.")] = 10,
    views: Annotated[int, typer.Option(
        "--views", help="Cameras of the rig (images per frame).")] = 8,
    resolution: Annotated[str, typer.Option(
        "--resolution", metavar="WxH", help="Image size in pixels, e.g. 1024x667.")] = "1024x667",
    seed: Annotated[int, typer.Option(
        "--seed", help="Seed of every random choice (same seed, same dataset).")] = 0,
    workers: Annotated[int, typer.Option(
        "--workers", help="Worker processes (0: one per CPU core, at most 8; 1: no workers). "
                          "The dataset does not depend on it.")] = 0,
    scan_points: Annotated[int, typer.Option(
        "--scan-points", help="Scan points per frame (scan.npz).")] = 20000,
    sdf_samples: Annotated[int, typer.Option(
        "--sdf-samples", help="Near-surface SDF samples per frame (scan.npz).")] = 20000,
    mesh_resolution: Annotated[int, typer.Option(
        "--mesh-resolution",
        help="Marching-cubes voxels per hand length (255: ~0.7 mm, 100k+ vertices; lower only "
             "for quick tests).")] = 255,
    preview: Annotated[Path | None, typer.Option(
        "--preview", metavar="PNG",
        help="Also write a contact sheet PNG here: up to 4 of the dataset's subjects (rows) x "
             "6 poses (columns). Alone (no OUT) it writes only the sheet (about a minute).",
    )] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite",
        help="Write into a non-empty OUT, first removing a previous dataset's subject folders, "
             "dataset.json and split.json (nothing else).",
    )] = False,
    hand_model: Annotated[str, typer.Option(
        "--hand-model", metavar="v1|v2|v3",
        help="Version of the open hand model: v1 (default; what the shipped model was trained "
             "on), v2 (rounded, padded palm, forearm stub, D-shaped fingers, shapes drawn "
             "from adult hand anthropometry) or v3 (MakeHuman's sculpted hand, CC0: sizes from "
             "the same anthropometry, skinned by dual quaternions, skin tones by ethnic "
             "mix).")] = "v1",
    ages: Annotated[str, typer.Option(
        "--ages", metavar="MIN,MAX",
        help="Ages in years of the v3 hands (default 18,80); a narrower range holds the rest "
             "out, e.g. 18,65 to test on older hands.")] = "18,80",
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress bar.")] = False,
) -> None:
    """Write a synthetic dataset (LISA-open layout, docs/data_formats.md) and/or a preview sheet.

    Per subject and frame: mesh (PLY), scan and SDF samples (NPZ), images, masks and depth (PNG)
    of every camera, cameras and keypoints (JSON), pose parameters; split.json divides the
    subjects into train/val/test. Prints the time taken.
    """
    from ..data.scans import ScanConfig
    from ..data.synth.dataset import SynthConfig, parse_resolution, synthesize, write_preview

    if out is None and preview is None:
        raise ValueError("nothing to write: give a dataset folder OUT, --preview PNG, or both")
    config = SynthConfig(
        num_subjects=subjects, num_poses=poses, num_views=views,
        resolution=parse_resolution(resolution), seed=seed, num_workers=workers,
        scan=ScanConfig(num_points=scan_points), num_sdf_samples=sdf_samples,
        voxels_per_length=mesh_resolution, hand_model=hand_model, ages=_ages(ages),
    )
    if out is not None:
        summary = synthesize(out, config, progress=not quiet, overwrite=overwrite)
        typer.echo(summary.describe())
    if preview is not None:
        path = write_preview(preview, config, num_subjects=min(subjects, 4), num_poses=6)
        typer.echo(f"wrote preview {path}")


def register(app: typer.Typer) -> None:
    app.command("synth")(synth)


def _ages(text: str) -> tuple[float, float]:
    """``--ages MIN,MAX`` -> (MIN, MAX) years."""
    try:
        youngest, oldest = (float(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--ages must be MIN,MAX in years (e.g. 18,65), got {text!r}") from None
    return youngest, oldest
