"""Photographs in: :func:`read_photo` (any photo Pillow reads, made upright, RGB, float, at most
``max_side`` pixels), :func:`photo_camera` (the pinhole camera of an uncalibrated photo) and
:func:`save_camera` (``camera.json``).

**Reading.** The EXIF orientation is applied before anything else
(``PIL.ImageOps.exif_transpose``), so every size, keypoint and camera refers to the upright photo
as a viewer shows it. Then the colours become float32 RGB in [0, 1], and each conversion leaves a
line in :attr:`Photo.notes`:

* CMYK (print JPEGs): Pillow's conversion to RGB, no colour profile applied;
* 16-bit PNG: greyscale keeps its 16 bits (divided by 65535); Pillow reads 16-bit RGB(A) at 8
  bits per channel (the high byte), which is far finer than anything the fit resolves;
* an alpha channel (RGBA, LA, palette transparency) is **dropped**: the stored colours are kept as
  they are, also under transparent pixels. A cut-out photo keeps the background it was saved
  with (often black); compositing over white would change what the photo looks like. The note
  gives the transparent fraction;
* greyscale (L, 1-bit, 16-bit) is replicated to three channels;
* a photo larger than ``max_side`` along its long side is downscaled (Lanczos; large JPEGs are
  first decoded at 1/2, 1/4 or 1/8 scale, never below the target size). :attr:`Photo.scale` and
  :attr:`Photo.original_size` keep the way back to original pixels for reports.

Bad input raises one line naming the file: ``FileNotFoundError`` (missing), ``IsADirectoryError``
(a folder), ``ValueError`` (not an image, truncated or corrupt, too many pixels to decode safely).

**Cameras.** :func:`photo_camera` picks, in this order: a calibrated ``cameras.json``-convention
file (``--camera``), a focal length in original pixels (``--focal-px``), a field of view
(``--fov``), the EXIF 35 mm equivalent focal length, and :data:`DEFAULT_FOV_DEG`. The principal
point is the image centre (``(W / 2, H / 2)``, continuous pixel coordinates of
:mod:`lisa_hand.geometry.cameras`), pixels are square, and the camera frame is the world frame
(``R = I``, ``t = 0``).

A 35 mm equivalent focal length ``f35`` refers to a 36 x 24 mm frame, whose diagonal is
:data:`FILM_DIAGONAL_MM` = 43.27 mm. It is converted along the diagonal, the usual definition
(crop factor = 43.27 mm / sensor diagonal, as in CIPA DC-008 practice and ExifTool's "ScaleFactor
35efl"), which does not depend on the photo's aspect ratio or orientation::

    f_px = f35 * hypot(W, H) / 43.27          (W, H the photo's size in pixels)

For a 3:2 photo it equals the width-based ``f35 / 36 * W``; for a 4:3 phone photo the width-based
formula would give a focal length 4% shorter. A field of view (``--fov`` and the default) is
measured along the photo's **long** side (the horizontal of a landscape photo), so a portrait
photo from the same camera gets the same focal length: ``f_px = (L / 2) / tan(fov / 2)``, ``L`` the
long side in pixels.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..geometry.cameras import FOCAL_RANGE, Camera
from ..utils.io import read_json, require_file, write_json

__all__ = [
    "DEFAULT_MAX_SIDE",
    "DEFAULT_FOCAL_35MM",
    "DEFAULT_FOV_DEG",
    "FILM_DIAGONAL_MM",
    "CAMERA_SOURCES",
    "Photo",
    "read_photo",
    "exif_focal_35mm",
    "photo_camera",
    "save_camera",
]

DEFAULT_MAX_SIDE = 1600
"""Long side, in pixels, that photos are downscaled to (at most) for detection and fitting."""

FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
"""Diagonal of the 36 x 24 mm frame that 35 mm equivalent focal lengths refer to (43.27 mm)."""

DEFAULT_FOCAL_35MM = 26.0
"""A phone's main camera, 35 mm equivalent (iPhone 11-15 main cameras: 26 mm; Pixel and Galaxy
main cameras: 24-27 mm)."""

DEFAULT_FOV_DEG = 67.0
"""Field of view along the long side when nothing is known about the camera, degrees: a 26 mm
equivalent lens (:data:`DEFAULT_FOCAL_35MM`) on a 4:3 frame, whose long side is 4/5 of the
43.27 mm diagonal, sees ``2 atan(0.4 * 43.27 / 26) = 67.3`` degrees along it (69.4 on a 3:2
frame). Rounded to 67; a wrong guess scales the hand's distance, not its pose."""

