"""The pictures and the page of a photo fit: ``overlay.png`` (:func:`overlay_image`) and
``report.html`` (:func:`report_html`).

``overlay.png`` holds three panels side by side, each the region of the photo around the hand
(the crop the fit saw, at most :data:`PANEL_MAX_SIDE` pixels a side):

1. the photo;
2. the fitted hand, rendered with the model's colours into the photo's camera, over the photo;
3. the photo dimmed, with the keypoints given to the fit (detected, or ``--keypoints``) in
   :data:`DETECTED_COLOUR` and the fitted hand's projected keypoints in :data:`FITTED_COLOUR`,
   each drawn with the skeleton's bones (:data:`lisa_hand.fitting.photo.mask.HAND_BONES`).

``report.html`` is one self-contained page (the pictures embedded as base64 PNG, no external
file or script): the overlay, the mask, and the numbers of each fitted hand (keypoint error in
the photo's pixels, the geometry guard's figures, the camera and where it came from, timings,
notes).
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .mask import HAND_BONES

__all__ = ["PANEL_MAX_SIDE", "DETECTED_COLOUR", "FITTED_COLOUR", "overlay_image", "png_bytes",
           "report_html"]

PANEL_MAX_SIDE = 480
"""Largest side of a panel of ``overlay.png``, pixels (smaller crops are not enlarged beyond
twice their size)."""
DETECTED_COLOUR = (40, 220, 60)
"""Colour (RGB 0-255) of the given (detected) keypoints and bones in the third panel."""
FITTED_COLOUR = (240, 40, 200)
"""Colour (RGB 0-255) of the fitted hand's projected keypoints and bones in the third panel."""
_GAP = 4  # pixels of white between the panels


def _uint8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _panel_size(width: int, height: int) -> tuple[int, int]:
    factor = min(PANEL_MAX_SIDE / max(width, height), 2.0)
    return max(int(round(width * factor)), 1), max(int(round(height * factor)), 1)


def _draw_skeleton(draw: Any, points: np.ndarray, colour: tuple[int, int, int],
                   line_width: int, radius: float) -> None:
    for start, end in HAND_BONES:
        draw.line([tuple(points[start]), tuple(points[end])], fill=colour, width=line_width)
    for x, y in points:
        draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=colour,
                     outline=(0, 0, 0))


def overlay_image(photo_crop: np.ndarray, render_rgb: np.ndarray, render_alpha: np.ndarray,
                  detected: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """The three panels of ``overlay.png`` (see the module docstring).

    photo_crop: [h, w, 3] float in [0, 1] (or uint8), the region of the photo around the hand.
    render_rgb: [h', w', 3] float in [0, 1], the fitted hand rendered into that region's camera
    over black (colour times opacity; any size: it is resized to the crop's); render_alpha:
    [h', w'] its opacity in [0, 1]. The second panel is ``render_rgb + (1 - alpha) photo``.
    detected, fitted: [21, 2] keypoints in the crop's pixels (continuous coordinates); rows
    that are not finite are not drawn.
    -> [H, 3 W + 2 gaps, 3] uint8.
    """
    from PIL import Image, ImageDraw

    crop = _uint8(photo_crop)
    height, width = crop.shape[:2]
    size = _panel_size(width, height)
    factor = np.array([size[0] / width, size[1] / height])
    photo = Image.fromarray(crop).resize(size, Image.BILINEAR)
    base = np.asarray(photo).astype(np.float32) / 255.0
    rgb = np.asarray(Image.fromarray(_uint8(render_rgb)).resize(size, Image.BILINEAR),
                     dtype=np.float32) / 255.0
    alpha = np.asarray(Image.fromarray(_uint8(render_alpha)).resize(size, Image.BILINEAR),
                       dtype=np.float32)[..., None] / 255.0
    composite = Image.fromarray(_uint8(rgb + base * (1.0 - alpha)))
    dimmed = Image.fromarray(_uint8(0.55 * base))
    draw = ImageDraw.Draw(dimmed)
    line_width = max(int(round(max(size) / 160)), 1)
    radius = max(max(size) / 120, 1.5)
    for points, colour in ((detected, DETECTED_COLOUR), (fitted, FITTED_COLOUR)):
        points = np.asarray(points, dtype=np.float64) * factor
        if np.isfinite(points).all():
            _draw_skeleton(draw, points, colour, line_width, radius)
    draw.text((4, 2), "given", fill=DETECTED_COLOUR)
    draw.text((4, 14), "fitted", fill=FITTED_COLOUR)
    canvas = Image.new("RGB", (3 * size[0] + 2 * _GAP, size[1]), (255, 255, 255))
    for index, panel in enumerate((photo, composite, dimmed)):
        canvas.paste(panel, (index * (size[0] + _GAP), 0))
    return np.asarray(canvas)


def png_bytes(image: np.ndarray) -> bytes:
    """An image ([H, W, 3] or [H, W]; float in [0, 1], bool or uint8) as PNG file bytes."""
    from PIL import Image

    image = np.asarray(image)
    if image.dtype == bool:
        image = image.astype(np.uint8) * 255
    buffer = io.BytesIO()
    Image.fromarray(_uint8(image)).save(buffer, format="PNG")
    return buffer.getvalue()


def _embedded(png: bytes, alt: str, max_width: str = "100%") -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<img alt="{html.escape(alt)}" style="max-width:{max_width}" '
            f'src="data:image/png;base64,{data}">')


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(_shown(item) for item in value)
    return "n/a" if value is None else str(value)


