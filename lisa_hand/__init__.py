"""LISA-open: Learning Implicit Shape and Appearance of hands (Corona et al., CVPR 2022).

The public API, for notebooks and scripts (``docs/api.md`` has runnable examples)::

    import lisa_hand

    model = lisa_hand.load_model()                   # a shipped model, by name or path
    fit = lisa_hand.fit_points(cloud)                # [N, 3] array or a point-cloud file
    mesh = lisa_hand.mesh_hand(fit.params)           # vertices, faces, colours, skin weights
    images = lisa_hand.render_hand(fit.params, num_views=4)
    out = lisa_hand.evaluate_hand(points, fit.params)  # sdf, rgb, skinning weights at points

Each function does what the ``lisa`` command of the same verb does, with its defaults, but takes
arrays and returns objects instead of writing files (``fit_photo`` also writes its files). The
one hand state is :class:`HandParams` (``params.json``: :func:`read_params`,
:func:`write_params`). Names are imported on first use (PEP 562), so ``import lisa_hand`` loads
neither torch nor the optional extras.

The pipeline, one folder a layer (imports flow left to right only): ``utils`` -> ``geometry`` ->
``skeleton`` -> ``handmodel``/``data`` -> ``fields`` -> ``model`` -> ``render`` ->
``training``/``fitting``/``inference`` -> ``evaluation`` -> ``bench``/``cli``. The map is
``docs/architecture.md``.
"""

from __future__ import annotations

import importlib
import os  # loaded before any package: free

__version__ = "0.1.0"

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (2 ms, twice the package)
if TYPE_CHECKING:
    from collections.abc import Sequence

    from .fitting.images.fit import FitImagesResult
    from .fitting.images.views import ImageView
    from .fitting.photo.fit import PhotoFitReport
    from .fitting.points.fit import FitResult
    from .fitting.video.io import VideoFitReport
    from .geometry.cameras import Camera
    from .geometry.meshing import Mesh
    from .geometry.planes import Plane
    from .inference.hand_field import HandOutput
    from .model.trained import TrainedModel
    from .render.image import ImageOutput
    from .skeleton.params import HandParams, read_params, write_params

__all__ = [
    "__version__",
    "HandParams",
    "read_params",
    "write_params",
    "TrainedModel",
    "load_model",
    "HandOutput",
    "evaluate_hand",
    "fit_points",
    "fit_images",
    "fit_photo",
    "fit_video",
    "mesh_hand",
    "render_hand",
]

_LAZY = {
    "HandParams": "lisa_hand.skeleton.params",
    "read_params": "lisa_hand.skeleton.params",
    "write_params": "lisa_hand.skeleton.params",
    "TrainedModel": "lisa_hand.model.trained",
    "HandOutput": "lisa_hand.inference.hand_field",
}
"""Re-exported names -> the module that defines them, imported on first access."""


