"""What ``lisa fit-photo`` writes: each fitted hand's files as artefacts of the one writer
(:func:`photo_artefacts`, written all or nothing by :func:`lisa_hand.fitting.outputs.write_fit`).

One fitted hand's folder (``DIR``, or ``DIR/handN`` when a photo holds several hands and no
``--hand`` was given):

* ``params.json``: the hand (:mod:`lisa_hand.skeleton.params`), in the frame of the (first)
  photo's camera (OpenCV: x right, y down, z forward, metres);
* ``mesh.ply``: its surface with vertex colours and skinning weights
  (:func:`lisa_hand.inference.mesh_hand`), same frame, cut ``FitPhotoConfig.wrist_clip_m`` past
  the fitted wrist, without specks (:func:`lisa_hand.geometry.pieces.drop_specks`; what was
  removed in ``metrics.json``'s ``"specks_removed"``);
* ``keypoints.json`` (:func:`keypoints_record`): ``"names"`` the 21 keypoint names in OpenPose
  order, ``"keypoints_2d_detected"`` [21, 2] (what the fit was given: detected, or ``--keypoints``;
  with ``FitPhotoConfig.detector_wrist_shift`` the detected wrist moved, and the detector's own
  keypoints kept as ``"keypoints_2d_detector"``) and ``"keypoints_2d_fitted"`` [21, 2] (the fitted
  hand's keypoints projected) in pixels of the ORIGINAL photo (upright, full size, continuous
  coordinates: pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)``), ``"visible"`` [21],
  ``"keypoints_3d"`` [21, 3] metres in the photo's camera frame, ``"side"``, ``"photo"``,
  ``"image_size"`` (W, H of the original photo), ``"keypoint_error_px"`` (the mean distance between
  the two sets of 2D keypoints over the visible ones, original pixels), ``"frame"`` (``"camera"``),
  ``"units"`` (:data:`UNITS`, in words) and, when the fit had them, ``"landmarks_3d"`` [21, 3]
  (the detector's 3D landmarks, metres, camera axes). ``lisa fit-photo --keypoints`` reads this
  file back (its detected keypoints, side and landmarks: the same fit again).
* ``camera.json``: the camera used (:func:`lisa_hand.data.photo.save_camera`: at the fitted
  image's size and at the original photo's, with its source);
* ``mask.png``: the hand's mask at the original photo's size (white: hand);
* ``overlay.png``: photo | fitted hand over the photo | keypoints given and fitted
  (:func:`lisa_hand.fitting.photo.report.overlay_image`);
* ``report.html``: one self-contained page with the pictures and the numbers;
* ``metrics.json``: the numbers of the report: per photo the keypoint errors (original pixels),
  the camera and its focal length, the wrist's distance, how well the fitted hand matches the
  photo (``"silhouette_iou"``: its silhouette against the mask the fit started from,
  ``"psnr_in_mask_db"``: its colours against the photo's inside both; :func:`agreement`); the
  geometry guard of the fit
  (``"guard"``) and the same figures for the written ``mesh.ply`` (``"surface"``), where the side
  and the mask came from, timings, notes.

Several photos of one hand: ``params.json``, ``mesh.ply``, ``metrics.json``, ``report.html``
and ``keypoints.json`` as above (the frame: the first photo's camera; ``keypoints.json`` holds
the first photo's keys and a ``"photos"`` list with every photo's, each ``keypoints_3d`` in
that photo's camera frame), ``cameras.json`` (every photo's camera in that frame, the
``cameras.json`` convention, at the original photos' sizes), and ``photoK/`` per photo with its
``camera.json``, ``mask.png``, ``overlay.png`` and ``keypoints.json``.

The whole ``DIR`` is staged beside itself and moved into place once every file of every hand
is written (:func:`lisa_hand.fitting.outputs.write_fit`); a reused ``DIR`` must hold only what a
previous photo fit wrote (:func:`photo_entry`, :data:`PHOTO_DESCRIBED`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera
from ...geometry.meshing import Mesh
from ...skeleton import KEYPOINT_NAMES
from ...skeleton.params import HandParams
from ..outputs import (
    Artefact,
    image_artefact,
    json_artefact,
    json_safe,
    mask_artefact,
    mesh_artefact,
    params_artefact,
    text_artefact,
)

__all__ = ["PHOTO_FILES", "PHOTO_DESCRIBED", "PhotoOfHand", "PhotoViewOutputs",
           "PhotoHandOutputs", "photo_entry", "build_hand_outputs", "photo_report_html",
           "keypoints_record", "photo_artefacts", "agreement"]

PHOTO_FILES = ("params.json", "mesh.ply", "keypoints.json", "camera.json", "cameras.json",
               "mask.png", "overlay.png", "report.html", "metrics.json", "hands.json",
               "hands.ply")
"""The files a photo fit writes into a hand's folder (or a ``photoK/`` folder)."""
_FOLDER = re.compile(r"(hand|photo)\d+")
PHOTO_DESCRIBED = ", ".join(PHOTO_FILES) + " and hand0/, photo0/, ... folders"
"""How a refused output folder's error names what a photo fit leaves."""
UNITS = {"keypoints_2d": "pixels of the original photo (upright, full size; continuous "
                         "coordinates: pixel (col, row) covers [col, col + 1) x [row, row + 1))",
         "keypoints_3d": "metres in the photo's camera frame (OpenCV: x right, y down, "
                         "z forward)"}
