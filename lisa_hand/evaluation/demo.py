"""``lisa demo``: the main job end to end, on the shipped model and a hand it never saw.

1. Synthesize one hand of the open hand model (a subject and pose drawn from a seed stream that
   training never used): its ground-truth mesh, a scan, and ``views`` calibrated images with
   masks and 2D keypoints (:func:`lisa_hand.data.synth.dataset.synthesize`).
2. Fit the shipped model to the scan (``lisa fit-points``), to 1 view and to 4 views
   (``lisa fit-images``); mesh each fit.
3. Measure each fit against the truth: V2V and V2S both ways (mm), and the PSNR of the fitted
   hand rendered into views that no fit used (novel views), twice: with the model's mean colour
   calibration (the novel cameras' colour response unknown, as for any new camera), and with
   each novel camera's own simulated gain and bias (as on a calibrated rig: the paper's test
   views come from the training rig, whose per-camera gain and bias were learned).
4. Render a turntable of the 4-view fit and write ``report.html`` (pictures and the table, all
   embedded: one self-contained file).
"""

from __future__ import annotations

import base64
import html
import io
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..handmodel import HAND_MODELS

__all__ = ["DemoConfig", "DemoResult", "run_demo"]

_METRICS = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
            "v2s_scan_to_recon_mm")
# Subjects of the demo come from this synth seed; the shipped model was trained on seed 0.
_DEMO_SEED_OFFSET = 1000


@dataclass(frozen=True)
class DemoConfig:
    """Settings of the demo (defaults: about 3-5 minutes on 2 CPU cores)."""

    seed: int = 0
    """Which unseen hand (synth seed ``1000 + seed``)."""
    model: str | None = None
    """Model file or run (None: the shipped model)."""
    resolution: tuple[int, int] = (384, 250)
    """Input images (width, height), pixels."""
    num_views: int = 8
    """Views synthesized: 4 are fitted, the others are the novel views of the PSNR."""
    mesh_resolution: int = 128
    """Marching-cubes samples a side."""
    orbit_views: int = 24
    """Frames of the turntable."""
    orbit_size: int = 256
    """Turntable frame size, pixels."""
    fit_scale: float = 1.0
    """Multiplies the fits' iteration counts (< 1: faster, less accurate)."""
    device: str = "auto"
    """"auto", "cpu" or "cuda"."""
    hand_model: str = "v1"
    """Version of the open hand model the unseen hand is drawn from (``lisa synth
    --hand-model``): "v1", what the shipped LISA-full was trained on, or "v2" (for a model
    trained on v2 hands)."""


@dataclass
class DemoResult:
    """rows: one dict per fit (``method``, the four distances in mm, ``psnr_db`` on novel
    views with the model's mean calibration, ``psnr_calibrated_db`` with the novel cameras' own
    response, ``seconds``); report: the HTML file; seconds: the whole demo."""

    rows: list[dict]
    report: Path
    seconds: float


def _scaled(config, scale: float, names: tuple[str, ...]):
    if scale == 1.0:
        return config
    return replace(config, **{n: max(1, int(round(getattr(config, n) * scale))) for n in names})


