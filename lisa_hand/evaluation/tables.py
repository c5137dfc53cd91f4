"""``lisa eval``: the paper's three tables on held-out subjects of a synthetic dataset.

Test sets (subjects of the ``test`` split, never seen in training):

* Table 1, point clouds: set ``subjects`` (frame f000 of each of ``num_subjects`` held-out
  subjects) and set ``poses`` (``num_poses`` frames of one held-out subject). Each method fits
  the frame's ``scan.npz``: the implicit models with :func:`lisa_hand.fitting.io.fit_point_file`
  (global pose from scratch, then pose, skeleton and shape code), meshed by marching cubes at
  ``resolution``^3; the MANO-like template with
  :func:`lisa_hand.evaluation.template_fit.fit_template_points`, subdivided to about 100k
  vertices. V2V and V2S in mm, both ways, against the frame's ground-truth ``mesh.ply``.
* Table 2 and 3, images: frame f000 of ``image_subjects`` held-out subjects; the views are
  split once per frame into 4 input views spread around the rig (1 view: the first, 2 views:
  the first and the third) and the other views, novel for every fit. Stage 1 of
  :func:`lisa_hand.fitting.images.fit_images` (pose from keypoints and masks on the template)
  depends on the views only, so it runs once per frame and view count and is shared: it is
  also the MANO-like row (the template fitted to the keypoints and masks). Each colour model
  then runs stage 2 (pose, shape and colour codes from the colour loss), is meshed (V2V, V2S
  scan to reconstruction, Table 2) and rendered into the novel views: PSNR inside the mask
  (Table 2 and 3), SSIM of the whole image and LPIPS (Table 3; LPIPS where its weights are
  installed, else the column is empty and the JSON says why).

Every number comes from the run. Each fit's result is kept in ``OUT/jobs/*.json`` as it
finishes: the same command resumes an interrupted evaluation (delete ``OUT`` to start afresh).
Fits run in ``workers`` processes of one thread each.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..utils.config import check_int_fields
from ..utils.io import read_json, write_json
from .methods import METHODS, check_model_method

__all__ = ["EvalConfig", "EvalResult", "run_eval", "plan_jobs", "build_results", "markdown_tables",
           "make_pictures"]

DISTANCES = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
             "v2s_scan_to_recon_mm")
VIEW_COUNTS = (1, 2, 4)


@dataclass(frozen=True)
class EvalConfig:
    """What :func:`run_eval` measures (defaults: the full run of ``docs/results.md``)."""

    num_subjects: int | None = None
    """Table 1 set 'subjects': held-out subjects, frame f000 each (None: all)."""
    num_poses: int = 6
    """Table 1 set 'poses': frames of one held-out subject."""
    pose_subject: str | None = None
    """The subject of set 'poses' (None: the last test subject)."""
    image_subjects: int = 4
    """Tables 2 and 3: held-out subjects (frame f000 each)."""
    views: tuple[int, ...] = VIEW_COUNTS
    """Input view counts of Tables 2 and 3 (each of 1, 2, 4)."""
    resolution: int = 256
    """Marching-cubes samples a side for every implicit method (the paper: 256)."""
    template_vertices: int = 100_000
    """The MANO-like mesh is loop-subdivided to about this many vertices (the paper: ~100k)."""
    fit_scale: float = 1.0
    """Multiplies every fit's iteration counts (quick mode: a small fraction)."""
    render_samples: int = 32
    """Samples per ray in the band around the surface for the novel views."""
    tables: tuple[str, ...] = ("points", "images")
    """Which fits to run: 'points' (Table 1) and/or 'images' (Tables 2 and 3)."""
    workers: int = 2
    """Processes running fits at once (one CPU thread each); 1: in this process."""
    device: str = "cpu"
    """Where the models run: 'cpu', 'cuda', 'cuda:N' or 'auto' (CUDA when available)."""

    def __post_init__(self) -> None:
        check_int_fields(self, ("num_poses", "image_subjects", "resolution", "workers",
                                "template_vertices", "render_samples"), 1)
        if self.num_subjects is not None and self.num_subjects < 1:
            raise ValueError(f"num_subjects must be >= 1 or None, got {self.num_subjects!r}")
        if not self.views or any(v not in VIEW_COUNTS for v in self.views):
            raise ValueError(f"views must be a non-empty subset of {VIEW_COUNTS}, got "
                             f"{self.views!r}")
        if not self.tables or any(t not in ("points", "images") for t in self.tables):
            raise ValueError(f"tables must name 'points' and/or 'images', got {self.tables!r}")
        if not self.fit_scale > 0:
            raise ValueError(f"fit_scale must be > 0, got {self.fit_scale!r}")


