"""Photo fitting benchmark: ``lisa fit-photo`` on synthetic photos with ground truth and on the
two shared real photos.

``python -m benchmarks photo [--json FILE] [--photos N] [--shared DIR] [--out DIR]``

* Synthetic photos (:mod:`benchmarks._photo_scenes`): ``--photos`` (default 12) photos of the
  6 held-out subjects of the open hand model in turn (the shipped model's test split; every other
  photo a left hand) in natural
  poses, photographed by a phone-like camera (60-70 degrees horizontal field of view, 0.4-0.6 m
  away), saved as JPEG without EXIF. Each is fitted as a user would
  (:func:`lisa_hand.fitting.photo.fit.fit_photo_folder` with its defaults: detection, the default
  camera, ``--side auto``), and the fitted 21 3D keypoints (``keypoints.json``,
  ``keypoints_3d``, camera frame) are compared with the truth: MPJPE after root (wrist)
  alignment and PA-MPJPE (Procrustes with scale), mm (:mod:`lisa_hand.metrics.keypoints`), and
  the wrist's absolute position error (what one uncalibrated view leaves: mostly depth). Without
  the ``[photo]`` extra (no MediaPipe) the fit gets the true 2D keypoints and the true side
  instead of detections (a note says so).
* Reference, measured in the same run: a hand that ignores the photo (the open hand model's
  default shape in the 'relaxed' pose, of the photo's side), Procrustes-aligned to the truth:
  the PA-MPJPE a fit must beat to have read the pose from the photo at all.
* Real photos (``--shared``, default the repository's ``tests/assets/photos``; a photo missing
  from the folder is skipped with a note, a folder that does not exist is an error): seconds,
  and the geometry guard's figures of the fit (connected
  pieces of the fitted surface, its area over the keypoint-stage mesh's, from the fit's report)
  and the keypoint reprojection error (mean distance between the detected and the fitted 2D
  keypoints of ``keypoints.json``, pixels of the original photo), and how well the fitted hand
  matches the photo (``metrics.json``: its silhouette's IoU with the mask the fit started from,
  the PSNR of its colours inside both: :func:`lisa_hand.fitting.photo.artefacts.agreement`).

Targets (on 2 CPU cores): under 30 s a photo (every photo), PA-MPJPE under 5 mm (mean
over the synthetic photos), one piece on each real photo; the summary says which are met.
Torch runs with ``--threads`` CPU threads (default 2).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lisa_hand.fitting.outputs.records import json_safe
from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["SyntheticResult", "SharedResult", "PhotoBenchmark", "default_shared_dir",
           "keypoint_error_px", "reference_keypoints", "detector_wrist_shift",
           "run_photo_benchmark", "main"]

SHARED_PHOTOS = ("hand_thumb_up.jpg", "thumbs-up.png")
"""The real photos (``tests/assets/photos/README.md``: source and licence)."""
TARGET_SECONDS = 30.0
TARGET_PA_MPJPE_MM = 5.0
TARGET_PIECES = 1


def default_shared_dir() -> Path:
    """The repository's ``tests/assets/photos`` (the benchmarks run from a clone)."""
    return Path(__file__).resolve().parents[1] / "tests" / "assets" / "photos"


@dataclass
class SyntheticResult:
    """One synthetic photo's fit; distances in mm, NaN when the fit failed."""

    photo: str
    subject: str
    side: str
    """The true side."""
    fitted_side: str | None
    seconds: float
    mpjpe_mm: float
    pa_mpjpe_mm: float
    reference_pa_mpjpe_mm: float
    """The photo-blind reference hand (see the module docstring)."""
    wrist_error_mm: float
    """|fitted wrist - true wrist|, camera frame (no alignment)."""
    depth_error_mm: float
    """Fitted minus true wrist depth (z, camera frame): + is too far."""
    pieces: int | None = None
    """Connected pieces of the fitted surface (guard)."""
    area_ratio: float | None = None
    """Fitted surface area / keypoint-stage mesh area (guard)."""
    error: str | None = None
    """Why the fit failed (its one-line message), or None."""
    detector_wrist_shift: float | None = None
    """Where the detector put the wrist: its offset from the true wrist along the true
    wrist-to-middle-knuckle line, a fraction of that line's length in the photo (+: towards the
    fingers; :data:`lisa_hand.data.detect.MEDIAPIPE_WRIST_SHIFT`); None without
    detection."""