def _png_data_uri(image: np.ndarray) -> str:
    import imageio.v3 as iio

    buffer = io.BytesIO()
    iio.imwrite(buffer, image, extension=".png")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _file_data_uri(path: Path, kind: str) -> str:
    """The image file ``path`` of type ``kind`` ("gif", "png") as a data URI, its bytes as
    they are."""
    return f"data:image/{kind};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _novel_view_psnr(model, params, frame, names: list[str]) -> tuple[float, float, list]:
    """Mean PSNR (dB, inside the masks) of the fitted hand in the views ``names`` of ``frame``
    (a FramePaths) -> (psnr with the model's mean calibration, psnr with each view's true gain
    and bias from the frame's ``params.json``, [rendered uint8 [H, W, 3], target uint8] per
    view, with the mean calibration)."""
    import json

    import torch

    from ..fitting.images.folder import render_fitted_views
    from ..fitting.images.views import read_views
    from ..metrics import psnr

    views = read_views(frame.root, names)
    renders = render_fitted_views(model, params, views)
    values, pictures = [], []
    for render in renders:
        values.append(psnr(render.rgb.numpy(), render.target.numpy(), render.mask.numpy()))
        pictures.append((_to_uint8(render.rgb.numpy()), _to_uint8(render.target.numpy())))
    truth = json.loads(frame.params.read_text())
    calibrated = []
    for view in views:
        own = replace(model, gain=torch.tensor(truth["camera_gain"][view.name]),
                      bias=torch.tensor(truth["camera_bias"][view.name]))
        (render,) = render_fitted_views(own, params, [view])
        calibrated.append(psnr(render.rgb.numpy(), render.target.numpy(), render.mask.numpy()))
    return float(np.mean(values)), float(np.mean(calibrated)), pictures


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def run_demo(
    out_dir: str | Path, config: DemoConfig | None = None, log: Callable[[str], None] = print
) -> DemoResult:
    """Run the demo into ``out_dir`` (see the module docstring) and return its table."""
    from ..data.layout import read_image
    from ..inference import hand_render_config, orbit_views, prepare_render, render_to_folder
    from ..model.trained import load_trained
    from ..utils.device import resolve_device

    config = DemoConfig() if config is None else config
    if config.num_views < 5:
        raise ValueError(f"num_views must be >= 5 (4 fitted + novel views), got "
                         f"{config.num_views}")
    if config.hand_model not in HAND_MODELS:
        raise ValueError(f"hand_model must be one of {', '.join(HAND_MODELS)}, got "
                         f"{config.hand_model!r}")
    out_dir = Path(out_dir)
    start = time.perf_counter()
    device = resolve_device(config.device)
    model = load_trained(config.model, device)  # fail early when the model is missing
    log(f"model: {model.source} ({'geometry and colour' if model.has_color else 'geometry'})")

    log("1/5 synthesizing an unseen hand (mesh, scan, images, masks, keypoints)")
    frame, fitted, novel = _unseen_hand(out_dir / "input", config)
    rows, pictures, params = _run_fits(model, frame, fitted, novel, out_dir, config, log)

    log("5/5 rendering a turntable of the 4-view fit")
    scene = prepare_render(model, params, hand_render_config(model, normals="autograd"))
    cameras = orbit_views(scene, config.orbit_views, config.orbit_size, config.orbit_size)
    turntable = render_to_folder(scene, cameras, out_dir / "turntable", turntable=True)

    total = time.perf_counter() - start
    table = _markdown_table(rows)
    log("")
    log(table)
    log(f"(PSNR: inside the mask, in {len(novel)} views that no fit used, with the model's mean "
        "colour calibration, then with each novel camera's own simulated gain and bias; "
        "distances in mm against the ground-truth mesh)")
    preview = out_dir / "fit_points" / "preview.png"
    report_path = _write_report(out_dir / "report.html", rows, pictures, turntable.gif_path,
                                _to_uint8(read_image(frame.image(fitted[0]))), model.source, total,
                                config, preview if preview.is_file() else None)
    (out_dir / "results.md").write_text(table + "\n", encoding="utf-8")
    log(f"demo finished in {total:.0f} s: {report_path}")
    return DemoResult(rows=rows, report=report_path, seconds=total)


def _unseen_hand(data: Path, config: DemoConfig):
    """Synthesize the demo's hand into ``data``: -> (its frame's FramePaths, the 4 fitted view
    names spread around the rig, the novel view names)."""
    from ..data.layout import FramePaths
    from ..data.synth.dataset import SynthConfig, synthesize
    from ..geometry.cameras import load_cameras

    synthesize(data, SynthConfig(num_subjects=1, num_poses=1, num_views=config.num_views,
                                 resolution=config.resolution,
                                 seed=_DEMO_SEED_OFFSET + config.seed,
                                 hand_model=config.hand_model),
               progress=True, overwrite=True)
    frame = FramePaths(data / "s000" / "f000")
    names = [camera.name for camera in load_cameras(frame.cameras)]
    step = len(names) / 4
    fitted = [names[int(i * step)] for i in range(4)]
    return frame, fitted, [name for name in names if name not in fitted]