@dataclass
class EvalResult:
    """results: what ``results.json`` holds; markdown: ``results.md``; out: the folder."""

    results: dict[str, Any]
    markdown: str
    out: Path


# ------------------------------------------------------------------------------------------------
# Jobs (each runs in a worker process; models are loaded once per process)

_MODELS: dict[str, Any] = {}


def _model(path: str, device: str):
    from ..model.trained import load_trained

    key = f"{path}@{device}"
    if key not in _MODELS:
        _MODELS[key] = load_trained(path, device)
    return _MODELS[key]


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)


def _scaled(config, scale: float, names: Sequence[str]):
    return dataclasses.replace(config, **{n: max(1, int(round(getattr(config, n) * scale)))
                                          for n in names})


def _distances(vertices, faces, truth_path: Path) -> dict[str, float]:
    from ..metrics import load_mesh, mesh_distances

    truth = load_mesh(truth_path)
    return mesh_distances(vertices, faces, truth.vertices, truth.faces).to_dict()


def _write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    from ..utils.io import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        trimesh.Trimesh(vertices, faces, process=False).export(tmp, file_type="ply")


def _point_job(job: dict) -> dict:
    """Fit one method to one frame's scan -> the four distances and the time."""
    from ..data.layout import FramePaths, read_npz
    from ..fitting.io import fit_point_file
    from ..fitting.points import FitPointsConfig
    from .template_fit import TemplateFitConfig, fit_template_points, subdivide_to, template_mesh

    frame = FramePaths(Path(job["frame"]))
    out = Path(job["out"])
    start = time.perf_counter()
    if job["method"] == "mano":
        from ..handmodel.template import load_template

        config = _scaled(TemplateFitConfig(), job["fit_scale"], ("rigid_iters", "iters"))
        points = read_npz(frame.scan, required=("points",))["points"]
        fit = fit_template_points(points, config=config)
        vertices, faces = template_mesh(load_template(), fit.pose, fit.betas, fit.translation)
        vertices, faces = subdivide_to(vertices, faces, job["template_vertices"])
        seconds = time.perf_counter() - start
        _write_mesh(out / "mesh.ply", vertices, faces)
        metrics = _distances(vertices, faces, frame.mesh)
    else:
        config = _scaled(FitPointsConfig(), job["fit_scale"],
                         ("align_iterations", "pose_iterations", "iterations"))
        report = fit_point_file(frame.scan, out, model_path=job["model"], gt_path=frame.mesh,
                                units="m", resolution=job["resolution"], config=config,
                                device=job["device"])
        seconds = time.perf_counter() - start
        metrics = dict(report.metrics)
    return {**{k: job[k] for k in ("kind", "set", "frame_name", "method")},
            **metrics, "seconds": seconds}


def _novel_metrics(model, params, views, samples: int, picture: Path | None) -> dict:
    from ..data.layout import write_image
    from ..fitting.images import render_fitted_views
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


def _image_job(job: dict) -> list[dict]:
    """Stage 1 once for one frame and view count (also the MANO-like row), then stage 2, the
    mesh and the novel views for every colour model."""
    import torch

    from ..fitting.images import FitImagesConfig, fit_images, fit_keypoints, read_views
    from ..handmodel.template import load_template
    from ..inference import mesh_hand
    from .template_fit import subdivide_to, template_mesh

    frame_dir = Path(job["frame"])
    out = Path(job["out"])
    views = read_views(frame_dir, job["views"])
    novel = read_views(frame_dir, job["novel"])
    config = _scaled(FitImagesConfig(), job["fit_scale"], ("keypoint_iters", "color_iters"))
    template = load_template()
    rows = []
    base = {k: job[k] for k in ("kind", "frame_name", "num_views")}
    start = time.perf_counter()
    torch.manual_seed(0)
    pose_fit = fit_keypoints(views, config, template)
    stage1 = time.perf_counter() - start
    vertices, faces = template_mesh(template, pose_fit.pose, pose_fit.betas,
                                    pose_fit.translation)
    vertices, faces = subdivide_to(vertices, faces, job["template_vertices"])
    _write_mesh(out / "mano" / "mesh.ply", vertices, faces)
    rows.append({**base, "method": "mano", **_distances(vertices, faces, frame_dir / "mesh.ply"),
                 "psnr_db": None, "ssim": None, "lpips": None, "seconds": stage1,
                 "keypoint_error_px": pose_fit.keypoint_error_px})
    for method, path in job["models"].items():
        model = _model(path, job["device"])
        began = time.perf_counter()
        fit = fit_images(model, views, config, start=pose_fit, template=template)
        seconds = stage1 + time.perf_counter() - began
        mesh = mesh_hand(model, fit.params, job["resolution"])
        _write_mesh(out / method / "mesh.ply", mesh.vertices, mesh.faces)
        novel_scores = _novel_metrics(model, fit.params, novel, job["render_samples"],
                                      out / method / "novel.png")
        rows.append({**base, "method": method,
                     **_distances(mesh.vertices, mesh.faces, frame_dir / "mesh.ply"),
                     **novel_scores, "seconds": seconds,
                     "keypoint_error_px": fit.keypoint_error_px["color"]})
    return rows


