"""Two-hand benchmark: rendered scenes of two hands with ground truth fitted from one photo
(``lisa_hand.fit_photo``), from a scan and from calibrated views, the hands fitted together
against each fitted alone; and ``fit_photo`` on the shared real photos.

``python -m benchmarks two_hands [--json FILE] [--modes photo,scan,views] [--scenes N] [--quick]
[--work DIR] [--shared DIR] [--sheet FILE] [--scenes-only] [--true-keypoints] [--threads T]``

1. **Rendered scenes** (:mod:`benchmarks._two_hand_scenes`): ``--scenes`` (default 10: two of
   each kind, apart, crossed, clasped, interlaced, holding_wrist) photos of a right and a left
   hand of two different held-out subjects, 1024x768, JPEG without EXIF. Each is fitted twice in
   the same run: together (``fit_photo(photo, out)``: the hands fitted alone, then together)
   and the reference, alone (``fit_photo(photo, out, joint=JointConfig(iters=0))``). The fitted
   hands are matched to the true ones by their 2D keypoints (``keypoints_2d_fitted``; the
   assignment of least mean distance, a pair farther than half the true hand's size in the
   photo left unmatched). Per scene and fit: hands found (matched, 0-2); per matched hand the
   root-aligned MPJPE and PA-MPJPE (mm, :mod:`lisa_hand.metrics.keypoints`); MRRPE (mm: the
   fitted left wrist minus the right one, of the matched hands' ``keypoints_3d``, against the
   truth's; ``hands.json``'s ``right_to_left_m`` is scored too); the deepest penetration between
   the fitted hands (``hands.json``'s ``penetration_mm``); seconds. Without MediaPipe (the
   ``[photo]`` extra), or with ``--true-keypoints``, the fits get the true 2D keypoints and sides.
   ``--modes`` (default all three): the same scenes are also fitted, together and alone, from a
   scan of both hands (``scan``) and from 4 calibrated views (``views``) as
   :mod:`benchmarks._two_hand_modes` makes them, the hands matched in 3D (by side, else the
   nearest wrist) and scored the same way; tables and targets per mode.
2. **Real photos** (with the photo mode; ``--shared``, default ``../shared/data/photos`` of the
   repository's root, and its ``gestures/`` folder): the hands found (fitted hand folders) and
   the fit's overlay (``overlay.png``) per photo, fitted together; no truth.

Output folders: ``fit_photo`` writes ``out/hands.json`` when it fits two hands or more
(``hands``: ``folder``, ``side``, ``root_m`` each; ``right_to_left_m``; ``penetration_mm``) and
each hand into ``out/handN`` (``keypoints.json``: ``keypoints_3d`` [21, 3] metres, camera frame,
``keypoints_2d_fitted`` [21, 2] pixels, ``side``); one hand alone goes into ``out`` itself. The
reading copes with a missing ``hands.json`` (the ``handN`` folders) and says what it missed.

Targets (the issue's; the "together" fit, per mode): both hands found in every scene;
root-aligned MPJPE <= 15 mm, MRRPE <= 30 mm and penetration <= 2 mm (means over the scenes).
``--quick``: 2 scenes and the two close-up real photos. Torch runs with ``--threads`` CPU
threads (default 2).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict
from pathlib import Path

from . import write_results
from ._two_hand_scores import (
    FITS,
    FitOutput,
    FittedHand,
    HandResult,
    ModeResult,
    RealResult,
    SceneResult,
    _mean,
    failed_fit,
    match_hands,
    mrrpe_mm,
    read_fit_output,
    score_fit,
)

__all__ = ["FittedHand", "FitOutput", "HandResult", "ModeResult", "SceneResult", "RealResult",
           "read_fit_output", "match_hands", "mrrpe_mm", "score_fit", "failed_fit",
           "default_shared_dir",
           "run_two_hands_benchmark", "main"]

TARGET_MPJPE_MM = 15.0
TARGET_MRRPE_MM = 30.0
TARGET_PENETRATION_MM = 2.0
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


def default_shared_dir() -> Path:
    """The real photos: ``../shared/data/photos`` beside the repository's root."""
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "photos"


