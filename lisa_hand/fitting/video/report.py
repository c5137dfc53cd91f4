"""The numbers and the page of a video fit: ``metrics.json`` (:func:`video_metrics`) and
``report.html`` (:func:`video_report_html`): per hand a strip of frames with the fitted hand
rendered over them and the detected (green) and fitted (magenta) keypoints, the trajectories
of the wrist and the index fingertip in the image (detected as dots, fitted as lines), the
jitter along the clip (:mod:`lisa_hand.fitting.video.quality`), and the hand's numbers."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .quality import agreement_px, jitter_mm, nan_mean

__all__ = ["video_metrics", "line_plot", "report_rows", "video_report_html"]

_PLOT_SIZE = (720, 240)
_SERIES_COLOURS = ((31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189))


def _hand_metrics(fit: Any, hand: Any) -> dict[str, Any]:
    fitted = np.isfinite(hand.motion.pose).all(-1)
    agreement = agreement_px(hand.keypoints_2d, hand.track.keypoints / fit.scale,
                             hand.track.detected & fitted)
    return {"identity": hand.track.identity, "side": hand.side,
            "side_source": hand.side_source,
            "frames_fitted": int(fitted.sum()), "frames_detected": int(hand.track.detected.sum()),
            "frames_bridged": int(hand.track.bridged.sum()),
            "keyframe": {"index": int(fit.indices[hand.keyframe_row]),
                         "time_s": float(fit.times[hand.keyframe_row])},
            "keyframes": [int(fit.indices[row]) for row in sorted(hand.keyframe.rows)],
            "jitter_mm_per_frame2": nan_mean(jitter_mm(hand.motion.keypoints_3d)),
            "agreement_px": nan_mean(agreement),
            "keyframe_keypoint_error_px": float(
                hand.keyframe.result.keypoint_error_px.get("color", float("nan"))),
            "motion_seconds": hand.motion.seconds, "motion_iterations": hand.motion.iterations}


def video_metrics(fit: Any, seconds: float) -> dict[str, Any]:
    """``metrics.json``: the clip, the camera, each hand's figures (frames fitted, detected,
    bridged; jitter mm/frame^2; agreement with the detector, pixels of the clip), timings,
    frames a second (``seconds``: reading, detection and fit, before the files), the notes."""
    info = fit.video.info
    count = len(fit.indices)
    return {"video": str(info.path), "frames": count, "fps": info.fps,
            "size": [info.width, info.height], "processed_size": list(info.size),
            "independent": fit.independent, "camera_source": fit.camera_source,
            "focal_px": float(fit.camera.K[0, 0]) / fit.scale,
            "hands": [_hand_metrics(fit, hand) for hand in fit.hands],
            "seconds": seconds, "frames_per_second": count / max(seconds, 1e-9),
            **{key: value for key, value in fit.timings.items()}, "notes": list(fit.notes)}


def line_plot(series: Sequence[tuple[str, np.ndarray, np.ndarray, bool]], title: str,
              size: tuple[int, int] = _PLOT_SIZE) -> np.ndarray:
    """A small line chart: series of (label, x [N], y [N], dots: drawn as dots instead of a
    line; NaN values leave gaps) -> [H, W, 3] uint8."""
    from PIL import Image, ImageDraw

    width, height = size
    image = Image.new("RGB", size, (255, 255, 255))
    draw = ImageDraw.Draw(image)
    left, top, right, bottom = 48, 20, width - 10, height - 22
    xs = np.concatenate([np.asarray(x, float) for _, x, _, _ in series]) if series else []
    ys = np.concatenate([np.asarray(y, float) for _, _, y, _ in series]) if series else []
    finite = np.isfinite(xs) & np.isfinite(ys) if len(xs) else np.zeros(0, bool)
    draw.text((left, 4), title, fill=(0, 0, 0))
    draw.rectangle([left, top, right, bottom], outline=(160, 160, 160))
    if not finite.any():
        return np.asarray(image)
    x_low, x_high = float(xs[finite].min()), float(xs[finite].max())
    y_low, y_high = float(ys[finite].min()), float(ys[finite].max())
    x_span, y_span = max(x_high - x_low, 1e-9), max(y_high - y_low, 1e-9)

    def to_pixel(x: float, y: float) -> tuple[float, float]:
        return (left + (x - x_low) / x_span * (right - left),
                bottom - (y - y_low) / y_span * (bottom - top))

    for value, row in ((y_high, top), (y_low, bottom)):
        draw.text((2, row - 6), f"{value:.3g}", fill=(80, 80, 80))
    draw.text((left, bottom + 4), f"{x_low:.2f}", fill=(80, 80, 80))
    draw.text((right - 40, bottom + 4), f"{x_high:.2f} s", fill=(80, 80, 80))
    for number, (label, x, y, dots) in enumerate(series):
        colour = _SERIES_COLOURS[number % len(_SERIES_COLOURS)]
        points = [to_pixel(a, b) if np.isfinite(a) and np.isfinite(b) else None
                  for a, b in zip(np.asarray(x, float), np.asarray(y, float), strict=True)]
        for first, second in zip(points[:-1], points[1:], strict=True):
            if not dots and first is not None and second is not None:
                draw.line([first, second], fill=colour, width=2)
        for point in points:
            if dots and point is not None:
                draw.ellipse([point[0] - 1.5, point[1] - 1.5, point[0] + 1.5, point[1] + 1.5],
                             fill=colour)
        draw.text((right - 200, top + 4 + 12 * number), label, fill=colour)
    return np.asarray(image)


def report_rows(hand: Any, count: int) -> list[int]:
    """The rows of the frames the report shows for ``hand``: ``count`` spread over those where
    it is fitted."""
    fitted = np.flatnonzero(np.isfinite(hand.motion.pose).all(-1))
    if not len(fitted):
        return []
    picks = np.linspace(0, len(fitted) - 1, min(count, len(fitted))).round().astype(int)
    return sorted(set(fitted[picks].tolist()))


def _strip(fit: Any, hand: Any, rows: list[int], frame: Callable[[int], np.ndarray]
           ) -> np.ndarray:
    """The frames of ``rows`` with the fitted hands over them (``frame(row)``) and this hand's
    keypoints drawn, side by side."""
    from PIL import Image, ImageDraw

    from ..photo.report import DETECTED_COLOUR, FITTED_COLOUR, _draw_skeleton

    panels = []
    for row in rows:
        shown = Image.fromarray(frame(row))
        draw = ImageDraw.Draw(shown)
        if hand.track.detected[row]:
            _draw_skeleton(draw, hand.track.keypoints[row], DETECTED_COLOUR, 1, 1.5)
        _draw_skeleton(draw, hand.keypoints_2d[row] * fit.scale, FITTED_COLOUR, 1, 1.5)
        draw.text((4, 4), f"{fit.times[row]:.2f} s", fill=(255, 255, 255))
        panels.append(shown)
    scale = min(1.0, 360.0 / max(panels[0].size))
    panels = [panel.resize((int(panel.width * scale), int(panel.height * scale)))
              for panel in panels]
    canvas = Image.new("RGB", (sum(p.width + 4 for p in panels), panels[0].height),
                       (255, 255, 255))
    for number, panel in enumerate(panels):
        canvas.paste(panel, (number * (panel.width + 4), 0))
    return np.asarray(canvas)


def video_report_html(fit: Any, metrics: dict[str, Any], config: Any,
                      frame: Callable[[int], np.ndarray]) -> str:
    """``report.html``: one section per hand (module docstring), the notes in the first.
    frame: row -> that frame of the overlay ([H, W, 3] uint8, the fitted hands over it)."""
    from ..photo.report import png_bytes, report_html

    times = fit.times
    sections = []
    for hand, numbers in zip(fit.hands, metrics["hands"], strict=True):
        detected = np.where(hand.track.detected[:, None, None], hand.track.keypoints / fit.scale,
                            np.nan)
        trajectories = line_plot(
            [("wrist u (detected)", times, detected[:, 0, 0], True),
             ("wrist u (fitted)", times, hand.keypoints_2d[:, 0, 0], False),
             ("index tip v (detected)", times, detected[:, 8, 1], True),
             ("index tip v (fitted)", times, hand.keypoints_2d[:, 8, 1], False)],
            "keypoints in the image, pixels")
        jitter = jitter_mm(hand.motion.keypoints_3d)
        jitter_plot = line_plot([("jitter", times[1:-1], jitter, False)],
                                "jitter: second difference of the wrist-relative 3D "
                                "keypoints, mm/frame^2")
        rows = {"side": f"{hand.side} ({hand.side_source})",
                "frames fitted / detected / bridged":
                    f"{numbers['frames_fitted']} / {numbers['frames_detected']} / "
                    f"{numbers['frames_bridged']} of {len(times)}",
                "keyframes (shape and colour)": "frames " + ", ".join(
                    str(index) for index in numbers["keyframes"])
                    + f"; skeleton from frame {numbers['keyframe']['index']} "
                      f"({numbers['keyframe']['time_s']:.2f} s), the best seen",
                "jitter (mm/frame^2)": numbers["jitter_mm_per_frame2"],
                "agreement with the detector (px)": numbers["agreement_px"],
                "camera": f"{fit.camera_source}, focal length {metrics['focal_px']:.0f} px",
                "seconds (all hands) / frames a second":
                    f"{metrics['seconds']:.1f} / {metrics['frames_per_second']:.2f}"}
        sections.append({"heading": f"hand {hand.track.identity}: {hand.side}",
                         "overlay": png_bytes(_strip(fit, hand, report_rows(
                             hand, config.report_frames), frame)),
                         "pictures": [png_bytes(trajectories), png_bytes(jitter_plot)],
                         "numbers": rows, "notes": list(fit.notes) if not sections else []})
    intro = ("Frames of the clip with the fitted hand rendered over them, the detected "
             "keypoints (green) and the fitted hand's (magenta); the keypoints' paths in the "
             "image; the jitter along the clip. Pixels are the clip's own.")
    return report_html(f"lisa fit-video: {fit.video.info.path.name}", sections, intro=intro)