def _run_job(job: dict) -> dict | list[dict]:
    return _point_job(job) if job["kind"] == "points" else _image_job(job)


# ------------------------------------------------------------------------------------------------
# Planning


def _spread(names: Sequence[str], count: int) -> list[str]:
    step = len(names) / count
    return [names[int(i * step)] for i in range(count)]


def plan_jobs(data_dir: Path, models: dict[str, str], config: EvalConfig, out: Path
              ) -> list[dict]:
    """The fits to run: one job per (method, frame) for the point clouds, one per (frame, view
    count) for the images."""
    from ..data.layout import list_frames, read_split
    from ..geometry.cameras import load_cameras
    from ..utils.device import resolve_device

    subjects = read_split(data_dir).get("test", [])
    if not subjects:
        raise ValueError(f"{data_dir}: the split has no test subjects (split.json)")
    frames = {}
    for paths in list_frames(data_dir, subjects):
        frames.setdefault(paths.root.parent.name, []).append(paths)
    for subject in frames:
        frames[subject].sort(key=lambda p: p.root.name)
    subjects = [s for s in subjects if s in frames]
    common = {"resolution": config.resolution, "fit_scale": config.fit_scale,
              "template_vertices": config.template_vertices,
              "device": str(resolve_device(config.device))}
    jobs = []
    if "points" in config.tables:
        pose_subject = config.pose_subject or subjects[-1]
        if pose_subject not in frames:
            raise ValueError(f"{data_dir}: pose subject {pose_subject!r} is not a test subject "
                             f"({', '.join(subjects)})")
        sets = {"subjects": [frames[s][0] for s in subjects[: config.num_subjects]],
                "poses": frames[pose_subject][: config.num_poses]}
        point_methods = ["mano", *[m for m in models if m in METHODS]]
        for set_name, paths_list in sets.items():
            for paths in paths_list:
                name = f"{paths.root.parent.name}_{paths.root.name}"
                for method in point_methods:
                    jobs.append({"kind": "points", "set": set_name, "frame_name": name,
                                 "method": method, "frame": str(paths.root),
                                 "model": models.get(method),
                                 "out": str(out / "fits" / "points" / set_name / name / method),
                                 **common})
    if "images" in config.tables:
        color_models = {m: p for m, p in models.items() if METHODS[m].color is True}
        for subject in subjects[: config.image_subjects]:
            paths = frames[subject][0]
            names = [camera.name for camera in load_cameras(paths.cameras)]
            if len(names) < 5:
                raise ValueError(f"{paths.root}: {len(names)} views; the image tables need at "
                                 "least 5 (4 inputs and a novel view)")
            inputs = _spread(names, 4)
            chosen = {1: inputs[:1], 2: [inputs[0], inputs[2]], 4: inputs}
            novel = [n for n in names if n not in inputs]
            name = f"{paths.root.parent.name}_{paths.root.name}"
            for count in config.views:
                jobs.append({"kind": "images", "frame_name": name, "num_views": count,
                             "frame": str(paths.root), "views": chosen[count], "novel": novel,
                             "models": color_models, "render_samples": config.render_samples,
                             "out": str(out / "fits" / f"images_{count}" / name), **common})
    return jobs


def _job_id(job: dict) -> str:
    if job["kind"] == "points":
        return f"points_{job['set']}_{job['frame_name']}_{job['method']}"
    return f"images_{job['num_views']}_{job['frame_name']}"


