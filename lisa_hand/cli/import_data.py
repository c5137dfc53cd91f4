"""``lisa import ...``: real datasets into the package's layout (docs/datasets.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

import_app = typer.Typer(
    name="import", no_args_is_help=True, rich_markup_mode=None,
    help="Import a dataset you downloaded (InterHand2.6M, FreiHAND, a folder of scans) into "
         "the LISA-open layout that 'lisa train' and 'lisa train-prior' read. Images are "
         "referred to, not copied. See docs/datasets.md.")

OutOpt = Annotated[Path, typer.Option(
    "--out", help="Dataset folder to write (created; must be empty unless --overwrite).")]
OverwriteOpt = Annotated[bool, typer.Option(
    "--overwrite", help="Write into a non-empty --out, first removing a previous dataset's "
                        "subject folders and dataset files (nothing else).")]
QuietOpt = Annotated[bool, typer.Option("--quiet", help="No progress bar.")]
SkinningOpt = Annotated[int, typer.Option(
    "--skinning-points", help="Points of the posed MANO (with --mano) or template per frame in "
                              "scan.npz with their skinning weights: lisa train's L_w pseudo "
                              "ground truth (0: none).")]
MaxFramesOpt = Annotated[int, typer.Option("--max-frames", help="At most this many frames "
                                           "(0: all).")]
ManoOpt = Annotated[Path | None, typer.Option(
    "--mano", help="Folder with your MANO_RIGHT.pkl / MANO_LEFT.pkl (mano.is.tue.mpg.de): poses "
                   "and skeletons from the dataset's MANO parameters instead of inverse "
                   "kinematics of its 3D joints.")]


def _csv(text: str) -> tuple[str, ...]:
    return tuple(part.strip() for part in text.split(",") if part.strip())


def _ints(text: str, name: str) -> tuple[int, ...]:
    try:
        return tuple(int(part.removeprefix("Capture")) for part in _csv(text))
    except ValueError:
        raise ValueError(f"{name} must be comma-separated integers, got {text!r}") from None


@import_app.command("interhand2.6m")
def interhand(
    root: Annotated[Path, typer.Argument(metavar="ROOT", help="The InterHand2.6M folder "
                                         "(annotations/ and images/).")],
    out: OutOpt,
    split: Annotated[str, typer.Option("--split", help="train, val or test.")] = "train",
    captures: Annotated[str, typer.Option(
        "--captures", help="Comma-separated capture numbers (0,1 or Capture0); default all.")] = "",
    sequences: Annotated[str, typer.Option(
        "--sequences", help="Comma-separated sequence names or patterns (ROM*); default all.")
    ] = "",
    cameras: Annotated[str, typer.Option(
        "--cameras", help="Comma-separated camera ids (400002 or cam400002); default all.")] = "",
    hand: Annotated[str, typer.Option(
        "--hand", help="right, left, or both (an interacting frame gives two frames).")
    ] = "both",
    every: Annotated[int, typer.Option("--every", help="Keep every Nth frame of a sequence.")
                     ] = 1,
    max_frames: MaxFramesOpt = 0,
    masks: Annotated[Path | None, typer.Option(
        "--masks", help="Folder of hand masks laid out as images/SPLIT (same relative paths, "
                        ".png or .jpg).")] = None,
    mano: ManoOpt = None,
    skinning_points: SkinningOpt = 2000,
    overwrite: OverwriteOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """InterHand2.6M: cameras (mm -> m), joints (tip-to-base, wrist last -> OpenPose), poses."""
    from ..data.importers.interhand import InterHandConfig, import_interhand

    config = InterHandConfig(
        root=str(root), split=split, captures=_ints(captures, "--captures"),
        sequences=_csv(sequences), cameras=_csv(cameras), hand=hand, every=every,
        max_frames=max_frames, masks=None if masks is None else str(masks),
        mano=None if mano is None else str(mano), skinning_points=skinning_points)
    typer.echo(import_interhand(config, out, overwrite=overwrite, progress=not quiet).describe())


@import_app.command("freihand")
def freihand(
    root: Annotated[Path, typer.Argument(metavar="ROOT", help="The FreiHAND folder "
                                         "(training_K.json, training/rgb, ...).")],
    out: OutOpt,
    set_name: Annotated[str, typer.Option("--set", help="training or evaluation.")
                        ] = "training",
    versions: Annotated[str, typer.Option(
        "--versions", help="Training-image versions: 0 green screen, 1-3 backgrounds.")] = "0",
    every: Annotated[int, typer.Option("--every", help="Keep every Nth sample.")] = 1,
    max_frames: MaxFramesOpt = 0,
    vertices: Annotated[bool, typer.Option(
        "--vertices", help="Also keep the MANO vertices ({set}_verts.json) per frame.")] = False,
    split: Annotated[str, typer.Option("--as-split", help="The split the subjects go into.")
                     ] = "test",
    mano: ManoOpt = None,
    skinning_points: SkinningOpt = 2000,
    overwrite: OverwriteOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """FreiHAND: K, xyz (camera frame, metres), MANO parameters, images and masks."""
    from ..data.importers.freihand import FreiHandConfig, import_freihand

    config = FreiHandConfig(
        root=str(root), set=set_name, versions=_ints(versions, "--versions"), every=every,
        max_frames=max_frames, vertices=vertices, split=split,
        mano=None if mano is None else str(mano), skinning_points=skinning_points)
    typer.echo(import_freihand(config, out, overwrite=overwrite, progress=not quiet).describe())


@import_app.command("scans")
def scans(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="Folder of scan meshes or point "
                                           "clouds (PLY, OBJ, ...), one subfolder per person.")],
    out: OutOpt,
    units: Annotated[str, typer.Option("--units", help="m, cm, mm or auto.")] = "auto",
    points: Annotated[int, typer.Option("--points", help="Scan points kept per scan.")] = 20000,
    sdf_samples: Annotated[int, typer.Option("--sdf-samples", help="Near-surface SDF samples "
                                             "per scan.")] = 20000,
    split: Annotated[str, typer.Option("--as-split", help="The split the subjects go into.")
                     ] = "train",
    mano: ManoOpt = None,
    side: Annotated[str, typer.Option(
        "--side", help="right or left: the side of scans whose files do not say it.")
    ] = "right",
    pose_search: Annotated[bool, typer.Option(
        "--pose-search/--no-pose-search",
        help="Scans without NAME.keypoints3d.json or MANO parameters: find their pose with the "
             "point-cloud fit of 'lisa fit-points' (about 20 s a scan on a CPU), or skip them."
    )] = True,
    model: Annotated[Path | None, typer.Option(
        "--model", help="--pose-search: the trained model that fits (default: that of 'lisa "
                        "fit-points', the shipped geometric prior).")] = None,
    overwrite: OverwriteOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Scans for the geometric prior: scan.npz with skinning pseudo ground truth per scan."""
    from ..data.importers.scans import ScanImportConfig, import_scans

    config = ScanImportConfig(root=str(folder), units=units, num_points=points,
                              num_sdf_samples=sdf_samples, split=split,
                              mano=None if mano is None else str(mano), side=side)
    keypoints_fn = scan_pose_search(model) if pose_search else None
    typer.echo(import_scans(config, out, overwrite=overwrite, progress=not quiet,
                            keypoints_fn=keypoints_fn).describe())


def scan_pose_search(model_path: Path | None):
    """The pose search of ``lisa import scans``: a callable (points [N, 3] metres, normals or
    None, side) -> [21, 3] keypoints metres, from :func:`lisa_hand.fitting.points.fit.fit_points`
    with the trained model (loaded on first use) and its fitted hand's keypoints."""
    state: dict = {}

    def search(points, normals, side):
        from ..fitting.outputs import hand_keypoints_3d
        from ..fitting.points.fit import fit_points
        from ..fitting.points.io import default_point_model
        from ..model.trained import load_trained

        if "model" not in state:
            state["model"] = load_trained(model_path or default_point_model(), "cpu")
        fit = fit_points(state["model"], points, normals, side=side)
        return hand_keypoints_3d(fit.params)

    return search


def register(app: typer.Typer) -> None:
    app.add_typer(import_app, name="import")
