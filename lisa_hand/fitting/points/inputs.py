"""From a file to the cloud a point fit takes: point-cloud and mesh files (PLY, OBJ, XYZ, NPY,
NPZ; STL, OFF, GLB, GLTF), depth images (:mod:`lisa_hand.data.depth`), one hand of several.

:func:`read_point_cloud` returns what a file holds, as it is stored; :func:`prepare_point_cloud`
turns that into what the fitter accepts (finite points in metres, at most ``max_points``) and
says in plain words what it changed, so that the command line can print it;
:func:`read_cloud_file` does both for ``lisa fit-points`` (a depth image with its camera, the
other hands of a scan of several left out: :func:`count_hands`).

Formats: the point files of :func:`lisa_hand.data.pointio.read_points` (PLY, OBJ, XYZ, NPY,
NPZ: points and optional normals; PLY and OBJ parsed by :mod:`lisa_hand.data.meshio`), and
``.stl``, ``.off``, ``.glb``, ``.gltf``: a mesh's distinct vertices, through trimesh
(:func:`lisa_hand.metrics.load_mesh`: vertices repeated at the same position, as STL repeats
them for every triangle, are merged; a scene's meshes are placed and joined); no normals.
Colours are read by :mod:`.colours`, as for the other formats that hold them.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...data.pointio import POINT_FILE_SUFFIXES, named_read_errors, read_points
from ...data.units import UNIT_CHOICES, decide_length_unit
from ...skeleton.params import MAX_TRANSLATION_M
from ...utils.io import require_file

__all__ = [
    "POINT_CLOUD_SUFFIXES",
    "UNITS",
    "PointCloud",
    "read_point_cloud",
    "prepare_point_cloud",
    "read_cloud_file",
    "count_hands",
]


POINT_CLOUD_SUFFIXES = POINT_FILE_SUFFIXES + (".stl", ".off", ".glb", ".gltf")
"""File extensions :func:`read_point_cloud` understands: point files, and meshes read by trimesh."""

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
    if suffix in POINT_FILE_SUFFIXES:
        points, normals = read_points(path)
    else:
        with named_read_errors(path):
            points, normals = _read_mesh_vertices(path), None
    points, normals = _checked_cloud(points, normals, str(path))
    return np.ascontiguousarray(points), (None if normals is None
                                          else np.ascontiguousarray(normals))


def _checked_cloud(points, normals, name: str) -> tuple[np.ndarray, np.ndarray | None]:
    """points [N, 3] and normals [N, 3] or None as float64, checked (N >= 1; a ValueError
    naming ``name`` if not; complex, boolean or text values are refused, not converted)."""
    for what, values in (("points", points), ("normals", normals)):
        if values is not None and np.asarray(values).dtype.kind not in "iuf":
            raise ValueError(f"{name}: {what} must be real numbers, got dtype "
                             f"{np.asarray(values).dtype}")
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: points must have shape [N, 3], got {list(points.shape)}")
    if points.shape[0] == 0:
        raise ValueError(f"{name}: the point cloud is empty (no points)")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != points.shape:
            raise ValueError(f"{name}: normals must have the points' shape {list(points.shape)},"
                             f" got {list(normals.shape)}")
    return points, normals


def _read_mesh_vertices(path: Path) -> np.ndarray:
    """A mesh file's distinct vertices (:func:`lisa_hand.metrics.load_mesh`)."""
    from ...metrics import load_mesh

    return load_mesh(path).vertices


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
    colors: np.ndarray | None = None
    """[N, 3] float32 in [0, 1], the points' colours (:mod:`.colours`), or None."""


def prepare_point_cloud(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    colors: np.ndarray | None = None,
    units: str = "auto",
    max_points: int = 5_000_000,
    min_points: int = 20,
    seed: int = 0,
    name: str = "points",
) -> PointCloud:
    """Check a cloud and bring it to metres.

    points: [N, 3] in ``units``; normals: [N, 3] or None (they need not be unit length);
    colors: [N, 3] in [0, 1] or None, kept with their points.
    units: "m", "cm", "mm" or "auto": :func:`lisa_hand.data.units.decide_length_unit` reads
        the unit from the hand's size (a note says which, when not metres) or checks the given
        one; a size that is no hand's in that unit (or in any, with "auto") is an error naming
        the ``--units`` that fits.
    max_points: a larger cloud is randomly subsampled to this many points (the fitter draws a
        few hundred points per iteration; more only costs memory).
    min_points: fewer finite points than this is an error.
    name: how errors call the cloud (the file path, for the command line).

    A cloud whose median lies over :data:`lisa_hand.skeleton.params.MAX_TRANSLATION_M` from the
    origin is refused (float32 would flatten the fitted hand).

    Documented fallbacks (each adds a sentence to ``notes``): points with NaN or inf
    coordinates are dropped (depth sensors write NaN for missing pixels); normals are dropped
    when any kept one is not finite or has zero length.
    """
    if units not in UNITS:
        raise ValueError(f"units must be one of {UNITS}, got {units!r}")
    points, normals = _checked_cloud(points, normals, name)
    num_input = points.shape[0]
    if colors is not None:
        colors = np.asarray(colors, np.float32)
        if colors.shape != points.shape:
            raise ValueError(f"{name}: colours must have the points' shape "
                             f"{list(points.shape)}, got {list(colors.shape)}")
    notes: list[str] = []
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        kept = int(finite.sum())
        if kept < min_points:
            raise ValueError(f"{name}: only {kept} of {num_input} points have finite "
                             f"coordinates (NaN or inf), fewer than the {min_points} needed")
        points = points[finite]
        normals = None if normals is None else normals[finite]
        colors = None if colors is None else colors[finite]
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
    distance = float(np.linalg.norm(np.median(points, axis=0)))
    if distance > MAX_TRANSLATION_M:
        raise ValueError(f"{name}: the cloud lies {distance:.3g} m from the origin (at most "
                         f"{MAX_TRANSLATION_M:g} m: in float32 a hand that far is flattened); "
                         "move it near the origin")

    if points.shape[0] > max_points:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(points.shape[0], size=max_points, replace=False))
        notes.append(f"randomly subsampled {points.shape[0]} points to {max_points}")
        points = points[keep]
        normals = None if normals is None else normals[keep]
        colors = None if colors is None else colors[keep]
    return PointCloud(points=np.ascontiguousarray(points), normals=normals, unit=unit,
                      unit_detected=units == "auto", num_input=num_input, notes=notes,
                      colors=colors)


