"""The methods of the paper's tables: how a trained model is checked against its method, and how
each method fits one frame (its point cloud for Table 1, its views for Tables 2 and 3).

Every implicit method is a configuration of the same code (:class:`lisa_hand.fields.FieldConfig`
``composition``), trained by ``lisa train`` (images) and ``lisa train-prior`` (scans):

========== ============ ======================================================= ===============
method      composition  what it is                                              trained on
========== ============ ======================================================= ===============
mano        (mesh)       the MANO-like template, pose and shape fitted            (built in)
volsdf      single       one SDF and one colour MLP on pose, shape and colour     images
nasa        nasa         per-bone SDF, the bone with the smallest SDF selected    images
narf        narf         skinning weights from the unposed points only            images
lisa_im     lisa         LISA from images only                                    images
lisa_geom   lisa         LISA's geometric prior only (no colour)                  scans
lisa_full   lisa         the prior, then images                                   scans, images
========== ============ ======================================================= ===============

Two kinds of method fit a frame: the mesh template (:class:`TemplateMethod`: the template fitted
to the scan's points, or to the views' keypoints and masks) and the trained fields
(:class:`FieldMethod`: :func:`lisa_hand.fitting.points.io.fit_point_file` on the scan, or the colour
stage of :func:`lisa_hand.fitting.images.fit.fit_images` from the template's keypoint fit).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "Method",
    "TemplateMethod",
    "FieldMethod",
    "METHODS",
    "TEMPLATE_METHOD",
    "FitSettings",
    "ImageInputs",
    "image_inputs",
    "method_names",
    "check_model_method",
]


@dataclass(frozen=True)
class FitSettings:
    """The settings every fit of an evaluation shares."""

    resolution: int
    """Marching-cubes samples a side of every implicit method's mesh."""
    fit_scale: float
    """Multiplies every fit's iteration counts (quick mode: a small fraction)."""
    template_vertices: int
    """The template's mesh is loop-subdivided to about this many vertices."""
    device: str
    """Where the models run (resolved: 'cpu', 'cuda:0', ...)."""


@dataclass(frozen=True)
class ImageInputs:
    """What every method's image fit of one frame and view count shares."""

    frame_dir: Path
    """The frame folder (its ``mesh.ply`` is the truth of V2V and V2S)."""
    out: Path
    """Folder of the fits' files: ``OUT/METHOD/mesh.ply`` and ``novel.png``."""
    views: list
    """The input views (:class:`lisa_hand.fitting.images.views.ImageView`)."""
    novel: list
    """The views the fits are rendered into (never inputs)."""
    config: Any
    """The image fit's settings (``FitImagesConfig``, iterations scaled)."""
    template: Any
    """The mesh template (MANO's layout)."""
    settings: FitSettings
    """Resolution, template size, device."""
    render_samples: int
    """Samples per ray in the band around the surface for the novel views."""


def _scaled(config, scale: float, names: Sequence[str]):
    return dataclasses.replace(config, **{n: max(1, int(round(getattr(config, n) * scale)))
                                          for n in names})


def image_inputs(frame_dir: Path, views: Sequence[str], novel: Sequence[str], out: Path,
                 settings: FitSettings, render_samples: int) -> ImageInputs:
    """Read the frame's input and novel views (by camera name) and the template, and scale the
    image fit's iterations by ``settings.fit_scale``."""
    from ..fitting.images.config import FitImagesConfig
    from ..fitting.images.views import read_views
    from ..handmodel.template import load_template

    return ImageInputs(
        frame_dir=frame_dir, out=out,
        views=read_views(frame_dir, list(views)), novel=read_views(frame_dir, list(novel)),
        config=_scaled(FitImagesConfig(), settings.fit_scale, ("keypoint_iters", "color_iters")),
        template=load_template(), settings=settings, render_samples=render_samples)


def _distances(vertices, faces, truth_path: Path, clip=None) -> dict[str, float]:
    """The four distances (mm) to the frame's true mesh; ``clip``: a wrist cut both are cut at
    first (:func:`lisa_hand.metrics.mesh_distances`)."""
    from ..metrics import load_mesh, mesh_distances

    truth = load_mesh(truth_path)
    return mesh_distances(vertices, faces, truth.vertices, truth.faces, clip=clip).to_dict()


def _write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    from ..utils.io import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        trimesh.Trimesh(vertices, faces, process=False).export(tmp, file_type="ply")