# ------------------------------------------------------------------------------------------------
# Running the fits


def _fit(photo_path: Path, out_dir: Path, fit: str, options: dict) -> tuple[float, str | None]:
    """Fit ``photo_path`` into ``out_dir`` (``fit``: together or alone) -> (seconds, error)."""
    import lisa_hand

    start = time.perf_counter()
    try:
        settings = dict(options)
        if fit == "alone":
            from lisa_hand.fitting.pair.config import JointConfig

            settings["joint"] = JointConfig(iters=0)
        lisa_hand.fit_photo(photo_path, out_dir, progress=False, **settings)
    except Exception as exc:  # noqa: BLE001 (a benchmark reports a failed fit and goes on)
        return time.perf_counter() - start, f"{type(exc).__name__}: {exc}"
    return time.perf_counter() - start, None


def _true_keypoints_file(photo, path: Path) -> Path:
    """A ``--keypoints`` file with both true hands (all 21 keypoints each, and their sides)."""
    hands = [{"keypoints": hand.keypoints_2d.tolist(), "side": hand.side}
             for hand in (photo.right, photo.left)]
    path.write_text(json.dumps({"hands": hands}))
    return path


def _photo_fits(photo, work_dir: Path, options: dict, true_keypoints: bool) -> dict:
    """Fit ``photo`` together and alone, and score both -> {fit: ModeResult}."""
    fit_options = dict(options)
    if true_keypoints:
        fit_options["keypoints"] = _true_keypoints_file(
            photo, work_dir / "scenes" / f"{photo.path.stem}.keypoints.json")
    results = {}
    for fit in FITS:
        out_dir = work_dir / "fits" / "photo" / photo.path.stem / fit
        seconds, error = _fit(photo.path, out_dir, fit, fit_options)
        results[fit] = (failed_fit(seconds, error) if error is not None
                        else score_fit(read_fit_output(out_dir), photo, seconds))
    return results


def _scene_part(num_scenes: int, scene_config, work_dir: Path, options: dict,
                true_keypoints: bool, modes: tuple[str, ...],
                log) -> tuple[dict[str, list[SceneResult]], list]:
    """-> ({input mode: the scenes' results}, their photos)."""
    from ._two_hand_modes import fit_scene_input
    from ._two_hand_scenes import make_two_hand_photo

    results: dict[str, list[SceneResult]] = {mode: [] for mode in modes}
    photos = []
    for index in range(num_scenes):
        photo = make_two_hand_photo(scene_config, index, work_dir / "scenes")
        photos.append(photo)
        for mode in modes:
            if mode == "photo":
                fits, seconds_input = _photo_fits(photo, work_dir, options, true_keypoints), 0.0
            else:
                fits, seconds_input = fit_scene_input(mode, photo, work_dir, options,
                                                      scene_config.seed)
            results[mode].append(SceneResult(
                photo.path.name, photo.kind,
                {"right": photo.right.subject, "left": photo.left.subject},
                photo.penetration_mm, photo.seconds, seconds_input, **fits))
            log(_scene_line(results[mode][-1], mode))
    return results, photos


def _real_photos(shared_dir: Path, quick: bool) -> list[Path]:
    folders = [shared_dir] + ([] if quick else [shared_dir / "gestures"])
    return [path for folder in folders if folder.is_dir()
            for path in sorted(folder.iterdir()) if path.suffix.lower() in IMAGE_SUFFIXES]


def _real_part(photos: list[Path], shared_dir: Path, work_dir: Path, options: dict,
               log) -> list[RealResult]:
    results = []
    for path in photos:
        name = path.relative_to(shared_dir).as_posix()
        out_dir = work_dir / "real" / name.replace("/", "_").rsplit(".", 1)[0]
        seconds, error = _fit(path, out_dir, "together", options)
        output = read_fit_output(out_dir) if error is None else FitOutput([])
        overlay = out_dir / "overlay.png"
        if not overlay.is_file() and output.hands:  # several hands without a joint overlay
            overlay = out_dir / output.hands[0].folder / "overlay.png"
        results.append(RealResult(name, len(output.hands),
                                  str(overlay) if overlay.is_file() else None, seconds, error))
        log(f"  {name}: {results[-1].hands} hand(s), {seconds:.1f} s, overlay "
            f"{results[-1].overlay or '-'}" + (f", failed: {error}" if error else ""))
    return results