CAMERA_SOURCES = ("calibrated", "focal-px", "fov", "exif", "default")
"""Where :func:`photo_camera`'s camera came from, in the order of priority."""

# EXIF tags (CIPA DC-008): the Exif sub-IFD and the ones read from it.
_EXIF_IFD = 0x8769
_TAG_ORIENTATION = 0x0112
_TAG_FOCAL_LENGTH = 37386
_TAG_FOCAL_35MM = 41989
_TAG_PLANE_X_RES = 41486
_TAG_PLANE_Y_RES = 41487
_TAG_PLANE_UNIT = 41488
_TAG_PIXEL_X = 40962
_TAG_PIXEL_Y = 40963
# FocalPlaneResolutionUnit -> millimetres (2 = inch is the standard's default; 1 = "no unit").
_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
# A 35 mm equivalent outside this range (mm) is a broken tag, not a lens.
_FOCAL_35MM_RANGE = (5.0, 2000.0)
_ORIENTATION_WORDS = {2: "mirrored", 3: "rotated 180 degrees", 4: "flipped upside down",
                      5: "transposed", 6: "rotated 90 degrees clockwise", 7: "transversed",
                      8: "rotated 90 degrees counter-clockwise"}
_GREY_16BIT_MODES = ("I;16", "I;16B", "I;16L", "I;16N")
# ISO base media "ftyp" brands of HEIF images (HEIC from phones) and AVIF.
_HEIF_BRANDS = (b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1", b"avif")
# Calibrated image size and photo size must agree in aspect ratio to this relative tolerance.
_ASPECT_TOL = 0.01


@dataclass(frozen=True)
class Photo:
    """One photograph, upright and ready for detection and fitting (see the module docstring)."""

    path: Path
    """The file it was read from."""
    image: np.ndarray
    """[H, W, 3] float32 RGB in [0, 1]: EXIF orientation applied, ``max(H, W) <= max_side``."""
    original_size: tuple[int, int]
    """(W, H) pixels of the upright full-size photo."""
    scale: float
    """Image pixels per original pixel (<= 1; the two axes agree to within half a pixel)."""
    focal_35mm: float | None
    """35 mm equivalent focal length from EXIF, mm (FocalLengthIn35mmFilm, or FocalLength and
    the sensor size from FocalPlaneX/YResolution), or None."""
    notes: tuple[str, ...] = ()
    """What was converted: orientation, CMYK, 16-bit, alpha, greyscale, downscaled."""

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) pixels of :attr:`image`."""
        return int(self.image.shape[1]), int(self.image.shape[0])


def read_photo(path: str | os.PathLike, max_side: int = DEFAULT_MAX_SIDE) -> Photo:
    """Read a photo (JPEG, PNG, or anything else Pillow opens) as a :class:`Photo`.

    The EXIF orientation is applied first, then the colour conversions of the module docstring,
    then a downscale so that ``max(H, W) <= max_side``. Errors are one line naming the file.
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    if isinstance(max_side, bool) or not isinstance(max_side, int) or max_side < 16:
        raise ValueError(f"max_side must be an integer >= 16 (pixels), got {max_side!r}")
    path = require_file(path)
    try:
        pil = Image.open(path)
    except UnidentifiedImageError:
        raise ValueError(_unreadable_message(path)) from None
    except Image.DecompressionBombError as exc:
        raise ValueError(f"{path}: too many pixels to decode safely ({exc})") from None
    except (OSError, SyntaxError, ValueError) as exc:  # e.g. a JPEG cut inside its header
        raise ValueError(f"{path}: truncated or corrupt image file ({exc})") from None
    with pil:
        notes: list[str] = []
        stored_w, stored_h = pil.size
        is_16bit = (pil.mode in _GREY_16BIT_MODES
                    or any(";16" in str(tile.args) for tile in pil.tile))
        scale = min(1.0, max_side / max(stored_w, stored_h))
        if scale < 1.0 and pil.format == "JPEG":
            # Decode at 1/2, 1/4 or 1/8 when that stays at least as large as the target.
            pil.draft(None, (math.ceil(stored_w * scale), math.ceil(stored_h * scale)))
        try:
            pil.load()
        except (OSError, SyntaxError, ValueError) as exc:
            raise ValueError(f"{path}: truncated or corrupt image file ({exc})") from None
        orientation, focal_35mm = _read_exif(pil, (stored_w, stored_h), notes)
        swapped = orientation in (5, 6, 7, 8)
        original = (stored_h, stored_w) if swapped else (stored_w, stored_h)
        if orientation in _ORIENTATION_WORDS:
            pil = ImageOps.exif_transpose(pil)
            notes.append(f"EXIF orientation {orientation} applied "
                         f"({_ORIENTATION_WORDS[orientation]})")
        image = _to_float_rgb(pil, is_16bit, notes)
    if scale < 1.0:
        size = (max(1, round(original[0] * scale)), max(1, round(original[1] * scale)))
        image = _resize(image, size)
        notes.append(f"downscaled from {original[0]}x{original[1]} to {size[0]}x{size[1]} "
                     f"(scale {scale:.4g}); reports are in original pixels")
    return Photo(path=path, image=np.ascontiguousarray(image, dtype=np.float32),
                 original_size=(int(original[0]), int(original[1])), scale=float(scale),
                 focal_35mm=focal_35mm, notes=tuple(notes))