def __getattr__(name: str):
    """``lisa_hand.NAME`` for a re-exported name: its module imported on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'lisa_hand' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next access skips this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


# ---------------------------------------------------------------------------------------------
# Models and hands


def load_model(model: str | os.PathLike | TrainedModel | None = None,
               device: str = "auto") -> TrainedModel:
    """A trained LISA model.

    model: a shipped model's name: "default" (LISA-full on hand model v1: geometry and colour;
        also None), "geometry" (its geometric prior: no colour) or "geometry_v3" (the
        geometric prior of hand models v1-v3: what :func:`fit_points` takes); a file exported
        by ``python -m lisa_hand.model.trained``; a ``lisa train`` / ``lisa train-prior`` run
        folder or checkpoint; or a loaded model, returned as it is.
    device: "auto" (CUDA when available, as the commands), "cpu", "cuda" or "cuda:N".
    -> :class:`TrainedModel`: ``field`` (the :class:`lisa_hand.model.lisa.LisaModel`),
    ``shape_codes`` [S, D] and ``color_codes`` [S, D'] (None without colour) of the S training
    subjects, ``beta`` (VolSDF's, metres), ``gain`` and ``bias`` [3] (the mean colour
    calibration), ``has_color``.
    """
    from .model.trained import TrainedModel, load_trained
    from .utils.device import resolve_device

    if isinstance(model, TrainedModel):
        return model
    return load_trained(model, resolve_device(device))


def _model_label(model: TrainedModel, given) -> str:
    """What ``params.json`` records as the model: a shipped model's name (also when ``model``
    was loaded from its file), else the absolute path it came from (``given`` as loaded, or the
    model's ``source``)."""
    from pathlib import Path

    from .model.trained import SHIPPED_MODELS, TrainedModel, model_label, shipped_model_path

    if given is not None and not isinstance(given, TrainedModel):
        return model_label(given)
    for name in SHIPPED_MODELS:
        if Path(model.source) == shipped_model_path(name):
            return name
    return model.source


def _hand_and_model(hand: HandParams | str | os.PathLike, model, device: str
                    ) -> tuple[HandParams, TrainedModel]:
    """(the hand: ``hand``, or the ``params.json`` at that path; its model: ``model``, or the
    one the hand names), the hand's codes checked against the model."""
    from .inference.hand_field import check_params, resolve_model_path
    from .model.trained import TrainedModel
    from .skeleton.params import HandParams, read_params

    path = None
    if not isinstance(hand, HandParams):
        path, hand = hand, read_params(hand)
    if not isinstance(model, TrainedModel):
        model = load_model(resolve_model_path(hand, path, model), device)
    check_params(model, hand, source=None if path is None else str(path))
    return hand, model


def evaluate_hand(
    points,
    hand: HandParams | str | os.PathLike | None = None,
    *,
    model: str | os.PathLike | TrainedModel | None = None,
    pose=None,
    shape_code=None,
    color_code=None,
    translation=None,
    rest_joints=None,
    side: str | None = None,
    colors: bool = True,
    device: str = "auto",
) -> HandOutput:
    """The model as a function, smplx-style: pose, shape code, colour code and world points ->
    SDF, colour and skinning weights (paper Eq. 6-9), one field pass per 65536 points.

    points: [N, 3] world metres (numpy, torch or nested lists).
    hand: the hand to evaluate (:class:`HandParams`, or a ``params.json`` path); None: the
        model's neutral hand of ``side`` (zero pose and translation, the training subjects'
        mean shape and colour codes, the mesh template's mean skeleton, mirrored for a left
        hand).
    model: as :func:`load_model`; None: the one ``hand`` names ("default" without a hand).
    pose: [48] axis-angle radians (MANO order: global rotation, then 15 finger joints);
    shape_code: [D] (LISA's beta+); color_code: [D'] (gamma); translation: [3] metres;
    rest_joints: [16, 3] metres (the skeleton): each one given replaces the hand's, in its
        side's convention (a left hand's are the mirror image, x -> -x, of a right one's).
    side: "right" or "left": the neutral hand's side (default right), or a given hand's new
        side (its pose and skeleton then read as that side's).
    colors: also evaluate the colours. device: where a model loaded here goes.
    -> :class:`HandOutput`: ``sdf`` [N] metres (negative inside), ``rgb`` [N, 3] in [0, 1]
    (calibrated with the model's mean gain and bias; grey for a geometry-only model; None with
    ``colors=False``), ``weights`` [N, 16]; torch tensors on the model's device. Not
    differentiable: for gradients use :meth:`lisa_hand.model.lisa.LisaModel.field`.
    """
    import dataclasses

    import torch

    from .inference.hand_field import hand_field

    if hand is None:
        model = load_model(model, device)
        hand, side = _neutral_hand(model, _model_label(model, None), side or "right"), None
    hand, model = _hand_and_model(hand, model, device)
    given = {"pose": pose, "shape_code": shape_code, "color_code": color_code,
             "translation": translation, "rest_joints": rest_joints, "side": side}
    changes = {name: value for name, value in given.items() if value is not None}
    hand = dataclasses.replace(hand, **changes) if changes else hand
    field = model.field
    query = torch.as_tensor(points, dtype=field.dtype, device=field.device)
    if query.dim() != 2 or query.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3] (metres), got {list(query.shape)}")
    return hand_field(model, hand).evaluate(query, colors=colors)


def _neutral_hand(model: TrainedModel, label: str, side: str) -> HandParams:
    """The ``side`` hand at rest of ``model``: zero pose and translation, the mean shape and
    colour codes, the mesh template's mean skeleton (where the fits start; mirrored, x -> -x,
    for a left hand)."""
    import torch

    from .handmodel.template import load_template
    from .skeleton import check_side, mirror_points
    from .skeleton.params import HandParams

    template = load_template()
    betas = torch.zeros(template.num_betas, dtype=torch.float64)
    rest_joints = template.rest_joints(betas)[0].float()
    color = model.mean_color_code()
    return HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                      rest_joints=mirror_points(rest_joints) if check_side(side) == "left"
                      else rest_joints,
                      shape_code=model.mean_shape_code().cpu(),
                      color_code=None if color is None else color.cpu(), betas=betas.float(),
                      side=side, model=label)


