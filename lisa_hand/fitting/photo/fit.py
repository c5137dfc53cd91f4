"""``lisa fit-photo``: from uncalibrated photographs to a fitted hand on disk
(:func:`fit_photo_folder`).

Per photo: read it upright (:func:`lisa_hand.data.photo.read_photo`: EXIF orientation,
colours, downscaled to ``max_side``), choose its camera
(:func:`lisa_hand.data.photo.photo_camera`: ``--camera``, ``--focal-px``, ``--fov``, EXIF,
default), find the hands (:func:`lisa_hand.data.detect.detect_hands`, or the
``--keypoints`` file: :func:`lisa_hand.fitting.photo.inputs.read_given_hands`), make a coarse
mask (:func:`lisa_hand.fitting.photo.mask.coarse_mask`, or ``--mask``; without OpenCV the
mask from the keypoints alone is no outline, so the fit then uses none: keypoints, and colours
against the photo's border colour), and crop the region
around the hand as a view with its own camera (:func:`lisa_hand.fitting.photo.inputs.crop_view`:
the fit's cost does not depend on the photo's size). Every input is checked before the model is
loaded; an error is one line and nothing is written.

Then per hand: the keypoint stage (:func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`)
and the image fit from it (:func:`lisa_hand.fitting.images.fit.fit_images`, its ``start``), the
geometry guard (:mod:`lisa_hand.fitting.images.guard`), the mesh (the guard's own mesh of the
returned hand, with colours and skinning weights), the mesh ray cast into each photo
(:func:`lisa_hand.inference.mesh_render.render_mesh`; its silhouette refines the mask:
:func:`lisa_hand.fitting.photo.mask.refine_mask`),
and the files (:mod:`lisa_hand.fitting.photo.artefacts`, all hands at once, all or nothing).

**Side.** ``--side right|left``, or ``auto``: the detector's side (when its score reaches
``side_confidence``; a note when its estimates in plain and mirrored windows disagree), or the
``--keypoints`` file's ``"side"``; when neither says, the keypoint
stage is run as a right and as a left hand and the lower objective wins (the wrong side can
match the 2D keypoints only by bending joints beyond their limits or far from the pose prior;
the tests check it on a synthetic photo and its mirror image).

**Several hands** in a photo: each is fitted into ``DIR/handN`` (N: its index, left to right
for detected hands, file order for given ones), or only hand N into ``DIR`` with ``--hand N``.

**Several photos of one hand** (``PHOTO...``): they must show the hand in the SAME pose (a hand
photographed from several sides, or by several cameras at once); shape, colour and pose are then
shared. Each photo keeps its own intrinsics (``photo_camera``). The photos are not calibrated
against each other, so their cameras are placed by the hand itself: the keypoint stage is run on
each photo alone, which gives the hand's rigid pose in that photo's camera ``T_i`` (the root
bone's rotation about the wrist, and the translation), and photo ``i``'s camera becomes
``T_i T_0^-1`` in the frame of the first photo's camera (the world of the outputs). The keypoint
stage then runs on all views at once, each camera but the first is re-placed by that joint hand
(the rigid pose that best projects its keypoints onto the photo's), and the image fit starts
from it. A photo whose keypoints the joint hand does not explain (mean error above
``inconsistent_fraction`` of the hand's size in it) gets a note: the photos may not show one pose.
Each photo must hold one hand, or ``--hand N`` picks the same index in each. Cameras placed by
the hand keep one photo's scale ambiguity (a larger hand with cameras further apart looks the
same): the hand's size, hence its distance, still comes from the hand-size prior.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams
from ..outputs import releases_output_locks
from .artefacts import PhotoOfHand, build_hand_outputs, photo_report_html
from .config import FitPhotoConfig, photo_fit_defaults
from .inputs import PhotoHand, find_hands, votes_text

__all__ = ["photo_fit_defaults", "FitPhotoConfig", "PhotoFitReport", "fit_photo_folder",
           "keypoint_hand"]

SIDES = ("auto", "right", "left")


@dataclass
class PhotoFitReport:
    """What :func:`fit_photo_folder` did for one hand.

    folder: its output folder. photos: the photos it was fitted to. params: the fitted hand
    (frame: the first photo's camera). side: "right" / "left"; side_source: "--side",
    "detected", "--keypoints" or "fitted" (both tried). camera_sources: per photo, where its
    camera came from. keypoint_error_px: per photo, mean distance between the given and the
    fitted keypoints, ORIGINAL photo pixels. guard: the
    :class:`lisa_hand.fitting.images.guard.GuardReport` of the surface. seconds: this hand's
    wall time (its share of reading and detection not included). metrics: what
    ``metrics.json`` holds. written: its files. notes: sentences about what was assumed.
    """

    folder: Path
    photos: list[Path]
    params: HandParams
    side: str
    side_source: str
    camera_sources: list[str]
    keypoint_error_px: list[float]
    guard: Any
    seconds: float
    metrics: dict[str, Any]
    written: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class _PhotoInput:
    """One photo, read and checked: the photo, its camera and source, its hands, a given mask."""

    photo: Any
    camera: Any
    camera_source: str
    hands: list[PhotoHand]
    mask: np.ndarray | None
    name: str


def _per_photo(value: Any, photos: list[Path], option: str, shared_ok: bool) -> list[Any]:
    """A per-photo option (None, one path, or one per photo) -> [value per photo]."""
    if value is None:
        return [None] * len(photos)
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if len(values) == len(photos):
        return values
    if len(values) == 1 and shared_ok:
        return values * len(photos)
    raise ValueError(f"{option}: {len(values)} file(s) for {len(photos)} photos; give one per "
                     f"photo, in the photos' order" + (" (or one for all)" if shared_ok else ""))


def _read_inputs(photos: list[Path], camera_json: Any, focal_px: float | None,
                 fov_deg: float | None, keypoints_json: Any, mask_path: Any,
                 config: FitPhotoConfig, log: Callable[[str], None]) -> list[_PhotoInput]:
    """Every photo read, with its camera, hands and given mask (all checks before the fit)."""
    from ...data.photo import photo_camera, read_photo
    from .inputs import read_given_mask

    cameras = _per_photo(camera_json, photos, "--camera", shared_ok=True)
    keypoints = _per_photo(keypoints_json, photos, "--keypoints", shared_ok=True)
    masks = _per_photo(mask_path, photos, "--mask", shared_ok=False)
    inputs, names = [], set()
    for index, path in enumerate(photos):
        photo = read_photo(path, config.max_side)
        for note in photo.notes:
            log(f"{path.name}: {note}")
        camera, source = photo_camera(photo, cameras[index], focal_px, fov_deg)
        log(f"{path.name}: camera from {source} (focal length "
            f"{float(camera.K[0, 0]) / photo.scale:.0f} px of the original photo)")
        mask = None if masks[index] is None else read_given_mask(masks[index], photo)
        name = path.name if path.name not in names else f"{index}_{path.name}"
        names.add(name)
        inputs.append(_PhotoInput(photo=photo, camera=camera, camera_source=source,
                                  hands=find_hands(photo, keypoints[index], config, log),
                                  mask=mask, name=name))
    return inputs


def _targets(inputs: list[_PhotoInput], hand: int | None) -> list[tuple[str, list[PhotoHand]]]:
    """The hands to fit: [(output folder, one hand per photo)]."""
    def pick(item: _PhotoInput) -> PhotoHand:
        if hand >= len(item.hands):
            raise ValueError(f"{item.photo.path}: --hand {hand}, but {len(item.hands)} hand(s) "
                             f"were found (0 to {len(item.hands) - 1}, left to right)")
        return item.hands[hand]

    if hand is not None:
        return [("", [pick(item) for item in inputs])]
    if len(inputs) == 1:
        hands = inputs[0].hands
        if len(hands) > 1 and inputs[0].mask is not None:
            raise ValueError(f"{inputs[0].photo.path}: {len(hands)} hands and one --mask: pass "
                             "--hand N to fit the hand the mask shows")
        return [("" if len(hands) == 1 else f"hand{index}", [one])
                for index, one in enumerate(hands)]
    crowded = [item.photo.path.name for item in inputs if len(item.hands) > 1]
    if crowded:
        raise ValueError(f"several photos of one hand, but {', '.join(crowded)} hold(s) several "
                         "hands: pass --hand N (the same index in every photo)")
    return [("", [item.hands[0] for item in inputs])]


def _check_arguments(photos: Any, side: str, hand: int | None) -> list[Path]:
    if side not in SIDES:
        raise ValueError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
    if hand is not None and (isinstance(hand, bool) or not isinstance(hand, int) or hand < 0):
        raise ValueError(f"--hand must be an integer >= 0, got {hand!r}")
    photos = [Path(photo) for photo in ([photos] if isinstance(photos, (str, os.PathLike))
                                        else photos)]
    if not photos:
        raise ValueError("no photo given")
    return photos


@releases_output_locks
def fit_photo_folder(
    photos: Sequence[str | os.PathLike] | str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    side: str = "auto",
    camera_json: Any = None,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    keypoints_json: Any = None,
    mask_path: Any = None,
    hand: int | None = None,
    model_path: str | os.PathLike | None = None,
    device: str = "auto",
    progress: bool = True,
    log: Callable[[str], None] | None = print,
    config: FitPhotoConfig | None = None,
) -> list[PhotoFitReport]:
    """Fit the hand(s) of photos and write them into ``out_dir`` (see the module docstring and
    :mod:`lisa_hand.fitting.photo.artefacts` for the files).

    photos: one photo, or several of the same hand in the same pose. side: "auto", "right" or
    "left". camera_json: a calibration file (``cameras.json`` convention; one for all photos or
    one per photo). focal_px: focal length in original pixels; fov_deg: field of view along the
    long side, degrees (all photos). keypoints_json: a ``--keypoints`` file
    (:mod:`lisa_hand.fitting.photo.inputs`; one for all photos or one per photo): no detection.
    mask_path: a mask per photo (``--mask``): no automatic mask. hand: fit only hand N of each
    photo, into ``out_dir`` itself. model_path: a trained model (None: the shipped one).
    device: "auto", "cpu", "cuda" or "cuda:N". progress: show the stages' progress bars.
    log: called with one line per step and note (None: silent). config: :class:`FitPhotoConfig`.
    -> one :class:`PhotoFitReport` per fitted hand.
    """
    from ...model.trained import load_trained
    from ...model.trained import model_label as label_of
    from ...utils.device import resolve_device
    from ..outputs import claim_output_folder, write_fit
    from . import several
    from .artefacts import PHOTO_DESCRIBED, photo_artefacts, photo_entry
    from .inputs import check_hand_size

    log = log or (lambda line: None)
    config = FitPhotoConfig() if config is None else config
    photos = _check_arguments(photos, side, hand)
    out_dir = claim_output_folder(out_dir, photo_entry, PHOTO_DESCRIBED)  # freed at the end
    inputs = _read_inputs(photos, camera_json, focal_px, fov_deg, keypoints_json, mask_path,
                          config, log)
    targets = _targets(inputs, hand)
    for folder, hands in targets:
        for item, one in zip(inputs, hands, strict=True):
            label = f"{item.photo.path}" + (f" ({folder})" if folder else "")
            check_hand_size(one, item.photo, config.min_hand_px, label)
    model = load_trained(model_path, resolve_device(device))
    model_label = label_of(model_path)
    masks = several.split_coarse_masks(inputs, targets) if len(targets) > 1 else None
    alones = []
    for index, (folder, hands) in enumerate(targets):
        if folder:
            log(f"fitting {folder}")
        alones.append(_fit_alone(model, inputs, hands, folder, side, config, progress, log,
                                 model_label, None if masks is None else masks[index]))
    together = several.fit_together(model, alones, config, progress, log) \
        if len(alones) > 1 else None
    outcomes = [_hand_files(model, alone, config, log,
                            None if together is None else together.meshes[index])
                for index, alone in enumerate(alones)]
    artefacts = photo_artefacts([outputs for outputs, _ in outcomes])
    if together is not None:
        artefacts += several.several_artefacts(model, together, alones)
    written = write_fit(out_dir, artefacts, photo_entry, PHOTO_DESCRIBED)
    if together is not None:
        log("all hands: " + ", ".join(str(path) for path in written if path.parent == out_dir))
    for outputs, report in outcomes:
        report.folder = out_dir / outputs.folder if outputs.folder else out_dir
        report.written = [path for path in written
                          if not outputs.folder or report.folder in path.parents]
    return [report for _, report in outcomes]


def keypoint_hand(views: list[Any], side: str, config: FitPhotoConfig, template: Any,
                  progress: bool) -> tuple[HandParams, Any]:
    """The keypoint stage as a ``side`` hand -> (the hand, of that side, in the views' world;
    its StageReport)."""
    from ..images.keypoint_stage import fit_keypoints
    from ..images.views import mirror_view
    from ..sides import mirror_hand

    if side == "left":
        hand, report = fit_keypoints([mirror_view(view) for view in views], config.fit,
                                     template, progress)
        return mirror_hand(hand), report
    return fit_keypoints(views, config.fit, template, progress)


def _choose_side(views: list[Any], side: str, hands: list[PhotoHand], config: FitPhotoConfig,
                 template: Any, progress: bool, notes: list[str]
                 ) -> tuple[str, str, HandParams | None]:
    """(side, where it came from, the keypoint-stage hand when choosing it needed one)."""
    if side != "auto":
        return side, "--side", None
    split = [f"{one.side} {votes_text(one)}" for one in hands if one.side_split]
    if split:
        notes.append(f"the detector's estimates disagree on the side ({', '.join(split)}, plain "
                     "and mirrored windows): it may be wrong; pass --side to choose")
    known = [one.side for one in hands if one.side is not None and (
        one.score is None or one.score >= config.side_confidence)]
    if known:
        chosen = max(("right", "left"), key=known.count)
        if len(set(known)) > 1:
            notes.append(f"the photos disagree on the side ({', '.join(known)}): {chosen} chosen")
        return chosen, "detected" if hands[0].source == "detected" else "--keypoints", None
    unsure = [f"{one.side} {one.score:.2f}" for one in hands if one.side is not None]
    if unsure:
        notes.append(f"the detector is unsure of the side ({', '.join(unsure)}, below "
                     f"{config.side_confidence:g})")
    fits = {name: keypoint_hand(views[:1], name, config, template, progress)
            for name in ("right", "left")}
    chosen = min(fits, key=lambda name: fits[name][1].loss)
    other = "left" if chosen == "right" else "right"
    notes.append(f"side unknown: fitted as both, {chosen} won (keypoint-stage objective "
                 f"{fits[chosen][1].loss:.3g} against {fits[other][1].loss:.3g}); pass --side "
                 "to choose")
    return chosen, "fitted", fits[chosen][0] if len(views) == 1 else None


def _root_transform(hand: HandParams) -> torch.Tensor:
    """[4, 4] float64: the rigid motion of a RIGHT hand's root bone (rotation about the wrist
    joint, then the translation): rest-pose hand coordinates -> the views' world."""
    from ...geometry import axis_angle_to_matrix

    rotation = axis_angle_to_matrix(hand.pose[:3].double())
    wrist = hand.rest_joints[0].double()
    transform = torch.eye(4, dtype=torch.float64)
    transform[:3, :3] = rotation
    transform[:3, 3] = wrist - rotation @ wrist + hand.translation.double()
    return transform


