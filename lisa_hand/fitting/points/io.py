"""From a point-cloud file to a fitted hand on disk (``lisa fit-points``): :func:`fit_point_file`
reads the file (:mod:`.inputs`), fits it, makes the mesh and the picture (:mod:`.preview`) and
hands them to the one writer (:func:`lisa_hand.fitting.outputs.write_fit`, all or nothing).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...data.units import LENGTH_UNITS
from ..outputs import releases_output_locks
from .inputs import (
    POINT_CLOUD_SUFFIXES,
    UNITS,
    PointCloud,
    count_hands,
    prepare_point_cloud,
    read_cloud_file,
    read_point_cloud,
)
from .others import HAND_REACH_M

__all__ = [
    "POINT_CLOUD_SUFFIXES",
    "UNITS",
    "PointCloud",
    "FitPointsReport",
    "read_point_cloud",
    "prepare_point_cloud",
    "fit_point_file",
    "count_hands",
    "default_point_model",
    "hand_points",
]

# ---------------------------------------------------------------------------------------------
# From a file to a fitted hand on disk (``lisa fit-points``)


@dataclass
class FitPointsReport:
    """What :func:`fit_point_file` did.

    cloud: the cloud as fitted (metres) and what was changed on reading it.
    fit: the :class:`lisa_hand.fitting.points.fit.FitResult`.
    mesh: the fitted surface (:class:`lisa_hand.geometry.meshing.Mesh`, colours and skinning
        weights).
    metrics: the four distances (mm) to the ground truth (``MeshDistances.to_dict`` keys; None
        where undefined), or None without one.
    written: the files written, in order (``model.pt``, the refined model, with ``refine``).
    """

    cloud: PointCloud
    fit: Any
    mesh: Any
    metrics: dict[str, float | None] | None
    written: list[Path]
    refine: Any = None
    """The refinement's :class:`~lisa_hand.fitting.stages.StageReport` (``--refine``), or None."""


def default_point_model() -> str:
    """The model of a point fit without ``--model``: the first shipped one installed of
    "geometry_v3" (the geometric prior on 644 subjects of hand models v1, v2 and v3: geometry
    that image training has not blurred, the closest on hands no generator made, from one view
    and from all round), "geometry" (the prior of hand model v1) and "default" (LISA-full). A
    point cloud has no colour, so a prior's lack of one costs nothing but the mesh's vertex
    colours (``--model default`` keeps them)."""
    from ...model.trained import shipped_model_path

    for name in ("geometry_v3", "geometry"):
        if shipped_model_path(name).is_file():
            return name
    return "default"


