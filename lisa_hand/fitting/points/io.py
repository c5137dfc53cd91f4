"""Point-cloud files for fitting: reading (PLY, OBJ, XYZ, NPY, NPZ; STL, OFF, GLB, GLTF meshes)
and checking them.

:func:`read_point_cloud` returns what a file holds, as it is stored; :func:`prepare_point_cloud`
turns that into what the fitter accepts (finite points in metres, at most ``max_points``) and
says in plain words what it changed, so that the command line can print it.

Formats (normals are optional everywhere):

* ``.ply``: the vertex element's ``x y z`` and, when present, ``nx ny nz`` (ASCII or binary);
  faces, colours and other properties are ignored (a mesh's vertices are its points).
* ``.obj``: the ``v`` lines (first three numbers); the ``vn`` lines are the normals when there
  is one per vertex (point-cloud exports), else they are ignored.
* ``.xyz``: text, one point a line, ``x y z`` or ``x y z nx ny nz``; ``#`` starts a comment.
* ``.npy``: an ``[N, 3]`` or ``[N, 6]`` (points, normals) array.
* ``.npz``: ``points`` (or ``vertices``) ``[N, 3]`` and optional ``normals`` ``[N, 3]`` (the
  ``scan.npz`` files of ``lisa synth``).
* ``.stl``, ``.off``, ``.glb``, ``.gltf``: a mesh's distinct vertices, through trimesh
  (:func:`lisa_hand.metrics.load_mesh`: vertices repeated at the same position, as STL repeats
  them for every triangle, are merged; a scene's meshes are placed and joined); no normals.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...data.meshio import read_ply_vertices
from ...data.units import LENGTH_UNITS, UNIT_CHOICES, decide_length_unit
from ...utils.io import require_file

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
]

POINT_CLOUD_SUFFIXES = (".ply", ".obj", ".xyz", ".npy", ".npz", ".stl", ".off", ".glb", ".gltf")
"""File extensions :func:`read_point_cloud` understands."""

UNITS = UNIT_CHOICES
"""Length units of an input cloud: metres, centimetres, millimetres, or guessed from its size
(:func:`lisa_hand.data.units.decide_length_unit`)."""


def read_point_cloud(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point cloud as stored (see the module docstring for the formats).

    -> (points [N, 3] float64 in the file's units, normals [N, 3] float64 or None). Values are
    not checked beyond their shape (NaN stays NaN; see :func:`prepare_point_cloud`).
    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder and ValueError
    naming the file for an unknown extension, a corrupt file or an empty cloud.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in POINT_CLOUD_SUFFIXES:
        raise ValueError(f"{path}: unsupported point-cloud file type {path.suffix!r} (expected "
                         f"one of {', '.join(POINT_CLOUD_SUFFIXES)})")
    require_file(path)
    reader = {".ply": _read_ply, ".obj": _read_obj, ".xyz": _read_xyz, ".npy": _read_npy,
              ".npz": _read_npz}.get(suffix, _read_mesh_vertices)
    try:
        points, normals = reader(path)
    except (OSError, EOFError, ValueError, TypeError, IndexError, KeyError,
            UnicodeDecodeError) as exc:
        message = str(exc)
        if message.startswith(str(path)):
            raise ValueError(message) from None
        raise ValueError(f"{path}: cannot read this {suffix[1:].upper()} file "
                         f"({type(exc).__name__}: {message})") from None
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: points must have shape [N, 3], got {list(points.shape)}")
    if points.shape[0] == 0:
        raise ValueError(f"{path}: the point cloud is empty (no points)")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != points.shape:
            raise ValueError(f"{path}: normals have shape {list(normals.shape)}, the points "
                             f"{list(points.shape)}")
    return np.ascontiguousarray(points), (None if normals is None
                                          else np.ascontiguousarray(normals))


def _columns(array: np.ndarray, path: Path, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """[N, 3] points or [N, 6] points and normals from one array."""
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] not in (3, 6):
        raise ValueError(f"{path}: {what} must have shape [N, 3] or [N, 6] (points, normals), "
                         f"got {list(array.shape)}")
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{path}: {what} must be numbers, got dtype {array.dtype}")
    return array[:, :3], (array[:, 3:6] if array.shape[1] == 6 else None)


def _read_npy(path: Path):
    return _columns(np.load(path, allow_pickle=False), path, "the array")


def _read_xyz(path: Path):
    table = np.loadtxt(path, ndmin=2, comments="#")
    if table.size == 0:
        return np.zeros((0, 3)), None
    return _columns(table, path, "the table")


def _read_npz(path: Path):
    with np.load(path, allow_pickle=False) as archive:
        key = next((k for k in ("points", "vertices") if k in archive.files), None)
        if key is None:
            raise ValueError(f"{path}: expected an array named 'points' or 'vertices', found "
                             f"{archive.files}")
        points = archive[key]
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"{path}: '{key}' must have shape [N, 3], got {list(points.shape)}")
        normals = archive["normals"] if "normals" in archive.files else None
    return points, normals


def _read_obj(path: Path):
    vertices, normals = [], []
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            if line.startswith("v "):
                vertices.append(line.split()[1:4])
            elif line.startswith("vn "):
                normals.append(line.split()[1:4])
    if any(len(row) < 3 for row in vertices):
        raise ValueError(f"{path}: a 'v' line has fewer than 3 coordinates")
    points = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    if normals and len(normals) == len(vertices) and all(len(row) == 3 for row in normals):
        return points, np.array(normals, dtype=np.float64)
    return points, None


def _read_mesh_vertices(path: Path):
    from ...metrics import load_mesh

    return load_mesh(path).vertices, None


def _read_ply(path: Path):
    # The vertex element only (the mesh reader's parser; faces and other elements are skipped).
    vertex = read_ply_vertices(path)
    columns = vertex.dtype.names
    points = np.stack([vertex[axis] for axis in "xyz"], axis=1)
    normals = None
    if all(name in columns for name in ("nx", "ny", "nz")):
        normals = np.stack([vertex[name] for name in ("nx", "ny", "nz")], axis=1)
    return points, normals


@dataclass
class PointCloud:
    """A cloud ready for fitting (:func:`prepare_point_cloud`)."""

    points: np.ndarray
    """[N, 3] float64 metres, finite."""
    normals: np.ndarray | None
    """[N, 3] float64 unit outward normals, or None."""
    unit: str
    """The unit the input was read in: "m", "cm" or "mm"."""
    unit_detected: bool
    """True when ``unit`` was guessed (``units="auto"``)."""
    num_input: int
    """Points in the input, before anything was dropped."""
    notes: list[str] = field(default_factory=list)
    """What was changed, one sentence each (dropped points, unit conversion, subsampling)."""


def prepare_point_cloud(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    units: str = "auto",
    max_points: int = 5_000_000,
    min_points: int = 20,
    seed: int = 0,
    name: str = "points",
) -> PointCloud:
    """Check a cloud and bring it to metres.

    points: [N, 3] in ``units``; normals: [N, 3] or None (they need not be unit length).
    units: "m", "cm", "mm" or "auto": :func:`lisa_hand.data.units.decide_length_unit` reads
        the unit from the hand's size (a note says which, when not metres) or checks the given
        one; a size that is no hand's in that unit (or in any, with "auto") is an error naming
        the ``--units`` that fits.
    max_points: a larger cloud is randomly subsampled to this many points (the fitter draws a
        few hundred points per iteration; more only costs memory).
    min_points: fewer finite points than this is an error.
    name: how errors call the cloud (the file path, for the command line).

    Documented fallbacks (each adds a sentence to ``notes``): points with NaN or inf
    coordinates are dropped (depth sensors write NaN for missing pixels); normals are dropped
    when any kept one is not finite or has zero length.
    """
    if units not in UNITS:
        raise ValueError(f"units must be one of {UNITS}, got {units!r}")
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: points must have shape [N, 3], got {list(points.shape)}")
    num_input = points.shape[0]
    if num_input == 0:
        raise ValueError(f"{name}: the point cloud is empty (no points)")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != points.shape:
            raise ValueError(f"{name}: normals must have the points' shape {list(points.shape)},"
                             f" got {list(normals.shape)}")
    notes: list[str] = []
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        kept = int(finite.sum())
        if kept < min_points:
            raise ValueError(f"{name}: only {kept} of {num_input} points have finite "
                             f"coordinates (NaN or inf), fewer than the {min_points} needed")
        points = points[finite]
        normals = None if normals is None else normals[finite]
        notes.append(f"dropped {num_input - kept} of {num_input} points with NaN or inf "
                     "coordinates")
    if points.shape[0] < min_points:
        raise ValueError(f"{name}: {points.shape[0]} points, fewer than the {min_points} "
                         "needed to fit a hand")
    if normals is not None:
        lengths = np.linalg.norm(normals, axis=1)
        if not (np.isfinite(lengths).all() and (lengths > 1e-12).all()):
            notes.append("ignored the normals: some are NaN, inf or zero")
            normals = None
        else:
            normals = normals / lengths[:, None]

    length = decide_length_unit(points, units, name=name, what="the cloud")
    unit = length.unit
    if unit != "m":
        points = points * length.metres_per_unit
    if length.note is not None:
        notes.append(length.note)

    if points.shape[0] > max_points:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(points.shape[0], size=max_points, replace=False))
        notes.append(f"randomly subsampled {points.shape[0]} points to {max_points}")
        points = points[keep]
        normals = None if normals is None else normals[keep]
    return PointCloud(points=np.ascontiguousarray(points), normals=normals, unit=unit,
                      unit_detected=units == "auto", num_input=num_input, notes=notes)


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
    "geometry_v2" (the geometric prior on 203 subjects of the open hand model v2: geometry that
    image training has not blurred, a rounded palm and a forearm stub), "geometry" (the same on
    hand model v1) and "default" (LISA-full). A point cloud has no colour, so a prior's lack of
    one costs nothing but the mesh's vertex colours (``--model default`` keeps them)."""
    from ...model.trained import shipped_model_path

    for name in ("geometry_v2", "geometry"):
        if shipped_model_path(name).is_file():
            return name
    return "default"


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
) -> FitPointsReport:
    """Read a cloud, fit the model, write ``params.json``, ``mesh.ply`` (skinning weights, and
    vertex colours from the mean colour code when the model has colour) and (with ``gt_path``)
    ``metrics.json`` into ``out_dir``; with ``refine`` (a
    :class:`lisa_hand.fitting.points.refine.RefineConfig`) the model's per-bone SDF networks are
    then fine-tuned on the scan (:func:`lisa_hand.fitting.points.refine.refine_surface`), the
    refined model is written as ``model.pt`` and ``params.json`` names it.

    Every input is checked before the fit (the cloud, the ground truth, the model, the output
    folder: new, empty or holding only a previous fit's files), and the files are written all or
    nothing (:func:`lisa_hand.fitting.outputs.write_fit_outputs`): a failure leaves nothing
    half-written, and a previous fit in ``out_dir`` is replaced as a whole.

    points_path: the cloud (:func:`read_point_cloud`); units: of the cloud and the ground truth
        ("auto", "m", "cm", "mm", see :func:`prepare_point_cloud`). model_path: a trained model
        (:func:`lisa_hand.model.trained.load_trained`; None: :func:`default_point_model`, the
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
    """
    from ...model.trained import model_label
    from ..outputs import ground_truth_metrics, prepare_fit, write_fit_outputs
    from .fit import FitPointsConfig, fit_points

    log = log or (lambda line: None)
    model_path = default_point_model() if model_path is None else model_path
    points_path, out_dir = Path(points_path), Path(out_dir)
    config = FitPointsConfig() if config is None else config
    cloud, sensor = _read_cloud(points_path, units, config, hand, log, depth)
    truth, model = prepare_fit(out_dir, gt_path, units, model_path, device, log)
    view = viewpoint  # checked by fit_points; a depth image's sensor, in metres, for "auto"
    if sensor is not None and viewpoint == "auto":
        view = sensor
    elif viewpoint is not None and not isinstance(viewpoint, str):
        view = np.asarray(viewpoint, dtype=np.float64) * LENGTH_UNITS[cloud.unit]
    fit = fit_points(model, cloud.points, cloud.normals, config, side=side, viewpoint=view,
                     support=support, others=others, progress=progress)
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
    metrics = None if truth is None else ground_truth_metrics(mesh, truth, fit.wrist_plane)
    written = write_fit_outputs(out_dir, params, mesh, metrics,
                                model=None if refined is None else model,
                                preview=_preview(mesh, cloud, fit, params.extra["input"], log))
    return FitPointsReport(cloud=cloud, fit=fit, mesh=mesh, metrics=metrics, written=written,
                           refine=refined)


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