"""The ``"units"`` of a photo fit's ``keypoints.json``."""


def photo_entry(path: Path) -> bool:
    """Whether ``path``, an entry of an output folder, is what a photo fit writes: a file of
    :data:`PHOTO_FILES`, or a ``handN`` / ``photoN`` folder holding only such entries."""
    if path.is_symlink():
        return False
    if path.is_file():
        return path.name in PHOTO_FILES
    if path.is_dir() and _FOLDER.fullmatch(path.name):
        return all(photo_entry(entry) for entry in path.iterdir())
    return False


@dataclass
class PhotoViewOutputs:
    """One photo of a fitted hand, as written.

    photo: the photo's file. original_size: (W, H) of the original (upright) photo, pixels.
    camera: its camera at the fitted image's size (:func:`lisa_hand.data.photo.photo_camera`;
    R, t: world to this camera, the identity for the first photo). camera_source: where it came
    from. detected_px, fitted_px: [21, 2] original pixels (the given keypoints; the fitted
    hand's projected). visible: [21] bool (the given keypoints that counted).
    keypoints_3d: [21, 3] metres in this photo's camera frame. mask: [H, W] bool at the
    original size. overlay: [h, w, 3] uint8 (:func:`lisa_hand.fitting.photo.report.overlay_image`).
    keypoint_error_px: mean distance (original pixels) of the visible keypoints.
    detector_px: [21, 2] original pixels, the detector's own keypoints when the fit was given
    them changed (its wrist moved to the skeleton's), else None. landmarks_3d: [21, 3] metres,
    the detector's 3D landmarks the fit was given (camera axes), else None.
    silhouette_iou, psnr_db: how well the fitted hand matches the photo (:func:`agreement`).
    """

    photo: Path
    original_size: tuple[int, int]
    camera: Camera
    camera_source: str
    detected_px: np.ndarray
    fitted_px: np.ndarray
    visible: np.ndarray
    keypoints_3d: np.ndarray
    mask: np.ndarray
    overlay: np.ndarray
    keypoint_error_px: float
    detector_px: np.ndarray | None = None
    landmarks_3d: np.ndarray | None = None
    silhouette_iou: float = float("nan")
    psnr_db: float = float("nan")