def _table(rows: Mapping[str, Any]) -> str:
    cells = "".join(f"<tr><th>{html.escape(str(key))}</th><td>{html.escape(_shown(value))}"
                    "</td></tr>" for key, value in rows.items())
    return f"<table>{cells}</table>"


_STYLE = ("body{font-family:sans-serif;margin:1.5em;max-width:1500px}"
          "table{border-collapse:collapse;margin:0.5em 0}"
          "th,td{border:1px solid #ccc;padding:2px 8px;text-align:left;vertical-align:top}"
          "th{background:#f3f3f3;font-weight:normal}.notes li{margin:2px 0}"
          ".fail{color:#b00}.pass{color:#070}")


PHOTO_INTRO = ("Panels: the photo | the fitted hand rendered over it | keypoints given to the "
               "fit (green) and of the fitted hand (magenta). Pixels are the photo's own (its "
               "full size, EXIF orientation applied).")
"""The first paragraph of a photo fit's page."""


def report_html(title: str, sections: Sequence[Mapping[str, Any]],
                intro: str = PHOTO_INTRO) -> str:
    """``report.html``: one self-contained page (see the module docstring).

    title: the page's heading. sections: one per fitted hand, each a mapping with
    ``"heading"`` (str), ``"overlay"`` (PNG bytes of ``overlay.png``), ``"pictures"``
    (optional, more PNG bytes shown below it), ``"mask"`` (PNG bytes, optional),
    ``"numbers"`` ({label: value}: numbers, strings, lists), ``"guard"`` (optional {label:
    value} with ``"passed"``), and ``"notes"`` (list of str). intro: the first paragraph.
    -> the page's text (UTF-8).
    """
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>", f"<p>{html.escape(intro)}</p>"]
    for section in sections:
        parts.append(f"<h2>{html.escape(str(section['heading']))}</h2>")
        parts.append(_embedded(section["overlay"], "overlay"))
        for picture in section.get("pictures", ()):
            parts.append(_embedded(picture, "plot"))
        parts.append(_table(section.get("numbers", {})))
        guard = section.get("guard")
        if guard:
            verdict = "pass" if guard.get("passed") else "fail"
            parts.append(f'<h3>Geometry guard: <span class="{verdict}">{verdict}</span></h3>')
            parts.append(_table(guard))
        notes = section.get("notes") or []
        if notes:
            items = "".join(f"<li>{html.escape(str(note))}</li>" for note in notes)
            parts.append(f'<h3>Notes</h3><ul class="notes">{items}</ul>')
        if section.get("mask") is not None:
            parts.append("<h3>Mask</h3>" + _embedded(section["mask"], "mask", "480px"))
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