@dataclass
class SharedResult:
    """One shared real photo's fit."""

    photo: str
    seconds: float
    pieces: int | None
    """Connected pieces of the fitted surface (guard)."""
    area_ratio: float | None
    """Fitted surface area / keypoint-stage mesh area (guard)."""
    keypoint_error_px: float | None
    """Mean |detected - fitted| 2D keypoint, pixels of the original photo."""
    guard_passed: bool | None
    side: str | None
    error: str | None = None
    silhouette_iou: float | None = None
    """The fitted hand's silhouette against the mask the fit started from (metrics.json)."""
    psnr_in_mask_db: float | None = None
    """Its colours against the photo's where both are the hand, dB (metrics.json)."""


@dataclass
class PhotoBenchmark:
    """Numbers of one run (JSON via :meth:`to_dict`)."""

    detection: str
    """'mediapipe', or 'true-keypoints' (the [photo] extra is not installed)."""
    threads: int
    device: str
    num_photos: int
    seconds_per_photo: float
    """Mean over every fitted photo, synthetic and shared."""
    synthetic_seconds_per_photo: float
    """Mean over the synthetic photos that were fitted."""
    max_seconds: float
    mpjpe_mm: float
    """Mean over the synthetic photos that were fitted."""
    pa_mpjpe_mm: float
    reference_pa_mpjpe_mm: float
    """The photo-blind reference hand, mean over the same photos."""
    wrist_error_mm: float
    failed: int
    """Synthetic photos whose fit failed (no hand found, ...)."""
    detector_wrist_shift: float | None
    """The median of the photos' :attr:`SyntheticResult.detector_wrist_shift` (None without
    detection)."""
    synthetic: list[SyntheticResult]
    shared: dict[str, SharedResult]
    targets: dict[str, bool | None]
    """Per target, met (True), missed (False) or not measured (None)."""
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------------------
# Pieces


def keypoint_error_px(keypoints_json: dict[str, Any]) -> float:
    """Mean distance between ``keypoints_2d_detected`` and ``keypoints_2d_fitted`` of a
    ``lisa fit-photo`` ``keypoints.json`` (pixels), over the keypoints finite in both."""
    detected = np.asarray(keypoints_json["keypoints_2d_detected"], np.float64)
    fitted = np.asarray(keypoints_json["keypoints_2d_fitted"], np.float64)
    if detected.shape != fitted.shape or detected.ndim != 2 or detected.shape[1] != 2:
        raise ValueError(f"keypoints.json: keypoints_2d_detected {list(detected.shape)} and "
                         f"keypoints_2d_fitted {list(fitted.shape)} must both be [21, 2]")
    finite = np.isfinite(detected).all(1) & np.isfinite(fitted).all(1)
    if not finite.any():
        return math.nan
    return float(np.linalg.norm(detected[finite] - fitted[finite], axis=1).mean())


def reference_keypoints(side: str) -> np.ndarray:
    """[21, 3] metres: the photo-blind reference hand (the open hand model's default shape in
    the 'relaxed' pose, of ``side``)."""
    import torch

    from lisa_hand.handmodel import OpenHand, named_pose

    pose = named_pose("relaxed", side=side, dtype=torch.float64)
    return OpenHand(side=side).posed(pose).keypoints.numpy()


def _fitted_folders(out_dir: Path) -> list[Path]:
    """The folders of ``out_dir`` (itself included) that hold a fitted ``keypoints.json``."""
    return sorted(path.parent for path in out_dir.rglob("keypoints.json"))


def _read_fit(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "keypoints.json").read_text())


def _closest_hand(folders: list[Path], keypoints_2d: np.ndarray) -> Path:
    """Of several fitted hands, the one whose detected keypoints are nearest ``keypoints_2d``."""
    def distance(folder: Path) -> float:
        detected = np.asarray(_read_fit(folder)["keypoints_2d_detected"], np.float64)
        return float(np.nanmean(np.linalg.norm(detected - keypoints_2d, axis=1)))

    return min(folders, key=distance)


