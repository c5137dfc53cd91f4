"""``python -m benchmarks pages [--results DIR] [--out FILE]``: write the results page
(``docs/results.md``) from the recorded JSON (``benchmarks/results/*.json``).

Every number on the page comes from a JSON file a run wrote, shown with the command that wrote it
and the date, commit and machine recorded in it (``recorded``, :func:`benchmarks.write_results`);
nothing on the page is typed by hand. A benchmark without a JSON file yet is listed with the
command that records one. ``lisa eval``'s tables (the paper's Tables 1-3) are recorded as
``eval_*.json`` files that name the ``results.json`` ``lisa eval`` wrote (``results_file``) and
the commands of the run; :func:`lisa_hand.evaluation.tables.markdown_tables` makes the tables
from it, as ``lisa eval`` does.

To update a section: run its command (from the repository root; its ``--json`` path is the file
in ``benchmarks/results/``), then ``python -m benchmarks pages``.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path

from . import RESULTS_DIR, benchmark_names

__all__ = ["render_page", "main"]

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "results.md"

SECTIONS: dict[str, tuple[str, str]] = {
    "field": ("Field: points per second against a straightforward reference",
              "python -m benchmarks field --points 65536 --no-fused --repeats 1"),
    "mesh": ("Meshing: coarse-to-fine marching cubes against the dense grid",
             "python -m benchmarks mesh --threads 1"),
    "render": ("Rendering: a whole image, fast path against uniform sampling",
               "python -m benchmarks render --threads 1 --resolution 512x333"),
    "train": ("Image training: steps per second and novel-view PSNR",
              "python -m benchmarks train"),
    "fit": ("Point-cloud fitting: time to V2S 1 mm, and the WebXR hand",
            "python -m benchmarks fit"),
    "heldout": ("Point-cloud fitting: MakeHuman hands older than any the models learnt from",
                "python -m benchmarks heldout"),
    "oneview": ("One view: the keypoint stage's depth restarts",
                "python -m benchmarks oneview --hands 3"),
    "photo": ("Photos: lisa fit-photo on synthetic photos with ground truth",
              "python -m benchmarks photo"),
    "video": ("Video: lisa fit-video tracked against every frame fitted alone",
              "python -m benchmarks video"),
    "two_hands": ("Two hands: photos, scans and views of two hands fitted together against each "
                  "hand alone", "python -m benchmarks two_hands --modes photo,scan,views"),
    "rgbd": ("RGB-D frames: depth with and without its colour image",
             "python -m benchmarks rgbd --frames 1 --threads 1"),
    "colours": ("Colours of a fit from a coloured scan",
                "python -m benchmarks colours --hands 1"),
    "handmodel": ("Hand model v3: its population and the volume its skinning keeps",
                  "python -m benchmarks handmodel"),
}
"""Benchmark -> (section title, the command that records its JSON, without ``--json``), in the
page's order."""

_EVAL_METHODS = """| method | configuration | trained on |
| --- | --- | --- |
| MANO-like | the mesh template (`lisa_hand/assets/template.npz`), pose and shape fitted by optimisation, loop-subdivided for the metrics | built once from the open hand model |
| VolSDF | `field.composition=single`: one SDF MLP and one colour MLP on the pose, shape and colour codes | images |
| NASA | `field.composition=nasa`: per-bone SDF MLPs, the bone with the smallest SDF selected | images |
| NARF | `field.composition=narf`: per-bone MLPs blended by a skinning MLP of the unposed points | images |
| LISA-im | `field.composition=lisa`, without the geometric prior | images |
| LISA-geom | the geometric prior (`lisa train-prior`) | scans |
| LISA-full | `lisa train --prior ...` (each run's settings are in its commands below) | scans, then images |"""  # noqa: E501


# ------------------------------------------------------------------------------------------------
# Formatting


