"""Video fitting benchmark: ``lisa fit-video`` tracked against every frame fitted alone, on
rendered clips with ground truth, on a real clip, and for speed.

``python -m benchmarks video [--json FILE] [--clips N] [--frames F] [--threads T]
[--skip-speed] [--skip-real] [--real PATH] [--out DIR]``

Each part fits every clip twice, measured in the same run: tracked (``fit_video`` with its
defaults: one hand through the clip, a motion prior) and the reference, independent
(``FitVideoConfig(independent=True)``: every frame fitted alone, each starting from the previous
frame's fit).

1. **Rendered clips with truth** (:mod:`benchmarks._video_scenes`): ``--clips`` (default 3)
   clips of ``--frames`` (default 40) frames, 25 fps, 640x480, each a held-out subject of the
   open hand model (one clip in three a left hand) going relaxed -> fist -> point -> relaxed while
   it turns 30-40 degrees and moves 4 cm, seen by a known camera (focal 550 px, 0.45-0.55 m
   away) that the fit is given (``camera_json``). Per clip and mean: frames with a fitted hand
   out of the clip's; over the frames fitted in both modes, MPJPE after root (wrist) alignment
   and PA-MPJPE (mm, :mod:`lisa_hand.metrics.keypoints`), the acceleration error (mm/frame^2,
   :func:`lisa_hand.fitting.video.quality.acceleration_error_mm`) and the jitter of the fit and
   of the truth (mm/frame^2, :func:`~lisa_hand.fitting.video.quality.jitter_mm`); seconds a fit.
   The fitted hand is the one nearest the true hand in the image.
2. **A real clip** (``--real``, default ``tests/assets/videos/hand_landmarker_test_video.mp4``;
   skipped with a note when missing): the share of the frames where the detector found a hand
   that have a fitted hand, the jitter (mm/frame^2), the 2D agreement between the fitted
   keypoints projected and the detector's (pixels of the clip), seconds.

In parts 1 and 2 the hand's look through the clip: the PSNR of the fitted hand rendered at its
fitted poses against the frames it was not fitted on
(:func:`lisa_hand.fitting.video.quality.appearance_psnr_db`).
3. **Speed** (``--skip-speed`` to skip): the real clip upscaled to 1280x720 (bicubic), fitted
   with its files (:func:`lisa_hand.fitting.video.fit_video_folder`): frames a second end to
   end and of the detection alone.

Targets (on 2 CPU cores): MPJPE tracked <= independent and acceleration error tracked <
independent (rendered clips, means); jitter tracked <= a third of independent and no loss of
2D agreement, tracked <= independent (real clip); at least 5 frames a second tracked, end to
end (speed). The summary says which are met. Torch runs with ``--threads`` CPU threads (default 2).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from lisa_hand.fitting.outputs.records import json_safe
from lisa_hand.utils.threads import cpu_threads

from . import write_results
from ._video_tables import (
    MODES,
    SPEED_SIZE,
    _clip_lines,
    _mean,
    _real_line,
    _speed_line,
    _table,
    _target_lines,
)

__all__ = ["ModeResult", "ClipResult", "RealResult", "SpeedResult", "VideoBenchmark",
           "default_real_clip", "fit_config", "run_video_benchmark", "main"]

TARGET_JITTER_RATIO = 1.0 / 3.0
TARGET_AGREEMENT_RATIO = 1.0
TARGET_FPS = 5.0


def default_real_clip() -> Path:
    """The real clip of the repository's test assets (``tests/assets/videos/``)."""
    return (Path(__file__).resolve().parents[1] / "tests" / "assets" / "videos"
            / "hand_landmarker_test_video.mp4")


# ------------------------------------------------------------------------------------------------
# Results


@dataclass
class ModeResult:
    """One fit of a rendered clip (tracked or independent); mm, NaN when not measured."""

    fitted_frames: int
    """Frames with a fitted hand (the hand compared with the truth)."""
    mpjpe_mm: float
    """Root-aligned MPJPE, mean over the frames fitted in both modes."""
    pa_mpjpe_mm: float
    acceleration_error_mm: float
    """mm/frame^2, over the frame triples fitted in both modes."""
    jitter_mm: float
    """mm/frame^2, over the same triples."""
    seconds: float
    fitted_side: str | None = None
    hands: int = 0
    """Hands the fit followed."""
    error: str | None = None
    appearance_psnr_db: float = math.nan
    """The hand's look through the clip
    (:func:`lisa_hand.fitting.video.quality.appearance_psnr_db`)."""