def _place_cameras(views: list[Any], side: str, config: FitPhotoConfig, template: Any,
                   progress: bool) -> list[Any]:
    """Several photos: each view's camera placed in the frame of the first photo's camera by
    the hand's rigid pose in each photo alone (see the module docstring) -> the views with
    those cameras."""
    from ...geometry.cameras import Camera
    from ..sides import mirror_hand

    flip = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
    transforms = []
    for view in views:
        hand, _ = keypoint_hand([view], side, config, template, progress)
        transforms.append(_root_transform(mirror_hand(hand) if side == "left" else hand))
    placed = []
    for view, transform in zip(views, transforms, strict=True):
        motion = transform @ torch.linalg.inv(transforms[0])  # (mirrored) camera 0 -> camera i
        rotation, shift = motion[:3, :3], motion[:3, 3]
        if side == "left":  # the motion was found in the mirrored world (right hands)
            rotation, shift = flip @ rotation @ flip, flip @ shift
        camera = view.camera
        placed.append(dataclasses.replace(view, camera=Camera(K=camera.K, R=rotation.float(),
                                                  t=shift.float(), width=camera.width,
                                                  height=camera.height, name=camera.name)))
    return placed


def _refine_cameras(views: list[Any], hand: HandParams, iterations: int = 50) -> list[Any]:
    """Several photos, after the joint keypoint stage: every camera but the first re-placed by
    the joint hand (better determined than any photo's alone; :func:`_pose_camera`)."""
    from ..outputs import hand_keypoints_3d

    points = torch.from_numpy(hand_keypoints_3d(hand))
    return [views[0]] + [_pose_camera(view, points, iterations) for view in views[1:]]