@dataclass
class PhotoHandOutputs:
    """One fitted hand, as written into ``folder`` ("" for ``DIR`` itself, else ``handN``).

    params: the hand (world = the first photo's camera frame). mesh: its surface (colours,
    skinning weights). views: one per photo. metrics: what ``metrics.json`` holds. report:
    the text of ``report.html``.
    """

    folder: str
    params: HandParams
    mesh: Mesh
    views: list[PhotoViewOutputs]
    metrics: dict[str, Any]
    report: str
    notes: list[str] = field(default_factory=list)


@dataclass
class PhotoOfHand:
    """One photo of a fitted hand, as the fit saw it.

    photo: the :class:`lisa_hand.data.photo.Photo`. camera: its camera at ``photo.image``'s
    size (:func:`lisa_hand.data.photo.photo_camera`, R = I). camera_source: where it came from.
    hand: the :class:`lisa_hand.fitting.photo.inputs.PhotoHand` given to the fit. crop: the
    :class:`lisa_hand.fitting.photo.inputs.CropView` the fit saw (its camera's R, t: world to
    this photo's camera). coarse: [H, W] bool, the mask before the fit (``photo.image``'s size).
    refine: refine it with the fitted hand's silhouette
    (:func:`lisa_hand.fitting.photo.mask.refine_mask`); False for a given ``--mask``, which is
    written as it is.
    """

    photo: Any
    camera: Camera
    camera_source: str
    hand: Any
    crop: Any
    coarse: np.ndarray
    refine: bool = True


