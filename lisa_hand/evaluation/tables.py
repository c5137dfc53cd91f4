"""``lisa eval``: the paper's three tables on held-out subjects of a synthetic dataset.

Test sets (subjects of the ``test`` split, never seen in training):

* Table 1, point clouds: set ``subjects`` (frame f000 of each of ``num_subjects`` held-out
  subjects) and set ``poses`` (``num_poses`` frames of one held-out subject). Each method fits
  the frame's ``scan.npz``: the implicit models with
  :func:`lisa_hand.fitting.points.io.fit_point_file`
  (global pose from scratch, then pose, skeleton and shape code), meshed by marching cubes at
  ``resolution``^3; the MANO-like template with
  :func:`lisa_hand.evaluation.template_fit.fit_template_points`, subdivided to about 100k
  vertices. V2V and V2S in mm, both ways, against the frame's ground-truth ``mesh.ply``.
* Table 2 and 3, images: frame f000 of ``image_subjects`` held-out subjects; the views are
  split once per frame into 4 input views spread around the rig (1 view: the first, 2 views:
  the first and the third) and the other views, novel for every fit. Stage 1 of
  :func:`lisa_hand.fitting.images.fit.fit_images` (pose from keypoints and masks on the template)
  depends on the views only, so it runs once per frame and view count and is shared: it is
  also the MANO-like row (the template fitted to the keypoints and masks). Each colour model
  then runs stage 2 (pose, shape and colour codes from the colour loss), is meshed (V2V, V2S
  scan to reconstruction, Table 2) and rendered into the novel views: PSNR inside the mask
  (Table 2 and 3), SSIM of the whole image and LPIPS (Table 3; LPIPS where its weights are
  installed, else the column is empty and the JSON says why).

Every number comes from the run. Each fit's result is kept in ``OUT/jobs/*.json`` as it
finishes: the same command resumes an interrupted evaluation (delete ``OUT`` to start afresh).
Fits run in ``workers`` processes of one thread each.

The jobs (planning, running, the cache) are in :mod:`lisa_hand.evaluation.jobs`, how each method
fits a frame in :mod:`lisa_hand.evaluation.methods`, the settings in
:mod:`lisa_hand.evaluation.config`, the pictures in :mod:`lisa_hand.evaluation.pictures`; this
module runs them and makes the tables.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..utils.io import write_json
from .config import VIEW_COUNTS, EvalConfig
from .jobs import ImageJob, Job, PointJob, cached_results, plan_jobs, run_jobs
from .methods import METHODS, TEMPLATE_METHOD, check_model_method
from .pictures import make_pictures

__all__ = ["DISTANCES", "EvalResult", "run_eval", "build_results", "markdown_tables"]

DISTANCES = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
             "v2s_scan_to_recon_mm")


@dataclass
class EvalResult:
    """results: what ``results.json`` holds; markdown: ``results.md``; out: the folder."""

    results: dict[str, Any]
    markdown: str
    out: Path


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
            colour_rows = [r for r in rows if r["method"] != TEMPLATE_METHOD.name]
            table3[str(count)] = _aggregate(colour_rows, ("psnr_db", "ssim", "lpips"), order)
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
# The run


def _checked_models(data_dir: Path, models: dict[str, str]) -> dict[str, str]:
    """``models`` with normalised paths, each checked to be its method's kind of model."""
    from ..model.trained import load_trained

    if not (data_dir / "split.json").is_file():
        raise FileNotFoundError(f"{data_dir}: not a dataset folder (no split.json; make one "
                                "with 'lisa synth')")
    models = {m: str(Path(p)) for m, p in models.items()}
    for method, path in models.items():
        check_model_method(method, load_trained(path, "cpu"), path)
    return models


def _run_all(jobs: list[Job], config: EvalConfig, models: dict[str, str], out: Path,
             log: Callable[[str], None], progress: bool) -> dict[str, Any]:
    """Every job's result ({job_id: result}): the cached ones, then the others, run."""
    log(f"eval: {len(jobs)} fits ({sum(isinstance(j, PointJob) for j in jobs)} point-cloud "
        f"fits, {sum(isinstance(j, ImageJob) for j in jobs)} image fits of "
        f"{1 + sum(METHODS[m].color is True for m in models)} methods each), "
        f"{config.workers} worker(s)")
    done, todo = cached_results(jobs, out / "jobs")
    if done:
        log(f"resuming: {len(done)} fits already done in {out / 'jobs'}")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(done), desc="eval", unit="fit")
    try:
        done.update(run_jobs(todo, config.workers, out / "jobs",
                             on_done=None if bar is None else lambda: bar.update(1)))
    finally:
        if bar is not None:
            bar.close()
    return done


def _fit_rows(jobs: list[Job], done: dict[str, Any]) -> tuple[list[dict], list[dict]]:
    """The per-fit rows of the point and the image tables, with their frame folders."""
    point_rows = [{**done[j.job_id], "frame": j.frame} for j in jobs if isinstance(j, PointJob)]
    image_rows = []
    for job in jobs:
        if isinstance(job, ImageJob):
            for row in done[job.job_id]:
                image_rows.append({**row, "frame": job.frame, "novel_view": job.novel[0]})
    bad = [(r.get("frame_name"), r["method"], k) for r in point_rows + image_rows
           for k in DISTANCES if k in r and (r[k] is None or not math.isfinite(r[k]))]
    if bad:
        raise ValueError(f"non-finite distances in {len(bad)} fits, e.g. {bad[0]}")
    return point_rows, image_rows


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
    from ..fitting.outputs import json_safe

    config = EvalConfig() if config is None else config
    data_dir, out = Path(data_dir), Path(out_dir)
    models = _checked_models(data_dir, models)
    order = [m for m in METHODS if m == TEMPLATE_METHOD.name or m in models]
    out.mkdir(parents=True, exist_ok=True)
    jobs = plan_jobs(data_dir, models, config, out)
    start = time.perf_counter()
    done = _run_all(jobs, config, models, out, log, progress)
    point_rows, image_rows = _fit_rows(jobs, done)
    results = build_results(point_rows, image_rows, order)
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
    write_json(out / "results.json", json_safe(results))
    (out / "results.md").write_text(markdown + "\n", encoding="utf-8")
    log(markdown)
    log(f"eval finished in {results['seconds']:.0f} s: {out / 'results.md'}")
    return EvalResult(results=results, markdown=markdown, out=out)