def _run_fit(fit, photo: Path, out_dir: Path, options: dict[str, Any]) -> tuple[float, list]:
    """-> (seconds, fit reports) of ``fit([photo], out_dir, ...)`` (its log lines dropped)."""
    start = time.perf_counter()
    reports = fit([photo], out_dir, progress=False, log=lambda *_: None, **options)
    return time.perf_counter() - start, list(reports or [])


def _write_true_keypoints(path: Path, photo) -> Path:
    """``--keypoints`` file of a synthetic photo: its true 2D keypoints, all 21 (as a detector
    gives them, hidden ones included) and its side."""
    from lisa_hand.skeleton import KEYPOINT_NAMES

    data = {"names": list(KEYPOINT_NAMES), "side": photo.side,
            "keypoints": photo.keypoints_2d.tolist()}
    path.write_text(json.dumps(data))
    return path


# ------------------------------------------------------------------------------------------------
# The two parts


def _synthetic_one(fit, photo, out_dir: Path, detect: bool, options: dict) -> SyntheticResult:
    from lisa_hand.metrics import mpjpe, pa_mpjpe

    options = dict(options)
    if not detect:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        options.update(side=photo.side, keypoints_json=_write_true_keypoints(
            out_dir.with_suffix(".keypoints.json"), photo))
    reference = pa_mpjpe(reference_keypoints(photo.side), photo.keypoints_3d)
    nan = math.nan
    try:
        seconds, reports = _run_fit(fit, photo.path, out_dir, options)
    except (ValueError, OSError) as exc:
        return SyntheticResult(photo.path.name, photo.subject, photo.side, None, nan, nan, nan,
                               reference, nan, nan, error=str(exc))
    folder = _closest_hand(_fitted_folders(out_dir), photo.keypoints_2d)
    fit = _read_fit(folder)
    fitted = np.asarray(fit["keypoints_3d"], np.float64)
    wrist = fitted[0] - photo.keypoints_3d[0]
    guard = _guard_of(reports, folder)
    shift = None
    if detect:
        detector = np.asarray(fit.get("keypoints_2d_detector", fit["keypoints_2d_detected"]))
        shift = detector_wrist_shift(detector, photo.keypoints_2d)  # both in the photo's pixels
    return SyntheticResult(photo.path.name, photo.subject, photo.side, fit.get("side"), seconds,
                           mpjpe(fitted, photo.keypoints_3d), pa_mpjpe(fitted, photo.keypoints_3d),
                           reference, float(np.linalg.norm(wrist) * 1000.0),
                           float(wrist[2] * 1000.0),
                           pieces=None if guard is None else int(guard.pieces),
                           area_ratio=None if guard is None else float(guard.area_ratio),
                           detector_wrist_shift=shift)


def detector_wrist_shift(detected: np.ndarray, true: np.ndarray) -> float:
    """detected, true: [21, 2] pixels -> the detected wrist's offset from the true one along the
    true wrist-to-middle-knuckle line, a fraction of its length (+: towards the knuckle)."""
    from lisa_hand.data.detect import MIDDLE_MCP

    axis = true[MIDDLE_MCP] - true[0]
    length = float(np.linalg.norm(axis))
    return float((detected[0] - true[0]) @ axis) / (length * length)


def _guard_of(reports: list, folder: Path | None = None) -> Any:
    """The guard report (``report.guard``) of the hand fitted into ``folder`` (None: the first
    fitted hand), or None."""
    for report in reports:
        guard = getattr(report, "guard", None)
        where = getattr(report, "folder", None)
        if guard is not None and (folder is None or where is None
                                  or Path(where).resolve() == folder.resolve()):
            return guard
    return None


def _shared_one(fit, path: Path, out_dir: Path, options: dict) -> SharedResult:
    try:
        seconds, reports = _run_fit(fit, path, out_dir, options)
    except (ValueError, OSError) as exc:
        return SharedResult(path.name, math.nan, None, None, None, None, None, error=str(exc))
    folders = _fitted_folders(out_dir)
    fit = _read_fit(folders[0])
    guard = _guard_of(reports)
    numbers = json.loads((folders[0] / "metrics.json").read_text())["per_photo"][0]
    return SharedResult(
        photo=path.name, seconds=seconds,
        pieces=None if guard is None else int(guard.pieces),
        area_ratio=None if guard is None else float(guard.area_ratio),
        keypoint_error_px=keypoint_error_px(fit),
        guard_passed=None if guard is None else bool(guard.passed), side=fit.get("side"),
        silhouette_iou=numbers.get("silhouette_iou"),
        psnr_in_mask_db=numbers.get("psnr_in_mask_db"))