def _unreadable_message(path: Path) -> str:
    """Why Pillow cannot open ``path``: an HEIF container (iPhone photos) or not an image."""
    with open(path, "rb") as stream:
        head = stream.read(12)
    if head[4:8] == b"ftyp" and head[8:12] in _HEIF_BRANDS:
        return (f"{path}: an HEIC/HEIF photo ({head[8:12].decode()}), which Pillow cannot read; "
                "export it as JPEG or PNG (on an iPhone: Settings > Camera > Formats > Most "
                "Compatible)")
    return f"{path}: not an image file (Pillow cannot read it as JPEG, PNG or any other format)"


def _read_exif(pil: Any, stored_size: tuple[int, int],
               notes: list[str]) -> tuple[int, float | None]:
    """(EXIF orientation, 1 when absent; 35 mm equivalent focal length or None) of a loaded
    image whose stored (W, H) before any draft decoding is ``stored_size``."""
    try:
        exif = pil.getexif()
        orientation = int(exif.get(_TAG_ORIENTATION, 1) or 1)
        sub_ifd = dict(exif.get_ifd(_EXIF_IFD))
    except Exception as exc:  # noqa: BLE001 - a broken EXIF block must not lose the photo
        notes.append(f"EXIF unreadable, ignored ({type(exc).__name__})")
        return 1, None
    focal = exif_focal_35mm(sub_ifd, stored_size)
    if focal is None and (_TAG_FOCAL_35MM in sub_ifd or _TAG_FOCAL_LENGTH in sub_ifd):
        notes.append("EXIF focal length present but unusable (no 35 mm equivalent and no "
                     "sensor size), ignored")
    return orientation, focal


def _positive(value: Any) -> float | None:
    """A finite positive float from an EXIF value (int, IFDRational, tuple), else None."""
    try:
        number = float(value[0]) / float(value[1]) if isinstance(value, tuple) else float(value)
    except (TypeError, ValueError, ZeroDivisionError, IndexError):
        return None
    return number if math.isfinite(number) and number > 0 else None