# ------------------------------------------------------------------------------------------------
# Tables


def _mean(rows: list[dict], key: str) -> float | None:
    values = [r[key] for r in rows if r.get(key) is not None and math.isfinite(r[key])]
    return float(np.mean(values)) if values else None


def _aggregate(rows: list[dict], keys: Sequence[str], order: Sequence[str]) -> dict:
    table = {}
    for method in order:
        mine = [r for r in rows if r["method"] == method]
        if mine:
            table[method] = {**{k: _mean(mine, k) for k in keys}, "count": len(mine),
                             "seconds": _mean(mine, "seconds")}
    return table


def build_results(point_rows: list[dict], image_rows: list[dict], order: Sequence[str]) -> dict:
    """The three tables (means over the frames) from the per-fit rows."""
    table1 = {}
    for set_name in ("subjects", "poses"):
        rows = [r for r in point_rows if r["set"] == set_name]
        if rows:
            table1[set_name] = _aggregate(rows, DISTANCES, order)
    table2, table3 = {}, {}
    for count in VIEW_COUNTS:
        rows = [r for r in image_rows if r["num_views"] == count]
        if rows:
            table2[str(count)] = _aggregate(rows, ("v2v_scan_to_recon_mm",
                                                   "v2s_scan_to_recon_mm", "psnr_db"), order)
            table3[str(count)] = _aggregate([r for r in rows if r["method"] != "mano"],
                                            ("psnr_db", "ssim", "lpips"), order)
    lpips_note = next((r["lpips_message"] for r in image_rows if r.get("lpips_message")), "")
    return {"table1": table1, "table2": table2, "table3": table3,
            "lpips_note": lpips_note or None}


def _cell(value: float | None, digits: int, best: bool) -> str:
    if value is None:
        return "-"
    text = f"{value:.{digits}f}"
    return f"**{text}**" if best else text


def _best(table: dict, key: str, lower: bool) -> float | None:
    values = [row[key] for row in table.values() if row.get(key) is not None]
    if not values:
        return None
    return min(values) if lower else max(values)


def markdown_tables(results: dict) -> str:
    """Tables 1-3 as Markdown (best value of each column in bold)."""
    lines = []
    t1 = results["table1"]
    if t1:
        lines += ["### Table 1: shape from point clouds (mm, lower is better)", "",
                  "| Method | V2V recon->scan | V2S recon->scan | V2V scan->recon | "
                  "V2S scan->recon | fit time (s) |",
                  "|---|---|---|---|---|---|"]
        for set_name, title in (("subjects", "held-out subjects, one pose each"),
                                ("poses", "one held-out subject, many poses")):
            table = t1.get(set_name)
            if not table:
                continue
            count = max(row["count"] for row in table.values())
            lines.append(f"| *{title} ({count} scans)* | | | | | |")
            for method, row in table.items():
                cells = [_cell(row[k], 2, row[k] is not None and row[k] == _best(table, k, True))
                         for k in DISTANCES]
                lines.append(f"| {METHODS[method].label} | " + " | ".join(cells)
                             + f" | {row['seconds']:.0f} |")
        lines.append("")
    for key, title, columns in (
            ("table2", "Table 2: shape and colour from images (V2V, V2S scan->recon in mm; "
             "PSNR in dB inside the mask, novel views)",
             (("v2v_scan_to_recon_mm", "V2V", True, 2), ("v2s_scan_to_recon_mm", "V2S", True, 2),
              ("psnr_db", "PSNR", False, 2))),
            ("table3", "Table 3: colour in novel views (PSNR in the mask, dB; SSIM and LPIPS "
             "of the whole image)",
             (("psnr_db", "PSNR", False, 2), ("ssim", "SSIM", False, 3),
              ("lpips", "LPIPS", True, 3)))):
        tables = results[key]
        if not tables:
            continue
        counts = list(tables)
        header = "| Method | " + " | ".join(f"{name} ({c} view{'s' if c != '1' else ''})"
                                           for c in counts for _, name, _, _ in columns) + " |"
        lines += [f"### {title}", "", header,
                  "|---|" + "---|" * (len(counts) * len(columns))]
        methods = [m for m in METHODS if any(m in tables[c] for c in counts)]
        for method in methods:
            cells = []
            for c in counts:
                row = tables[c].get(method)
                for column, _, lower, digits in columns:
                    value = None if row is None else row.get(column)
                    cells.append(_cell(value, digits,
                                       value is not None and value == _best(tables[c], column,
                                                                            lower)))
            lines.append(f"| {METHODS[method].label} | " + " | ".join(cells) + " |")
        if key == "table3" and results.get("lpips_note"):
            lines.append("")
            lines.append(results['lpips_note'])
        lines.append("")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# Pictures