# ---------------------------------------------------------------------------------------------
# Fitting


def _config(config_type, config, settings: dict):
    """``config`` (default: ``config_type()``) with the fields ``settings`` names replaced
    (TypeError naming an unknown one)."""
    import dataclasses

    config = config_type() if config is None else config
    if not isinstance(config, config_type):
        raise TypeError(f"config must be a {config_type.__name__}, got {type(config).__name__}")
    from .utils.config import renamed_field

    unknown = sorted(set(settings) - {field.name for field in dataclasses.fields(config_type)})
    if unknown:
        named = [name if renamed_field(config_type, name) is None
                 else f"{name} (now {renamed_field(config_type, name)})" for name in unknown]
        raise TypeError(f"unknown {config_type.__name__} setting(s): {', '.join(named)}")
    return dataclasses.replace(config, **settings) if settings else config


def fit_points(
    points,
    *,
    normals=None,
    model: str | os.PathLike | TrainedModel | None = None,
    units: str = "auto",
    side: str = "auto",
    viewpoint="auto",
    support: str | None = "auto",
    others: str | None = "auto",
    config=None,
    device: str = "auto",
    progress: bool = False,
    **settings,
) -> FitResult:
    """Fit LISA to a point cloud of one hand (paper Section 4.3), as ``lisa fit-points`` does:
    any position and orientation, partial or full, noise and outliers.

    points: [N, 3] in ``units`` (numpy, torch or nested lists), or a point-cloud or mesh file
        (PLY, OBJ, XYZ, NPY, NPZ, STL, OFF, GLB, GLTF; its normals are used). Depth images:
        ``lisa fit-points --camera``.
    normals: [N, 3] outward normals of an array cloud, or None.
    model: as :func:`load_model`; None: the command's default (the geometric prior
        "geometry_v3").
    units: "auto" (from the hand's size), "m", "cm" or "mm".
    side: "auto" (fitted as both, the nearer kept: twice the time), "right" or "left".
    viewpoint: the sensor of a one-view scan, [3] in ``units``; "auto" (found when the scan
        looks like one view) or None.
    support, others: "auto" (a desk or wall the hand rests on, and pieces of the scan apart
        from the hand, are found and left out) or None.
    config: a :class:`lisa_hand.fitting.points.config.FitPointsConfig` (default: its defaults,
        as the command's); settings: its fields to replace, e.g. ``field_iters=100``, ``seed=1``,
        ``tries=2``.
    device: where a model loaded here goes. progress: show a progress bar.
    -> :class:`lisa_hand.fitting.points.fit.FitResult`: ``params`` (the fitted
    :class:`HandParams`, world metres, ``model`` naming the model), ``residual_median_mm``,
    ``wrist_plane`` (where the command's mesh ends: :func:`mesh_hand`'s ``clip``), timings.
    """
    import numpy as np

    from .fitting.points.analysis import analyse_scan
    from .fitting.points.config import FitPointsConfig
    from .fitting.points.fit import fit_points as fit_cloud
    from .fitting.points.io import default_point_model, prepare_point_cloud, read_point_cloud

    config = _config(FitPointsConfig, config, settings)
    source = "array"
    if isinstance(points, (str, os.PathLike)):
        source, (points, file_normals) = str(points), read_point_cloud(points)
        normals = file_normals if normals is None else normals
    else:
        points = _numpy(points)
        normals = None if normals is None else _numpy(normals)
    cloud = prepare_point_cloud(points, normals, units=units, seed=config.seed,
                                name="points" if source == "array" else source)
    view = viewpoint
    if viewpoint is not None and not isinstance(viewpoint, str):
        view = _numpy(viewpoint).astype(np.float64) * _metres_per(cloud.unit)
    analysis = analyse_scan(cloud.points, viewpoint=view, support=support, others=others,
                            config=config.analysis, seed=config.seed)
    given = default_point_model() if model is None else model
    loaded = load_model(given, device)
    fit = fit_cloud(loaded, cloud.points, cloud.normals, config, side=side, analysis=analysis,
                    progress=progress)
    fit.params.model = _model_label(loaded, given)
    fit.params.extra["input"] = {"path": source, "unit": cloud.unit,
                                 "num_input_points": cloud.num_input, "notes": cloud.notes}
    return fit


def _numpy(values):
    """A numpy array of an array-like (a torch tensor on any device included)."""
    import numpy as np

    if hasattr(values, "detach"):
        values = values.detach().cpu().numpy()
    return np.asarray(values)