def _novel_metrics(model, params, views, samples: int, picture: Path | None) -> dict:
    """PSNR (inside the mask and whole), SSIM and LPIPS of the fit rendered into ``views``,
    averaged over them; the first render saved to ``picture``."""
    from ..data.layout import write_image
    from ..fitting.images.folder import render_fitted_views
    from ..metrics import image_metrics

    renders = render_fitted_views(model, params, views, samples=samples)
    rows = [image_metrics(r.rgb.numpy(), r.target.numpy(), r.mask.numpy()
                          if r.mask is not None else None) for r in renders]
    if picture is not None:
        picture.parent.mkdir(parents=True, exist_ok=True)
        write_image(picture, renders[0].rgb.numpy())

    def mean(values):
        values = [v for v in values if not math.isnan(v)]
        return float(np.mean(values)) if values else math.nan

    return {"psnr_db": mean([r.psnr_mask_db for r in rows]),
            "psnr_whole_db": mean([r.psnr_db for r in rows]),
            "ssim": mean([r.ssim for r in rows]),
            "ssim_mask": mean([r.ssim_mask for r in rows]),
            "lpips": mean([r.lpips for r in rows]),
            "lpips_message": rows[0].lpips_message if rows else ""}


@dataclass(frozen=True)
class Method:
    """One row of the tables: ``name`` (CLI and JSON key), ``label`` (in the tables), the
    field ``composition`` its model must have (None: the mesh template), and whether the model
    must have colour (True), must not (False) or either (None)."""

    name: str
    label: str
    composition: str | None
    color: bool | None
    description: str

    @property
    def takes_model(self) -> bool:
        """Whether the method is a trained model (else it is the built-in mesh template)."""
        return self.composition is not None

    def fit_points(self, frame: Any, out: Path, settings: FitSettings,
                   model_path: str | None) -> dict[str, float]:
        """Fit the frame's scan (``frame``: :class:`lisa_hand.data.layout.FramePaths`), write
        ``out/mesh.ply`` -> the four V2V/V2S distances (mm) and ``seconds`` (the fit's)."""
        raise NotImplementedError


@dataclass(frozen=True)
class TemplateMethod(Method):
    """The mesh template fitted to a frame: to the scan's points, or to the views' keypoints
    and masks (the image fits' stage 1, which every field method starts from)."""

    def fit_points(self, frame: Any, out: Path, settings: FitSettings,
                   model_path: str | None = None) -> dict[str, float]:
        from ..data.layout import read_npz
        from ..handmodel.template import load_template
        from ..skeleton.wrist import wrist_plane
        from .template_fit import (
            TemplateFitConfig,
            fit_template_points,
            subdivide_to,
            template_mesh,
        )

        start = time.perf_counter()
        config = _scaled(TemplateFitConfig(), settings.fit_scale, ("rigid_iters", "full_iters"))
        points = read_npz(frame.scan, required=("points",))["points"]
        hand = fit_template_points(points, config=config).params
        vertices, faces = template_mesh(load_template(), hand.pose, hand.betas, hand.translation)
        vertices, faces = subdivide_to(vertices, faces, settings.template_vertices)
        seconds = time.perf_counter() - start
        _write_mesh(out / "mesh.ply", vertices, faces)
        # Cut at the fitted wrist as the point fits of the field methods are
        # (lisa_hand.skeleton.wrist: the scan's forearm stub counts for no method).
        clip = wrist_plane(hand)
        return {**_distances(vertices, faces, frame.mesh, clip), "seconds": seconds}

    def fit_images(self, inputs: ImageInputs) -> tuple[dict[str, Any], Any]:
        """Stage 1 (pose and shape from the keypoints and masks, seeded) -> (its row's values:
        distances, no colour scores, ``seconds``, ``keypoint_error_px``; the keypoint fit that
        the field methods start from, with its ``seconds`` in the row)."""
        import torch

        from ..fitting.images.keypoint_stage import fit_keypoints
        from .template_fit import subdivide_to, template_mesh

        start = time.perf_counter()
        torch.manual_seed(0)
        pose_fit, report = fit_keypoints(inputs.views, inputs.config, inputs.template)
        seconds = time.perf_counter() - start
        vertices, faces = template_mesh(inputs.template, pose_fit.pose, pose_fit.betas,
                                        pose_fit.translation)
        vertices, faces = subdivide_to(vertices, faces, inputs.settings.template_vertices)
        _write_mesh(inputs.out / self.name / "mesh.ply", vertices, faces)
        row = {**_distances(vertices, faces, inputs.frame_dir / "mesh.ply"),
               "psnr_db": None, "ssim": None, "lpips": None, "seconds": seconds,
               "keypoint_error_px": report.keypoint_error_px}
        return row, pose_fit