def _crop(images: list[np.ndarray], background: int, margin: int = 8) -> list[np.ndarray]:
    """The images (same size) cropped to the box around every pixel that is not the
    background colour in any of them, plus a margin."""
    content = np.zeros(images[0].shape[:2], bool)
    for image in images:
        content |= np.abs(image.astype(np.int16) - background).max(axis=-1) > 8
    if not content.any():
        return images
    rows, cols = np.nonzero(content.any(axis=1))[0], np.nonzero(content.any(axis=0))[0]
    top, bottom = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, content.shape[0])
    left, right = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, content.shape[1])
    return [image[top:bottom, left:right] for image in images]


def _tile(images: list[np.ndarray], labels: list[str], background: int) -> np.ndarray:
    """Images side by side (cropped to the hand), each with its label written above it."""
    from PIL import Image, ImageDraw

    if len({image.shape for image in images}) == 1:
        images = _crop(images, background)
    height = max(image.shape[0] for image in images)
    strip = 18
    tiles = []
    for image, label in zip(images, labels, strict=True):
        canvas = Image.new("RGB", (image.shape[1], height + strip), (255, 255, 255))
        canvas.paste(Image.fromarray(image), (0, strip))
        ImageDraw.Draw(canvas).text((4, 3), label, fill=(0, 0, 0))
        tiles.append(np.asarray(canvas))
    return np.concatenate(tiles, axis=1)