def _read_cloud(points_path: Path, units: str, config, hand: int | None, log, depth=None
                ) -> tuple[PointCloud, np.ndarray | None]:
    """The file's cloud, prepared (:func:`prepare_point_cloud`) and, with ``hand``, without the
    other hands' points (:func:`_one_hand`), each note logged; and a depth image's sensor
    position (metres; None for a cloud)."""
    from ...data.depth import DEPTH_SUFFIXES, read_depth_cloud

    sensor, notes = None, []
    if points_path.suffix.lower() in DEPTH_SUFFIXES:
        if depth is None:
            raise ValueError(f"{points_path}: a depth image is read with its camera: pass "
                             "--camera CAM.json (K, width, height) and, unless it is in "
                             "millimetres, --depth-scale")
        raw_points, sensor, note = read_depth_cloud(points_path, depth)
        raw_normals, units, notes = None, "m", [note]
    else:
        if depth is not None:
            raise ValueError(f"{points_path}: --camera, --depth-scale and --mask are for a depth "
                             f"image ({', '.join(DEPTH_SUFFIXES)}), not a point cloud")
        raw_points, raw_normals = read_point_cloud(points_path)
    try:
        cloud = prepare_point_cloud(raw_points, raw_normals, units=units, seed=config.seed,
                                    min_points=config.min_points, name=str(points_path))
    except ValueError as error:
        if sensor is None or "too large" not in str(error):
            raise
        raise ValueError(f"{points_path}: the depth image's points reach over "
                         f"{np.ptp(raw_points, axis=0).max():.1f} m (the room behind the hand): "
                         "pass --mask MASK.png with the hand's pixels") from None
    cloud.notes[:0] = notes
    if hand is not None:
        cloud = _one_hand(cloud, hand, config.seed, str(points_path))
    for note in cloud.notes:
        log(f"{points_path}: {note}")
    return cloud, sensor