def _number(value, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits ('-' for None, NaN as 'nan')."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        if math.isnan(value) or math.isinf(value):
            return str(value)
        if value != 0 and (abs(value) >= 10 ** digits or abs(value) < 1e-3):
            return f"{value:.{digits - 1}e}" if abs(value) < 1e-3 else f"{value:,.0f}"
        return f"{value:.{digits}g}"
    return str(value)


def _here(text: str) -> str:
    """``text`` with this repository's absolute path left out (paths relative to its root)."""
    return str(text).replace(f"{ROOT}/", "")


def _table(header: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(cell if isinstance(cell, str) else _number(cell) for cell in row)
              + " |" for row in rows]
    return lines


def _recorded(data: dict, fallback_command: str | None) -> list[str]:
    """The lines saying which command, date, commit and machine produced ``data``."""
    recorded = data.get("recorded") or {}
    command = recorded.get("command") or fallback_command
    machine = recorded.get("machine")
    if isinstance(machine, dict):
        parts = [f"{machine.get('cpu')} ({machine.get('cpu_count')} logical cores)"]
        if machine.get("gpu"):
            parts.append(machine["gpu"])
        parts.append(f"torch {machine.get('torch')}, Python {machine.get('python')}")
        if machine.get("omp_num_threads"):
            parts.append(f"OMP_NUM_THREADS={machine['omp_num_threads']}")
        machine = "; ".join(parts)
    commit = f", commit {recorded['commit']}" if recorded.get("commit") else ""
    date = recorded.get("date", "at an unknown date")
    return [f"Command: `{command}`", "",
            f"Recorded {date}{commit} on {machine or 'an unknown machine'}."]


def _scalars(data: dict, skip: tuple[str, ...] = ("recorded",)) -> list[str]:
    """A table of the top-level numbers, strings and flags of ``data`` (any benchmark)."""
    rows = [[f"`{key}`", value] for key, value in data.items()
            if key not in skip and (value is None or isinstance(value, (int, float, str, bool)))]
    return _table(["quantity", "value"], rows) if rows else []


# ------------------------------------------------------------------------------------------------
# One renderer a benchmark (the others get _scalars)


def _field(data: dict) -> list[str]:
    rows = [["reference", data["reference_points_per_s"], 1.0,
             data["reference_points_per_s_color"], 1.0, data["reference_gflops"], "-"]]
    for name, step in data["steps"].items():
        rows.append([f"{name} (+ {step['adds']})", step["points_per_s"], step["speedup"],
                     step["points_per_s_color"], step["speedup_color"], step["gflops"],
                     step["within_tolerance"] and step["within_tolerance_color"]])
    lines = [f"{data['num_points']:,} points, {data['threads']} thread(s) on {data['device']}; "
             f"headline step `{data['headline_step']}`: x{data['speedup']:.1f} geometry, "
             f"x{data['speedup_color']:.1f} with colour; a {data['matmul']} matmul runs at "
             f"{data['matmul_gflops']:.1f} GFLOP/s.", ""]
    lines += _table(["step", "points/s", "x reference", "points/s with colour", "x reference",
                     "GFLOP/s", "within tolerance"], rows)
    if data.get("backward"):
        train = data["backward"]
        lines += ["", "Training steps (culled field, float32):", ""]
        lines += _table(["step", "ms", "points/s", "GFLOP/s nominal", "x forward"],
                        [[name, train[name]["ms"], train[name]["points_per_s"],
                          train[name]["gflops_nominal"], train[name]["over_forward"]]
                         for name in ("forward", "backward", "eikonal") if name in train])
    if data.get("pair_strategies"):
        lines += ["", "The SDF MLP on the culled (point, bone) pairs, ways of running it:", ""]
        lines += _table(["way", "ms", "GFLOP/s"],
                        [[name, value.get("ms"), value.get("gflops")] if "error" not in value
                         else [name, value["error"], "-"]
                         for name, value in data["pair_strategies"].items()])
    return lines


def _mesh(data: dict) -> list[str]:
    lines = [f"{_here(data['model'])}; {data['threads']} thread(s), Lipschitz bound "
             f"{data['lipschitz']}; load average {data['load_average_at_start']:.1f} at the "
             f"start.", ""]
    rows = [[f"{run['resolution']}^3", run["seconds"], run["reference_seconds"],
             run["reference_seconds"] / run["seconds"], run["mean_distance_mm"]]
            for run in data["runs"]]
    return lines + _table(["grid", "coarse to fine, s", "dense, s", "speedup",
                           "mean distance between the meshes, mm"], rows)


def _render(data: dict) -> list[str]:
    lines = [f"{_here(data['field_description'])}; {data['resolution']}, {data['threads']} "
             f"thread(s) "
             f"on {data['device']}, load average {data['load_average_at_start']:.1f} at the "
             f"start.", ""]
    dense = data.get("dense_check") or {}
    lines += _table(["fast, s", "reference, s", "speedup", "PSNR vs reference, dB",
                     "hand pixels, dB", "dense check: fast / reference, dB"],
                    [[data["seconds"], data["reference_seconds"], data["speedup"],
                      data["psnr_vs_reference_db"], data["psnr_vs_reference_hand_db"],
                      f"{_number(dense.get('psnr_fast_db'))} / "
                      f"{_number(dense.get('psnr_reference_db'))}" if dense else "-"]])
    return lines


def _handmodel(data: dict) -> list[str]:
    from lisa_hand.handmodel.anthropometry import ANTHROPOMETRIC_TABLE

    keys = ("hand_length_mm", "hand_breadth_mm", "palm_thickness_mm")
    rows = []
    for sex, row in data["population"].items():
        published = ANTHROPOMETRIC_TABLE.get(sex)
        cells = []
        for index, key in enumerate(keys):
            cell = f"{row[key][0]:.1f} sd {row[key][1]:.1f}"
            if published is not None:
                cell += (f" ({1000 * published['mean'][index]:.1f} sd "
                         f"{1000 * published['std'][index]:.1f})")
            cells.append(cell)
        rows.append([sex, row["count"], *cells, row["corr_length_breadth"]])
    lines = ["Sizes measured on the meshes of the v3 population, mm (published anthropometry in "
             "brackets):", ""]
    lines += _table(["sex", "subjects", "hand length", "hand breadth", "palm thickness",
                     "r(length, breadth)"], rows)
    volumes = data["volume_change_percent"]
    poses = list(next(iter(volumes.values())))
    lines += ["", "Enclosed volume change from the rest pose, % (mean over "
              f"{data.get('volume_subjects', 'the')} subjects):", ""]
    lines += _table(["skinning", *poses, "mean abs"],
                    [[name, *[row[pose] for pose in poses],
                      sum(abs(v) for v in row.values()) / len(row)]
                     for name, row in volumes.items()])
    return lines


def _oneview(data: dict) -> list[str]:
    rows = [["with depth restarts (default)", data["mpjpe_mm"], data["worst_mpjpe_mm"],
             data["wrist_depth_mm"], data["seconds"]],
            ["without (reference)", data["reference_mpjpe_mm"], data["reference_worst_mpjpe_mm"],
             data["reference_wrist_depth_mm"], data["reference_seconds"]]]
    return ([f"{data['hands']} unseen hands, view {data['view']}.", ""]
            + _table(["one view", "MPJPE mm (mean)", "MPJPE mm (worst)",
                      "wrist depth error mm (mean abs)", "s a fit"], rows))


def _rgbd(data: dict) -> list[str]:
    rows = []
    for row in data["rows"]:
        for name, label in (("with_rgb", "depth and colour image"), ("depth_only", "depth only")):
            fit = row[name]
            rows.append([row["frame"], label, fit["v2s_scan_to_recon_mm"],
                         fit["v2s_recon_to_scan_mm"], fit["seconds"], fit.get("coloured_share")])
    return _table(["frame", "input", "V2S scan->recon, mm", "V2S recon->scan, mm", "s",
                   "coloured share"], rows)


def _colours(data: dict) -> list[str]:
    rows = []
    for kind, guesses in data["mean"].items():
        for name, value in guesses.items():
            rows.append([kind, name, value["seen_mae"], value["hidden_mae"], value["seen_psnr"],
                         value["hidden_psnr"], value["seen_share"]])
    lines = [f"Means over {len(data['rows']) // max(1, len(data['mean']))} held-out hand(s) a "
             "kind of scan: `fit` is the fitted mesh's colours, `scan_mean` one colour (the "
             "scan's mean) and `grey` a geometric prior's grey, at the same vertices.", ""]
    lines += _table(["scan", "colours", "seen, levels", "hidden, levels", "seen, dB",
                     "hidden, dB", "seen share"], rows)
    lines += ["", "The fits (V2S against the true mesh):", ""]
    lines += _table(["subject", "scan", "s", "V2S scan->recon, mm", "V2S recon->scan, mm"],
                    [[row["subject"], row["scan"], row["seconds"],
                      row["v2s_mm"]["v2s_scan_to_recon_mm"], row["v2s_mm"]["v2s_recon_to_scan_mm"]]
                     for row in data["rows"]])
    return lines


def _rows_table(data: dict, key: str = "rows") -> list[str]:
    """A table of a list of flat dicts (the numbers and strings of each row)."""
    rows = data.get(key) or []
    if not rows:
        return []
    header = [name for name, value in rows[0].items()
              if value is None or isinstance(value, (int, float, str, bool))]
    return _table(header, [[row.get(name) for name in header] for row in rows])


def _fit(data: dict) -> list[str]:
    """The WebXR hand's fits: one row a pose and scan (mm; the model by file name), and the
    time-to-1-mm numbers when the run had them."""
    lines = _scalars({key: value for key, value in data.items() if key != "webxr"})
    rows = [[row["pose"], row["scan"], row.get("wrist"), row.get("scale"),
             Path(str(row.get("model", ""))).stem, row["v2s_scan_to_recon_mm"],
             row["v2s_recon_to_scan_mm"], row.get("scan_points_to_recon_mm"), row["seconds"]]
            for row in data.get("webxr", [])]
    if rows:
        lines += ["", "The WebXR hand (MIT; `tests/assets/webxr_hand/`), a 5000-point scan with "
                  "0.3 mm noise: from all round (full) or one side with its sensor (partial).",
                  ""]
        lines += _table(["pose", "scan", "wrist", "scale", "model", "V2S scan->recon mm",
                         "V2S recon->scan mm", "scan points -> recon mm", "s"], rows)
    return lines


def _photo(data: dict) -> list[str]:
    """The synthetic photos' numbers, then one row a real photo."""
    lines = _scalars({key: value for key, value in data.items()
                      if key not in ("synthetic", "shared", "targets", "notes", "overrides")})
    rows = [[row.get("photo", name), row.get("side"), row.get("seconds"), row.get("pieces"),
             row.get("area_ratio"), row.get("keypoint_error_px"), row.get("guard_passed"),
             row.get("error")] for name, row in (data.get("shared") or {}).items()]
    if rows:
        lines += ["", "The real photos (`tests/assets/photos/`): the fitted keypoints' distance "
                  "from the detected ones in the photo's pixels, the surface's pieces and its "
                  "area against the keypoint stage's.", ""]
        lines += _table(["photo", "side", "s", "pieces", "area ratio", "keypoint error px",
                         "guard passed", "error"], rows)
    return lines


def _video(data: dict) -> list[str]:
    """The means, then one row a rendered clip and mode, the real clip and the speed runs, and
    the targets."""
    lines = _scalars({key: value for key, value in data.items()
                      if key not in ("clips", "real", "speed", "targets", "notes", "overrides",
                                     "seconds_parts")})
    rows = [[clip["clip"], clip["subject"], clip["side"], mode,
             f"{clip[mode]['fitted_frames']}/{clip['frames']}", clip[mode]["mpjpe_mm"],
             clip[mode]["pa_mpjpe_mm"], clip[mode]["acceleration_error_mm"],
             clip[mode]["jitter_mm"], clip["truth_jitter_mm"],
             clip[mode].get("appearance_psnr_db"), clip[mode]["seconds"]]
            for clip in data.get("clips") or [] for mode in ("tracked", "independent")]
    if rows:
        lines += ["", "Rendered clips of held-out hands with truth; the distances over the frames "
                  "fitted in both modes (mm; acceleration error and jitter mm/frame^2):", ""]
        lines += _table(["clip", "subject", "side", "mode", "fitted frames", "MPJPE",
                         "PA-MPJPE", "acceleration error", "jitter", "truth's jitter",
                         "look dB", "s"], rows)
        lines += ["", "Look: the PSNR of the fitted hand rendered at its fitted poses against "
                  "the frames it was not fitted on, over the pixels it covers fully."]
    real = data.get("real") or {}
    if real:
        lines += ["", "The real clip (no truth): the share of the detected frames with a fitted "
                  "hand, jitter (mm/frame^2) and the fitted keypoints' distance from the "
                  "detected ones (pixels of the clip):", ""]
        lines += _table(["mode", "hands", "fitted share", "jitter", "agreement px", "look dB",
                         "s"],
                        [[mode, row.get("hands"), row.get("fitted_share"), row.get("jitter_mm"),
                          row.get("agreement_px"), row.get("appearance_psnr_db"),
                          row.get("seconds")]
                         for mode, row in real.items()])
    speed = data.get("speed") or {}
    if speed:
        lines += ["", "Speed: the real clip upscaled to 1280x720, fitted with its files:", ""]
        lines += _table(["mode", "frames", "s end to end", "frames/s", "detection frames/s"],
                        [[mode, row.get("frames"), row.get("seconds"),
                          row.get("frames_per_second"), row.get("detect_frames_per_second")]
                         for mode, row in speed.items()])
    targets = data.get("targets") or {}
    if targets:
        lines += ["", "Targets:", ""]
        lines += _table(["target", "met"], [[f"`{name}`", "not measured" if met is None else met]
                                            for name, met in targets.items()])
    return lines


def _two_hands(data: dict) -> list[str]:
    """Per input mode (photo, scan, views): the means per kind and fit, the targets, one row a
    scene and fit; then the real photos. A file of before ``--modes`` is its photo mode."""
    per_mode = data.get("per_mode") or ({"photo": data} if "means" in data else {})
    lines = _scalars({key: value for key, value in data.items() if key != "work"})
    if data.get("notes"):
        lines += ["", *(f"- {note}" for note in data["notes"])]
    header = ["kind", "fit", "both hands found", "MPJPE mm", "PA-MPJPE mm", "MRRPE mm",
              "MRRPE (hands.json) mm", "penetration mm", "max penetration mm", "s / fit",
              "failed"]
    for mode, part in per_mode.items():
        groups = [*(part.get("kinds") or {}).items(), ("all", part.get("means") or {})]
        rows = [[kind, fit, f"{row['both_found']}/{row['scenes']}", row["mpjpe_mm"],
                 row["pa_mpjpe_mm"], row["mrrpe_mm"], row.get("hands_json_mrrpe_mm"),
                 row["penetration_mm"], row.get("max_penetration_mm"), row["seconds"],
                 row["failed"]] for kind, fits in groups for fit, row in fits.items()]
        if rows:
            lines += ["", f"**From {_TWO_HAND_INPUTS.get(mode, mode)}** (`{mode}`): rendered "
                      "two-hand scenes with truth (held-out subjects), means per kind and over "
                      "all (MPJPE root-aligned; MRRPE from the matched hands' wrists; "
                      "penetration: the fit's `hands.json`):", ""]
            lines += _table(header, rows)
        targets = part.get("targets") or {}
        if targets:
            lines += ["", f"Targets (`{mode}`, the fit together):", ""]
            lines += _table(["target", "met", "measured"],
                            [[f"`{name}`", "not measured" if t["met"] is None else t["met"],
                              t["value"]] for name, t in targets.items()])
    rows = [[mode, scene["scene"], scene["kind"], fit, f"{scene[fit]['hands_found']}/2",
             scene[fit].get("mpjpe_mm"), scene[fit].get("pa_mpjpe_mm"),
             scene[fit]["mrrpe_mm"], scene[fit]["penetration_mm"], scene[fit]["seconds"],
             scene[fit].get("error")]
            for mode, part in per_mode.items() for scene in part.get("scenes") or []
            for fit in ("together", "alone")]
    if rows:
        lines += ["", "Per scene:", ""]
        lines += _table(["mode", "scene", "kind", "fit", "hands found", "MPJPE mm",
                         "PA-MPJPE mm", "MRRPE mm", "penetration mm", "s", "error"], rows)
    real = data.get("real") or []
    if real:
        lines += ["", "Real photos (no truth): the hands fitted and the fit's overlay:", ""]
        lines += _table(["photo", "hands", "overlay", "s", "error"],
                        [[row["photo"], row["hands"], _here(row["overlay"] or "-"),
                          row["seconds"], row.get("error")] for row in real])
    return lines


_TWO_HAND_INPUTS = {"photo": "one photo", "scan": "a scan of both hands",
                    "views": "4 calibrated views"}


RENDERERS: dict[str, Callable[[dict], list[str]]] = {
    "fit": _fit, "photo": _photo, "video": _video, "field": _field, "mesh": _mesh,
    "render": _render, "handmodel": _handmodel, "oneview": _oneview, "rgbd": _rgbd,
    "colours": _colours, "two_hands": _two_hands,
}


def _benchmark_section(name: str, data: dict | None) -> list[str]:
    title, command = SECTIONS.get(name, (name, f"python -m benchmarks {name}"))
    json_path = f"benchmarks/results/{name}.json"
    lines = [f"### {title}", ""]
    if data is None:
        return lines + [f"Not recorded yet: `{command} --json {json_path}`.", ""]
    try:
        body = RENDERERS.get(name, _scalars)(data)
    except (KeyError, TypeError, ValueError, StopIteration) as exc:  # an older or newer layout
        body = [f"(its JSON does not have the expected layout: {exc!r}; its top-level numbers:)",
                ""] + _scalars(data)
    if name not in RENDERERS:
        extra = _rows_table(data)
        body += ["", *extra] if extra else []
    return lines + _recorded(data, f"{command} --json {json_path}") + [""] + body + [""]


def _part_section(name: str, part: str, data: dict) -> list[str]:
    """A later run of benchmark ``name`` on part of its inputs
    (``benchmarks/results/NAME.PART.json``, e.g. ``two_hands.scan.json``: one mode run again
    after a change that touched only it), shown after the whole run's section with its own
    command, date and commit."""
    title = SECTIONS.get(name, (name, ""))[0]
    try:
        body = RENDERERS.get(name, _scalars)(data)
    except (KeyError, TypeError, ValueError, StopIteration) as exc:
        body = [f"(its JSON does not have the expected layout: {exc!r})"]
    return ([f"#### {title}: `{part.split('.', 1)[1]}`, run again", ""]
            + _recorded(data, None) + [""] + body + [""])


# ------------------------------------------------------------------------------------------------
# lisa eval's tables


def _eval_section(record: dict, source: Path) -> list[str]:
    from lisa_hand.evaluation.tables import markdown_tables

    results_file = ROOT / record["results_file"]
    results = json.loads(results_file.read_text())
    lines = [f"### {record['title']}", ""]
    if record.get("setup"):
        lines += ["The run's commands (in a folder `runs/`):", "", "```bash",
                  *record["setup"], "```", ""]
    lines += _recorded(record, None)
    lines += ["", f"Tables made from [`{record['results_file']}`]"
              f"({results_file.relative_to(ROOT / 'docs').as_posix()}) (per-fit numbers there) "
              f"by `lisa_hand.evaluation.tables.markdown_tables`; recorded in "
              f"`{source.relative_to(ROOT).as_posix()}`.", ""]
    if record.get("note"):
        lines += [record["note"], ""]
    tables = markdown_tables(results).strip().replace("\n### ", "\n#### ")
    lines += [tables.replace("### ", "#### ", 1) if tables.startswith("### ") else tables, ""]
    pictures = [Path(picture).name for picture in results.get("pictures", [])]
    folder = results_file.parent
    shown = [name for name in pictures if (folder / name).is_file()]
    if shown:
        lines += ["Pictures (each method's fit and the truth):", ""]
        lines += [f"![{name}]({(folder / name).relative_to(ROOT / 'docs').as_posix()})"
                  for name in shown] + [""]
    return lines


# ------------------------------------------------------------------------------------------------
# The page


def _load(results_dir: Path) -> dict[str, dict]:
    records = {}
    for path in sorted(results_dir.glob("*.json")):
        try:
            records[path.stem] = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not JSON ({exc})") from exc
    return records


def render_page(results_dir: Path = RESULTS_DIR) -> str:
    """The results page (Markdown) from the JSON files in ``results_dir``."""
    records = _load(Path(results_dir))
    evals = {name: data for name, data in records.items() if data.get("benchmark") == "eval"}
    lines = [
        "<!-- Generated by `python -m benchmarks pages` from benchmarks/results/*.json: do not "
        "edit; rerun a section's command, then `python -m benchmarks pages`. -->",
        "",
        "# Results: measured accuracy and speed",
        "",
        "*This page is generated: `python -m benchmarks pages` (from the repository root) writes "
        "it from the JSON files in `benchmarks/results/`. To update a section, run the command "
        "shown under it (it writes that JSON file), then regenerate the page.*",
        "",
        "Each section gives the command that produced its numbers and the date, commit and "
        "machine recorded with them; timings depend on the machine and on what else ran on it "
        "(the benchmarks print the load average). The benchmarks are in `benchmarks/` at the "
        "repository's root (not installed with the package); each compares the package with a "
        "reference measured in the same run.",
        "",
        "## The paper's tables (`lisa eval`)",
        "",
        "LISA's Tables 1-3 reproduced on data where the truth is known: hands of the package's "
        "open hand model, scored on held-out subjects that no method saw in training. Every "
        "implicit method is a configuration of the same code (`FieldConfig.composition`), "
        "trained by the same trainer on the same data with the same losses:",
        "",
        _EVAL_METHODS,
        "",
    ]
    if not evals:
        lines += ["Not recorded yet: run `lisa eval DATA --out OUT --model NAME=RUN ...` and "
                  "record it as `benchmarks/results/eval_NAME.json` (`results_file`: "
                  "OUT/results.json).", ""]
    for name in sorted(evals, key=lambda n: evals[n].get("order", 0)):
        lines += _eval_section(evals[name], Path(results_dir) / f"{name}.json")
    lines += ["## The benchmarks", ""]
    names = [name for name in SECTIONS if name in benchmark_names()]
    names += [name for name in benchmark_names() if name not in SECTIONS and name != "pages"]
    for name in names:
        lines += _benchmark_section(name, records.get(name))
        for part in sorted(key for key in records if key.startswith(f"{name}.")):
            lines += _part_section(name, part, records[part])
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> Path:
    """Command line: write the page; returns its path."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks pages",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=RESULTS_DIR,
                        help="folder of the recorded JSON (default benchmarks/results)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="the page to write (default docs/results.md)")
    args = parser.parse_args(argv)
    if not args.results.is_dir():
        raise ValueError(f"--results {args.results}: no such folder")
    from lisa_hand.utils.io import atomic_path

    page = render_page(args.results)
    with atomic_path(args.out) as tmp:
        Path(tmp).write_text(page, encoding="utf-8")
    print(f"wrote {args.out}")
    return args.out


if __name__ == "__main__":
    main()