def _metres_per(unit: str) -> float:
    from .data.units import LENGTH_UNITS

    return LENGTH_UNITS[unit]


def fit_images(
    frame: str | os.PathLike | Sequence[ImageView],
    *,
    views: Sequence[str] | None = None,
    model: str | os.PathLike | TrainedModel | None = None,
    side: str = "right",
    config=None,
    device: str = "auto",
    progress: bool = False,
    **settings,
) -> FitImagesResult:
    """Fit LISA to 1..N calibrated views (paper Section 4.3), as ``lisa fit-images`` does: the
    pose from 2D keypoints and masks on the mesh template, then pose, shape and colour codes by
    volume rendering, the surface guarded.

    frame: a frame folder (``cameras.json``, ``images/NAME.png``, optional ``masks/NAME.png``
        and ``keypoints.json``: what ``lisa synth`` writes), or a list of
        :class:`lisa_hand.fitting.images.views.ImageView` (image [H, W, 3] in [0, 1], mask
        [H, W], keypoints [21, 2] pixels, camera).
    views: camera names of the folder to use (default: all).
    model: as :func:`load_model`; None: "default" (a model with colour: the colour stage needs
        one; a geometric prior only with ``color_iters=0``).
    side: "right" or "left" (the hand the views show).
    config: a :class:`lisa_hand.fitting.images.config.FitImagesConfig` (default: its defaults,
        as the command's); settings: its fields to replace, e.g. ``keypoint_iters=200``,
        ``color_iters=0``, ``num_rays=256``.
    device: where a model loaded here goes. progress: show progress bars.
    -> :class:`lisa_hand.fitting.images.fit.FitImagesResult`: ``params`` (the fitted
    :class:`HandParams`, in the cameras' world frame, metres), ``keypoint_error_px``, ``guard``,
    ``notes``, timings.
    """
    from .fitting.images.config import FitImagesConfig
    from .fitting.images.fit import fit_images as fit_views
    from .fitting.images.views import read_views

    config = _config(FitImagesConfig, config, settings)
    if isinstance(frame, (str, os.PathLike)):
        frame = read_views(frame, views)
    elif views is not None:
        raise ValueError("views selects cameras of a frame folder; pass the ImageViews wanted")
    loaded = load_model(model, device)
    fit = fit_views(loaded, frame, config, progress, side=side)
    fit.params.model = _model_label(loaded, model)
    return fit


def fit_photo(
    photos: str | os.PathLike | Sequence[str | os.PathLike],
    out: str | os.PathLike | None = None,
    *,
    side: str = "auto",
    keypoints=None,
    camera=None,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    mask=None,
    hand: int | None = None,
    model: str | os.PathLike | None = None,
    device: str = "auto",
    progress: bool = False,
    log=None,
    **settings,
) -> list[PhotoFitReport]:
    """Fit LISA to uncalibrated photos of a hand, as ``lisa fit-photo`` does, and write its files
    (``params.json``, ``mesh.ply``, ``keypoints.json``, ``camera.json``, ``mask.png``,
    ``overlay.png``, ``report.html``, ``metrics.json``) into ``out``.

    photos: one photo (JPEG, PNG, ...; EXIF orientation applied) or several of one hand in one
        pose. out: the output folder (new or empty); None: a new temporary folder (kept; each
        report's ``folder``).
    side: "auto" (the detector's side, else both tried), "right" or "left".
    keypoints: a ``--keypoints`` JSON file (21 keypoints in the original photo's pixels,
        OpenPose order), one for all photos or a list, instead of detection (which needs
        MediaPipe: ``pip install -e '.[photo]'``).
    camera: a calibrated ``cameras.json``-style file (one, or a list per photo); focal_px: focal
        length in the original photo's pixels; fov_deg: field of view along its long side,
        degrees (default: EXIF, else 67). mask: a mask file per photo (white = hand), or None.
    hand: fit only hand N (0 = leftmost) of a photo of several; None: every hand.
    model: as :func:`load_model` (a name or path); None: "default".
    settings: fields of :class:`lisa_hand.fitting.images.config.FitImagesConfig` (the photo
        defaults: :func:`lisa_hand.fitting.photo.config.photo_fit_defaults`, e.g.
        ``color_iters=0``) or of :class:`lisa_hand.fitting.photo.config.FitPhotoConfig` (e.g.
        ``mesh_resolution=96``).
    log: called with one line per step (None: silent). device, progress: as :func:`fit_points`.
    -> one :class:`lisa_hand.fitting.photo.fit.PhotoFitReport` per hand: ``params`` (frame:
    the first photo's camera, metres), ``keypoint_error_px``, ``folder``, ``written``,
    ``notes``.
    """
    import dataclasses
    import tempfile

    from .fitting.images.config import FitImagesConfig
    from .fitting.photo.config import FitPhotoConfig, photo_fit_defaults
    from .fitting.photo.fit import fit_photo_folder

    image_fields = {field.name for field in dataclasses.fields(FitImagesConfig)}
    photo_settings = {k: v for k, v in settings.items() if k not in image_fields}
    fit = photo_fit_defaults(**{k: v for k, v in settings.items() if k in image_fields})
    config = _config(FitPhotoConfig, FitPhotoConfig(fit=fit), photo_settings)
    if out is None:
        out = tempfile.mkdtemp(prefix="lisa-fit-photo-")
    return fit_photo_folder(photos, out, side=side, camera_json=camera, focal_px=focal_px,
                            fov_deg=fov_deg, keypoints_json=keypoints, mask_path=mask,
                            hand=hand, model_path=model, device=device, progress=progress,
                            log=log, config=config)


