"""The lines and tables the video benchmark prints (:mod:`benchmarks.video`): its results in
words, a table per part, and the targets met or not."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .video import ClipResult, RealResult, SpeedResult, VideoBenchmark

MODES = ("tracked", "independent")
"""The two fits of every clip: the tracked one and its reference."""
SPEED_SIZE = (1280, 720)
"""The speed part's frame size, pixels."""


def _mean(values) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan



def _clip_mean(result: VideoBenchmark, mode: str, name: str) -> float:
    """The mean of a rendered clips' figure of ``mode``."""
    return _mean(getattr(getattr(clip, mode), name) for clip in result.clips)


def _number(value, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def _clip_lines(result: ClipResult) -> list[str]:
    lines = []
    for mode in MODES:
        mode_result = getattr(result, mode)
        if mode_result.fitted_frames == 0:
            lines.append(f"    {mode}: failed: {mode_result.error}")
            continue
        lines.append(
            f"    {mode:<11}: {mode_result.fitted_frames}/{result.frames} frames fitted "
            f"({mode_result.fitted_side}), MPJPE {_number(mode_result.mpjpe_mm)} mm, PA-MPJPE "
            f"{_number(mode_result.pa_mpjpe_mm)} mm, acceleration error "
            f"{_number(mode_result.acceleration_error_mm, 2)}, jitter "
            f"{_number(mode_result.jitter_mm, 2)} (truth {_number(result.truth_jitter_mm, 2)}) "
            f"mm/frame^2, look {_number(mode_result.appearance_psnr_db, 2)} dB, "
            f"{mode_result.seconds:.1f} s")
    return lines


def _real_line(mode: str, result: RealResult) -> str:
    if result.error is not None:
        return f"    {mode}: failed: {result.error}"
    share = _number(100 * result.fitted_share)
    return (f"    {mode:<11}: {result.hands} hand(s), fitted in {share} % of "
            f"{result.detected_frames} detected frames (of {result.frames}), jitter "
            f"{_number(result.jitter_mm, 2)} mm/frame^2, agreement "
            f"{_number(result.agreement_px, 2)} px, look "
            f"{_number(result.appearance_psnr_db, 2)} dB, {result.seconds:.1f} s")


def _speed_line(mode: str, result: SpeedResult) -> str:
    if result.error is not None:
        return f"    {mode}: failed: {result.error}"
    return (f"    {mode:<11}: {result.frames} frames in {result.seconds:.1f} s: "
            f"{_number(result.frames_per_second, 2)} frames/s end to end, detection "
            f"{_number(result.detect_frames_per_second, 2)} frames/s")


def _table(result: VideoBenchmark) -> list[str]:
    rows = []
    if result.clips:
        rows += ["| rendered clip | subject | side | mode | fitted frames | MPJPE mm | PA-MPJPE mm "
                 "| accel. error mm/f^2 | jitter mm/f^2 (truth) | look dB | s |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for clip in result.clips:
            for mode in MODES:
                m = getattr(clip, mode)
                rows.append(f"| {clip.clip} | {clip.subject} | {clip.side} | {mode} | "
                            f"{m.fitted_frames}/{clip.frames} | {_number(m.mpjpe_mm)} | "
                            f"{_number(m.pa_mpjpe_mm)} | {_number(m.acceleration_error_mm, 2)} | "
                            f"{_number(m.jitter_mm, 2)} ({_number(clip.truth_jitter_mm, 2)}) | "
                            f"{_number(m.appearance_psnr_db, 2)} | {_number(m.seconds)} |")
        for mode, prefix in (("tracked", ""), ("independent", "reference_")):
            d = result.to_dict()
            rows.append(f"| mean | | | {mode} | {_number(100 * d[prefix + 'fitted_share'])} % | "
                        f"{_number(d[prefix + 'mpjpe_mm'])} | {_number(d[prefix + 'pa_mpjpe_mm'])}"
                        f" | {_number(d[prefix + 'acceleration_error_mm'], 2)} | "
                        f"{_number(d[prefix + 'jitter_mm'], 2)} "
                        f"({_number(result.truth_jitter_mm, 2)}) | "
                        f"{_number(_clip_mean(result, mode, 'appearance_psnr_db'), 2)} | "
                        f"{_number(_clip_mean(result, mode, 'seconds'))} |")
        rows.append("")
    if result.real:
        rows += ["| real clip | hands | fitted share of detected | jitter mm/f^2 | agreement px "
                 "| look dB | s |",
                 "| --- | --- | --- | --- | --- | --- | --- |"]
        for mode, r in result.real.items():
            rows.append(f"| {mode} | {r.hands} | {_number(100 * r.fitted_share)} % | "
                        f"{_number(r.jitter_mm, 2)} | {_number(r.agreement_px, 3)} | "
                        f"{_number(r.appearance_psnr_db, 2)} | {_number(r.seconds)} |")
        rows.append("")
    if result.speed:
        rows += [f"| speed, {SPEED_SIZE[0]}x{SPEED_SIZE[1]} | frames | s end to end | frames/s | "
                 "detection frames/s |", "| --- | --- | --- | --- | --- |"]
        for mode, r in result.speed.items():
            rows.append(f"| {mode} | {r.frames} | {_number(r.seconds)} | "
                        f"{_number(r.frames_per_second, 2)} | "
                        f"{_number(r.detect_frames_per_second, 2)} |")
        rows.append("")
    return rows


def _target_lines(targets: dict[str, bool | None]) -> list[str]:
    words = {True: "met", False: "NOT met", None: "not measured"}
    labels = {"mpjpe_tracked_le_independent": "MPJPE tracked <= independent (rendered clips)",
              "acceleration_error_tracked_lt_independent":
                  "acceleration error tracked < independent (rendered clips)",
              "real_jitter_tracked_le_third_of_independent":
                  "jitter tracked <= 1/3 of independent (real clip)",
              "real_agreement_no_loss":
                  "no loss of 2D agreement, tracked <= independent (real clip)",
              "speed_tracked_at_least_5_fps": "at least 5 frames/s tracked, end to end (speed)"}
    return [f"target {labels[name]}: {words[value]}" for name, value in targets.items()]