# ------------------------------------------------------------------------------------------------
# Summaries, tables, targets


def _summary(modes: list[ModeResult]) -> dict[str, float]:
    """Means over the scenes of one fit (of one kind, or all) of one input mode."""
    pens = [m.penetration_mm for m in modes if m.penetration_mm is not None]
    return {"scenes": len(modes), "hands_found": int(sum(m.hands_found for m in modes)),
            "both_found": int(sum(m.hands_found == 2 for m in modes)),
            "mpjpe_mm": _mean(h.mpjpe_mm for m in modes for h in m.hands),
            "pa_mpjpe_mm": _mean(h.pa_mpjpe_mm for m in modes for h in m.hands),
            "mrrpe_mm": _mean(m.mrrpe_mm for m in modes),
            "hands_json_mrrpe_mm": _mean(m.hands_json_mrrpe_mm for m in modes),
            "penetration_mm": _mean(pens), "max_penetration_mm": max(pens, default=math.nan),
            "seconds": _mean(m.seconds for m in modes),
            "failed": int(sum(m.error is not None for m in modes))}


def summaries(scenes: list[SceneResult]) -> tuple[dict, dict]:
    """One input mode's scenes -> ({fit: summary over every scene}, {kind: {fit: summary}})."""
    overall = {fit: _summary([getattr(s, fit) for s in scenes]) for fit in FITS}
    kinds = {}
    for kind in dict.fromkeys(s.kind for s in scenes):
        of_kind = [s for s in scenes if s.kind == kind]
        kinds[kind] = {fit: _summary([getattr(s, fit) for s in of_kind]) for fit in FITS}
    return overall, kinds


def targets(scenes: list[SceneResult]) -> dict[str, dict]:
    """The issue's targets on the together fit: {name: {"met": bool | None, "value": ...}}."""
    if not scenes:
        return {}
    together = _summary([s.together for s in scenes])

    def target(value: float, limit: float) -> dict:
        return {"met": None if not math.isfinite(value) else bool(value <= limit),
                "value": value, "limit": limit}

    both = together["both_found"]
    return {"both_hands_found_every_scene": {"met": both == len(scenes),
                                             "value": f"{both}/{len(scenes)}", "limit": None},
            "mpjpe_le_15_mm": target(together["mpjpe_mm"], TARGET_MPJPE_MM),
            "mrrpe_le_30_mm": target(together["mrrpe_mm"], TARGET_MRRPE_MM),
            "penetration_le_2_mm": target(together["penetration_mm"], TARGET_PENETRATION_MM)}