def fit_video(
    video: str | os.PathLike,
    out: str | os.PathLike | None = None,
    *,
    side: str = "auto",
    camera=None,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    stride: int = 1,
    fps: float | None = None,
    model: str | os.PathLike | None = None,
    device: str = "auto",
    progress: bool = False,
    log=None,
    **settings,
) -> VideoFitReport:
    """Fit LISA through a video clip, as ``lisa fit-video`` does, and write its files
    (``params.json``, ``mesh.ply``, ``hand.glb``, ``track.json``, ``overlay.mp4``,
    ``report.html``, ``metrics.json``) into ``out``.

    video: a video file (MP4, MOV, WebM, AVI...) or a folder of frames. out: the output folder
        (new or empty); None: a new temporary folder (kept; the report's ``folder``).
    side: "auto" (each hand's detected side), "right" or "left". camera, focal_px (the clip's
        pixels), fov_deg (along its long side): the camera, as :func:`fit_photo`'s.
    start_s, end_s: the part of the clip, seconds; stride: every n-th frame; fps: a frame
        folder's rate (default 30).
    settings: fields of :class:`lisa_hand.fitting.video.config.FitVideoConfig` (e.g.
        ``independent=True``: every frame fitted alone).
    model, device, progress, log: as :func:`fit_photo`.
    -> :class:`lisa_hand.fitting.video.io.VideoFitReport`: ``fit.hands`` (each hand's
    ``params``, ``motion.pose`` [N, 48], ``motion.translation`` [N, 3] m,
    ``motion.keypoints_3d`` [N, 21, 3] m in the camera frame, ``keypoints_2d`` [N, 21, 2] px),
    ``metrics``, ``seconds``, ``written``. Needs the photo extra (MediaPipe, OpenCV).
    """
    import tempfile

    from .fitting.video import FitVideoConfig, fit_video_folder

    config = _config(FitVideoConfig, FitVideoConfig(), settings)
    if out is None:
        out = tempfile.mkdtemp(prefix="lisa-fit-video-")
    return fit_video_folder(video, out, camera_json=camera, focal_px=focal_px,
                            fov_deg=fov_deg, side=side, start_s=start_s, end_s=end_s,
                            stride=stride, fps=fps, model_path=model, device=device,
                            progress=progress, log=log, config=config)


# ---------------------------------------------------------------------------------------------
# Meshes and images of a hand