@releases_output_locks
def fit_point_file(
    points_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    model_path: str | os.PathLike | None = None,
    gt_path: str | os.PathLike | None = None,
    units: str = "auto",
    resolution: int = 128,
    config=None,
    device: str = "auto",
    side: str = "right",
    progress: bool = False,
    log: Callable[[str], None] | None = None,
    refine: Any = None,
    viewpoint: Sequence[float] | str | None = None,
    support: str | None = None,
    others: str | None = None,
    hand: int | None = None,
    depth: Any = None,
    colours: str = "auto",
) -> FitPointsReport:
    """Read a cloud, fit the model, write ``params.json``, ``mesh.ply`` (skinning weights, and
    vertex colours from the mean colour code when the model has colour) and (with ``gt_path``)
    ``metrics.json`` into ``out_dir``; with ``refine`` (a
    :class:`lisa_hand.fitting.points.refine.RefineConfig`) the model's per-bone SDF networks are
    then fine-tuned on the scan (:func:`lisa_hand.fitting.points.refine.refine_surface`), the
    refined model is written as ``model.pt`` and ``params.json`` names it.

    Every input is checked before the fit (the cloud, the ground truth, the model, the output
    folder: new, empty or holding only a previous fit's files), and the files are written all or
    nothing (:func:`lisa_hand.fitting.outputs.write_fit`): a failure leaves nothing
    half-written, and a previous fit in ``out_dir`` is replaced as a whole.

    points_path: the cloud (:func:`read_point_cloud`); units: of the cloud and the ground truth
        ("auto", "m", "cm", "mm", see :func:`prepare_point_cloud`). model_path: a trained model
        (:func:`lisa_hand.model.trained.load_trained`; None: :func:`default_point_model`, a
        shipped geometric prior). gt_path: a mesh or
        points (:func:`lisa_hand.metrics.load_mesh`). resolution: marching-cubes samples a side.
    config: :class:`lisa_hand.fitting.points.fit.FitPointsConfig`. device: "auto", "cpu", "cuda".
    side: "right" or "left", the hand the cloud shows, or "auto": both fitted, the nearer kept
    (:func:`lisa_hand.fitting.points.fit.fit_points`; the choice is logged).
    log: called with one line per note (unit conversion, dropped points).
    viewpoint: the sensor position of a one-view scan, 3 numbers in the cloud's units (a depth
        camera's points in its own frame: 0, 0, 0), "auto" (found from the scan when it looks
        like one view; logged) or None (:func:`lisa_hand.fitting.points.fit.fit_points`).
    support: "auto": a surface the hand rests on is found, left out and kept as a bound (logged
        when found), or None (:func:`lisa_hand.fitting.points.fit.fit_points`).
    others: "auto": pieces of the scan well apart from the hand are left out (logged), or None.
    hand: of a scan of several hands (:func:`count_hands`), the one to fit (0: the largest), the
        others' points left out; None: the scan is one hand. depth: a :class:`lisa_hand.data.
        depth.DepthFrame` for a depth image (its camera's centre the sensor for "auto").
    colours: "auto": a scan's colours colour ``mesh.ply`` (:mod:`.colours`; logged); "none".
    """
    from ...model.trained import model_label
    from ..outputs import fit_artefacts, ground_truth_metrics, prepare_fit, write_fit
    from .fit import FitPointsConfig, fit_points

    log = log or (lambda line: None)
    _check_choice("colours", colours, ("auto", "none"))
    points_path, out_dir = Path(points_path), Path(out_dir)
    config = FitPointsConfig() if config is None else config
    cloud, sensor = read_cloud_file(points_path, units, config, hand, log, depth, support)
    view = _fit_viewpoint(viewpoint, sensor, cloud.unit)
    analysis, model_path = _analysed(cloud, view, support, others, config, model_path, log)
    truth, model = prepare_fit(out_dir, gt_path, units, model_path, device, log)
    fit = fit_points(model, cloud.points, cloud.normals, config, side=side, analysis=analysis,
                     progress=progress)
    params = fit.params
    params.model = model_label(model_path)
    params.extra["input"] = {"path": str(points_path), "unit": cloud.unit,
                             "num_input_points": cloud.num_input, "notes": cloud.notes,
                             **_fit_notes(points_path, fit, view, cloud.unit, config, log)}
    refined = None
    if refine is not None:
        model, refined = _refined(model, fit, cloud, params.side, refine, progress, log,
                                  points_path)
        params.model = str((out_dir / "model.pt").resolve())
    mesh = _mesh_without_specks(model, params, resolution, fit.wrist_plane, out_dir, log)
    if colours == "auto" and cloud.colors is not None:
        _scan_coloured(mesh, cloud, fit, model, params, config.seed, out_dir, log)
    metrics = None if truth is None else ground_truth_metrics(mesh, truth, fit.wrist_plane)
    artefacts = fit_artefacts(params, mesh, metrics, model=None if refined is None else model,
                              preview=_preview(mesh, cloud, fit, params.extra["input"], log))
    written = write_fit(out_dir, artefacts)
    return FitPointsReport(cloud=cloud, fit=fit, mesh=mesh, metrics=metrics, written=written,
                           refine=refined)


def _analysed(cloud: PointCloud, view, support, others, config, model_path, log):
    """The scan analysed once (:func:`.analysis.analyse_scan`) and the model: ``model_path``, or
    :func:`default_point_model` (logged) -> (analysis, model path)."""
    from .analysis import analyse_scan

    analysis = analyse_scan(cloud.points, viewpoint=view, support=support, others=others,
                            config=config.analysis, seed=config.seed)
    if model_path is None:
        model_path = default_point_model()
        log(f"model: {model_path} (the point fit's default; --model to choose another)")
    return analysis, model_path