def exif_focal_35mm(exif_ifd: Mapping[int, Any], stored_size: tuple[int, int]) -> float | None:
    """The 35 mm equivalent focal length (mm) of a photo's Exif sub-IFD, or None.

    exif_ifd: tag -> value of the Exif sub-IFD (0x8769); stored_size: (W, H) pixels of the image
    as stored (before the EXIF orientation: the sensor's axes).

    FocalLengthIn35mmFilm (41989) when present; else FocalLength (37386) times
    ``43.27 mm / sensor diagonal``, the sensor measured from FocalPlaneXResolution (41486) and
    FocalPlaneYResolution (41487, default: the X one) in FocalPlaneResolutionUnit (41488, default
    inch) over PixelXDimension / PixelYDimension (40962, 40963; default ``stored_size``); else
    None. Values outside 5-2000 mm are treated as broken tags (None).
    """
    low, high = _FOCAL_35MM_RANGE
    focal_35mm = _positive(exif_ifd.get(_TAG_FOCAL_35MM))
    if focal_35mm is not None and low <= focal_35mm <= high:
        return focal_35mm
    focal_mm = _positive(exif_ifd.get(_TAG_FOCAL_LENGTH))
    res_x = _positive(exif_ifd.get(_TAG_PLANE_X_RES))
    unit_mm = _PLANE_UNIT_MM.get(int(_positive(exif_ifd.get(_TAG_PLANE_UNIT)) or 2))
    if focal_mm is None or res_x is None or unit_mm is None:
        return None
    res_y = _positive(exif_ifd.get(_TAG_PLANE_Y_RES)) or res_x
    width_px = _positive(exif_ifd.get(_TAG_PIXEL_X)) or float(stored_size[0])
    height_px = _positive(exif_ifd.get(_TAG_PIXEL_Y)) or float(stored_size[1])
    sensor_diagonal_mm = math.hypot(width_px / res_x * unit_mm, height_px / res_y * unit_mm)
    focal_35mm = focal_mm * FILM_DIAGONAL_MM / sensor_diagonal_mm
    return focal_35mm if low <= focal_35mm <= high else None


def _to_float_rgb(pil: Any, is_16bit: bool, notes: list[str]) -> np.ndarray:
    """A loaded Pillow image -> [H, W, 3] float32 in [0, 1]; conversions noted."""
    mode = pil.mode
    if mode == "P":
        pil = pil.convert("RGBA" if "transparency" in pil.info else "RGB")
        mode = pil.mode
    if mode in ("RGBA", "RGBa", "LA", "La", "PA"):
        alpha = np.asarray(pil.getchannel("A"))
        transparent = float(np.mean(alpha < 255))
        notes.append(f"alpha channel dropped ({transparent:.0%} of the pixels not opaque; their "
                     "stored colour kept)")
        pil = pil.convert("RGB" if mode in ("RGBA", "RGBa", "PA") else "L")
        mode = pil.mode
    if mode == "CMYK":
        notes.append("CMYK converted to RGB (no colour profile applied)")
    if mode in ("1", "L") or mode.startswith("I") or mode == "F":
        grey = _grey(pil, mode, is_16bit, notes)
        notes.append("greyscale: replicated to RGB")
        return np.repeat(grey[..., None], 3, axis=-1)
    if mode != "RGB":
        pil = pil.convert("RGB")
    if is_16bit:
        notes.append("16-bit PNG read at 8 bits per channel, scaled to [0, 1]")
    return np.asarray(pil, dtype=np.float32) / 255.0