def mesh_hand(
    hand: HandParams | str | os.PathLike,
    *,
    model: str | os.PathLike | TrainedModel | None = None,
    resolution: int = 128,
    clip: Plane | None = None,
    colors: bool = True,
    skin_weights: bool = True,
    keep_specks: bool = False,
    padding: float = 0.03,
    device: str = "auto",
) -> Mesh:
    """The hand's surface as a triangle mesh, as ``lisa mesh`` makes it: marching cubes coarse
    to fine (full resolution only near the surface), per-vertex colours and skinning weights
    (dense correspondences across poses and subjects).

    hand: a :class:`HandParams` or a ``params.json`` path. model: as :func:`load_model`; None:
        the one the hand names. resolution: grid samples along each side of the cube around the
        hand (>= 8; 128: about 1.7 mm voxels).
    clip: a :class:`lisa_hand.geometry.planes.Plane` the surface is cut along (a point fit's
        ``wrist_plane``: where ``lisa fit-points``' mesh ends), or None.
    colors, skin_weights: attach them. keep_specks: keep the pieces smaller than 0.1 % of the
        surface that marching cubes leaves where the field dips below zero away from the hand
        (removed by default, as the command does). padding: metres around the posed skeleton's
        box. device: where a model loaded here goes.
    -> :class:`lisa_hand.geometry.meshing.Mesh`: ``vertices`` [V, 3] float32 world metres,
    ``faces`` [F, 3] int64 (outward), ``colors`` [V, 3] uint8 or None, ``skin_weights``
    [V, 16] float32 (rows sum to 1) or None.
    """
    from .geometry.pieces import MIN_PIECE_FRACTION, drop_specks
    from .inference.mesh import MeshConfig, check_resolution
    from .inference.mesh import mesh_hand as extract

    hand, model = _hand_and_model(hand, model, device)
    config = MeshConfig(padding=padding, colors=colors, skin_weights=skin_weights)
    mesh = extract(model, hand, check_resolution(resolution), config, clip=clip)
    return drop_specks(mesh, 0.0 if keep_specks else MIN_PIECE_FRACTION)[0]


_BACKGROUNDS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}


def render_hand(
    hand: HandParams | str | os.PathLike,
    cameras: str | os.PathLike | Sequence[Camera] | None = None,
    *,
    model: str | os.PathLike | TrainedModel | None = None,
    num_views: int = 1,
    width: int | None = None,
    height: int | None = None,
    elevation_deg: float = 15.0,
    fov_deg: float = 30.0,
    mode: str = "volume",
    background: str | tuple[float, float, float] = "black",
    normals: bool = True,
    device: str = "auto",
) -> list[ImageOutput]:
    """Images of the hand, as ``lisa render`` makes them: volume rendered (VolSDF, what LISA
    renders) or sphere traced, colours calibrated with the model's mean gain and bias, one
    occupancy grid shared by the views.

    hand: a :class:`HandParams` or a ``params.json`` path. model: as :func:`load_model`; None:
        the one the hand names.
    cameras: a ``cameras.json`` path or a list of :class:`lisa_hand.geometry.cameras.Camera`
        (OpenCV convention, world metres); None: ``num_views`` cameras on a circle around the
        hand's finger axis, the first facing the palm (``elevation_deg`` above it, horizontal
        field of view ``fov_deg``, degrees).
    width, height: pixels (default 512 x 512 on the circle, the cameras' own size otherwise,
        their intrinsics scaled when given).
    mode: "volume" or "surface". background: "black", "white" or RGB in [0, 1].
    normals: also the normal maps. device: where a model loaded here goes.
    -> one :class:`lisa_hand.render.image.ImageOutput` per camera: ``rgb`` [H, W, 3] in [0, 1],
    ``opacity`` [H, W], ``depth`` [H, W] metres along the ray, ``normals`` [H, W, 3] world,
    ``mask`` [H, W] bool (torch tensors on the model's device).
    """
    from .geometry.cameras import load_cameras
    from .inference.render import hand_render_config, orbit_views, prepare_render, scale_camera

    hand, model = _hand_and_model(hand, model, device)
    if mode not in ("volume", "surface"):
        raise ValueError(f"mode must be 'volume' or 'surface', got {mode!r}")
    background = _BACKGROUNDS.get(background, background) if isinstance(background, str) \
        else background
    if isinstance(background, str) or len(background) != 3:
        raise ValueError(f"background must be 'black', 'white' or 3 numbers in [0, 1], got "
                         f"{background!r}")
    config = hand_render_config(model, mode=mode, background=tuple(map(float, background)),
                                normals="autograd" if normals else "none")
    scene = prepare_render(model, hand, config)
    if cameras is None:
        if isinstance(num_views, bool) or not isinstance(num_views, int) or num_views < 1:
            raise ValueError(f"num_views must be an int >= 1, got {num_views!r}")
        cameras = orbit_views(scene, num_views, width or 512, height or 512,
                              elevation_deg=elevation_deg, fov_deg=fov_deg)
    else:
        cameras = load_cameras(cameras) if isinstance(cameras, (str, os.PathLike)) \
            else list(cameras)
        if width is not None or height is not None:
            cameras = [scale_camera(camera, width or camera.width, height or camera.height)
                       for camera in cameras]
    if not cameras:
        raise ValueError("cameras must not be empty")
    return [scene.render(camera) for camera in cameras]