def _fit_viewpoint(viewpoint, sensor, unit: str):
    """What the fit gets as its viewpoint (checked by ``fit_points``): for "auto", a depth
    image's sensor (metres) when there is one; numbers in the cloud's ``unit`` in metres;
    otherwise ``viewpoint`` as it is ("auto", "none" or None)."""
    if sensor is not None and viewpoint == "auto":
        return sensor
    if viewpoint is not None and not isinstance(viewpoint, str):
        return np.asarray(viewpoint, dtype=np.float64) * LENGTH_UNITS[unit]
    return viewpoint


def _check_choice(name: str, value: Any, choices: Sequence[str]) -> None:
    """A ValueError unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")


def _mesh_without_specks(model, params, resolution: int, clip, out_dir: Path, log):
    """The fitted hand's mesh (colours, skinning weights) cut at ``clip``, without specks
    (:func:`lisa_hand.geometry.pieces.drop_specks`; logged when any)."""
    from ...geometry.pieces import drop_specks
    from ...inference import MeshConfig, mesh_hand

    mesh, specks = drop_specks(mesh_hand(model, params, resolution,
                                         MeshConfig(colors=model.has_color), clip=clip))
    if specks.count:
        log(specks.note(f"{out_dir / 'mesh.ply'}"))
    return mesh


def hand_points(cloud: PointCloud, fit) -> np.ndarray:
    """[N] bool: the cloud's points the fit took as the hand's (not a support's, another
    piece's, or beyond the fitted wrist's cut)."""
    points = np.asarray(cloud.points, np.float64)
    kept = fit.analysis.keep.copy()
    if fit.wrist_plane is not None:
        kept &= fit.wrist_plane.keeps(points)
    return kept


def _scan_coloured(mesh, cloud: PointCloud, fit, model, params, seed: int, out_dir: Path,
                   log) -> None:
    """``mesh`` coloured by the scan's colours (:func:`.colours.transfer_colours`, from the
    hand's points only; logged); with a colour model its colour code is fitted to them first
    (``params.color_code``, :func:`.colours.fit_colour_code`) and guesses the unseen surface.
    ``params.json``'s input record says what was done ("colours")."""
    import torch

    from .colours import fit_colour_code, transfer_colours

    kept = hand_points(cloud, fit)
    points, colours, base = cloud.points[kept], cloud.colors[kept], None
    if model.has_color and len(points):  # the model's colour guesses what the scan did not see
        from ...inference.hand_field import hand_field

        params.color_code = fit_colour_code(model, params, points, colours, seed=seed)
        vertices = torch.as_tensor(mesh.vertices, dtype=model.field.dtype,
                                   device=model.field.device)
        base = hand_field(model, params).attributes(vertices, skin_weights=False)[0]
        base = base.cpu().double().numpy()
    found = transfer_colours(mesh.vertices, mesh.faces, points, colours, base=base)
    record: dict[str, Any] = {"used": found is not None, "colour_code_fitted": base is not None}
    if found is None:
        log(f"{out_dir / 'mesh.ply'}: no scan point near the fitted surface to colour it")
    else:
        mesh.colors = found.colors
        log(found.note(out_dir / "mesh.ply", by_model=base is not None))
        record.update(seen_share=round(found.seen_share, 4),
                      radius_mm=round(1000.0 * found.radius_m, 3))
    params.extra["input"]["colours"] = record


def _preview(mesh, cloud: PointCloud, fit, record: dict, log) -> np.ndarray | None:
    """``preview.png`` (:func:`lisa_hand.fitting.points.preview.fit_preview`) of the fitted
    ``mesh`` and the scan, from the sensor when ``record`` (``params.json``'s "input") has one;
    None for a mesh without faces, or when the picture fails (logged: the fit's files are
    written without it)."""
    import point_cloud_utils as pcu

    from .preview import fit_preview

    if len(mesh.faces) == 0:
        return None
    points = np.asarray(cloud.points, np.float64)
    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    try:
        distances, _, _ = pcu.closest_points_on_mesh(points, vertices, faces)
        kept = hand_points(cloud, fit)
        return fit_preview(vertices, faces, points, 1000.0 * distances, kept=kept,
                           viewpoint=record.get("viewpoint_m"))
    except Exception as error:  # a picture is not worth the fit: write the rest
        log(f"preview.png not written: {type(error).__name__}: {error}")
        return None