@dataclass
class ClipResult:
    """One rendered clip, both fits."""

    clip: str
    subject: str
    side: str
    frames: int
    common_frames: int
    """Frames fitted in both modes (those the distances are over)."""
    truth_jitter_mm: float
    """The true hand's jitter over the same triples (its own motion), mm/frame^2."""
    seconds_render: float
    tracked: ModeResult
    independent: ModeResult


@dataclass
class RealResult:
    """One fit of the real clip."""

    frames: int
    detected_frames: int
    """Frames (summed over the hands) where the detector found a followed hand."""
    fitted_share: float
    """Of those, the share with a fitted hand."""
    jitter_mm: float
    agreement_px: float
    seconds: float
    hands: int
    error: str | None = None
    appearance_psnr_db: float = math.nan
    """The hands' look through the clip
    (:func:`lisa_hand.fitting.video.quality.appearance_psnr_db`)."""


@dataclass
class SpeedResult:
    """One fit of the upscaled clip, with its files."""

    frames: int
    seconds: float
    """End to end (reading, detection, fit, files)."""
    frames_per_second: float
    detect_frames_per_second: float
    timings: dict[str, float] = field(default_factory=dict)
    error: str | None = None


@dataclass
class VideoBenchmark:
    """Numbers of one run (JSON via :meth:`to_dict`)."""

    threads: int
    device: str
    num_clips: int
    frames_per_clip: int
    seconds_per_rendered_frame: float
    mpjpe_mm: float
    reference_mpjpe_mm: float
    pa_mpjpe_mm: float
    reference_pa_mpjpe_mm: float
    acceleration_error_mm: float
    reference_acceleration_error_mm: float
    jitter_mm: float
    reference_jitter_mm: float
    truth_jitter_mm: float
    fitted_share: float
    """Rendered clips: frames with a fitted hand over frames, tracked."""
    reference_fitted_share: float
    real_jitter_mm: float | None
    reference_real_jitter_mm: float | None
    real_agreement_px: float | None
    reference_real_agreement_px: float | None
    speed_frames_per_second: float | None
    reference_speed_frames_per_second: float | None
    appearance_psnr_db: float
    """Rendered clips, tracked: the mean
    :func:`lisa_hand.fitting.video.quality.appearance_psnr_db`."""
    real_appearance_psnr_db: float | None
    clips: list[ClipResult]
    real: dict[str, RealResult]
    speed: dict[str, SpeedResult]
    targets: dict[str, bool | None]
    seconds_parts: dict[str, float]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------------------
# Pieces


def _fitted_rows(keypoints_3d: np.ndarray) -> np.ndarray:
    """[N] bool: the rows of [N, 21, 3] that hold a fitted hand."""
    return np.isfinite(np.asarray(keypoints_3d, np.float64)).all(axis=(1, 2))


def fit_config(independent: bool, threads: int, overrides=()):
    """The :class:`~lisa_hand.fitting.video.config.FitVideoConfig` of a fit: the defaults with
    ``independent``, ``threads`` CPU threads and the ``--set KEY=VALUE`` overrides."""
    from lisa_hand.fitting.video.config import FitVideoConfig
    from lisa_hand.utils.config import apply_overrides

    config = FitVideoConfig(independent=independent, num_threads=threads)
    return apply_overrides(config, list(overrides)) if overrides else config


def _nearest_hand(fit, keypoints_2d: np.ndarray):
    """Of the fit's hands, the one whose fitted 2D keypoints are nearest ``keypoints_2d``
    [N, 21, 2] (original pixels), or None."""
    def distance(hand) -> float:
        gap = np.linalg.norm(hand.keypoints_2d - keypoints_2d, axis=-1).mean(-1)
        gap = gap[np.isfinite(gap)]
        return float(gap.mean()) if gap.size else math.inf

    return min(fit.hands, key=distance, default=None)


def _masked(keypoints_3d: np.ndarray, rows: np.ndarray) -> np.ndarray:
    out = np.array(keypoints_3d, np.float64)
    out[~rows] = np.nan
    return out


