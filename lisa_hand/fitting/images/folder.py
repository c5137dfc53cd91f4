"""``lisa fit-images``: from a frame folder to a fitted hand on disk (:func:`fit_image_folder`),
and the fitted hand re-rendered into the input views (:func:`render_fitted_views`,
:func:`view_psnrs`).

Outputs of :func:`fit_image_folder`: ``params.json`` (the hand; under ``extra["config"]``
the :class:`FitImagesConfig` that fitted it, as :func:`lisa_hand.utils.config.config_to_dict`
writes it), ``mesh.ply``
(:func:`lisa_hand.inference.mesh_hand`: vertex colours and skinning weights; the surface
guard's mesh of the returned hand reused, :func:`fitted_mesh`) and
``metrics.json`` (keypoint errors, PSNR of the re-rendered input views, timings, the surface
guard's figures, and with a ground truth the V2V / V2S distances), written all or nothing by
:mod:`lisa_hand.fitting.outputs`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...render import RenderConfig
from ...skeleton.params import HandParams
from ...utils.threads import cpu_threads
from ..outputs import releases_output_locks
from .config import FitImagesConfig
from .fit import FitImagesResult, fit_images
from .views import ImageView, background_colour, fit_target, input_notes, read_views

__all__ = ["ViewRender", "render_fitted_views", "view_psnrs", "FitImagesReport",
           "fit_image_folder", "fitted_mesh", "output_surface"]


@dataclass
class ViewRender:
    """A fitted hand rendered into one input view.

    name: the view. rgb: [H, W, 3] in [0, 1] (calibrated, over the view's background).
    opacity: [H, W]. target: [H, W, 3] what the fit compared with
    (:func:`lisa_hand.fitting.images.views.fit_target`). mask: [H, W] bool or None.
    """

    name: str
    rgb: torch.Tensor
    opacity: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor | None


def render_fitted_views(model: Any, params: HandParams, views: Sequence[ImageView],
                        samples: int = 32) -> list[ViewRender]:
    """Render the fitted hand into every view with the model's mean colour calibration
    (:func:`lisa_hand.inference.prepare_render`: VolSDF, one occupancy grid for all views),
    over each view's background (black with a mask, else the border's median colour).

    samples: samples per ray in the band around the surface (32: as ``lisa render``). Runs
    under ``torch.no_grad``.
    """
    from ...inference import hand_render_config, prepare_render

    config = hand_render_config(model, normals="none", render=RenderConfig(
        sampler="sphere_traced", num_samples=samples, num_samples_extra=0))
    scene = prepare_render(model, params, config)
    results = []
    for view in views:
        background = tuple(float(c) for c in background_colour(view))
        view_scene = dataclasses.replace(scene, config=dataclasses.replace(
            config, background=background))
        with torch.no_grad():
            image = view_scene.render(view.camera)
        results.append(ViewRender(name=view.name, rgb=image.rgb.clamp(0.0, 1.0).cpu(),
                                  opacity=image.opacity.cpu(), target=fit_target(view).cpu(),
                                  mask=None if view.mask is None else view.mask.cpu()))
    return results


def view_psnrs(renders: Sequence[ViewRender]) -> dict[str, Any]:
    """PSNR (dB, :func:`lisa_hand.metrics.psnr`) of re-rendered views against what the fit
    compared with: per view over the whole image ("psnr_db") and inside the mask
    ("psnr_mask_db"), and their means over the views (NaN without masks)."""
    from ...metrics import psnr

    per_view: dict[str, dict[str, float]] = {}
    whole, masked = [], []
    for render in renders:
        entry = {"psnr_db": psnr(render.rgb.numpy(), render.target.numpy())}
        whole.append(entry["psnr_db"])
        if render.mask is not None:
            entry["psnr_mask_db"] = psnr(render.rgb.numpy(), render.target.numpy(),
                                         render.mask.numpy())
            masked.append(entry["psnr_mask_db"])
        per_view[render.name] = entry
    return {"psnr_db": float(np.mean(whole)) if whole else math.nan,
            "psnr_mask_db": float(np.mean(masked)) if masked else math.nan,
            "views": per_view}


@dataclass
class FitImagesReport:
    """What :func:`fit_image_folder` did.

    fit: the :class:`lisa_hand.fitting.images.fit.FitImagesResult`. mesh: the fitted surface
    (colours, skinning weights). metrics: what ``metrics.json`` holds: keypoint errors (px),
    PSNR of the re-rendered input views (dB; whole image and inside the masks), timings and,
    with a ground truth, the four distances (mm). written: the files written, in order. notes:
    sentences about fallbacks that were used (missing masks or keypoints, keypoints outside
    the image).
    """

    fit: FitImagesResult
    mesh: Any
    metrics: dict[str, Any]
    written: list[Path]
    notes: list[str]


@releases_output_locks
def fit_image_folder(
    frame_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    views: Sequence[str] | None = None,
    model_path: str | os.PathLike | None = None,
    gt_path: str | os.PathLike | None = None,
    units: str = "auto",
    resolution: int = 128,
    config: FitImagesConfig | None = None,
    side: str = "right",
    device: str = "auto",
    psnr: bool = True,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> FitImagesReport:
    """Read a frame folder, fit the model, write ``params.json``, ``mesh.ply`` and
    ``metrics.json`` into ``out_dir`` (all or nothing,
    :func:`lisa_hand.fitting.outputs.write_fit_outputs`).

    Every input is checked before the fit (views, ground truth, model, output folder).
    frame_dir: :func:`lisa_hand.fitting.images.views.read_views`'s folder; views: camera names to
    use
    (default: all). model_path: a trained model (:func:`lisa_hand.model.trained.load_trained`;
    None: the shipped one). gt_path: a ground-truth mesh or points; units: its unit ("auto",
    "m", "cm", "mm"). resolution: marching-cubes samples a side of the mesh. config:
    :class:`FitImagesConfig`. side: "right" or "left" (the hand the views show). device:
    "auto", "cpu", "cuda" or "cuda:N" (where the model is loaded). psnr: re-render the input
    views for the PSNR. log: called with one line per note (fallbacks, unit guesses).
    """
    from ...model.trained import model_label
    from ...utils.config import config_to_dict
    from ..outputs import prepare_fit

    log = log or (lambda line: None)
    config = FitImagesConfig() if config is None else config
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    frame_dir, out_dir = Path(frame_dir), Path(out_dir)
    image_views = read_views(frame_dir, views)
    notes = input_notes(image_views)
    for note in notes:
        log(note)
    truth, model = prepare_fit(out_dir, gt_path, units, model_path, device, log)

    fit = fit_images(model, image_views, config, progress, side=side)
    for note in fit.notes:
        log(note)
    notes = notes + fit.notes
    params = fit.params
    params.model = model_label(model_path)
    params.extra["input"] = {"path": str(frame_dir), "notes": notes}
    params.extra["config"] = config_to_dict(config)  # the settings that fitted it
    with cpu_threads(config.num_threads):
        return _finish_folder(model, fit, image_views, out_dir, truth, resolution, psnr, notes,
                              log)


def fitted_mesh(model: Any, fit: FitImagesResult, resolution: int, clip: Any = None) -> Any:
    """The written mesh of ``fit.params`` (:func:`lisa_hand.inference.mesh_hand`: colours and
    skinning weights) at ``resolution``: the guard's mesh of the returned hand with its
    attributes when the guard meshed it at that resolution (the same surface, not extracted
    twice), else extracted. clip: a :class:`lisa_hand.geometry.planes.Plane` (the hand's wrist
    cut, :func:`lisa_hand.skeleton.wrist.wrist_plane`) along which the surface is cut, or
    None."""
    from ...geometry.meshing import Mesh
    from ...geometry.planes import clip_mesh
    from ...inference import mesh_attributes, mesh_hand

    surface = fit.surface_meshes.get("returned")
    if surface is not None and fit.surface_resolution == resolution:
        if clip is not None:
            surface = Mesh(*clip_mesh(surface.vertices, surface.faces, clip))
        return mesh_attributes(model, fit.params, surface)
    return mesh_hand(model, fit.params, resolution, clip=clip)


def output_surface(model: Any, fit: FitImagesResult, mesh: Any, resolution: int,
                   wrist_clip_m: float | None = None) -> dict[str, Any] | None:
    """The guard's figures on the written mesh: ``mesh`` (specks removed,
    :func:`lisa_hand.geometry.pieces.drop_specks`; cut ``wrist_clip_m`` past the fitted wrist
    when that is not None) against the colour stage's start meshed at the same ``resolution``,
    its specks removed and cut past its own wrist the same way
    (:func:`lisa_hand.fitting.images.guard.surface_guard`; the guard's own mesh of the start
    when it has that resolution); None when the colour stage did not run."""
    from ...geometry.meshing import Mesh
    from ...geometry.pieces import drop_specks
    from ...geometry.planes import clip_mesh
    from ...skeleton.wrist import wrist_plane
    from .guard import guard_mesh, surface_guard

    if fit.start is None or "color" not in fit.reports:
        return None
    reference = fit.surface_meshes.get("start")
    if reference is None or fit.surface_resolution != resolution:
        reference = guard_mesh(model, fit.start, resolution)
    if wrist_clip_m is not None:
        reference = Mesh(*clip_mesh(reference.vertices, reference.faces,
                                    wrist_plane(fit.start, wrist_clip_m)))
    report = surface_guard(drop_specks(reference)[0], mesh)
    return {"resolution": resolution, **report.to_dict()}


def _finish_folder(model: Any, fit: FitImagesResult, image_views: Sequence[ImageView],
                   out_dir: Path, truth: Any, resolution: int, psnr: bool,
                   notes: list[str], log: Callable[[str], None]) -> FitImagesReport:
    """Mesh, metrics and files of :func:`fit_image_folder`."""
    from ...geometry.pieces import drop_specks
    from ..outputs import ground_truth_metrics, write_fit_outputs

    params = fit.params
    mesh_start = time.perf_counter()
    mesh, specks = drop_specks(fitted_mesh(model, fit, resolution))
    if specks.count:
        log(specks.note("mesh.ply"))
    surface = output_surface(model, fit, mesh, resolution)
    if surface is not None and not surface["passed"]:
        note = (f"the written mesh (resolution {resolution}) fails the surface guard: "
                + "; ".join(surface["notes"]))
        log(note)
        notes.append(note)
        params.extra.setdefault("notes", []).append(note)
    metrics: dict[str, Any] = {
        "views": [view.name for view in image_views],
        "keypoint_error_px": fit.keypoint_error_px["color"],
        "keypoint_error_px_stage1": fit.keypoint_error_px["keypoints"],
        "keypoint_error_px_per_view": params.extra["keypoint_error_px_per_view"],
        "seconds_fit": fit.seconds,
        "seconds_keypoints": fit.stage_seconds["keypoints"],
        "seconds_color": fit.stage_seconds["color"],
        "seconds_mesh": time.perf_counter() - mesh_start,
    }
    if "guard" in params.extra:
        metrics["guard"] = {key: params.extra["guard"][key] for key in
                            ("passed", "pieces", "area_ratio", "fallback", "notes")}
    if surface is not None:
        metrics["surface"] = surface
    metrics["specks_removed"] = specks.to_dict()
    if psnr:
        render_start = time.perf_counter()
        scores = view_psnrs(render_fitted_views(model, params, image_views))
        metrics.update(psnr_db=scores["psnr_db"], psnr_mask_db=scores["psnr_mask_db"],
                       psnr_per_view=scores["views"],
                       seconds_render=time.perf_counter() - render_start)
    if truth is not None:
        metrics.update(ground_truth_metrics(mesh, truth))
        metrics["ground_truth"] = str(truth.path)
    written = write_fit_outputs(out_dir, params, mesh, metrics)
    return FitImagesReport(fit=fit, mesh=mesh, metrics=metrics, written=written, notes=notes)