def _fit_notes(points_path: Path, fit, view, unit: str, config, log) -> dict:
    """Log what the fit decided (the viewpoint found, or why none was for a scan that shows one
    side of the hand; the side kept; a one-sided scan without a viewpoint; points beyond the
    wrist) -> the viewpoint used, for ``params.json``'s "input" (``viewpoint_m``,
    ``viewpoint_source``; empty without one). A scan from all round for which none was found
    (as it should be) gets no line about it."""
    if fit.support is not None:
        found = fit.support
        log(f"{points_path}: {int(found.removed.sum())} of {len(found.removed)} points lie on "
            f"(or beyond) a surface the hand rests on ({100 * found.fraction:.0f}% of the scan "
            "on one plane, reaching out round the hand): left out, the hand kept on its side "
            "(--support none keeps them)")
    apart = fit.others
    if apart is not None and apart.pieces:
        log(f"{points_path}: {int(apart.removed.sum())} points in {apart.pieces} piece(s) "
            f"{100 * apart.gap_m:.0f} cm or more apart from the hand (another object or hand; "
            f"the largest {apart.largest} points) were left out (--others none keeps them)")
    if apart is not None and apart.oversize is not None and apart.nearest_m is not None:
        kept = len(apart.removed) - int(apart.removed.sum())
        log(f"{points_path}: the largest piece of the scan is {apart.oversize:.2f} m across, "
            f"larger than a hand (a person, a room): the hand was taken to be what is nearest "
            f"the sensor ({apart.nearest_m:.2f} m away), {kept} of {len(apart.removed)} points "
            f"within {100 * HAND_REACH_M:.0f} cm of it along the surface; if that is not the "
            "hand, crop the scan (a depth image: --mask) (--others none keeps every point)")
    elif apart is not None and apart.oversize is not None:
        log(f"{points_path}: the largest piece of the scan is {apart.oversize:.2f} m across, "
            "larger than a hand (a wall, a person): nothing was left out as apart from the hand; "
            "crop the scan to the hand")
    if apart is not None and apart.unclear:
        log(f"{points_path}: the scan holds {apart.unclear} more piece(s) 3 cm or more apart "
            "from the largest and nearly as large (another hand, a large object): kept, as "
            "which is the hand is not clear; crop the scan to the hand")
    if fit.viewpoint is not None:
        if fit.viewpoint.one_view or fit.coverage < config.covered_fraction:
            log(_viewpoint_found(points_path, fit.viewpoint, unit))
        view = fit.viewpoint.position if fit.viewpoint.one_view else None
    if fit.side_distances_mm is not None:
        log(_side_choice(points_path, fit, config))
    if view is None and fit.coverage < config.covered_fraction:
        log(f"{points_path}: the scan shows {fit.coverage:.0%} of the hand, one side of it; if it "
            "is one depth-camera view, --viewpoint X,Y,Z (the sensor's position, 0,0,0 in the "
            "camera's own frame) keeps the hand out of the space the sensor saw empty")
    if fit.beyond_wrist_points:
        log(f"{points_path}: {fit.beyond_wrist_points} points lie beyond the wrist cut "
            f"({1000 * config.wrist_clip_m:g} mm past the fitted wrist joint) and were left "
            "out; the mesh and the metrics end at the same cut")
    if view is None:
        return {}
    return {"viewpoint_m": [float(v) for v in view],
            "viewpoint_source": "given" if fit.viewpoint is None else "estimated"}