def _fit_clip(clip, independent: bool, options: dict, make_config):
    """-> (fit or None, seconds, error or None)."""
    from lisa_hand.fitting.video.fit import fit_video

    start = time.perf_counter()
    try:
        fit = fit_video(clip.folder, camera_json=clip.camera_json, fps=clip.fps, progress=False,
                        log=None, config=make_config(independent), **options)
    except (ValueError, OSError) as exc:
        return None, time.perf_counter() - start, str(exc)
    return fit, time.perf_counter() - start, None


def _clip_result(clip, fits: dict[str, tuple]) -> ClipResult:
    from lisa_hand.fitting.video.quality import (
        acceleration_error_mm,
        appearance_psnr_db,
        jitter_mm,
        nan_mean,
    )
    from lisa_hand.metrics import mpjpe, pa_mpjpe

    nan = math.nan
    truth = clip.keypoints_3d
    fitted = {}
    for mode, (fit, _, _) in fits.items():
        hand = None if fit is None else _nearest_hand(fit, clip.keypoints_2d)
        fitted[mode] = hand
    rows = {mode: (_fitted_rows(hand.motion.keypoints_3d) if hand is not None
                   else np.zeros(len(truth), bool)) for mode, hand in fitted.items()}
    common = rows["tracked"] & rows["independent"]
    modes = {}
    for mode, (fit, seconds, error) in fits.items():
        hand = fitted[mode]
        if hand is None:
            modes[mode] = ModeResult(0, nan, nan, nan, nan, seconds,
                                     error=error or "no hand fitted")
            continue
        points = hand.motion.keypoints_3d
        frames = np.flatnonzero(common)
        modes[mode] = ModeResult(
            fitted_frames=int(rows[mode].sum()),
            mpjpe_mm=_mean(mpjpe(points[i], truth[i]) for i in frames),
            pa_mpjpe_mm=_mean(pa_mpjpe(points[i], truth[i]) for i in frames),
            acceleration_error_mm=nan_mean(acceleration_error_mm(_masked(points, common),
                                                                 truth)),
            jitter_mm=nan_mean(jitter_mm(_masked(points, common))),
            seconds=seconds, fitted_side=hand.side, hands=len(fit.hands),
            appearance_psnr_db=appearance_psnr_db(fit))
    return ClipResult(clip=clip.folder.parent.name, subject=clip.subject, side=clip.side,
                      frames=clip.num_frames, common_frames=int(common.sum()),
                      truth_jitter_mm=nan_mean(jitter_mm(_masked(truth, common))),
                      seconds_render=clip.seconds_render, tracked=modes["tracked"],
                      independent=modes["independent"])


def _real_result(fit, seconds: float) -> RealResult:
    from lisa_hand.fitting.video.quality import agreement_px, appearance_psnr_db, jitter_mm

    detected = fitted = 0
    jitters, agreements = [], []
    for hand in fit.hands:
        track = hand.track
        rows = _fitted_rows(hand.motion.keypoints_3d)
        detected += int(track.detected.sum())
        fitted += int((track.detected & rows).sum())
        jitters.append(jitter_mm(hand.motion.keypoints_3d))
        agreements.append(agreement_px(hand.keypoints_2d, track.keypoints / fit.scale,
                                       track.detected))
    return RealResult(frames=len(fit.indices), detected_frames=detected,
                      fitted_share=fitted / detected if detected else math.nan,
                      jitter_mm=_nan_mean_all(jitters), agreement_px=_nan_mean_all(agreements),
                      seconds=seconds, hands=len(fit.hands),
                      appearance_psnr_db=appearance_psnr_db(fit))


def _nan_mean_all(arrays: list[np.ndarray]) -> float:
    from lisa_hand.fitting.video.quality import nan_mean

    return nan_mean(np.concatenate(arrays)) if arrays else math.nan


def _upscaled(real: Path, path: Path, size: tuple[int, int]) -> Path:
    """The clip ``real`` resized to ``size`` (bicubic), written as an MP4 at its frame rate."""
    import cv2

    from lisa_hand.data.video import write_video

    capture = cv2.VideoCapture(str(real))
    if not capture.isOpened():
        raise OSError(f"{real}: OpenCV cannot open it")
    fps = capture.get(cv2.CAP_PROP_FPS) or 25.0

    def frames():
        try:
            while True:
                ok, bgr = capture.read()
                if not ok:
                    return
                resized = cv2.resize(bgr, size, interpolation=cv2.INTER_CUBIC)
                yield cv2.cvtColor(resized, cv2.COLOR_BGR2RGB)
        finally:
            capture.release()

    return write_video(path, frames(), fps)