def _number(value, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _scene_line(result: SceneResult, mode: str) -> str:
    parts = []
    for fit in FITS:
        m = getattr(result, fit)
        if m.error is not None:
            parts.append(f"{fit}: failed: {m.error}")
            continue
        parts.append(f"{fit}: {m.hands_found}/2 found ({m.fitted_hands} fitted), MPJPE "
                     f"{_number(m.mpjpe_mm)} mm, PA {_number(m.pa_mpjpe_mm)}, MRRPE "
                     f"{_number(m.mrrpe_mm)}, pen {_number(m.penetration_mm)}, "
                     f"{m.seconds:.1f} s" + (f" [{'; '.join(m.notes)}]" if m.notes else ""))
    made = (f"render {result.seconds_render:.1f} s" if mode == "photo"
            else f"{mode} {result.seconds_input:.1f} s")
    return (f"  [{mode}] {result.scene} ({result.kind}, {result.subjects['right']}+"
            f"{result.subjects['left']}, {made}): " + " | ".join(parts))


def tables(overall: dict, kinds: dict) -> list[str]:
    header = ["| kind | fit | both found | MPJPE mm | PA-MPJPE mm | MRRPE mm | MRRPE "
              "(hands.json) mm | penetration mm (max) | s / fit | failed |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    rows = []
    for kind, fits in [*kinds.items(), ("all", overall)]:
        for fit, s in fits.items():
            rows.append(f"| {kind} | {fit} | {s['both_found']}/{s['scenes']} | "
                        f"{_number(s['mpjpe_mm'])} | {_number(s['pa_mpjpe_mm'])} | "
                        f"{_number(s['mrrpe_mm'])} | {_number(s['hands_json_mrrpe_mm'])} | "
                        f"{_number(s['penetration_mm'])} ({_number(s['max_penetration_mm'])}) | "
                        f"{_number(s['seconds'])} | {s['failed']} |")
    return header + rows


def target_lines(result: dict[str, dict], mode: str) -> list[str]:
    labels = {"both_hands_found_every_scene": "both hands found in every scene",
              "mpjpe_le_15_mm": "root-aligned MPJPE <= 15 mm",
              "mrrpe_le_30_mm": "MRRPE <= 30 mm", "penetration_le_2_mm": "penetration <= 2 mm"}
    words = {True: "met", False: "MISSED", None: "not measured"}
    return [f"target {labels.get(name, name)} ({mode}, together): {words[t['met']]} "
            f"(measured {_number(t['value'])})" for name, t in result.items()]


# ------------------------------------------------------------------------------------------------
# The benchmark


def _mode_part(scenes: list[SceneResult]) -> dict:
    """One input mode's results: its means (per fit), per kind, scenes and targets."""
    overall, kinds = summaries(scenes)
    scene_rows = []
    for scene in scenes:
        row = asdict(scene)
        for fit in FITS:
            row[fit].update(mpjpe_mm=getattr(scene, fit).mpjpe_mm,
                            pa_mpjpe_mm=getattr(scene, fit).pa_mpjpe_mm)
        scene_rows.append(row)
    return {"seconds_input": _mean(s.seconds_input for s in scenes), "means": overall,
            "kinds": kinds, "scenes": scene_rows, "targets": targets(scenes)}


def run_two_hands_benchmark(num_scenes: int = 10, *, work_dir: Path, shared_dir: Path | None,
                            modes: tuple[str, ...] = ("photo", "scan", "views"),
                            quick: bool = False, threads: int = 2, device: str = "auto",
                            true_keypoints: bool | None = None, seed: int = 0,
                            sheet: Path | None = None, log=print) -> dict:
    """Run the benchmark (see the module docstring) in ``work_dir``; -> its results (JSON-able
    apart from NaN: :func:`lisa_hand.fitting.outputs.records.json_safe`; ``per_mode``: each
    input mode's). sheet: also write a picture sheet of the scenes there. true_keypoints: None:
    when MediaPipe is missing."""
    from lisa_hand.data.detect import photo_extra_missing
    from lisa_hand.utils.threads import cpu_threads

    from ._two_hand_modes import mode_notes, picture_sheet
    from ._two_hand_scenes import TwoHandSceneConfig

    notes = []
    if "photo" not in modes:
        true_keypoints = False
    elif true_keypoints is None:
        true_keypoints = photo_extra_missing() is not None
        if true_keypoints:
            notes.append("MediaPipe is not installed (the [photo] extra): the scenes are fitted "
                         "from their true 2D keypoints and sides, the real photos skipped")
    elif true_keypoints:
        notes.append("the scenes are fitted from their true 2D keypoints and sides")
    notes += mode_notes(modes)
    for note in notes:
        log(f"note: {note}")
    options = {"device": device}
    with cpu_threads(threads):
        per_mode, photos = _scene_part(num_scenes, TwoHandSceneConfig(seed=seed), work_dir,
                                       options, true_keypoints, modes, log)
        if sheet is not None and photos:
            log(f"wrote {picture_sheet(photos, sheet)}")
        real: list[RealResult] = []
        if shared_dir is not None and "photo" in modes and photo_extra_missing() is None:
            log(f"real photos ({shared_dir}):")
            real = _real_part(_real_photos(shared_dir, quick), shared_dir, work_dir, options,
                              log)
    return {"modes": ",".join(modes),
            "detection": None if "photo" not in modes
            else "true-keypoints" if true_keypoints else "mediapipe",
            "num_scenes": num_scenes, "threads": threads, "device": device,
            "seconds_render": _mean(photo.seconds for photo in photos),
            "per_mode": {mode: _mode_part(scenes) for mode, scenes in per_mode.items()},
            "real": [asdict(r) for r in real], "notes": notes}


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks two_hands [--json FILE] [--modes M] [--scenes N] [--quick] ...``"""
    parser = argparse.ArgumentParser(prog="python -m benchmarks two_hands",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--modes", default="photo,scan,views",
                        help="what the scenes are fitted from (default photo,scan,views)")
    parser.add_argument("--scenes", type=int, default=None,
                        help="rendered scenes (default 10: two of each kind)")
    parser.add_argument("--quick", action="store_true",
                        help="2 scenes and the two close-up real photos (to try it)")
    parser.add_argument("--work", type=Path, default=None,
                        help="where the scenes and fits go (a new folder in it each run; "
                             "default runs/two_hands)")
    parser.add_argument("--shared", type=Path, default=None,
                        help="folder of the real photos (default ../shared/data/photos)")
    parser.add_argument("--sheet", type=Path, default=None,
                        help="also write a picture sheet of the scenes (PNG)")
    parser.add_argument("--scenes-only", action="store_true",
                        help="only make the scenes (and --sheet): no fits")
    parser.add_argument("--true-keypoints", action="store_true",
                        help="give the fits the true 2D keypoints and sides (no detection)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (CPU)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scenes")
    args = parser.parse_args(argv)
    from ._two_hand_modes import parse_modes

    modes = parse_modes(args.modes)
    num_scenes = args.scenes if args.scenes is not None else (2 if args.quick else 10)
    if num_scenes < 0:
        raise ValueError(f"--scenes must be >= 0, got {num_scenes}")
    shared = default_shared_dir() if args.shared is None else args.shared
    if not shared.is_dir():
        if args.shared is not None:
            raise ValueError(f"--shared {shared}: no such folder (the real photos' folder)")
        print(f"note: no real photos ({shared} is absent)")
        shared = None
    root = Path(__file__).resolve().parents[1] / "runs" / "two_hands"
    work = (args.work or root) / time.strftime("%Y%m%d-%H%M%S")
    work.mkdir(parents=True, exist_ok=False)
    print(f"two hands: {num_scenes} rendered scenes fitted from {', '.join(modes)}"
          + (", then the real photos" if "photo" in modes else "") + f"; work folder {work}")
    if args.scenes_only:
        _scenes_only(num_scenes, work, args.seed, args.sheet)
        return
    from lisa_hand.fitting.outputs.records import json_safe

    result = run_two_hands_benchmark(num_scenes, work_dir=work, shared_dir=shared,
                                     modes=modes, quick=args.quick, threads=args.threads,
                                     device=args.device,
                                     true_keypoints=True if args.true_keypoints else None,
                                     seed=args.seed, sheet=args.sheet)
    for mode, part in result["per_mode"].items():
        print(f"\n{mode}:\n")
        print("\n".join(tables(part["means"], part["kinds"])))
        print()
        print("\n".join(target_lines(part["targets"], mode)))
    write_results(args.json, json_safe({**result, "work": str(work)}))


def _scenes_only(num_scenes: int, work: Path, seed: int, sheet: Path | None) -> None:
    from ._two_hand_modes import picture_sheet
    from ._two_hand_scenes import TwoHandSceneConfig, make_two_hand_photo

    photos = []
    for index in range(num_scenes):
        photos.append(make_two_hand_photo(TwoHandSceneConfig(seed=seed), index, work / "scenes"))
        photo = photos[-1]
        print(f"  {photo.path.name}: {photo.kind}, {photo.right.subject}+{photo.left.subject}, "
              f"penetration {photo.penetration_mm:.2f} mm, gap {photo.gap_mm:.1f} mm, visible "
              f"{int(photo.right.visible.sum())}+{int(photo.left.visible.sum())}, "
              f"{photo.seconds:.1f} s")
    if sheet is not None and photos:
        print(f"wrote {picture_sheet(photos, sheet)}")