def _mean(values) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan


def _targets(synthetic: list[SyntheticResult], shared: dict[str, SharedResult]):
    seconds = [r.seconds for r in synthetic] + [r.seconds for r in shared.values()]
    seconds = [s for s in seconds if math.isfinite(s)]
    fitted = [r for r in synthetic if r.error is None]
    pieces = [r.pieces for r in shared.values()]
    return {
        "seconds_per_photo_under_30": (max(seconds) < TARGET_SECONDS) if seconds else None,
        "pa_mpjpe_under_5_mm": (_mean(r.pa_mpjpe_mm for r in fitted) < TARGET_PA_MPJPE_MM
                                and len(fitted) == len(synthetic)) if synthetic else None,
        "one_piece_on_real_photos": (all(p == TARGET_PIECES for p in pieces)
                                     if shared else None),
    }


def run_photo_benchmark(num_photos: int = 12, *, shared_dir: Path | None = None,
                        work_dir: Path | None = None, threads: int = 2, device: str = "cpu",
                        model_path=None, seed: int = 0, detect: bool | None = None, fit=None,
                        scene=None, config=None, log=print) -> PhotoBenchmark:
    """Run the benchmark (see the module docstring).

    work_dir: where the photos and fits go (default: a temporary folder, removed afterwards).
    detect: detect the keypoints of the synthetic photos (MediaPipe) or give the fit the true
        ones; None: detect when the [photo] extra is installed. The shared photos are fitted
        when the extra is installed or ``detect`` is True. fit: a callable with the signature of
        :func:`lisa_hand.fitting.photo.fit.fit_photo_folder` (default: it). scene: the
        :class:`~benchmarks._photo_scenes.PhotoSceneConfig` of the synthetic photos
        (default: its defaults with ``seed``). config: the
        :class:`~lisa_hand.fitting.photo.config.FitPhotoConfig` of every fit (None: the default).
    """
    if isinstance(num_photos, bool) or not isinstance(num_photos, int) or num_photos < 0:
        raise ValueError(f"--photos must be an integer >= 0, got {num_photos!r}")
    if work_dir is None:
        with tempfile.TemporaryDirectory(prefix="lisa_bench_photo_") as tmp:
            return run_photo_benchmark(num_photos, shared_dir=shared_dir, work_dir=Path(tmp),
                                       threads=threads, device=device, model_path=model_path,
                                       seed=seed, detect=detect, fit=fit, scene=scene,
                                       config=config, log=log)
    from ._photo_scenes import PhotoSceneConfig

    if fit is None:
        from lisa_hand.fitting.photo.fit import fit_photo_folder as fit
    from lisa_hand.data.detect import photo_extra_missing

    notes: list[str] = []
    extra = photo_extra_missing() is None
    if not extra:
        notes.append("MediaPipe is not installed (the [photo] extra): the synthetic photos are "
                     "fitted from their true 2D keypoints and side, the real ones skipped")
        log(f"note: {notes[-1]}")
    detect = extra if detect is None else detect
    if extra and not detect:
        notes.append("the synthetic photos are fitted from their true 2D keypoints and side "
                     "(no detection)")
    scene = PhotoSceneConfig(seed=seed) if scene is None else scene
    options = {"device": device, "model_path": model_path}
    if config is not None:
        options["config"] = config
    with cpu_threads(threads):
        synthetic = _synthetic_part(fit, num_photos, scene, Path(work_dir), detect, options, log)
        shared = {} if not (detect or extra) else _shared_part(fit, shared_dir, Path(work_dir),
                                                               options, notes, log)
    fitted = [r for r in synthetic if r.error is None]
    seconds = [r.seconds for r in fitted] + [r.seconds for r in shared.values()
                                              if math.isfinite(r.seconds)]
    return PhotoBenchmark(
        detection="mediapipe" if detect else "true-keypoints", threads=threads, device=device,
        num_photos=num_photos, seconds_per_photo=_mean(seconds),
        synthetic_seconds_per_photo=_mean(r.seconds for r in fitted),
        max_seconds=max(seconds) if seconds else math.nan,
        mpjpe_mm=_mean(r.mpjpe_mm for r in fitted),
        pa_mpjpe_mm=_mean(r.pa_mpjpe_mm for r in fitted),
        reference_pa_mpjpe_mm=_mean(r.reference_pa_mpjpe_mm for r in fitted),
        wrist_error_mm=_mean(r.wrist_error_mm for r in fitted),
        failed=len(synthetic) - len(fitted),
        detector_wrist_shift=_median([r.detector_wrist_shift for r in fitted
                                      if r.detector_wrist_shift is not None]),
        synthetic=synthetic, shared=shared,
        targets=_targets(synthetic, shared), notes=notes)