def count_hands(points_path: str | os.PathLike, units: str = "auto", config=None,
                depth=None) -> int:
    """How many hands the cloud in ``points_path`` (a depth image with ``depth``, as
    :func:`fit_point_file` reads it) holds apart from each other
    (:func:`lisa_hand.fitting.points.others.split_hands`; 1 when it is not split)."""
    from .fit import FitPointsConfig
    from .others import split_hands

    config = FitPointsConfig() if config is None else config
    cloud, _ = _read_cloud(Path(points_path), units, config, None, lambda line: None, depth)
    hands = split_hands(cloud.points, seed=config.seed)
    return 1 if hands is None else len(hands)


def _one_hand(cloud: PointCloud, hand: int, seed: int, name: str) -> PointCloud:
    """``cloud`` without the points of the hands other than ``hand`` (0: the largest), a note
    saying so; ValueError naming ``name`` when it holds fewer hands."""
    from .others import split_hands

    if isinstance(hand, bool) or not isinstance(hand, int) or hand < 0:
        raise ValueError(f"hand must be an integer >= 0, got {hand!r}")
    hands = split_hands(cloud.points, seed=seed)
    count = 1 if hands is None else len(hands)
    if hand >= count:
        raise ValueError(f"{name}: --hand {hand} asked for, but the scan holds {count} hand(s) "
                         f"apart from each other (--hand 0 to {count - 1})")
    if hands is None:
        return cloud
    keep = hands[hand]
    note = (f"hand {hand} of {count} (largest first): the other hands' {int((~keep).sum())} "
            "points left out")
    return dataclasses.replace(cloud, points=cloud.points[keep],
                               normals=None if cloud.normals is None else cloud.normals[keep],
                               notes=[*cloud.notes, note])


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
        kept = np.ones(len(points), bool) if fit.support is None else ~fit.support.removed
        if fit.others is not None:
            kept[np.flatnonzero(kept)[fit.others.removed]] = False
        if fit.wrist_plane is not None:
            kept &= fit.wrist_plane.keeps(points)
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
    if apart is not None and apart.oversize is not None:
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
    call, or a scan of one side of the hand (whose mirror image fits that side about as well:
    measured on one-view WebXR scans, the wrong side was kept in 6 of 24; 2 of 24 with
    ``--viewpoint auto``), asks for
    ``--side``."""
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