def _viewpoint_found(points_path: Path, found, unit: str) -> str:
    """The line that says what ``--viewpoint auto`` found (a
    :class:`~lisa_hand.fitting.points.viewpoint.ViewpointEstimate`)."""
    from .viewpoint import ViewpointConfig

    hidden = f"{found.hidden_fraction:.0%} of its points hidden from the best direction"
    if found.num_points < ViewpointConfig.min_points:
        return (f"{points_path}: {found.num_points} points are too few to find where a scan "
                f"was seen from (--viewpoint auto needs {ViewpointConfig.min_points}): fitted "
                "without a viewpoint")
    if not found.one_view:
        return f"{points_path}: the scan is not one view ({hidden}): fitted without a viewpoint"
    where = ("the cloud's origin (its frame looks like the camera's)" if found.at_origin else
             ",".join(f"{v / LENGTH_UNITS[unit]:.4g}" for v in found.position)
             + f" {unit}, a guess along the direction it was seen from")
    return (f"{points_path}: the scan looks like one view ({hidden}); its sensor taken to be at "
            f"{where}: pass --viewpoint X,Y,Z if you know it, or --viewpoint none")


_CLOSE_SIDES = 1.15
"""``--side auto``: a choice whose two distances are within this ratio is called close."""


def _side_choice(points_path: Path, fit, config) -> str:
    """The line that says which side ``--side auto`` chose, and how far to trust it: a close
    call, or a scan of one side of the hand (whose mirror image fits that side about as well,
    so that the wrong side is kept now and then, less often with ``--viewpoint auto``), asks
    for ``--side``."""
    side, distances = fit.params.side, fit.side_distances_mm
    other = "left" if side == "right" else "right"
    line = (f"{points_path}: fitted as a right and as a left hand; kept the {side} hand, "
            f"{distances[side]:.2f} mm from the scan against {distances[other]:.2f} mm")
    if fit.coverage < config.covered_fraction:
        line += (f" (the scan shows one side of the hand, {fit.coverage:.0%}, where the mirror "
                 "image can fit as well: pass --side if you know which hand it is)")
    elif distances[other] < _CLOSE_SIDES * distances[side]:
        line += " (close: pass --side if you know which hand it is)"
    return line


def _refined(model, fit, cloud: PointCloud, side: str, config, progress: bool, log,
             points_path: Path):
    """-> (the refined model, its :class:`~lisa_hand.fitting.stages.StageReport`): the scan's
    points on the hand's side of the wrist cut, a left hand's mirrored (LISA is a right hand)."""
    import torch

    from ..sides import mirror_cloud, mirror_hand
    from .refine import refine_surface

    points = np.asarray(cloud.points, np.float64)
    normals = None if cloud.normals is None else np.asarray(cloud.normals, np.float64)
    if fit.wrist_plane is not None:
        keep = fit.wrist_plane.keeps(points)
        points, normals = points[keep], None if normals is None else normals[keep]
    hand = mirror_hand(fit.params) if side == "left" else fit.params
    points_t = mirror_cloud(torch.from_numpy(points).float(), side)
    normals_t = None if normals is None else mirror_cloud(torch.from_numpy(normals).float(), side)
    refined, report = refine_surface(model, hand, points_t, normals_t, config, progress)
    before, after = (1e3 * value for value in report.energies)
    log(f"{points_path}: refined the surface in {report.seconds:.1f} s: mean |G| at the points "
        f"{before:.2f} -> {after:.2f} mm")
    fit.params.extra["refine"] = {"seconds": report.seconds, "mean_abs_sdf_before_mm": before,
                                  "mean_abs_sdf_after_mm": after}
    return refined, report


# ---------------------------------------------------------------------------------------------
# A scan of several hands that may touch (``lisa fit-points --hands N``)