def read_cloud_file(points_path: Path, units: str, config, hand: int | None, log, depth=None,
                    support: str | None = "auto") -> tuple[PointCloud, np.ndarray | None]:
    """The file's cloud, prepared (:func:`prepare_point_cloud`) and, with ``hand``, without the
    other hands' points (:func:`_one_hand`), each note logged; and a depth image's sensor
    position (metres; None for a cloud). depth: a :class:`lisa_hand.data.depth.DepthFrame` for
    a depth image (:data:`lisa_hand.data.depth.DEPTH_SUFFIXES`), else None. config: a
    :class:`~lisa_hand.fitting.points.fit.FitPointsConfig` (its seed and min_points). support:
    None leaves a support plane in when the hands are told apart (``--support none``)."""
    from ...data.depth import DEPTH_SUFFIXES, read_depth_cloud
    from .colours import depth_point_colours, read_point_colours

    sensor, notes, colours = None, [], None
    if points_path.suffix.lower() in DEPTH_SUFFIXES:
        if depth is None:
            raise ValueError(f"{points_path}: a depth image is read with its camera: pass "
                             "--camera CAM.json (K, width, height) and, unless it is in "
                             "millimetres, --depth-scale")
        raw_points, sensor, note = read_depth_cloud(points_path, depth)
        raw_normals, units, notes = None, "m", [note]
        if depth.colour is not None:
            colours = depth_point_colours(raw_points, depth, depth.colour)
    else:
        if depth is not None:
            raise ValueError(f"{points_path}: --camera, --depth-scale and --mask are for a depth "
                             f"image ({', '.join(DEPTH_SUFFIXES)}), not a point cloud")
        raw_points, raw_normals = read_point_cloud(points_path)
        try:
            colours = read_point_colours(points_path, len(raw_points))
        except ValueError as error:  # colours are an extra: the points are fitted without them
            notes.append(f"its colours were not read ({str(error).split(': ', 1)[-1]}); "
                         "the points are fitted without them")
    try:
        cloud = prepare_point_cloud(raw_points, raw_normals, colors=colours, units=units,
                                    seed=config.seed, min_points=config.min_points,
                                    name=str(points_path))
    except ValueError as error:
        large = "too large" in str(error)
        if sensor is None or not (large or "too small" in str(error)):
            raise
        reach = f"{points_path}: the depth image's points reach " \
                f"{np.ptp(raw_points, axis=0).max():.3g} m"
        if large and depth.mask is None:
            raise ValueError(f"{reach} (the room behind the hand): pass --mask MASK.png with "
                             "the hand's pixels") from None
        raise ValueError(f"{reach}{' inside the mask' if depth.mask is not None else ''}, no "
                         f"hand's size: check --depth-scale, the metres per unit of the image's "
                         f"values (now {depth.scale_m:g}; 0.001 for millimetres)") from None
    cloud.notes[:0] = notes
    if hand is not None:
        cloud = _one_hand(cloud, hand, config.seed, str(points_path), support is not None)
    for note in cloud.notes:
        log(f"{points_path}: {note}")
    return cloud, sensor


def count_hands(points_path: str | os.PathLike, units: str = "auto", config=None,
                depth=None, support: str | None = "auto") -> int:
    """How many hands the cloud in ``points_path`` (a depth image with ``depth``, as
    :func:`lisa_hand.fitting.points.io.fit_point_file` reads it) holds apart from each other
    (:func:`lisa_hand.fitting.points.others.split_hands`; 1 when it is not split)."""
    from .fit import FitPointsConfig
    from .others import split_hands

    config = FitPointsConfig() if config is None else config
    cloud, _ = read_cloud_file(Path(points_path), units, config, None, lambda line: None, depth)
    hands = split_hands(cloud.points, seed=config.seed, support=support is not None)
    return 1 if hands is None else len(hands)


def _one_hand(cloud: PointCloud, hand: int, seed: int, name: str, support: bool = True
              ) -> PointCloud:
    """``cloud`` without the points of the hands other than ``hand`` (0: the largest), a note
    saying so; ValueError naming ``name`` when it holds fewer hands."""
    from .others import split_hands

    if isinstance(hand, bool) or not isinstance(hand, int) or hand < 0:
        raise ValueError(f"hand must be an integer >= 0, got {hand!r}")
    hands = split_hands(cloud.points, seed=seed, support=support)
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
                               colors=None if cloud.colors is None else cloud.colors[keep],
                               notes=[*cloud.notes, note])