@dataclass(frozen=True)
class FieldMethod(Method):
    """A trained field fitted to a frame: surface fit of the scan, or the colour stage of the
    image fit from the template's keypoint fit, meshed and rendered into the novel views."""

    def fit_points(self, frame: Any, out: Path, settings: FitSettings,
                   model_path: str | None) -> dict[str, float]:
        from ..fitting.points.fit import FitPointsConfig
        from ..fitting.points.io import fit_point_file

        start = time.perf_counter()
        config = _scaled(FitPointsConfig(), settings.fit_scale,
                         ("align_iters", "pose_iters", "field_iters"))
        report = fit_point_file(frame.scan, out, model_path=model_path, gt_path=frame.mesh,
                                units="m", resolution=settings.resolution, config=config,
                                device=settings.device)
        seconds = time.perf_counter() - start
        return {**dict(report.metrics), "seconds": seconds}

    def fit_images(self, inputs: ImageInputs, model: Any, start: Any,
                   start_seconds: float) -> dict[str, Any]:
        """The colour stage of ``model`` (a loaded :class:`TrainedModel`) from the keypoint fit
        ``start`` (which took ``start_seconds``), meshed (V2V, V2S) and rendered into the novel
        views -> its row's values (``seconds`` includes the keypoint fit's)."""
        from ..fitting.images.fit import fit_images
        from ..inference import mesh_hand

        began = time.perf_counter()
        fit = fit_images(model, inputs.views, inputs.config, start=start,
                         template=inputs.template)
        seconds = start_seconds + time.perf_counter() - began
        mesh = mesh_hand(model, fit.params, inputs.settings.resolution)
        out = inputs.out / self.name
        _write_mesh(out / "mesh.ply", mesh.vertices, mesh.faces)
        novel_scores = _novel_metrics(model, fit.params, inputs.novel, inputs.render_samples,
                                      out / "novel.png")
        return {**_distances(mesh.vertices, mesh.faces, inputs.frame_dir / "mesh.ply"),
                **novel_scores, "seconds": seconds,
                "keypoint_error_px": fit.keypoint_error_px["color"]}


TEMPLATE_METHOD = TemplateMethod(
    "mano", "MANO-like", None, None,
    "the mesh template (MANO's layout), pose and shape fitted, subdivided to ~100k vertices")
"""The built-in mesh template: always evaluated, and the start of every image fit."""

METHODS: dict[str, Method] = {m.name: m for m in (
    TEMPLATE_METHOD,
    FieldMethod("volsdf", "VolSDF", "single", True,
                "one MLP conditioned on pose, shape and colour codes, no per-bone reasoning"),
    FieldMethod("nasa", "NASA", "nasa", True,
                "per-bone SDF and colour MLPs, the bone with the smallest SDF selected"),
    FieldMethod("narf", "NARF", "narf", True,
                "per-bone MLPs blended by weights predicted from the unposed points only"),
    FieldMethod("lisa_im", "LISA-im", "lisa", True, "LISA trained on images only"),
    FieldMethod("lisa_geom", "LISA-geom", "lisa", False, "LISA's geometric prior (scans) only"),
    FieldMethod("lisa_full", "LISA-full", "lisa", True,
                "LISA: the geometric prior, then images"),
)}
"""Every method, in table order."""


def method_names() -> list[str]:
    """The method names in table order."""
    return list(METHODS)


def check_model_method(method: str, model, source: str) -> None:
    """Raise ValueError when a loaded model (:class:`lisa_hand.model.trained.TrainedModel`)
    cannot be the method ``method`` (its composition, or colour, does not match)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    spec = METHODS[method]
    if not spec.takes_model:
        raise ValueError(f"{method}: the MANO-like baseline takes no model (it is the mesh "
                         "template)")
    composition = model.config.composition
    if composition != spec.composition:
        raise ValueError(f"{source}: a {composition!r} model cannot be {spec.label} (it needs "
                         f"field.composition={spec.composition!r})")
    if spec.color is True and not model.has_color:
        raise ValueError(f"{source}: {spec.label} is trained on images and has colour; this "
                         "model has none (a geometry prior?)")
    if spec.color is False and model.has_color:
        raise ValueError(f"{source}: {spec.label} is the geometric prior alone (no colour); "
                         "this model has colour (pass the 'lisa train-prior' run)")