def _grey(pil: Any, mode: str, is_16bit: bool, notes: list[str]) -> np.ndarray:
    """One greyscale channel [H, W] float32 in [0, 1] (8, 16, 32-bit integer or float)."""
    if mode in ("1", "L"):
        return np.asarray(pil.convert("L"), dtype=np.float32) / 255.0
    values = np.asarray(pil, dtype=np.float32)
    if mode == "F":
        notes.append("floating-point image clipped to [0, 1]")
        return np.clip(values, 0.0, 1.0)
    if is_16bit or mode != "I" or float(values.max(initial=0.0)) > 255.0:
        notes.append("16-bit greyscale scaled to [0, 1] (divided by 65535)")
        return np.clip(values / 65535.0, 0.0, 1.0)
    return np.clip(values / 255.0, 0.0, 1.0)


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[H, W, 3] float32 -> [size[1], size[0], 3] float32, Lanczos, per channel (Pillow "F")."""
    from PIL import Image

    channels = [np.asarray(Image.fromarray(np.ascontiguousarray(image[..., c])).resize(
        size, Image.Resampling.LANCZOS, reducing_gap=3.0)) for c in range(image.shape[-1])]
    return np.clip(np.stack(channels, axis=-1), 0.0, 1.0)


def _focal_from_fov(fov_deg: float, long_side_px: int) -> float:
    return 0.5 * long_side_px / math.tan(math.radians(fov_deg) / 2.0)


def photo_camera(photo: Photo, camera_json: str | os.PathLike | None = None,
                 focal_px: float | None = None,
                 fov_deg: float | None = None) -> tuple[Camera, str]:
    """The pinhole camera of ``photo`` at the size of ``photo.image``, and where it came from.

    camera_json: a ``cameras.json``-convention file (a list of ``{name, K, width, height}``, ``R``
    and ``t`` optional and not used, or one such object), calibrated for the upright photo at
    any size of the same aspect ratio; with several cameras, the one named like the photo's
    stem, or the original-size one of a ``camera.json`` written by :func:`save_camera`. ``K``
    is rescaled to ``photo.image``'s size. focal_px: focal length in ORIGINAL pixels. fov_deg:
    field of view along the long side, degrees. The first one given wins, then the EXIF 35 mm
    equivalent, then :data:`DEFAULT_FOV_DEG` (see the module docstring).

    -> (camera: ``R = I``, ``t = 0`` (world = camera frame), named after the photo's stem;
    source: one of :data:`CAMERA_SOURCES`)
    """
    width, height = photo.size
    orig_w, orig_h = photo.original_size
    scale_x, scale_y = width / orig_w, height / orig_h
    if camera_json is not None:
        K, source = _calibrated_K(Path(camera_json), photo), "calibrated"
    else:
        if focal_px is not None:
            focal, source = _check_positive(focal_px, "focal_px (pixels)"), "focal-px"
            low, high = (bound * max(orig_w, orig_h) for bound in FOCAL_RANGE)
            if not low <= focal <= high:
                raise ValueError(f"focal_px {focal:g} is implausible for the "
                                 f"{orig_w}x{orig_h} photo {photo.path.name} (expected {low:g} "
                                 f"to {high:g} px)")
        elif fov_deg is not None:
            fov = _check_positive(fov_deg, "fov_deg (degrees)")
            if not fov < 180.0:
                raise ValueError(f"fov_deg must be in (0, 180) degrees, got {fov_deg}")
            focal, source = _focal_from_fov(fov, max(orig_w, orig_h)), "fov"
        elif photo.focal_35mm is not None:
            focal = photo.focal_35mm * math.hypot(orig_w, orig_h) / FILM_DIAGONAL_MM
            source = "exif"
        else:
            focal, source = _focal_from_fov(DEFAULT_FOV_DEG, max(orig_w, orig_h)), "default"
        K = torch.tensor([[focal * scale_x, 0.0, 0.5 * width],
                          [0.0, focal * scale_y, 0.5 * height],
                          [0.0, 0.0, 1.0]], dtype=torch.float64)
    camera = Camera(K=K.float(), R=torch.eye(3), t=torch.zeros(3), width=width, height=height,
                    name=photo.path.stem)
    return camera, source


def _check_positive(value: Any, name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return number


def _pick_camera_entry(path: Path, data: Any, stem: str) -> tuple[Mapping[str, Any], str]:
    """The camera object of a calibration file for the photo ``stem``, and its label."""
    if isinstance(data, Mapping):
        return data, f"{path}"
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a camera object or a non-empty JSON list of cameras "
                         "({name, K, width, height}), as in cameras.json")
    if len(data) == 1:
        return data[0], f"{path}: camera 0"
    named = [i for i, entry in enumerate(data)
             if isinstance(entry, Mapping) and entry.get("name") == stem]
    if named:
        return data[named[0]], f"{path}: camera {named[0]}"
    if all(isinstance(entry, Mapping) and "image" in entry for entry in data):
        # A camera.json of save_camera: the original size is the more precise one.
        index = next((i for i, entry in enumerate(data) if entry["image"] == "original"), 0)
        return data[index], f"{path}: camera {index}"
    names = [entry.get("name") if isinstance(entry, Mapping) else None for entry in data]
    raise ValueError(f"{path}: {len(data)} cameras and none named {stem!r} (the photo's name); "
                     f"cameras: {', '.join(map(str, names))}")


def _calibrated_K(path: Path, photo: Photo) -> torch.Tensor:
    """K [3, 3] float64 of a calibration file, rescaled to ``photo.image``'s size."""
    entry, label = _pick_camera_entry(path, read_json(path), photo.path.stem)
    if not isinstance(entry, Mapping):
        raise ValueError(f"{label}: a camera must be a JSON object, got {type(entry).__name__}")
    filled = {"R": np.eye(3).tolist(), "t": [0.0, 0.0, 0.0], **entry}
    calibrated = Camera.from_dict(filled, source=label, dtype=torch.float64)
    orig_w, orig_h = photo.original_size
    cal_w, cal_h = calibrated.width, calibrated.height
    if abs((cal_w / cal_h) / (orig_w / orig_h) - 1.0) > _ASPECT_TOL:
        hint = (" (rotated: calibrate for the upright photo, EXIF orientation applied)"
                if abs((cal_h / cal_w) / (orig_w / orig_h) - 1.0) <= _ASPECT_TOL else "")
        raise ValueError(f"{label}: calibrated for {cal_w}x{cal_h} images but {photo.path.name} "
                         f"is {orig_w}x{orig_h}{hint}")
    width, height = photo.size
    rescale = torch.diag(torch.tensor([width / cal_w, height / cal_h, 1.0], dtype=torch.float64))
    return rescale @ calibrated.K