# ------------------------------------------------------------------------------------------------
# The three parts


def _clips_part(num_clips: int, scene, work_dir: Path, options: dict, make_config,
                log) -> list[ClipResult]:
    from ._video_scenes import make_clip

    results = []
    for index in range(num_clips):
        clip = make_clip(scene, index, work_dir / "clips", log=log)
        log(f"  clip {index} ({clip.subject}, {clip.side}, turns {clip.turn_deg:+.0f} deg): "
            f"{clip.num_frames} frames rendered in {clip.seconds_render:.1f} s "
            f"({clip.seconds_render / clip.num_frames:.2f} s a frame)"
            + (", by an earlier run: read back" if clip.read_back else ""))
        fits = {mode: _fit_clip(clip, mode == "independent", options, make_config)
                for mode in MODES}
        results.append(_clip_result(clip, fits))
        for line in _clip_lines(results[-1]):
            log(line)
    return results


def _real_part(real: Path, options: dict, make_config, log) -> dict[str, RealResult]:
    from lisa_hand.fitting.video.fit import fit_video

    results = {}
    for mode in MODES:
        start = time.perf_counter()
        try:
            fit = fit_video(real, progress=False, log=None,
                            config=make_config(mode == "independent"), **options)
        except (ValueError, OSError) as exc:
            results[mode] = RealResult(0, 0, math.nan, math.nan, math.nan,
                                       time.perf_counter() - start, 0, error=str(exc))
        else:
            results[mode] = _real_result(fit, time.perf_counter() - start)
        log(_real_line(mode, results[mode]))
    return results


def _speed_part(real: Path, work_dir: Path, options: dict, make_config,
                log) -> dict[str, SpeedResult]:
    from lisa_hand.fitting.video import fit_video_folder

    work_dir.mkdir(parents=True, exist_ok=True)
    clip = _upscaled(real, work_dir / f"real_{SPEED_SIZE[0]}x{SPEED_SIZE[1]}.mp4", SPEED_SIZE)
    log(f"  {real.name} upscaled to {SPEED_SIZE[0]}x{SPEED_SIZE[1]}: {clip}")
    results = {}
    for mode in MODES:
        out = work_dir / f"fit_{mode}"
        suffix = 0
        while out.exists():  # a fresh folder each time
            suffix += 1
            out = work_dir / f"fit_{mode}_{suffix}"
        start = time.perf_counter()
        try:
            report = fit_video_folder(clip, out, progress=False, log=None,
                                      config=make_config(mode == "independent"), **options)
        except (ValueError, OSError) as exc:
            results[mode] = SpeedResult(0, time.perf_counter() - start, math.nan, math.nan,
                                        error=str(exc))
        else:
            frames = len(report.fit.indices)
            timings = {key: float(value) for key, value in report.fit.timings.items()}
            detect = timings.get("seconds_detect", math.nan)
            results[mode] = SpeedResult(frames=frames, seconds=report.seconds,
                                        frames_per_second=frames / report.seconds,
                                        detect_frames_per_second=frames / detect
                                        if detect > 0 else math.nan, timings=timings)
        log(_speed_line(mode, results[mode]))
    return results


def _targets(clips: list[ClipResult], real: dict[str, RealResult],
             speed: dict[str, SpeedResult]) -> dict[str, bool | None]:
    def means(name: str) -> tuple[float, float]:
        return tuple(_mean(getattr(getattr(c, mode), name) for c in clips) for mode in MODES)

    def compare(pair: tuple[float, float], test) -> bool | None:
        return bool(test(*pair)) if all(math.isfinite(v) for v in pair) else None

    def real_pair(name: str) -> tuple[float, float]:
        return tuple(getattr(real[mode], name) if mode in real else math.nan for mode in MODES)

    tracked_fps = speed["tracked"].frames_per_second if "tracked" in speed else math.nan
    return {
        "mpjpe_tracked_le_independent": compare(means("mpjpe_mm"), lambda a, b: a <= b),
        "acceleration_error_tracked_lt_independent":
            compare(means("acceleration_error_mm"), lambda a, b: a < b),
        "real_jitter_tracked_le_third_of_independent":
            compare(real_pair("jitter_mm"), lambda a, b: a <= TARGET_JITTER_RATIO * b),
        "real_agreement_no_loss":
            compare(real_pair("agreement_px"), lambda a, b: a <= TARGET_AGREEMENT_RATIO * b),
        "speed_tracked_at_least_5_fps":
            (tracked_fps >= TARGET_FPS) if math.isfinite(tracked_fps) else None,
    }