def _project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixels [N, 2], camera-frame points [N, 3]) of world points [N, 3] (float64)."""
    rotation = camera.R.double().cpu().numpy()
    shift = camera.t.double().cpu().numpy()
    in_camera = points @ rotation.T + shift
    projected = in_camera @ camera.K.double().cpu().numpy().T
    return projected[:, :2] / projected[:, 2:3], in_camera


def _render_crop(model: Any, mesh: Any, view: Any, supersample: int, max_side: int) -> Any:
    """The fitted hand's mesh rendered into a crop's view at most ``max_side`` pixels a side
    (:func:`lisa_hand.inference.mesh_render.render_mesh`)."""
    from ...inference import scale_camera
    from ...inference.mesh_render import render_mesh

    camera = view.camera
    factor = min(1.0, max_side / max(view.width, view.height))
    if factor < 1.0:
        camera = scale_camera(camera, max(int(round(view.width * factor)), 1),
                              max(int(round(view.height * factor)), 1))
    return render_mesh(model, mesh, camera, supersample)


def _view_outputs(model: Any, mesh: Any, keypoints_world: np.ndarray, item: PhotoOfHand,
                  supersample: int, max_side: int) -> PhotoViewOutputs:
    """Render the fitted hand's mesh into one photo's crop; its mask, keypoints and overlay."""
    from .mask import refine_mask, resize_array
    from .report import overlay_image

    photo, crop = item.photo, item.crop
    render = _render_crop(model, mesh, crop.view, supersample, max_side)
    alpha, rgb = render.alpha, render.rgb
    x0, y0, x1, y1 = crop.box
    silhouette = np.zeros(photo.image.shape[:2], dtype=bool)
    silhouette[y0:y1, x0:x1] = resize_array(alpha > 0.5, (x1 - x0, y1 - y0))
    refined = (refine_mask(photo.image, item.coarse, silhouette) if item.refine
               else item.coarse)
    width, height = photo.original_size
    factors = np.array([photo.image.shape[1] / width, photo.image.shape[0] / height])
    camera = Camera(K=item.camera.K, R=crop.view.camera.R.cpu(), t=crop.view.camera.t.cpu(),
                    width=item.camera.width, height=item.camera.height, name=item.camera.name)
    fitted, in_camera = _project(camera, keypoints_world)
    visible = np.asarray(item.hand.visible, dtype=bool)
    error = np.linalg.norm((fitted - item.hand.keypoints) / factors, axis=1)[visible]
    overlay = overlay_image(photo.image[y0:y1, x0:x1], rgb, alpha,
                            item.hand.keypoints - [x0, y0], fitted - [x0, y0])
    iou, psnr = agreement(photo.image[y0:y1, x0:x1], item.coarse[y0:y1, x0:x1], rgb, alpha)
    return PhotoViewOutputs(
        photo=photo.path, original_size=(int(width), int(height)), camera=camera,
        camera_source=item.camera_source, detected_px=item.hand.keypoints / factors,
        fitted_px=fitted / factors, visible=visible, keypoints_3d=in_camera,
        mask=resize_array(refined, (int(width), int(height))), overlay=overlay,
        keypoint_error_px=float(error.mean()),
        detector_px=(None if item.hand.detector_keypoints is None
                     else item.hand.detector_keypoints / factors),
        landmarks_3d=item.hand.landmarks_3d, silhouette_iou=iou, psnr_db=psnr)


def agreement(photo: np.ndarray, mask: np.ndarray, rgb: np.ndarray,
              alpha: np.ndarray) -> tuple[float, float]:
    """How well a fitted hand's render matches the photo it was fitted to: (the intersection
    over union of its silhouette, alpha > 0.5, and the mask the fit started from, which the
    fitted hand did not shape; the PSNR in dB of its colours against the photo's where both are
    the hand). photo: [H, W, 3] float in [0, 1]; mask: [H, W] bool; rgb: [h, w, 3] colour times
    alpha (over black) and alpha: [h, w], the render (:func:`_render_crop`), the photo and the
    mask resized to it. NaN PSNR where they share no pixel."""
    from .mask import resize_array

    height, width = alpha.shape
    seen = alpha > 0.5
    hand = resize_array(mask, (width, height))
    image = resize_array(np.clip(photo * 255.0 + 0.5, 0, 255).astype(np.uint8),
                         (width, height)).astype(np.float64) / 255.0
    union = int((seen | hand).sum())
    both = seen & hand
    iou = float(both.sum()) / union if union else float("nan")
    if not both.any():
        return iou, float("nan")
    colour = rgb[both].astype(np.float64) / alpha[both, None]
    error = float(np.mean((np.clip(colour, 0.0, 1.0) - image[both]) ** 2))
    return iou, 10.0 * math.log10(1.0 / max(error, 1e-10))


def build_hand_outputs(model: Any, params: HandParams, photos: Sequence[PhotoOfHand],
                       folder: str, mesh: Any, render_supersample: int,
                       render_max_side: int) -> PhotoHandOutputs:
    """Everything a fitted hand's folder holds, in memory: ``mesh`` (the hand's
    :func:`lisa_hand.inference.mesh_hand`: colours, skinning weights), per photo the mesh's
    render (``render_supersample`` rays a pixel side, at most ``render_max_side`` pixels a side),
    refined mask, keypoints and overlay, and the per-photo metrics (``report`` is left empty:
    :func:`photo_report_html`, once the metrics are complete)."""
    from ..outputs import hand_keypoints_3d

    keypoints_world = hand_keypoints_3d(params)
    views = [_view_outputs(model, mesh, keypoints_world, item, render_supersample,
                           render_max_side) for item in photos]
    per_photo = []
    for view in views:
        focal = float(view.camera.K[0, 0]) * view.original_size[0] / view.camera.width
        distances = np.linalg.norm(view.fitted_px - view.detected_px, axis=1)[view.visible]
        per_photo.append({
            "photo": str(view.photo), "image_size": list(view.original_size),
            "camera_source": view.camera_source, "focal_px": focal,
            "keypoint_error_px": view.keypoint_error_px,
            "keypoint_error_px_max": float(distances.max()),
            "wrist_distance_m": float(np.linalg.norm(view.keypoints_3d[0])),
            "wrist_depth_m": float(view.keypoints_3d[0, 2]),
            "mask_fraction": float(view.mask.mean()),
            "silhouette_iou": view.silhouette_iou, "psnr_in_mask_db": view.psnr_db})
    metrics = {"photos": [str(view.photo) for view in views], "side": params.side,
               "keypoint_error_px": float(np.mean([v.keypoint_error_px for v in views])),
               "per_photo": per_photo}
    return PhotoHandOutputs(folder=folder, params=params, mesh=mesh, views=views,
                            metrics=metrics, report="")


def photo_report_html(hand: PhotoHandOutputs, notes: Sequence[str]) -> str:
    """The text of a hand's ``report.html`` (:func:`lisa_hand.fitting.photo.report.report_html`):
    a section per photo with its overlay, mask and numbers; the guard and the notes in the
    first."""
    from .mask import resize_array
    from .report import PANEL_MAX_SIDE, png_bytes, report_html

    metrics = hand.metrics
    sections = []
    for index, (view, numbers) in enumerate(zip(hand.views, metrics["per_photo"],
                                                strict=True)):
        rows = {"photo": view.photo.name, "size (original, px)": "x".join(
                    map(str, view.original_size)),
                "camera": f"{view.camera_source}, focal length {numbers['focal_px']:.1f} px",
                "side": f"{hand.params.side} ({metrics.get('side_source', 'n/a')})",
                "keypoint error (px, mean / max)": f"{numbers['keypoint_error_px']:.2f} / "
                                                   f"{numbers['keypoint_error_px_max']:.2f}",
                "wrist distance (m)": numbers["wrist_distance_m"],
                "mask": f"{metrics.get('mask', 'n/a')}, {100 * numbers['mask_fraction']:.1f} % "
                        "of the photo",
                "fit against the photo (silhouette IoU with the first mask / PSNR in it)":
                    f"{numbers['silhouette_iou']:.3f} / {numbers['psnr_in_mask_db']:.2f} dB"}
        surface = metrics.get("surface")
        if index == 0 and surface:
            rows["mesh.ply surface"] = (f"{surface['pieces']} piece(s), area "
                                        f"{surface['area_ratio']:.3f} x the keypoint-stage "
                                        "hand's")
        if index == 0:
            rows.update({"seconds (hand)": metrics.get("seconds"),
                         "seconds (keypoint stage / colour stage)":
                             f"{metrics.get('seconds_keypoints') or math.nan:.1f} / "
                             f"{metrics.get('seconds_color') or math.nan:.1f}"})
        guard = metrics.get("guard") if index == 0 else None
        if isinstance(guard, dict):
            guard = {key: guard[key] for key in ("passed", "pieces", "area_ratio", "fallback",
                                                 "notes") if key in guard}
        shrink = min(1.0, PANEL_MAX_SIDE / max(view.mask.shape))
        small = resize_array(view.mask, (max(int(view.mask.shape[1] * shrink), 1),
                                         max(int(view.mask.shape[0] * shrink), 1)))
        sections.append({"heading": view.photo.name, "overlay": png_bytes(view.overlay),
                         "mask": png_bytes(small), "numbers": rows,
                         "guard": dict(guard) if isinstance(guard, dict) else None,
                         "notes": list(notes) if index == 0 else []})
    title = "lisa fit-photo: " + ", ".join(view.photo.name for view in hand.views)
    return report_html(title + (f" ({hand.folder})" if hand.folder else ""), sections)


def _view_record(view: PhotoViewOutputs, side: str) -> dict[str, Any]:
    record = {"photo": str(view.photo), "image_size": list(view.original_size), "side": side,
              "keypoints_2d_detected": np.asarray(view.detected_px, np.float64).tolist(),
              "keypoints_2d_fitted": np.asarray(view.fitted_px, np.float64).tolist(),
              "visible": np.asarray(view.visible, bool).tolist(),
              "keypoints_3d": np.asarray(view.keypoints_3d, np.float64).tolist(),
              "keypoint_error_px": float(view.keypoint_error_px)}
    if view.detector_px is not None:
        record["keypoints_2d_detector"] = np.asarray(view.detector_px, np.float64).tolist()
    if view.landmarks_3d is not None:
        record["landmarks_3d"] = np.asarray(view.landmarks_3d, np.float64).tolist()
    return record


def keypoints_record(hand: PhotoHandOutputs) -> dict[str, Any]:
    """What a hand's ``keypoints.json`` holds (see the module docstring): the first photo's
    keys at the top, and ``"photos"`` (every photo's) when there are several."""
    side = hand.params.side
    record: dict[str, Any] = {"names": list(KEYPOINT_NAMES), "side": side, "frame": "camera",
                              "units": UNITS, **_view_record(hand.views[0], side)}
    if len(hand.views) > 1:
        record["frame"] = "camera of the first photo (keypoints_3d); photos[i]: photo i's"
        record["photos"] = [_view_record(view, side) for view in hand.views]
    return json_safe(record)


def _original_camera(view: PhotoViewOutputs) -> Camera:
    """The view's camera at the original photo's size (K rescaled per axis)."""
    width, height = view.original_size
    rescale = torch.diag(torch.tensor([width / view.camera.width, height / view.camera.height,
                                       1.0], dtype=torch.float64))
    return Camera(K=rescale @ view.camera.K.double().cpu(), R=view.camera.R.double().cpu(),
                  t=view.camera.t.double().cpu(), width=width, height=height,
                  name=view.photo.name)


def _view_artefacts(folder: str, view: PhotoViewOutputs, side: str,
                    with_keypoints: bool) -> list[Artefact]:
    """camera.json, mask.png, overlay.png (and first keypoints.json) of one photo, in
    ``folder`` ("" for the folder itself, else "NAME/")."""
    artefacts = []
    if with_keypoints:
        artefacts.append(json_artefact(folder + "keypoints.json", {
            "names": list(KEYPOINT_NAMES), "frame": "camera", "units": UNITS,
            **_view_record(view, side)}))

    def camera(path: Path) -> Path:
        from ...data.photo import save_camera

        return save_camera(path, view.camera, view.camera_source,
                           tuple(int(v) for v in view.original_size))

    return artefacts + [Artefact(folder + "camera.json", camera),
                        mask_artefact(folder + "mask.png", view.mask),
                        image_artefact(folder + "overlay.png", view.overlay)]


def _hand_artefacts(folder: str, hand: PhotoHandOutputs) -> list[Artefact]:
    """Every file of one hand in ``folder`` ("" or "handN/"; see the module docstring)."""

    def cameras(path: Path) -> Path:
        from ...geometry.cameras import save_cameras

        return save_cameras(path, [_original_camera(view) for view in hand.views])

    artefacts = [params_artefact(hand.params, folder + "params.json"),
                 mesh_artefact(hand.mesh, folder + "mesh.ply"),
                 json_artefact(folder + "keypoints.json", keypoints_record(hand))]
    side = hand.params.side
    if len(hand.views) == 1:
        artefacts += _view_artefacts(folder, hand.views[0], side, with_keypoints=False)
    else:
        artefacts.append(Artefact(folder + "cameras.json", cameras))
        for index, view in enumerate(hand.views):
            artefacts += _view_artefacts(f"{folder}photo{index}/", view, side,
                                         with_keypoints=True)
    return artefacts + [json_artefact(folder + "metrics.json", hand.metrics),
                        text_artefact(folder + "report.html", hand.report)]


def photo_artefacts(hands: Sequence[PhotoHandOutputs]) -> list[Artefact]:
    """Every hand's files (see the module docstring), for
    :func:`lisa_hand.fitting.outputs.write_fit` with :func:`photo_entry` and
    :data:`PHOTO_DESCRIBED`. hands: their ``folder`` names must be unique ("" only for a single
    hand). -> the artefacts, hand by hand."""
    hands = list(hands)
    names = [hand.folder for hand in hands]
    if not hands or len(set(names)) != len(names) or ("" in names and len(names) > 1):
        raise ValueError(f"hands must have unique folders ('' only alone), got {names}")
    return [artefact for hand in hands
            for artefact in _hand_artefacts(f"{hand.folder}/" if hand.folder else "", hand)]
