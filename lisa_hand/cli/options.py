"""Option types, declarations and parsing helpers shared by several ``lisa`` verbs."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from ..geometry.cameras import Camera


class Units(str, Enum):
    """Length unit of input files: metres, centimetres, millimetres, or guessed from their size
    (:func:`lisa_hand.data.units.decide_length_unit`)."""

    auto = "auto"
    m = "m"
    cm = "cm"
    mm = "mm"


class Side(str, Enum):
    """Which hand the input shows (``--side`` of the fit verbs)."""

    right = "right"
    left = "left"


class AutoSide(str, Enum):
    """``--side`` of ``lisa fit-photo`` and ``lisa fit-points``: given, or ``auto`` (found from
    the input: the detector's side, or both fitted and the better one kept)."""

    auto = "auto"
    right = "right"
    left = "left"


class ShapeFit(str, Enum):
    """How the image fits treat the shape code in the colour stage
    (:attr:`lisa_hand.fitting.images.config.FitImagesConfig.shape_fit`)."""

    space = "space"
    free = "free"
    fixed = "fixed"


ShapeFitOpt = Annotated[ShapeFit, typer.Option(
    "--shape-fit", help="Colour stage: the shape code kept in the learned shape space (space, "
                        "the default), every dimension free (free: the paper; on real photos "
                        "it broke the surface into lumps and floaters), or not fitted (fixed).")]
GuardOpt = Annotated[bool, typer.Option(
    "--guard/--no-guard", help="Check the surface after the colour stage (one piece, area "
                               "within 10% of its start) and undo what breaks it.")]

ViewCalibrationOpt = Annotated[bool, typer.Option(
    "--view-calibration/--no-view-calibration",
    help="With 2+ views: fit each view's colour response (gain and bias, a Gaussian prior) "
         "beside the colour code, so that the cameras' colour casts do not go into the hand's "
         "colour.")]

ThreadsOpt = Annotated[int, typer.Option(
    "--threads", min=0, help="CPU threads of torch during the fit (0: torch's default; 1 is "
                             "fastest on a busy machine).")]


def image_fit_overrides(*, seed: int, threads: int, shape_fit: ShapeFit, guard: bool,
                        keypoint_iters: int | None, color_iters: int | None,
                        rays: int | None, view_calibration: bool = True) -> dict:
    """The :class:`lisa_hand.fitting.images.config.FitImagesConfig` fields that the image-fit
    verbs' options set (``lisa fit-images``, ``lisa fit-photo``); options left out (None) keep
    the verb's defaults."""
    overrides: dict = {"seed": seed, "num_threads": threads if threads > 0 else None,
                       "shape_fit": shape_fit.value, "guard": guard,
                       "view_calibration": view_calibration}
    for key, value in (("keypoint_iters", keypoint_iters), ("color_iters", color_iters),
                       ("num_rays", rays)):
        if value is not None:
            overrides[key] = value
    return overrides


def set_option(config: str, examples: str):
    """The repeatable ``--set KEY=VALUE`` option of a fit verb, whose config is ``config`` (a
    class name) and whose help shows ``examples`` (read by :func:`with_settings`)."""
    return Annotated[list[str] | None, typer.Option(
        "--set", metavar="KEY=VALUE",
        help=f"Set any field of {config}, e.g. {examples} (repeatable; applied after the other "
             "options; keys as in params.json's extra.config, nested ones with dots). A bad "
             "key or value is an error naming it.")]


def with_settings(config, settings: list[str] | None):
    """``config`` with the ``--set KEY=VALUE`` settings applied
    (:func:`lisa_hand.utils.config.apply_overrides`: a bad key or value is a ValueError naming
    it, which the command prints in one line)."""
    from ..utils.config import apply_overrides

    return apply_overrides(config, list(settings or []))


FitModelOpt = Annotated[Path | None, typer.Option(
    "--model", help="Trained model: exported file, run folder or checkpoint, or a shipped "
                    "model's name: 'default' (LISA-full, hand model v1), 'geometry' (its "
                    "geometric prior) or 'geometry_v3' (the geometric prior of hand models "
                    "v1-v3); no colour without LISA-full (default: 'default').")]

PointModelOpt = Annotated[Path | None, typer.Option(
    "--model", help="Trained model: exported file, run folder or checkpoint, or a shipped "
                    "model's name (default: 'geometry_v3', the shipped geometric prior of hand "
                    "models v1-v3, no colour; 'geometry' is the v1 prior; 'default' is "
                    "LISA-full, whose mean colour the mesh then gets).")]

# The verbs over a fitted hand (lisa mesh, render, animate).
ParamsArg = Annotated[Path, typer.Argument(
    metavar="PARAMS",
    help="The hand: a params.json written by 'lisa fit-points', 'lisa fit-images' or "
         "'lisa blend'.")]
ModelOpt = Annotated[Path | None, typer.Option(
    "--model", help="Trained model (exported file, or a 'lisa train' / 'lisa train-prior' run); "
                    "default: the one PARAMS names ('default', 'geometry', 'geometry_v3': the "
                    "shipped ones).")]
DeviceOpt = Annotated[str, typer.Option(
    "--device", help="auto (CUDA when available), cpu, cuda or cuda:N.")]


def parse_image_size(text: str, name: str = "resolution") -> tuple[int, int]:
    """``"1024x667"`` -> ``(1024, 667)`` (width, height in pixels; ValueError naming ``name``)."""
    parts = str(text).lower().strip().split("x")
    try:
        width, height = (int(part) for part in parts)
    except ValueError:
        raise ValueError(f"{name} must look like WIDTHxHEIGHT, e.g. 512x512, got {text!r}") \
            from None
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise ValueError(f"{name} must be between 1x1 and 16384x16384 pixels, got {text!r}")
    return width, height


def read_cameras(path: Path, size: tuple[int, int] | None = None) -> list[Camera]:
    """The cameras of a ``--camera`` file (ValueError when it holds none), their intrinsics
    scaled to ``size`` (width, height pixels) when given."""
    from ..geometry.cameras import load_cameras
    from ..inference import scale_camera

    cameras = load_cameras(path)
    if not cameras:
        raise ValueError(f"--camera {path}: the file holds no camera")
    if size is not None:
        cameras = [scale_camera(camera, *size) for camera in cameras]
    return cameras