def _pose_camera(view: Any, points: torch.Tensor, iterations: int) -> Any:
    """The view with the camera pose that best projects ``points`` [21, 3] (world metres) onto
    its visible keypoints: a pseudo-Huber loss of 1 pixel on the distances, L-BFGS from its
    camera; the view unchanged unless that lowers the loss."""
    from ...geometry import axis_angle_to_matrix
    from ...geometry.cameras import Camera

    camera = view.camera
    K, start_R = camera.K.double().cpu(), camera.R.double().cpu()
    visible = view.visible.cpu()
    target = view.keypoints.double().cpu()[visible]
    delta = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    shift = camera.t.double().cpu().clone().requires_grad_(True)

    def loss_of(turn: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        pixels = (points @ (axis_angle_to_matrix(turn) @ start_R).T + offset) @ K.T
        pixels = pixels[:, :2] / pixels[:, 2:].clamp_min(1e-3)
        squared = ((pixels[visible] - target) ** 2).sum(-1)
        return (torch.sqrt(squared + 1.0) - 1.0).mean()

    optimizer = torch.optim.LBFGS([delta, shift], max_iter=iterations,
                                  line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        loss = loss_of(delta, shift)
        loss.backward()
        return loss

    with torch.no_grad():
        before = float(loss_of(torch.zeros(3, dtype=torch.float64), camera.t.double().cpu()))
    optimizer.step(closure)
    with torch.no_grad():
        if not float(loss_of(delta, shift)) < before:
            return view
        rotation = axis_angle_to_matrix(delta) @ start_R
    placed = Camera(K=camera.K, R=rotation.float(), t=shift.detach().float(),
                    width=camera.width, height=camera.height, name=camera.name)
    return dataclasses.replace(view, camera=placed)


@dataclass
class _Alone:
    """One hand fitted alone, before its files: what :func:`_hand_files` needs."""

    folder: str
    inputs: list[_PhotoInput]
    hands: list[PhotoHand]
    crops: list[Any]
    coarse: list[np.ndarray]
    method: str
    side: str
    side_source: str
    result: Any
    notes: list[str]
    timings: dict[str, float]
    began: float


def _fit_alone(model: Any, inputs: list[_PhotoInput], hands: list[PhotoHand], folder: str,
               side: str, config: FitPhotoConfig, progress: bool, log: Callable[[str], None],
               model_label: str, masks: list[np.ndarray] | None = None) -> _Alone:
    """Fit one hand to its photos, alone. masks: the hand's coarse mask per photo when already
    made (several hands of one photo: split between them), else made here."""
    from ...utils.config import config_to_dict
    from ...utils.threads import cpu_threads
    from ..images.fit import fit_images
    from ..stages import template_on
    from .inputs import crop_view
    from .mask import coarse_mask, mask_method

    began = time.perf_counter()
    notes: list[str] = []
    coarse = masks if masks is not None else [
        item.mask if item.mask is not None else coarse_mask(item.photo.image, one.keypoints)
        for item, one in zip(inputs, hands, strict=True)]
    method = "--mask" if all(item.mask is not None for item in inputs) else mask_method()
    if method == "keypoints":  # not an outline: the fit uses keypoints and colours only
        notes.append("mask: from the keypoints alone (OpenCV missing: pip install -e "
                     "'.[photo]' for GrabCut); the fit used no mask")
    crops = [crop_view(item.photo, item.camera, one, None if method == "keypoints" else mask,
                       item.name, config.crop_margin, config.view_max_side)
             for item, one, mask in zip(inputs, hands, coarse, strict=True)]
    views = [crop.view for crop in crops]
    template = template_on(None, torch.device("cpu"))
    timings = {"seconds_inputs": time.perf_counter() - began}
    with cpu_threads(config.fit.num_threads):
        chosen, side_source, start = _choose_side(views, side, hands, config, template,
                                                  progress, notes)
        if len(views) > 1:
            views = _place_cameras(views, chosen, config, template, progress)
            start, _ = keypoint_hand(views, chosen, config, template, progress)
            views = _refine_cameras(views, start)
            crops = [dataclasses.replace(crop, view=view) for crop, view in zip(crops, views,
                                                                                strict=True)]
        elif start is None:
            start, _ = keypoint_hand(views, chosen, config, template, progress)
    timings["seconds_keypoints"] = time.perf_counter() - began - timings["seconds_inputs"]
    log(f"side: {chosen} ({side_source}); fitting {len(views)} photo(s)")
    result = fit_images(model, views, config.fit, progress, side=chosen, start=start)
    timings["seconds_color"] = result.stage_seconds.get("color", math.nan)
    notes += list(getattr(result, "notes", []))
    params = result.params
    params.model = model_label
    params.extra["input"] = {"photos": [str(item.photo.path) for item in inputs],
                             "camera_sources": [item.camera_source for item in inputs],
                             "side_source": side_source, "mask": method,
                             "keypoints": [one.source for one in hands]}
    params.extra["config"] = config_to_dict(config)  # the settings that fitted it
    return _Alone(folder=folder, inputs=inputs, hands=hands, crops=crops, coarse=coarse,
                  method=method, side=chosen, side_source=side_source, result=result,
                  notes=notes, timings=timings, began=began)


def alone_mesh(model: Any, alone: _Alone, config: FitPhotoConfig) -> Any:
    """The mesh ``mesh.ply`` holds of a hand's fit (cut past its wrist, no specks) and what
    was dropped: (mesh, specks)."""
    from ...geometry.pieces import drop_specks
    from ...skeleton.wrist import wrist_plane
    from ..images.folder import fitted_mesh

    params = alone.result.params
    cut = None if config.wrist_clip_m is None else wrist_plane(params, config.wrist_clip_m)
    return drop_specks(fitted_mesh(model, alone.result, config.mesh_resolution, cut))


def _hand_files(model: Any, alone: _Alone, config: FitPhotoConfig, log: Callable[[str], None],
                mesh: Any = None) -> tuple[Any, PhotoFitReport]:
    """A hand's fit -> (what to write, the report). mesh: (mesh, specks) when already made."""
    from ...utils.threads import cpu_threads
    from ..images.folder import output_surface

    inputs, hands, result, notes = alone.inputs, alone.hands, alone.result, alone.notes
    params, timings = result.params, alone.timings
    outputs_began = time.perf_counter()
    with cpu_threads(config.fit.num_threads):
        guard = result.guard  # None when the colour stage did not run
        photos = [PhotoOfHand(photo=item.photo, camera=item.camera,
                              camera_source=item.camera_source, hand=one, crop=crop,
                              coarse=mask, refine=item.mask is None)
                  for item, one, crop, mask in zip(inputs, hands, alone.crops, alone.coarse,
                                                   strict=True)]
        mesh, specks = alone_mesh(model, alone, config) if mesh is None else mesh
        outputs = build_hand_outputs(model, params, photos, alone.folder, mesh,
                                     config.render_supersample, config.render_max_side)
        outputs.metrics["surface"] = output_surface(model, result, mesh, config.mesh_resolution,
                                                    config.wrist_clip_m)
        outputs.metrics["specks_removed"] = specks.to_dict()
        if specks.count:
            notes.append(specks.note("mesh.ply"))
    _consistency_notes(outputs, photos, config, notes)
    timings["seconds_outputs"] = time.perf_counter() - outputs_began
    seconds = time.perf_counter() - alone.began
    photo_notes = [f"{item.photo.path.name}: {note}" for item in inputs
                   for note in item.photo.notes]  # logged when read
    outputs.metrics.update(_fit_metrics(result, guard, alone.side_source, alone.method, seconds,
                                        timings, photo_notes + notes))
    outputs.report = photo_report_html(outputs, photo_notes + notes)
    for note in notes:
        log(note)
    report = PhotoFitReport(
        folder=Path(alone.folder), photos=[item.photo.path for item in inputs], params=params,
        side=alone.side, side_source=alone.side_source,
        camera_sources=[item.camera_source for item in inputs],
        keypoint_error_px=[view.keypoint_error_px for view in outputs.views], guard=guard,
        seconds=seconds, metrics=outputs.metrics, notes=notes)
    return outputs, report


def _consistency_notes(outputs: Any, photos: list[Any], config: FitPhotoConfig,
                       notes: list[str]) -> None:
    """Several photos: a note for each photo whose keypoints the joint hand misses."""
    from .mask import hand_scale_px

    if len(photos) < 2:
        return
    for view, photo in zip(outputs.views, photos, strict=True):
        size = hand_scale_px(photo.hand.keypoints) * photo.photo.original_size[0] / float(
            photo.photo.image.shape[1])  # original pixels
        if view.keypoint_error_px > config.inconsistent_fraction * size:
            notes.append(f"{view.photo.name}: the joint hand misses its keypoints by "
                         f"{view.keypoint_error_px:.1f} px on average (the hand is {size:.0f} "
                         "px from wrist to knuckles): do the photos show the hand in one pose?")


def _fit_metrics(result: Any, guard: Any, side_source: str, method: str, seconds: float,
                 timings: dict[str, float], notes: list[str]) -> dict[str, Any]:
    """The fit's part of ``metrics.json``: where the side and the mask came from, the
    keypoint errors of the fit's views (view pixels: the crops the fit saw), the guard, the
    seconds of this hand (masks and crops, the keypoint stage(s), the colour stage, mesh and
    renders) and the notes."""
    return {
        "side_source": side_source, "mask": method,
        "keypoint_error_view_px_keypoint_stage": result.keypoint_error_px.get("keypoints"),
        "keypoint_error_view_px": result.keypoint_error_px.get("color"),
        "guard": None if guard is None else {**guard.to_dict(), **result.params.extra.get(
            "guard", {})},
        "seconds": seconds, **timings, "notes": list(notes),
    }
