"""``lisa fit-points``: fit LISA to a point cloud (paper Section 4.3) and write the hand."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .options import AutoSide, DeviceOpt, PointModelOpt, Units, set_option, with_settings

SetOpt = set_option("FitPointsConfig (lisa_hand/fitting/points/config.py)",
                    "--set field_iters=300 --set shape_weight=3e-5 --set prior_pose=flat")

TriesOpt = Annotated[int, typer.Option(
    "--tries", min=1,
    help="Fits from seeds SEED, SEED+1, ... (of each side with --side auto), the one "
         "nearest the scan kept: it can help on one-view scans, where the seed decides "
         "whether a hidden finger is found; each try costs a fit.")]
ViewpointOpt = Annotated[str, typer.Option(
    "--viewpoint", metavar="X,Y,Z|auto|none",
    help="The sensor position of a one-view scan, in the cloud's units (a depth camera's "
         "points in its own frame: 0,0,0): the fit then keeps the hand out of the space the "
         "sensor saw to be empty (a finger it cannot see stays hidden). auto: found from "
         "the scan when it looks like one view (its own origin when that can be the "
         "sensor), left out for a scan from all round; none: never.")]


def _auto_or_none(flag: str, help_text: str):
    """An ``auto|none`` option of ``lisa fit-points`` (read by :func:`_auto`)."""
    return Annotated[str, typer.Option(flag, metavar="auto|none", help=help_text)]


def _auto(flag: str, text: str) -> str | None:
    """``auto`` -> "auto", ``none`` -> None (the API's values); else a one-line error."""
    value = text.strip().lower()
    if value not in ("auto", "none"):
        raise ValueError(f"{flag}: expected auto or none, got {text!r}")
    return "auto" if value == "auto" else None


SupportOpt = _auto_or_none(
    "--support", "auto: a surface the hand rests on (a desk or a wall in a depth camera's view, "
    "the largest plane of the scan reaching out round the hand) is found, its points left out "
    "and the hand kept on its side, and the command says so; none: every point is the hand's.")
OthersOpt = _auto_or_none(
    "--others", "auto: pieces of the scan 3 cm or more apart from the hand's (another object, "
    "the other hand), with at least 5% as many points, are left out, and the command says so; "
    "none: kept.")
ColoursOpt = _auto_or_none(
    "--colours", "auto: a scan with colours (PLY red/green/blue, OBJ 'v x y z r g b', NPZ "
    "'colors', a GLB's vertex colours or texture, a depth image's --rgb image) colours "
    "mesh.ply: each vertex the colour of the scan points within a few point spacings, the "
    "surface the scan did not show interpolated from what it showed (with a colour model, "
    "--model default: its colour code fitted to the scan's colours guesses it); "
    "none: the model's colours (grey for a geometric prior).")


HandOpt = Annotated[int | None, typer.Option(
    "--hand", min=0, metavar="N",
    help="For a scan of several hands apart from each other (both hands, two people's): fit "
         "only hand N (0 = the one with the most points) into OUT; default: every hand, into "
         "OUT/hand0, OUT/hand1, ...")]
HandsOpt = Annotated[int | None, typer.Option(
    "--hands", min=2, metavar="N",
    help="The scan holds N hands that may touch (clasped, crossed, one holding the other): the "
         "points are split between them by their fits, the hands fitted together so that they "
         "touch without overlapping, into OUT/hand0, OUT/hand1, ... with OUT/hands.json (sides, "
         "right-to-left wrist offset, deepest penetration) and OUT/hands.ply. Its settings are "
         "FitPointsConfig.hands, e.g. --set hands.candidate_iters=60 --set hands.joint.iters=0 "
         "(each hand fitted alone).")]
CameraOpt = Annotated[Path | None, typer.Option(
    "--camera", metavar="CAM.json",
    help="For a depth image: the camera that took it (cameras.json convention: K, width, "
         "height; R, t to place it in a world frame); its centre is the sensor position.")]
DepthScaleOpt = Annotated[float, typer.Option(
    "--depth-scale",
    help="For a depth image: metres per unit of its values (0.001: millimetres, as RealSense "
         "and Kinect cameras write them).")]
MaskOpt = Annotated[Path | None, typer.Option(
    "--mask", metavar="MASK.png",
    help="For a depth image: the hand's pixels (white), the rest left out.")]

ColourOpt = Annotated[Path | None, typer.Option(
    "--rgb", metavar="COLOUR.png",
    help="For a depth image: the colour image taken with it, aligned to the depth camera (the "
         "same pixels; RealSense: rs.align to depth): the hand is found in it (MediaPipe, the "
         "[photo] extra), its pixels kept and, with --side auto, its side taken.")]


def fit_points(
    points: Annotated[Path, typer.Argument(
        metavar="POINTS",
        help="Point cloud: PLY, OBJ, XYZ, NPY or NPZ (normals optional), a mesh (these, STL, "
             "OFF, GLB or GLTF), whose vertices are the points, or a depth camera's image "
             "(16-bit PNG or TIFF, with --camera).")],
    out: Annotated[Path, typer.Option(
        "--out", help="Output folder: params.json, mesh.ply, keypoints.json, preview.png (the "
                      "fit and the scan's points, coloured by their distance to it) and, with "
                      "--gt, metrics.json.")],
    model: PointModelOpt = None,
    gt: Annotated[Path | None, typer.Option(
        "--gt", help="Ground-truth mesh (or points): also write V2V and V2S distances (mm), "
                     "both ways.")] = None,
    units: Annotated[Units, typer.Option(
        "--units", help="Units of POINTS and GT: m, cm, mm, or auto (from the size of a hand: "
                        "0.1-0.3 m, 10-30 cm or 100-300 mm across).")] = Units.auto,
    res: Annotated[int, typer.Option(
        "--res", min=16, max=1024, help="Marching-cubes samples per axis of the mesh.")] = 128,
    iterations: Annotated[int | None, typer.Option(
        "--field-iters", "--iterations", min=0,
        help="Iterations of the field stage (default: the config's, 200).")] = None,
    restarts: Annotated[int | None, typer.Option(
        "--restarts", min=1, help="Candidate poses fitted with the field (default: the config's).")
    ] = None,
    device: DeviceOpt = "auto",
    side: Annotated[AutoSide, typer.Option(
        "--side", help="auto (fitted as both, side by side on two cores, the one nearer the "
                       "scan kept), "
                       "right or left hand (a left one is fitted as the mirrored right hand).")
    ] = AutoSide.auto,
    seed: Annotated[int, typer.Option(help="Seed of the random point subsets.")] = 0,
    tries: TriesOpt = 1,
    refine: Annotated[bool, typer.Option(
        "--refine", help="After the fit, fine-tune the model's per-bone SDF networks on this "
                         "scan (beyond the learned shape space; about 30 s on a CPU); writes the "
                         "refined model as OUT/model.pt, which params.json names, so that "
                         "'lisa mesh', 'render' and 'animate' use it.")] = False,
    refine_iters: Annotated[int | None, typer.Option(
        "--refine-iters", min=1, help="Steps of --refine (default 300).")] = None,
    viewpoint: ViewpointOpt = "auto",
    support: SupportOpt = "auto",
    others: OthersOpt = "auto",
    hand: HandOpt = None,
    hands: HandsOpt = None,
    camera: CameraOpt = None,
    depth_scale: DepthScaleOpt = 0.001,
    mask: MaskOpt = None,
    rgb: ColourOpt = None,
    colours: ColoursOpt = "auto",
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    settings: SetOpt = None,
) -> None:
    """Fit the LISA hand to the point cloud POINTS (any position and orientation, partial or
    full, with noise and outliers; a mesh file; a depth image with --camera) and write
    OUT/params.json, OUT/mesh.ply, OUT/keypoints.json and OUT/preview.png (a scan of several
    hands apart: each into OUT/hand0, OUT/hand1, ...)."""
    from ..fitting.points.fit import FitPointsConfig
    from ..fitting.points.io import count_hands

    overrides = {"seed": seed, "tries": tries}
    if iterations is not None:
        overrides["field_iters"] = iterations
    if restarts is not None:
        overrides["restarts"] = restarts
    config = with_settings(FitPointsConfig(**overrides), settings)
    view, colour_mode = _viewpoint(viewpoint), _auto("--colours", colours) or "none"
    support_mode, others_mode = _auto("--support", support), _auto("--others", others)
    refine_config = None
    if refine:
        from ..fitting.points.refine import RefineConfig

        refine_config = RefineConfig(seed=config.seed, **({} if refine_iters is None
                                                   else {"iters": refine_iters}))
    depth, side = _depth_frame(points, camera, depth_scale, mask, rgb, side)
    if hands is not None:
        _fit_together(points, out, hands, hand=hand, gt=gt, refine=refine, model_path=model,
                      units=units.value, viewpoint=view, support=support_mode, depth=depth,
                      resolution=res, config=config, device=device, side=side.value,
                      progress=progress)
        return
    count = 1 if hand is not None else count_hands(points, units.value, config, depth,
                                                   support_mode)
    _fit_each(points, out, count, hand, model_path=model, gt_path=gt,
              units=units.value, refine=refine_config, viewpoint=view, support=support_mode,
              others=others_mode, depth=depth, resolution=res, config=config, device=device,
              side=side.value, progress=progress, log=typer.echo, colours=colour_mode)


def _fit_together(points: Path, out: Path, count: int, *, hand, gt, refine, **options):
    """``--hands N``: the hands of the scan fitted together
    (:func:`lisa_hand.fitting.points.io.fit_hands_file`)."""
    from ..fitting.points.io import fit_hands_file

    for name, value in (("--hand", hand), ("--gt", gt), ("--refine", refine or None)):
        if value is not None:
            raise ValueError(f"--hands {count} fits every hand of the scan together; {name} is "
                             "for one hand: leave it out, or fit one hand with --hand N")
    for path in fit_hands_file(points, out, count, log=typer.echo, **options):
        typer.echo(f"wrote {path}")


def _fit_each(points: Path, out: Path, count: int, hand: int | None, **options):
    """Fit hand ``hand`` of the scan into ``out`` (``count`` 1), or each of its ``count`` hands
    into ``out/handN``, saying what it does (``options``: :func:`fit_point_file`'s)."""
    from ..fitting.points.io import fit_point_file

    if count > 1 and options["gt_path"] is not None:
        raise ValueError(f"{points}: the scan holds {count} hands apart from each other; --gt "
                         "compares one: pass --hand N with it")
    if count > 1:
        typer.echo(f"{points}: {count} hands apart from each other: fitting each into "
                   f"{out / 'hand0'} ... {out / f'hand{count - 1}'} (--hand N for one)")
    for index in range(count):
        if count > 1:
            typer.echo(f"fitting hand{index}")
        report = fit_point_file(points, out if count == 1 else out / f"hand{index}",
                                hand=hand if count == 1 else index, **options)
        _said(report, options["config"])


def _depth_frame(points: Path, camera: Path | None, scale: float, mask: Path | None,
                 rgb: Path | None, side: AutoSide):
    """(the :class:`~lisa_hand.data.depth.DepthFrame` of the depth options, or None when none is
    given; the side to fit: with --rgb and --side auto, the one found) (one-line errors)."""
    from ..data.depth import DepthFrame
    from .options import read_cameras

    if not scale > 0:
        raise ValueError(f"--depth-scale must be > 0 (metres per unit), got {scale!r}")
    if camera is None and mask is None and rgb is None and scale == 0.001:
        return None, side
    if camera is None:
        raise ValueError(f"{points}: --depth-scale, --mask and --rgb read a depth image with "
                         "its camera: pass --camera CAM.json too")
    cameras = read_cameras(camera)
    if len(cameras) != 1:
        raise ValueError(f"--camera {camera}: a depth image has one camera, the file holds "
                         f"{len(cameras)}")
    frame = DepthFrame(camera=cameras[0], scale_m=scale, mask=mask)
    return (frame, side) if rgb is None else _colour_hand(points, frame, rgb, side)


def _colour_hand(points: Path, depth, rgb: Path, side: AutoSide):
    """--rgb: the depth frame masked to the hand found in the colour image (which also colours
    the points), and the side to fit (the detected one for --side auto)."""
    import dataclasses

    from ..fitting.points.rgbd import with_colour_hand

    wanted = None if side.value == "auto" else side.value
    depth, found = with_colour_hand(points, depth, rgb, side=wanted)
    depth = dataclasses.replace(depth, colour=rgb)
    typer.echo(found.note)
    return depth, AutoSide(found.side) if wanted is None else side


def _said(report, config) -> None:
    """The fit's summary line, the ground truth's distances and the files written."""
    fit = report.fit
    counted = (f"{fit.num_points} of {fit.num_points + fit.beyond_wrist_points}"
               if fit.beyond_wrist_points else f"{fit.num_points}")
    typer.echo(f"fitted {counted} points in {fit.seconds:.1f} s: |G| at the points "
               f"median {fit.residual_median_mm:.2f} mm, mean {fit.residual_mean_mm:.2f} mm, "
               f"{100 * fit.inlier_fraction:.1f}% within {3 * config.robust_scale_mm:g} mm")
    if report.metrics is not None:
        for key, value in report.metrics.items():
            shown = "n/a (no faces)" if value is None else f"{value:.3f}"
            typer.echo(f"  {key}: {shown}")
    for path in report.written:
        typer.echo(f"wrote {path}")


def _viewpoint(text: str) -> list[float] | str | None:
    """``--viewpoint``: "auto", "none" (None) or three numbers X,Y,Z."""
    if text.strip().lower() in ("auto", "none"):
        return None if text.strip().lower() == "none" else "auto"
    try:
        view = [float(v) for v in text.split(",")]
    except ValueError:
        view = []
    if len(view) != 3:
        raise ValueError(f"--viewpoint: expected three numbers X,Y,Z, auto or none, got {text!r}")
    return view


def register(app: typer.Typer) -> None:
    app.command("fit-points")(fit_points)