def save_camera(path: str | os.PathLike, camera: Camera, source: str,
                original_size: tuple[int, int] | None = None) -> Path:
    """Write the camera used for a photo as ``camera.json``; return the file's path.

    path: the file (``*.json``) or a folder (then ``path/camera.json``). camera: at the size of
    the fitted (possibly downscaled) image, as :func:`photo_camera` returns it. source: one of
    :data:`CAMERA_SOURCES`. original_size: (W, H) of the original photo (default: the camera's
    size).

    The file follows the ``cameras.json`` convention, a JSON list of ``{name, K, R, t, width,
    height}``, with two entries told apart by ``"image"``: ``"fitted"`` (the camera at the size
    the fit used) and ``"original"`` (the same camera at the original photo's size, ``K``
    rescaled); both carry ``"source"``. ``--camera`` reads it back.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    if source not in CAMERA_SOURCES:
        raise ValueError(f"source must be one of {', '.join(CAMERA_SOURCES)}, got {source!r}")
    orig_w, orig_h = original_size if original_size is not None else (camera.width, camera.height)
    for name, value in (("original_size[0]", orig_w), ("original_size[1]", orig_h)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{name} must be a positive integer (pixels), got {value!r}")
    path = Path(path)
    if path.suffix.lower() != ".json":
        path = path / "camera.json"
    rescale = torch.diag(torch.tensor([orig_w / camera.width, orig_h / camera.height, 1.0],
                                      dtype=torch.float64))
    original = Camera(K=rescale @ camera.K.double().cpu(), R=camera.R.double().cpu(),
                      t=camera.t.double().cpu(), width=orig_w, height=orig_h, name=camera.name)
    entries = [
        {**camera.to_dict(), "image": "fitted", "source": source,
         "note": "the camera at the size of the image the fit used"},
        {**original.to_dict(), "image": "original", "source": source,
         "note": "the same camera at the size of the original photo"},
    ]
    return write_json(path, entries)