def _synthetic_part(fit, num_photos: int, scene, work_dir: Path, detect: bool, options: dict,
                    log) -> list[SyntheticResult]:
    from ._photo_scenes import make_photo

    results = []
    for index in range(num_photos):
        photo = make_photo(scene, index, work_dir / "photos")
        results.append(_synthetic_one(fit, photo, work_dir / "fits" / photo.path.stem, detect,
                                      options))
        log(_synthetic_line(results[-1]))
    return results


def _shared_part(fit, shared_dir, work_dir: Path, options: dict, notes: list[str],
                 log) -> dict[str, SharedResult]:
    shared_dir = default_shared_dir() if shared_dir is None else Path(shared_dir)
    results: dict[str, SharedResult] = {}
    for name in SHARED_PHOTOS:
        if not (shared_dir / name).is_file():
            where = "the folder is absent" if not shared_dir.is_dir() else "not there"
            notes.append(f"shared photo {name} skipped: {shared_dir / name}: {where}")
            log(f"note: {notes[-1]}")
            continue
        results[name] = _shared_one(fit, shared_dir / name, work_dir / "fits" / Path(name).stem,
                                    options)
        log(_shared_line(results[name]))
    return results


# ------------------------------------------------------------------------------------------------
# Printing


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def _number(value, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def _synthetic_line(result: SyntheticResult) -> str:
    if result.error is not None:
        return f"  {result.photo} ({result.subject}, {result.side}): failed: {result.error}"
    return (f"  {result.photo} ({result.subject}, {result.side}, fitted {result.fitted_side}): "
            f"{result.seconds:.1f} s, MPJPE {result.mpjpe_mm:.1f} mm, PA-MPJPE "
            f"{result.pa_mpjpe_mm:.1f} mm (reference {result.reference_pa_mpjpe_mm:.1f}), "
            f"wrist {result.wrist_error_mm:.0f} mm off (depth {result.depth_error_mm:+.0f} mm)")


def _shared_line(result: SharedResult) -> str:
    if result.error is not None:
        return f"  {result.photo}: failed: {result.error}"
    return (f"  {result.photo}: {result.seconds:.1f} s, {result.pieces} piece(s), area ratio "
            f"{_number(result.area_ratio, 3)}, keypoint error {_number(result.keypoint_error_px)}"
            f" px, silhouette IoU {_number(result.silhouette_iou, 3)}, PSNR in the mask "
            f"{_number(result.psnr_in_mask_db)} dB, guard "
            f"{'passed' if result.guard_passed else 'failed'}")


def _table(result: PhotoBenchmark) -> list[str]:
    rows = ["| photos | detection | s / photo (max of all) | MPJPE mm | PA-MPJPE mm | reference "
            "PA-MPJPE mm | wrist error mm | failed |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
            f"| {result.num_photos} synthetic | {result.detection} | "
            f"{_number(result.synthetic_seconds_per_photo)} ({_number(result.max_seconds)}) | "
            f"{_number(result.mpjpe_mm)} | {_number(result.pa_mpjpe_mm)} | "
            f"{_number(result.reference_pa_mpjpe_mm)} | {_number(result.wrist_error_mm, 0)} | "
            f"{result.failed} |"]
    if result.detector_wrist_shift is not None:
        rows += ["", f"the detector's wrist, median over the photos: "
                 f"{result.detector_wrist_shift:+.3f} of the wrist-to-middle-knuckle length "
                 "towards the fingers from the true wrist (detector_wrist_shift)"]
    if result.shared:
        rows += ["", "| real photo | s | pieces | area ratio | keypoint error px | silhouette "
                 "IoU | PSNR in mask dB | guard |", "| --- | --- | --- | --- | --- | --- | --- "
                 "| --- |"]
        for shared in result.shared.values():
            rows.append(f"| {shared.photo} | {_number(shared.seconds)} | "
                        f"{'-' if shared.pieces is None else shared.pieces} | "
                        f"{_number(shared.area_ratio, 3)} | {_number(shared.keypoint_error_px)} "
                        f"| {_number(shared.silhouette_iou, 3)} | "
                        f"{_number(shared.psnr_in_mask_db)} "
                        f"| {shared.error or ('passed' if shared.guard_passed else 'failed')} |")
    return rows


def _target_lines(targets: dict[str, bool | None]) -> list[str]:
    words = {True: "met", False: "NOT met", None: "not measured"}
    labels = {"seconds_per_photo_under_30": "under 30 s a photo",
              "pa_mpjpe_under_5_mm": "PA-MPJPE under 5 mm (synthetic)",
              "one_piece_on_real_photos": "one piece on the real photos"}
    return [f"target {labels[name]}: {words[value]}" for name, value in targets.items()]


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks photo [--json FILE] [--photos N] [--shared DIR] ...``"""
    parser = argparse.ArgumentParser(prog="python -m benchmarks photo",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--photos", type=int, default=12,
                        help="synthetic photos (two of each of the 6 held-out subjects)")
    parser.add_argument("--shared", type=Path, default=None,
                        help="folder of the real photos (default tests/assets/photos)")
    parser.add_argument("--out", type=Path, default=None,
                        help="keep the photos and fits here (default: a temporary folder)")
    parser.add_argument("--model", default=None, help="trained model (default: the shipped one)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (CPU)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic photos")
    parser.add_argument("--hand-model", default="v1", choices=("v1", "v2"),
                        help="open hand model version of the synthetic photos (default v1, "
                             "the shipped model's)")
    parser.add_argument("--subjects", default="test", choices=("test", "train"),
                        help="whose hands the synthetic photos show: the held-out test subjects "
                             "(the benchmark) or training subjects (to measure a convention, "
                             "e.g. detector_wrist_shift, off the benchmark)")
    parser.add_argument("--true-keypoints", action="store_true",
                        help="give the fit the true 2D keypoints and side of the synthetic photos "
                             "instead of detecting them (the fit's error without the detector's)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a FitPhotoConfig value of every fit, e.g. --set "
                             "fit.color_iters=80 --set detector_wrist_shift=0.17 (repeatable)")
    args = parser.parse_args(argv)
    if args.shared is not None and not args.shared.is_dir():
        raise ValueError(f"--shared {args.shared}: no such folder (the real photos' folder)")
    config = None
    if args.overrides:
        from lisa_hand.fitting.photo.fit import FitPhotoConfig
        from lisa_hand.utils.config import apply_overrides

        try:
            config = apply_overrides(FitPhotoConfig(), args.overrides)
        except (ValueError, TypeError) as exc:
            parser.error(f"--set: {exc}")
        print(f"fit config overrides: {', '.join(args.overrides)}")
    whose = "held-out" if args.subjects == "test" else "training"
    print(f"photo fitting: {args.photos} synthetic photos ({whose} subjects), then the shared "
          f"photos; {args.threads} torch threads, {args.device}")
    from ._photo_scenes import PhotoSceneConfig

    result = run_photo_benchmark(args.photos, shared_dir=args.shared, work_dir=args.out,
                                 threads=args.threads, device=args.device,
                                 model_path=args.model, seed=args.seed,
                                 detect=False if args.true_keypoints else None,
                                 scene=PhotoSceneConfig(seed=args.seed,
                                                        hand_model=args.hand_model,
                                                        subjects=args.subjects),
                                 config=config)
    print()
    print("\n".join(_table(result)))
    print()
    print("\n".join(_target_lines(result.targets)))
    write_results(args.json, {**json_safe(result.to_dict()), "overrides": list(args.overrides)})