def run_video_benchmark(num_clips: int = 3, frames: int = 40, *, real: Path | None = None,
                        skip_real: bool = False, skip_speed: bool = False,
                        work_dir: Path | None = None, threads: int = 2, device: str = "cpu",
                        model_path=None, seed: int = 0, overrides=(),
                        log=print) -> VideoBenchmark:
    """Run the benchmark (see the module docstring). work_dir: where the clips and fits go
    (default: a temporary folder, removed afterwards). real: the real clip (default
    :func:`default_real_clip`). overrides: ``KEY=VALUE`` strings applied to every fit's
    ``FitVideoConfig`` (:func:`fit_config`)."""
    if isinstance(num_clips, bool) or not isinstance(num_clips, int) or num_clips < 0:
        raise ValueError(f"--clips must be an integer >= 0, got {num_clips!r}")
    if work_dir is None:
        with tempfile.TemporaryDirectory(prefix="lisa_bench_video_") as tmp:
            return run_video_benchmark(num_clips, frames, real=real, skip_real=skip_real,
                                       skip_speed=skip_speed, work_dir=Path(tmp),
                                       threads=threads, device=device, model_path=model_path,
                                       seed=seed, overrides=overrides, log=log)
    from ._video_scenes import VideoSceneConfig

    scene = VideoSceneConfig(seed=seed, frames=frames)
    work_dir = Path(work_dir)
    real = default_real_clip() if real is None else Path(real)
    options = {"device": device, "model_path": model_path}

    def make_config(independent: bool):
        return fit_config(independent, threads, overrides)

    make_config(True)  # a bad override fails before any work
    notes: list[str] = []
    parts: dict[str, float] = {}
    clips: list[ClipResult] = []
    real_results: dict[str, RealResult] = {}
    speed: dict[str, SpeedResult] = {}
    with cpu_threads(threads):
        if num_clips:
            log(f"1. rendered clips with truth ({num_clips} x {frames} frames, "
                f"{scene.width}x{scene.height}, {scene.fps:g} fps)")
            start = time.perf_counter()
            clips = _clips_part(num_clips, scene, work_dir, options, make_config, log)
            parts["clips"] = time.perf_counter() - start
        wanted = [name for name, skip in (("real", skip_real), ("speed", skip_speed)) if not skip]
        if wanted and not real.is_file():
            notes.append(f"{' and '.join(wanted)} part(s) skipped: {real}: no such file")
            log(f"note: {notes[-1]}")
        elif wanted:
            if "real" in wanted:
                log(f"2. the real clip {real}")
                start = time.perf_counter()
                real_results = _real_part(real, options, make_config, log)
                parts["real"] = time.perf_counter() - start
            if "speed" in wanted:
                log(f"3. speed: {real.name} at {SPEED_SIZE[0]}x{SPEED_SIZE[1]}, with its files")
                start = time.perf_counter()
                speed = _speed_part(real, work_dir / "speed", options, make_config, log)
                parts["speed"] = time.perf_counter() - start

    def clip_mean(mode: str, name: str) -> float:
        return _mean(getattr(getattr(c, mode), name) for c in clips)

    def share(mode: str) -> float:
        total = sum(c.frames for c in clips)
        return sum(getattr(c, mode).fitted_frames for c in clips) / total if total else math.nan

    def part(results: dict, mode: str, name: str) -> float | None:
        return getattr(results[mode], name) if mode in results else None

    rendered = sum(c.frames for c in clips)
    return VideoBenchmark(
        threads=threads, device=device, num_clips=num_clips, frames_per_clip=frames,
        seconds_per_rendered_frame=(sum(c.seconds_render for c in clips) / rendered
                                    if rendered else math.nan),
        mpjpe_mm=clip_mean("tracked", "mpjpe_mm"),
        reference_mpjpe_mm=clip_mean("independent", "mpjpe_mm"),
        pa_mpjpe_mm=clip_mean("tracked", "pa_mpjpe_mm"),
        reference_pa_mpjpe_mm=clip_mean("independent", "pa_mpjpe_mm"),
        acceleration_error_mm=clip_mean("tracked", "acceleration_error_mm"),
        reference_acceleration_error_mm=clip_mean("independent", "acceleration_error_mm"),
        jitter_mm=clip_mean("tracked", "jitter_mm"),
        reference_jitter_mm=clip_mean("independent", "jitter_mm"),
        truth_jitter_mm=_mean(c.truth_jitter_mm for c in clips),
        fitted_share=share("tracked"), reference_fitted_share=share("independent"),
        real_jitter_mm=part(real_results, "tracked", "jitter_mm"),
        reference_real_jitter_mm=part(real_results, "independent", "jitter_mm"),
        real_agreement_px=part(real_results, "tracked", "agreement_px"),
        reference_real_agreement_px=part(real_results, "independent", "agreement_px"),
        speed_frames_per_second=part(speed, "tracked", "frames_per_second"),
        reference_speed_frames_per_second=part(speed, "independent", "frames_per_second"),
        appearance_psnr_db=clip_mean("tracked", "appearance_psnr_db"),
        real_appearance_psnr_db=part(real_results, "tracked", "appearance_psnr_db"),
        clips=clips, real=real_results, speed=speed,
        targets=_targets(clips, real_results, speed), seconds_parts=parts, notes=notes)


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks video [--json FILE] [--clips N] [--frames F] ...``"""
    parser = argparse.ArgumentParser(prog="python -m benchmarks video",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--clips", type=int, default=3, help="rendered clips (0: none)")
    parser.add_argument("--frames", type=int, default=40, help="frames a rendered clip")
    parser.add_argument("--real", type=Path, default=None,
                        help="the real clip (default tests/assets/videos/"
                             "hand_landmarker_test_video.mp4)")
    parser.add_argument("--skip-real", action="store_true", help="skip the real clip's part")
    parser.add_argument("--skip-speed", action="store_true", help="skip the speed part")
    parser.add_argument("--out", type=Path, default=None,
                        help="keep the clips and fits here (default: a temporary folder); "
                             "clips rendered there before with the same settings are reused")
    parser.add_argument("--model", default=None, help="trained model (default: the shipped one)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (CPU)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rendered clips")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a FitVideoConfig value of every fit (both modes), e.g. "
                             "--set motion.window_iters=30 (repeatable)")
    args = parser.parse_args(argv)
    if args.frames < 3:
        parser.error(f"--frames must be at least 3, got {args.frames}")
    if args.threads < 1:
        parser.error(f"--threads must be at least 1, got {args.threads}")
    if args.overrides:
        try:
            fit_config(False, args.threads, args.overrides)
        except (ValueError, TypeError) as exc:
            parser.error(f"--set: {exc}")
        print(f"fit config overrides: {', '.join(args.overrides)}")
    print(f"video fitting, tracked against independent frames: {args.clips} rendered clip(s) of "
          f"{args.frames} frames, then the real clip{'' if not args.skip_real else ' (skipped)'}"
          f", then speed{'' if not args.skip_speed else ' (skipped)'}; {args.threads} torch "
          f"threads, {args.device}")
    result = run_video_benchmark(args.clips, args.frames, real=args.real,
                                 skip_real=args.skip_real, skip_speed=args.skip_speed,
                                 work_dir=args.out, threads=args.threads, device=args.device,
                                 model_path=args.model, seed=args.seed,
                                 overrides=tuple(args.overrides))
    print()
    print("\n".join(_table(result)))
    if result.seconds_parts:
        print("seconds per part: " + ", ".join(f"{name} {seconds:.0f}"
                                               for name, seconds in result.seconds_parts.items())
              + (f"; {result.seconds_per_rendered_frame:.2f} s a rendered frame"
                 if result.clips else ""))
    for note in result.notes:
        print(f"note: {note}")
    print()
    print("\n".join(_target_lines(result.targets)))
    write_results(args.json, {**json_safe(result.to_dict()), "overrides": list(args.overrides)})