@releases_output_locks
def fit_hands_file(points_path: str | os.PathLike, out_dir: str | os.PathLike, count: int, *,
                   model_path: str | os.PathLike | None = None, units: str = "auto",
                   resolution: int = 128, config=None, device: str = "auto",
                   side: str = "auto", viewpoint=None, support: str | None = "auto",
                   depth=None, progress: bool = False, log: Callable[[str], None] | None = None
                   ) -> list[Path]:
    """Fit ``count`` >= 2 hands that may touch to the scan in ``points_path``
    (:func:`lisa_hand.fitting.points.hands.fit_scan_hands`) and write ``out_dir/handN/``
    (each hand's ``params.json``, ``mesh.ply``, ``keypoints.json``), ``hands.json``
    (:func:`lisa_hand.fitting.pair.record.hands_record`, world frame) and ``hands.ply`` (every
    hand's mesh). Options as :func:`fit_point_file`'s; ``config.hands`` says how the hands are
    split and fitted together. -> the written paths."""
    import dataclasses

    from ...model.trained import load_trained, model_label
    from ...skeleton.wrist import wrist_plane
    from ...utils.device import resolve_device
    from ..outputs import hand_keypoints_3d, json_artefact, mesh_artefact, write_fit
    from ..outputs.folder import claim_output_folder, hands_entry
    from ..outputs.writer import fit_artefacts
    from ..pair.contact import HandBody, penetration_depths
    from ..pair.record import hands_record, joined_mesh
    from .fit import FitPointsConfig
    from .hands import fit_scan_hands

    log = log or (lambda line: None)
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise ValueError(f"--hands must be an integer >= 2, got {count!r}")
    points_path, out_dir = Path(points_path), Path(out_dir)
    config = FitPointsConfig() if config is None else config
    claim_output_folder(out_dir, hands_entry, "hands.json, hands.ply and hand0/, hand1/, ...")
    cloud, sensor = read_cloud_file(points_path, units, config, None, log, depth, support)
    view = _fit_viewpoint(viewpoint, sensor, cloud.unit)
    analysis, model_path = _analysed(cloud, view, support, None, config, model_path, log)
    model = load_trained(model_path, resolve_device(device))
    points = np.asarray(cloud.points, np.float64)[analysis.keep]
    found = fit_scan_hands(model, points, count, config, side=side,
                           sensor=analysis.sensor, progress=progress, log=log)
    artefacts, meshes = [], []
    for index, params in enumerate(found.hands):
        params.model = model_label(model_path)
        params.extra["input"] = {"path": str(points_path), "unit": cloud.unit,
                                 "hand": index, "hands": count,
                                 "points": int((found.labels == index).sum())}
        params.extra["config"] = {"fit": dataclasses.asdict(config)}
        clip = None if config.wrist_clip_m is None else wrist_plane(params, config.wrist_clip_m)
        mesh = _mesh_without_specks(model, params, resolution, clip, out_dir / f"hand{index}",
                                    log)
        meshes.append(mesh)
        artefacts += [dataclasses.replace(artefact, name=f"hand{index}/{artefact.name}")
                      for artefact in fit_artefacts(params, mesh)]
    bodies = [HandBody.of(model, params, mesh, 1, 0)
              for params, mesh in zip(found.hands, meshes, strict=True)]
    depths = penetration_depths(model, bodies)
    roots = np.stack([hand_keypoints_3d(params)[0] for params in found.hands])
    record = hands_record(found.hands, [f"hand{k}" for k in range(count)], roots, depths,
                          "the scan's (metres)",
                          None if found.joint is None else found.joint.to_dict(), [])
    record["points_unassigned"] = int((found.labels < 0).sum())
    sides = [params.side for params in found.hands]
    for side in ("right", "left"):
        if sides.count(side) > 1:
            record["notes"].append(f"{sides.count(side)} {side} hands: fitted as found (two "
                                   "people's hands, or a side the fit got wrong: --side)")
            log(record["notes"][-1])
    artefacts += [json_artefact("hands.json", record),
                  mesh_artefact(joined_mesh(meshes), "hands.ply")]
    log(f"{count} hands fitted together in {found.seconds:.0f} s: "
        + ", ".join(f"hand{k} {params.side} ({int((found.labels == k).sum())} points)"
                    for k, params in enumerate(found.hands))
        + f"; deepest penetration {depths.max():.1f} mm")
    return write_fit(out_dir, artefacts, hands_entry,
                     "hands.json, hands.ply and hand0/, hand1/, ... folders")