def _run_fits(model, frame, fitted: list[str], novel: list[str], out_dir: Path,
              config: DemoConfig, log: Callable[[str], None]):
    """The point-cloud, 1-view and 4-view fits: -> (table rows, novel-view pictures by fit,
    the 4-view fit's HandParams)."""
    from ..fitting.images.config import FitImagesConfig
    from ..fitting.images.folder import fit_image_folder
    from ..fitting.points.fit import FitPointsConfig
    from ..fitting.points.io import fit_point_file

    points_config = _scaled(FitPointsConfig(), config.fit_scale,
                            ("align_iters", "pose_iters", "field_iters"))
    images_config = _scaled(FitImagesConfig(), config.fit_scale,
                            ("keypoint_iters", "color_iters"))
    if not model.has_color:
        log("the model has no colour: image fits use keypoints and masks only, and no PSNR")
        images_config = replace(images_config, color_iters=0)
    rows, pictures = [], {}
    runs = [("point cloud", "fit_points", None), ("1 view", "fit_1view", fitted[:1]),
            ("4 views", "fit_4views", fitted)]
    for index, (label, folder, views) in enumerate(runs, start=2):
        log(f"{index}/5 fitting to the {label}")
        began = time.perf_counter()
        if views is None:
            # The demo fits one model to all three inputs (the point fit's own default is the
            # geometric prior, which has no colour for the novel views' PSNR).
            report = fit_point_file(frame.scan, out_dir / folder,
                                    model_path=config.model or "default",
                                    gt_path=frame.mesh, units="m",
                                    resolution=config.mesh_resolution, config=points_config,
                                    device=config.device, progress=True, log=log)
        else:
            report = fit_image_folder(frame.root, out_dir / folder, views=views,
                                      model_path=config.model, gt_path=frame.mesh, units="m",
                                      resolution=config.mesh_resolution, config=images_config,
                                      device=config.device, psnr=False, progress=True, log=log)
        seconds = time.perf_counter() - began
        params = report.fit.params
        psnr_db = psnr_calibrated_db = math.nan
        if model.has_color:
            psnr_db, psnr_calibrated_db, shots = _novel_view_psnr(model, params, frame, novel)
            pictures[label] = shots[0]
        rows.append({"method": f"LISA, {label}", **{k: report.metrics[k] for k in _METRICS},
                     "psnr_db": psnr_db, "psnr_calibrated_db": psnr_calibrated_db,
                     "seconds": seconds})
    return rows, pictures, params


def _fmt(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _markdown_table(rows: list[dict]) -> str:
    lines = ["| input | V2V recon->scan | V2S recon->scan | V2V scan->recon | V2S scan->recon "
             "| PSNR novel views (dB) | PSNR, novel cameras calibrated (dB) | time (s) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        cells = [row["method"], *(_fmt(row[k]) for k in _METRICS), _fmt(row["psnr_db"]),
                 _fmt(row["psnr_calibrated_db"]), f"{row['seconds']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _write_report(path: Path, rows, pictures, gif: Path | None, input_image: np.ndarray,
                  source: str, seconds: float, config: DemoConfig,
                  preview: Path | None = None) -> Path:
    """report.html; preview: the point-cloud fit's ``preview.png`` (shown when given)."""
    from ..utils.io import atomic_path

    header = ("<tr><th>input</th><th>V2V recon&rarr;scan</th><th>V2S recon&rarr;scan</th>"
              "<th>V2V scan&rarr;recon</th><th>V2S scan&rarr;recon</th>"
              "<th>PSNR novel views (dB)</th><th>PSNR, novel cameras calibrated (dB)</th>"
              "<th>time (s)</th></tr>")
    body = "".join(
        "<tr><td>" + html.escape(row["method"]) + "</td>"
        + "".join(f"<td>{_fmt(row[k])}</td>" for k in _METRICS)
        + f"<td>{_fmt(row['psnr_db'])}</td><td>{_fmt(row['psnr_calibrated_db'])}</td>"
        + f"<td>{row['seconds']:.0f}</td></tr>"
        for row in rows
    )
    figures = "".join(
        f"<figure><img src='{_png_data_uri(np.concatenate([shot, truth], axis=1))}'>"
        f"<figcaption>{html.escape(label)}: fitted (left) and true (right), novel view"
        "</figcaption></figure>"
        for label, (shot, truth) in pictures.items()
    )
    turntable = (f"<figure><img src='{_file_data_uri(gif, 'gif')}'><figcaption>turntable of the "
                 "4-view fit</figcaption></figure>") if gif is not None else ""
    scan_fit = ("<h2>The point-cloud fit and its scan</h2><figure><img src='"
                f"{_file_data_uri(preview, 'png')}'><figcaption>preview.png: the scan's points "
                "coloured by their distance to the fitted surface</figcaption></figure>"
                ) if preview is not None else ""
    page = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>LISA-open demo</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}
figure{{display:inline-block;margin:8px}}img{{max-width:100%}}</style></head><body>
<h1>LISA-open demo</h1>
<p>Model: {html.escape(source)}. An unseen hand of the open hand model
{html.escape(config.hand_model)} (demo seed {config.seed}) fitted from its scan, from 1 view and
from 4 views. Distances in mm against the ground-truth mesh (V2V: vertex to nearest vertex;
V2S: vertex to surface), PSNR inside the mask in views that no fit used. Whole demo:
{seconds:.0f} s.</p>
<table>{header}{body}</table>
<h2>Input (one of the fitted views)</h2>
<figure><img src='{_png_data_uri(input_image)}'></figure>
<h2>Novel views</h2>{figures}
<h2>Turntable</h2>{turntable}
{scan_fit}
</body></html>
"""
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return path