def _mesh_picture(vertices: np.ndarray, faces: np.ndarray, camera) -> np.ndarray:
    from ..data.images import ShadingConfig, render_views

    image = render_views(vertices, faces, [camera], np.array([0.75, 0.72, 0.70]),
                         ShadingConfig(background=(1.0, 1.0, 1.0)))[0]
    return (np.clip(image.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def make_pictures(out: Path, point_rows: list[dict], image_rows: list[dict], order: list[str],
                  count: int = 2) -> list[Path]:
    """``pictures/points_FRAME.png``: each method's fitted mesh and the truth, from the
    frame's first camera; ``pictures/images4_FRAME.png``: each method's first novel view after
    the 4-view fit, and the true image. For the first ``count`` frames of Table 1's 'subjects'
    set and of the image tables."""
    from ..data.layout import FramePaths, read_image, write_image
    from ..geometry.cameras import load_cameras
    from ..metrics import load_mesh

    def as_uint8(image: np.ndarray) -> np.ndarray:
        return (image * 255 + 0.5).astype(np.uint8)

    written = []
    frames = dict.fromkeys((r["frame_name"], r["frame"]) for r in point_rows
                           if r["set"] == "subjects")
    for name, frame_dir in list(frames)[:count]:
        frame = FramePaths(Path(frame_dir))
        camera = load_cameras(frame.cameras)[0]
        images, labels = [], []
        for method in order:
            path = out / "fits" / "points" / "subjects" / name / method / "mesh.ply"
            if path.is_file():
                mesh = load_mesh(path)
                images.append(_mesh_picture(mesh.vertices, mesh.faces, camera))
                labels.append(METHODS[method].label)
        truth = load_mesh(frame.mesh)
        images.append(_mesh_picture(truth.vertices, truth.faces, camera))
        labels.append("ground truth")
        target = out / "pictures" / f"points_{name}.png"
        target.parent.mkdir(parents=True, exist_ok=True)
        write_image(target, _tile(images, labels, background=255))
        written.append(target)
    frames = dict.fromkeys((r["frame_name"], r["frame"], r["novel_view"]) for r in image_rows
                           if r["num_views"] == 4)
    for name, frame_dir, novel in list(frames)[:count]:
        folder = out / "fits" / "images_4" / name
        images, labels = [], []
        for method in order:
            path = folder / method / "novel.png"
            if path.is_file():
                images.append(as_uint8(read_image(path)))
                labels.append(METHODS[method].label)
        if images:
            images.append(as_uint8(read_image(FramePaths(Path(frame_dir)).image(novel))))
            labels.append("ground truth")
            target = out / "pictures" / f"images4_{name}.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            write_image(target, _tile(images, labels, background=0))
            written.append(target)
    return written


# ------------------------------------------------------------------------------------------------
# The run


def run_eval(
    data_dir: str | os.PathLike,
    models: dict[str, str],
    out_dir: str | os.PathLike,
    config: EvalConfig | None = None,
    log: Callable[[str], None] = print,
    progress: bool = True,
) -> EvalResult:
    """Evaluate ``models`` ({method: model path}, see :mod:`lisa_hand.evaluation.methods`; the
    MANO-like template is always in) on the held-out subjects of ``data_dir``; write
    ``results.json``, ``results.md`` and ``pictures/`` into ``out_dir``."""
    from ..model.trained import load_trained

    config = EvalConfig() if config is None else config
    data_dir, out = Path(data_dir), Path(out_dir)
    if not (data_dir / "split.json").is_file():
        raise FileNotFoundError(f"{data_dir}: not a dataset folder (no split.json; make one "
                                "with 'lisa synth')")
    models = {m: str(Path(p)) for m, p in models.items()}
    for method, path in models.items():
        check_model_method(method, load_trained(path, "cpu"), path)
    order = [m for m in METHODS if m == "mano" or m in models]
    out.mkdir(parents=True, exist_ok=True)
    jobs = plan_jobs(data_dir, models, config, out)
    start = time.perf_counter()
    log(f"eval: {len(jobs)} fits ({sum(j['kind'] == 'points' for j in jobs)} point-cloud fits, "
        f"{sum(j['kind'] == 'images' for j in jobs)} image fits of "
        f"{1 + sum(METHODS[m].color is True for m in models)} methods each), "
        f"{config.workers} worker(s)")
    done: dict[str, Any] = {}
    todo = []
    for job in jobs:
        cached = out / "jobs" / f"{_job_id(job)}.json"
        record = read_json(cached) if cached.is_file() else None
        if record is not None and record.get("job") == job:  # same fit, same settings
            done[_job_id(job)] = record["result"]
        else:
            todo.append(job)
    if done:
        log(f"resuming: {len(done)} fits already done in {out / 'jobs'}")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(done), desc="eval", unit="fit")

    def finish(job: dict, result) -> None:
        write_json(out / "jobs" / f"{_job_id(job)}.json", {"job": job, "result": result})
        done[_job_id(job)] = result
        if bar is not None:
            bar.update(1)

    if config.workers == 1 or len(todo) <= 1:
        import torch

        previous = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for job in todo:
                finish(job, _run_job(job))
        finally:
            torch.set_num_threads(previous)
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(config.workers, mp_context=context,
                                 initializer=_worker_init) as pool:
            futures = {pool.submit(_run_job, job): job for job in todo}
            for future in as_completed(futures):
                finish(futures[future], future.result())
    if bar is not None:
        bar.close()
    point_rows = [{**done[_job_id(j)], "frame": j["frame"]} for j in jobs if j["kind"] == "points"]
    image_rows = []
    for job in jobs:
        if job["kind"] == "images":
            for row in done[_job_id(job)]:
                image_rows.append({**row, "frame": job["frame"], "novel_view": job["novel"][0]})
    results = build_results(point_rows, image_rows, order)
    bad = [(r.get("frame_name"), r["method"], k) for r in point_rows + image_rows
           for k in DISTANCES if k in r and (r[k] is None or not math.isfinite(r[k]))]
    if bad:
        raise ValueError(f"non-finite distances in {len(bad)} fits, e.g. {bad[0]}")
    pictures = make_pictures(out, point_rows, image_rows, order)
    results.update({
        "data": str(data_dir),
        "models": {m: {"path": p, "label": METHODS[m].label,
                       "composition": METHODS[m].composition} for m, p in models.items()},
        "config": asdict(config),
        "fits": {"points": point_rows, "images": image_rows},
        "pictures": [str(p.relative_to(out)) for p in pictures],
        "seconds": time.perf_counter() - start,
    })
    markdown = markdown_tables(results)
    from ..fitting.outputs import json_safe

    write_json(out / "results.json", json_safe(results))
    (out / "results.md").write_text(markdown + "\n", encoding="utf-8")
    log(markdown)
    log(f"eval finished in {results['seconds']:.0f} s: {out / 'results.md'}")
    return EvalResult(results=results, markdown=markdown, out=out)

