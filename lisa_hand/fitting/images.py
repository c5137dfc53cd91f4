"""``lisa fit-images``: fit LISA to one or more calibrated views (paper Section 4.3).

Input: a frame folder in the layout of :mod:`lisa_hand.data.layout` (:func:`read_views`):
``cameras.json`` and ``images/NAME.png`` are required; ``masks/NAME.png`` and
``keypoints.json`` (21 keypoints per view, OpenPose order, pixels) are optional.

Unknowns: the 48-D pose (global rotation and 15 finger joints, axis-angle), the translation,
the mesh template's shape coefficients ``betas`` (LISA's skeleton is
``template.rest_joints(betas)``, as in training), the shape code ``beta+`` and the colour code
``gamma`` (both start at the mean of the training subjects' codes).

Stage 1, pose from keypoints (:func:`fit_keypoints`; paper: 1k iterations). The posed template's
21 keypoints are projected into every view and compared with the given ones (L1 in pixels over
the visible keypoints, as L_joints). Where a view has a mask, the projected template vertices
must fall inside it (the mask's outside distance transform at each vertex, pixels) and the
mask's contour must be covered by them (distance from contour pixels to the nearest projected
vertex). Priors: soft joint limits (:data:`lisa_hand.handmodel.poses.JOINT_LIMITS`), a small L2
pull of the finger pose towards the relaxed pose and of ``betas`` towards 0. Restarts: a pool
of ``rotation_pool`` random global rotations (plus, when two or more views have keypoints, the
Kabsch alignment of the template's keypoints with the triangulated ones) is scored without
optimisation, each with its translation in closed form (linear least squares on the palm's
keypoints; without keypoints, from the mask centroids and areas); the ``restarts`` best
(``restart_separation_deg`` apart) are optimised rigidly (palm keypoints only) for
``rigid_fraction`` of the iterations, the ``keep_restarts`` best then with every parameter, and
for the last ``finger_restart_fraction`` the best one beside copies of it in which each finger
whose keypoints are off by more than ``finger_restart_px`` restarts from the flat, relaxed and
fist poses (a finger bent the wrong way is a local minimum). The lowest objective wins.

Stage 2, pose, shape and colour (:func:`fit_color`; paper: 5k iterations). Each iteration draws
``num_rays`` camera rays, ``mask_fraction`` of them through the mask and a band of ``band_px``
pixels around it, renders them with VolSDF (:func:`lisa_hand.render.render_rays`, the model's
``field_fn`` with bone culling and ``LaplaceDensity(model.beta)``), applies the model's mean
colour calibration (:func:`lisa_hand.render.renderer.calibrate`) and minimises

    L = lambda_col L_col + lambda_reg L_reg + lambda_joints L_joints' + lambda_mask L_mask

* ``L_col``: L1 colour loss of the rays (Eq. 13). Pixels outside a view's mask are background:
  black, as in the training images (:func:`fit_target`; an image that is black outside its mask
  already is used as it is, soft edges included).
* ``L_reg = |beta+|_2 + |gamma|_2`` (Eq. 16).
* ``L_joints'``: stage 1's keypoint L1 (pixels) with its pose and shape priors (no silhouette
  terms: the geometry is now LISA's).
* ``L_mask`` (NOT in the paper; ``lambda_mask = 0`` turns it off): binary cross-entropy between
  the rays' opacity and the mask.

Fallbacks for incomplete input (documented behaviour, not errors):

* no ``keypoints.json`` (or a view missing from it): stage 1 uses the masks alone (silhouette
  terms, with the same restarts); L_joints is left out where there are no keypoints.
* a view without a mask: its rays are drawn from the whole image's box around the projected
  template (after stage 1, plus a margin), its background colour is estimated as the median of
  the image border, and it has no silhouette or mask term.
* a view with neither: kept for the colour loss only. At least one view must have keypoints or a
  mask (else ValueError).

LISA and the template are right hands: a left hand (``side='left'``) is fitted as the right
hand of the mirrored views (:func:`mirror_view`) and mirrored back.

Outputs of :func:`fit_image_folder` (``lisa fit-images``): ``params.json``, ``mesh.ply``
(:func:`lisa_hand.inference.mesh_hand`: vertex colours and skinning weights) and
``metrics.json`` (keypoint errors, PSNR of the re-rendered input views, timings, and with a
ground truth the V2V / V2S distances), written by :mod:`lisa_hand.fitting.outputs`.

Self-consistency (views rendered from a small random LISA model at a known pose and codes,
4 views of 96 x 72, noiseless keypoints; defaults, 1 CPU thread): stage 1 reaches 0.02 px
keypoint error (rotation 0.03 deg, translation 0.06 mm) in ~6 s; stage 2 keeps it below 0.05
px, lowers the colour loss to near its floor and gives 45 dB PSNR inside the masks. One view:
the rotation within ~4 deg, the depth within ~1 cm (a single view barely constrains it).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ..data.layout import FramePaths, read_image, read_mask
from ..geometry.cameras import Camera, load_cameras
from ..geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..model.losses import color_loss, latent_loss
from ..render import LaplaceDensity, RenderConfig, render_rays
from ..render.image import ray_box_bounds
from ..skeleton import FINGER_JOINTS, FINGER_NAMES, KEYPOINT_NAMES, NUM_KEYPOINTS
from ..skeleton.params import HandParams
from ..utils.io import read_json
from ..utils.threads import cpu_threads

__all__ = [
    "ImageView",
    "read_views",
    "FitImagesConfig",
    "PoseFit",
    "FitImagesResult",
    "fit_keypoints",
    "fit_color",
    "fit_images",
    "keypoint_errors",
    "fit_target",
    "mirror_view",
    "ViewRender",
    "render_fitted_views",
    "view_psnrs",
    "FitImagesReport",
    "input_notes",
    "fit_image_folder",
    "cpu_threads",
]

_BORDER_PX = 2  # width of the image border used to estimate a view's background colour
_PALM_KEYPOINTS = (0, 1, 5, 9, 13, 17)
"""Wrist, thumb CMC and the four MCP joints: nearly rigid, the rigid phase's keypoints."""
_MIN_DEPTH = 1e-3  # metres: projections divide by at least this (the depth term keeps 5 cm)


# ------------------------------------------------------------------------------------------------
# Input


@dataclass(eq=False)
class ImageView:
    """One calibrated view of the hand.

    name: the camera's name (``images/NAME.png``).
    camera: its calibration (OpenCV convention, :class:`lisa_hand.geometry.cameras.Camera`).
    rgb: [H, W, 3] float32 in [0, 1].
    mask: [H, W] bool foreground (other dtypes: nonzero is foreground), or None (no mask: see
        the module docstring's fallbacks).
    keypoints: [21, 2] pixels (continuous coordinates, OpenPose order), or None.
    visible: [21] bool, which keypoints count (None with ``keypoints`` None).
    """

    name: str
    camera: Camera
    rgb: torch.Tensor
    mask: torch.Tensor | None = None
    keypoints: torch.Tensor | None = None
    visible: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera):
            raise TypeError(f"view {self.name!r}: camera must be a Camera, got "
                            f"{type(self.camera).__name__}")
        expected = (self.camera.height, self.camera.width)
        if not isinstance(self.rgb, torch.Tensor) or self.rgb.shape != expected + (3,):
            raise ValueError(f"view {self.name!r}: rgb must be [H, W, 3] = "
                             f"{list(expected) + [3]} (the camera's size), got "
                             f"{list(getattr(self.rgb, 'shape', []))}")
        if not self.rgb.is_floating_point():
            raise TypeError(f"view {self.name!r}: rgb must be floats in [0, 1], got "
                            f"{self.rgb.dtype}")
        if self.mask is not None and (not isinstance(self.mask, torch.Tensor)
                                      or self.mask.shape != expected):
            raise ValueError(f"view {self.name!r}: mask must be [H, W] = {list(expected)}, got "
                             f"{list(getattr(self.mask, 'shape', []))}")
        if self.mask is not None and self.mask.dtype != torch.bool:
            self.mask = self.mask > 0  # any nonzero value is foreground
        if self.keypoints is not None:
            if self.keypoints.shape != (NUM_KEYPOINTS, 2):
                raise ValueError(f"view {self.name!r}: keypoints must be [21, 2], got "
                                 f"{list(self.keypoints.shape)}")
            if self.visible is None:
                self.visible = torch.ones(NUM_KEYPOINTS, dtype=torch.bool,
                                          device=self.keypoints.device)
            elif self.visible.shape != (NUM_KEYPOINTS,):
                raise ValueError(f"view {self.name!r}: visible must be [21], got "
                                 f"{list(self.visible.shape)}")

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def has_keypoints(self) -> bool:
        return self.keypoints is not None and bool(self.visible.any())

    def to(self, device: torch.device | str) -> ImageView:
        """This view with every tensor on ``device`` (float32 camera)."""
        def move(value: torch.Tensor | None) -> torch.Tensor | None:
            return None if value is None else value.to(device)

        return ImageView(name=self.name, camera=self.camera.to(device, torch.float32),
                         rgb=self.rgb.to(device), mask=move(self.mask),
                         keypoints=move(self.keypoints), visible=move(self.visible))


def _read_keypoints(path: Path, names: Sequence[str]) -> dict[str, tuple[torch.Tensor,
                                                                          torch.Tensor]]:
    """``keypoints.json`` -> {view: (keypoints [21, 2] px, visible [21] bool)} for ``names``."""
    data = read_json(path)
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, dict):
        raise ValueError(f"{path}: expected an object with 'views': {{name: {{'keypoints': "
                         "[21 x 2] pixels, 'visible': [21]}}}}")
    listed = data.get("names")
    if listed is not None and list(listed) != list(KEYPOINT_NAMES):
        raise ValueError(f"{path}: 'names' must be the 21 keypoint names in OpenPose order "
                         f"({', '.join(KEYPOINT_NAMES[:3])}, ...)")
    result = {}
    for name in names:
        entry = views.get(name)
        if entry is None:
            continue
        where = f"{path}: view {name!r}"
        if not isinstance(entry, dict) or "keypoints" not in entry:
            raise ValueError(f"{where}: expected an object with 'keypoints' [21, 2]")
        try:
            keypoints = torch.as_tensor(np.asarray(entry["keypoints"], dtype=np.float64),
                                        dtype=torch.float32)
            visible_raw = entry.get("visible")
            visible = (torch.ones(NUM_KEYPOINTS, dtype=torch.bool) if visible_raw is None
                       else torch.as_tensor(np.asarray(visible_raw, dtype=np.float64)) > 0)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: keypoints must be numbers ({exc})") from None
        if keypoints.shape != (NUM_KEYPOINTS, 2):
            raise ValueError(f"{where}: 'keypoints' must be [21, 2] pixels, got "
                             f"{list(keypoints.shape)}")
        if visible.shape != (NUM_KEYPOINTS,):
            raise ValueError(f"{where}: 'visible' must be [21], got {list(visible.shape)}")
        if not torch.isfinite(keypoints[visible]).all():
            raise ValueError(f"{where}: visible keypoints hold NaN or inf")
        keypoints = torch.where(visible[:, None], keypoints, torch.zeros(()))
        result[name] = (keypoints, visible)
    return result


def read_views(root: str | os.PathLike, names: Sequence[str] | None = None) -> list[ImageView]:
    """Read the views of a frame folder (the input of ``lisa fit-images``).

    root: a folder with ``cameras.json`` (a list of ``{name, K, R, t, width, height}``),
        ``images/NAME.png`` for every camera, and optionally ``masks/NAME.png`` and
        ``keypoints.json`` (``{"views": {NAME: {"keypoints": [21, 2] px, "visible": [21]}}}``).
    names: the cameras to use (default: all, in the file's order).

    Errors (ValueError / FileNotFoundError, naming the file): a missing ``cameras.json`` or
    image, missing camera fields, unnamed or duplicate cameras, unknown names, an image or mask
    whose size differs from its camera's, an empty mask, malformed keypoints, and no view with a
    mask or keypoints at all. A missing mask or keypoint entry is not an error (see the module
    docstring's fallbacks).
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder (expected a frame folder with "
                                "cameras.json and images/)")
    paths = FramePaths(root)
    if not paths.cameras.is_file():
        raise FileNotFoundError(f"{paths.cameras}: no such file (the views' calibration: a "
                                "list of {name, K, R, t, width, height})")
    cameras = load_cameras(paths.cameras)
    if not cameras:
        raise ValueError(f"{paths.cameras}: no cameras")
    by_name: dict[str, Camera] = {}
    for index, camera in enumerate(cameras):
        if not camera.name:
            raise ValueError(f"{paths.cameras}: camera {index} has no name (its image is "
                             "images/NAME.png)")
        if camera.name in by_name:
            raise ValueError(f"{paths.cameras}: camera name {camera.name!r} appears twice")
        by_name[camera.name] = camera
    if names is None:
        selected = list(by_name)
    else:
        selected = [str(name) for name in names]
        if not selected:
            raise ValueError("views: the list of view names is empty")
        unknown = [name for name in selected if name not in by_name]
        if unknown:
            raise ValueError(f"{paths.cameras}: no camera named {', '.join(map(repr, unknown))}"
                             f"; cameras: {', '.join(by_name)}")
        if len(set(selected)) != len(selected):
            raise ValueError(f"views: a view is listed twice in {selected}")
    keypoints = _read_keypoints(paths.keypoints, selected) if paths.keypoints.is_file() else {}

    views = []
    for name in selected:
        camera = by_name[name]
        expected = (camera.height, camera.width)
        image_path = paths.image(name)
        rgb = read_image(image_path)
        if rgb.shape[:2] != expected:
            raise ValueError(f"{image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but camera "
                             f"{name!r} in {paths.cameras} is {camera.width}x{camera.height}")
        mask = None
        mask_path = paths.mask(name)
        if mask_path.is_file():
            mask = read_mask(mask_path)
            if mask.shape != expected:
                raise ValueError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]} but "
                                 f"camera {name!r} in {paths.cameras} is "
                                 f"{camera.width}x{camera.height}")
            if not mask.any():
                raise ValueError(f"{mask_path}: the mask is empty (no foreground pixel); leave "
                                 "this view out with --views, or remove the mask file")
            mask = torch.from_numpy(mask)
        kp, visible = keypoints.get(name, (None, None))
        views.append(ImageView(name=name, camera=camera, rgb=torch.from_numpy(rgb), mask=mask,
                               keypoints=kp, visible=visible))
    if not any(view.mask is not None or view.has_keypoints for view in views):
        raise ValueError(f"{root}: no view has a mask (masks/NAME.png) or keypoints "
                         "(keypoints.json): the hand cannot be located")
    return views


# ------------------------------------------------------------------------------------------------
# Configuration and results


def _default_render() -> RenderConfig:
    return RenderConfig(sampler="sphere_traced", num_samples=16, num_samples_extra=8,
                        sphere_num_steps=16, stratified=True)


@dataclass(frozen=True)
class FitImagesConfig:
    """Settings of :func:`fit_images` (defaults: about 1-2 minutes on 2 CPU cores)."""

    keypoint_iters: int = 400
    """Stage 1 iterations (pose from keypoints and masks; the paper uses 1000)."""
    color_iters: int = 300
    """Stage 2 iterations (pose, shape and colour; the paper uses 5000). 0 skips stage 2."""
    num_rays: int = 512
    """Stage 2: camera rays rendered per iteration, over all views."""
    mask_fraction: float = 0.9
    """Stage 2: fraction of the rays through the mask and the band around it (the rest through
    the background)."""
    band_px: int = 4
    """Stage 2: width of the band around the mask, pixels."""
    no_mask_margin: float = 0.15
    """Stage 2, views without a mask: rays are drawn in the box around the projected template
    grown by this fraction of its size on each side."""
    render: RenderConfig = field(default_factory=_default_render)
    """Stage 2: ray sampling (VolSDF; default: a band of 16 samples around the sphere-traced
    surface (16 tracing steps) + 8 uniform ones, stratified)."""
    rotation_pool: int = 2048
    """Stage 1: random global rotations scored (without optimisation) to choose the restarts."""
    restarts: int = 12
    """Stage 1: the best-scoring rotations of the pool that are optimised (rigidly first)."""
    restart_separation_deg: float = 20.0
    """Stage 1: the restarts differ by at least this angle, degrees."""
    keep_restarts: int = 3
    """Stage 1: candidates kept after the rigid phase."""
    rigid_fraction: float = 0.3
    """Stage 1: fraction of the iterations with only rotation and translation free."""
    finger_restart_fraction: float = 0.25
    """Stage 1: fraction of the iterations, at the end, in which every finger whose keypoints
    are off by more than ``finger_restart_px`` is also restarted from the flat, relaxed and
    fist poses (the best of these and of the unchanged hand wins)."""
    finger_restart_px: float = 2.0
    """Stage 1: mean error (pixels) of a finger's visible keypoints that triggers its restart."""
    keypoint_pose_lr: float = 0.03
    """Stage 1: Adam learning rate of the pose, radians."""
    keypoint_translation_lr: float = 0.005
    """Stage 1: Adam learning rate of the translation, metres."""
    keypoint_betas_lr: float = 0.05
    """Stage 1: Adam learning rate of the template's betas."""
    color_pose_lr: float = 0.004
    """Stage 2: Adam learning rate of the pose, radians."""
    color_translation_lr: float = 0.0005
    """Stage 2: Adam learning rate of the translation, metres."""
    color_betas_lr: float = 0.01
    """Stage 2: Adam learning rate of the betas (0 keeps stage 1's)."""
    latent_lr: float = 0.01
    """Stage 2: Adam learning rate of the shape and colour codes."""
    final_lr_fraction: float = 0.1
    """Learning rates decay exponentially to this fraction over each stage."""
    lambda_silhouette: float = 0.2
    """Stage 1: weight of the mean outside-mask distance of the projected template vertices
    (pixels)."""
    lambda_coverage: float = 0.1
    """Stage 1: weight of the mean distance from mask pixels to the nearest projected template
    vertex (pixels)."""
    coverage_pixels: int = 64
    """Stage 1: mask contour pixels per view for the coverage term (chosen once, seeded)."""
    coverage_vertices: int = 256
    """Stage 1: template vertices (a fixed random subset) for the coverage term."""
    lambda_limits: float = 100.0
    """Weight of the squared excess over the joint limits (radians^2, summed over joints)."""
    lambda_pose: float = 0.2
    """Weight of the mean squared finger-pose difference from the relaxed pose (radians^2)."""
    lambda_betas: float = 0.5
    """Weight of the mean squared template betas."""
    lambda_col: float = 1.0
    """Stage 2: weight of L_col (L1 over RGB per ray, Eq. 13)."""
    lambda_reg: float = 1e-3
    """Stage 2: weight of L_reg = |beta+|_2 + |gamma|_2 (Eq. 16)."""
    lambda_joints: float = 1e-2
    """Stage 2: weight of the keypoint loss (pixels) and its priors (the joint loss)."""
    lambda_mask: float = 0.0
    """Stage 2: weight of the opacity/mask BCE (not in the paper; 0 turns it off)."""
    side: str = "right"
    """The hand's side: 'right', or 'left' (fitted as the right hand of the mirrored views)."""
    num_threads: int | None = 1
    """CPU threads of torch during the fit (restored afterwards); None keeps torch's setting.
    The fit runs many small operations: on a busy 2-core machine one thread was 2x (stage 2)
    to 10x (stage 1) faster than two."""
    seed: int = 0
    """Seed of every random choice (restarts, rays, stratified samples)."""

    def __post_init__(self) -> None:
        for name in ("keypoint_iters", "color_iters", "band_px", "coverage_pixels",
                     "coverage_vertices", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
        for name in ("num_rays", "rotation_pool", "restarts", "keep_restarts"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        for name in ("mask_fraction", "rigid_fraction", "finger_restart_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if self.rigid_fraction + self.finger_restart_fraction > 1.0:
            raise ValueError(f"rigid_fraction + finger_restart_fraction must be <= 1, got "
                             f"{self.rigid_fraction} + {self.finger_restart_fraction}")
        if not 0.0 < self.final_lr_fraction <= 1.0:
            raise ValueError(f"final_lr_fraction must be in (0, 1], got "
                             f"{self.final_lr_fraction!r}")
        for name in ("keypoint_pose_lr", "keypoint_translation_lr", "color_pose_lr",
                     "color_translation_lr", "latent_lr"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("keypoint_betas_lr", "color_betas_lr", "no_mask_margin",
                     "restart_separation_deg", "finger_restart_px",
                     "lambda_silhouette", "lambda_coverage", "lambda_limits", "lambda_pose",
                     "lambda_betas", "lambda_col", "lambda_reg", "lambda_joints", "lambda_mask"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not isinstance(self.render, RenderConfig):
            raise TypeError(f"render must be a RenderConfig, got {type(self.render).__name__}")
        if self.side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {self.side!r}")
        if self.num_threads is not None and (isinstance(self.num_threads, bool) or not isinstance(
                self.num_threads, int) or self.num_threads < 1):
            raise ValueError(f"num_threads must be an int >= 1 or None, got {self.num_threads!r}")


@dataclass
class PoseFit:
    """Result of stage 1 (:func:`fit_keypoints`), batch of one.

    pose: [48] radians; translation: [3] metres; betas: [K] template coefficients.
    keypoint_error_px: mean distance (pixels) between the projected and the given visible
        keypoints over all views (NaN without keypoints).
    loss: the stage's final objective; candidate: which restart won.
    history: per iteration, the best candidate's loss ("kp_loss") and keypoint error
        ("kp_px").
    """

    pose: torch.Tensor
    translation: torch.Tensor
    betas: torch.Tensor
    keypoint_error_px: float
    loss: float
    candidate: int
    history: dict[str, list[float]] = field(default_factory=dict)


@dataclass
class FitImagesResult:
    """Result of :func:`fit_images`.

    params: the fitted hand (pose, translation, rest joints, betas, codes), ``extra`` holds the
        stage timings and errors.
    history: per-iteration values: stage 1 "kp_loss", "kp_px" (the best restart's); stage 2
        "total", "col", "reg", "joints", "mask", "color_kp_px".
    seconds: wall time of the whole fit; stage_seconds: {"keypoints", "color"}.
    keypoint_error_px: mean keypoint reprojection error after each stage ({"keypoints",
        "color"}; NaN without keypoints).
    """

    params: HandParams
    history: dict[str, list[float]]
    seconds: float
    stage_seconds: dict[str, float]
    keypoint_error_px: dict[str, float]


# ------------------------------------------------------------------------------------------------
# Per-view constants shared by both stages


class _ViewData:
    """Stacked cameras and keypoints of the views, and per-view mask helpers (one device)."""

    def __init__(self, views: Sequence[ImageView], config: FitImagesConfig,
                 generator: torch.Generator) -> None:
        from scipy.ndimage import binary_erosion, distance_transform_edt

        device = views[0].rgb.device
        self.views = list(views)
        self.device = device
        self.K = torch.stack([v.camera.K for v in views]).float()  # [C, 3, 3]
        self.R = torch.stack([v.camera.R for v in views]).float()
        self.t = torch.stack([v.camera.t for v in views]).float()
        num = len(views)
        self.keypoints = torch.zeros(num, NUM_KEYPOINTS, 2, device=device)
        self.visible = torch.zeros(num, NUM_KEYPOINTS, device=device)
        for index, view in enumerate(views):
            if view.keypoints is not None:
                self.keypoints[index] = view.keypoints.float()
                self.visible[index] = view.visible.float()
        self.num_visible = float(self.visible.sum())
        palm = torch.zeros(NUM_KEYPOINTS, device=device)
        palm[list(_PALM_KEYPOINTS)] = 1.0
        self.palm_visible = self.visible * palm
        self.num_palm_visible = float(self.palm_visible.sum())
        # Per view with a mask: outside distance transform [1, 1, H, W] (pixels, 0 inside) and
        # a fixed random subset of the mask's contour pixel centres [M, 2] (coverage term).
        self.outside: list[torch.Tensor | None] = []
        self.coverage: list[torch.Tensor | None] = []
        for view in views:
            if view.mask is None:
                self.outside.append(None)
                self.coverage.append(None)
                continue
            mask = view.mask.cpu().numpy()
            outside = distance_transform_edt(~mask).astype(np.float32)
            self.outside.append(torch.from_numpy(outside)[None, None].to(device))
            contour = mask & ~binary_erosion(mask, border_value=0)
            pixels = torch.from_numpy(np.argwhere(contour)[:, ::-1].copy()).float() + 0.5
            if pixels.shape[0] > config.coverage_pixels:
                pick = torch.randperm(pixels.shape[0], generator=generator)
                pixels = pixels[pick[:config.coverage_pixels]]
            self.coverage.append(pixels.to(device) if config.coverage_pixels else None)
        self.num_masks = sum(o is not None for o in self.outside)
        self.vertex_subset: torch.Tensor | None = None

    def choose_vertices(self, num_vertices: int, most: int, generator: torch.Generator) -> None:
        """Fix the template vertices (at most ``most``, random) that the coverage term uses."""
        if num_vertices > most:
            self.vertex_subset = torch.randperm(num_vertices, generator=generator)[:most].to(
                self.device)

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points [B, N, 3] metres -> pixels [B, C, N, 2], depth [B, C, N] metres.

        :func:`lisa_hand.geometry.cameras.project_points` for every camera at once, written
        with einsum (one matrix product instead of B x C tiny batched ones, ~10x faster on a
        CPU).
        """
        x_cam = torch.einsum("bnk,cjk->bcnj", points, self.R) + self.t[None, :, None]
        homogeneous = torch.einsum("bcnk,cjk->bcnj", x_cam, self.K)
        depth = x_cam[..., 2]
        return homogeneous[..., :2] / depth.clamp_min(_MIN_DEPTH)[..., None], depth


def _keypoint_l1(pixels: torch.Tensor, data: _ViewData, palm_only: bool = False
                 ) -> torch.Tensor:
    """Mean L1 (pixels) over the visible keypoints (``palm_only``: the palm's, see
    :data:`_PALM_KEYPOINTS`): pixels [B, C, 21, 2] -> [B]."""
    visible, count = data.visible, data.num_visible
    if palm_only and data.num_palm_visible >= 3:
        visible, count = data.palm_visible, data.num_palm_visible
    if count == 0:
        return pixels.new_zeros(pixels.shape[0])
    residual = (pixels - data.keypoints).abs().sum(-1)  # [B, C, 21]
    return (residual * visible).sum((1, 2)) / count


def _keypoint_px(pixels: torch.Tensor, data: _ViewData) -> torch.Tensor:
    """Mean Euclidean error (pixels) over the visible keypoints: [B, C, 21, 2] -> [B] (NaN if
    none)."""
    if data.num_visible == 0:
        return pixels.new_full((pixels.shape[0],), math.nan)
    distance = (pixels - data.keypoints).norm(dim=-1)
    return (distance * data.visible).sum((1, 2)) / data.num_visible


def _sample_map(image: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of a map [1, 1, H, W] at continuous pixels [B, N, 2] -> [B, N]; outside
    the image the border value plus the distance to the image."""
    height, width = image.shape[-2:]
    scale = pixels.new_tensor([2.0 / width, 2.0 / height])
    grid = (pixels * scale - 1.0)[None]  # [1, B, N, 2]
    values = F.grid_sample(image, grid, mode="bilinear", padding_mode="border",
                           align_corners=False)[0, 0]
    size = pixels.new_tensor([width, height])
    beyond = (F.relu(-pixels) + F.relu(pixels - size)).sum(-1)
    return values + beyond


def _silhouette_terms(vertex_pixels: torch.Tensor, data: _ViewData
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Outside-mask distance of projected vertices and mask coverage, pixels, averaged over the
    views with masks: vertex_pixels [B, C, V, 2] -> ([B], [B])."""
    batch = vertex_pixels.shape[0]
    outside = vertex_pixels.new_zeros(batch)
    coverage = vertex_pixels.new_zeros(batch)
    if data.num_masks == 0:
        return outside, coverage
    for index, (distance_map, cover) in enumerate(zip(data.outside, data.coverage,
                                                      strict=True)):
        if distance_map is None:
            continue
        pixels = vertex_pixels[:, index]
        outside = outside + _sample_map(distance_map, pixels).mean(-1)
        if cover is not None:
            if data.vertex_subset is not None:
                pixels = pixels[:, data.vertex_subset]
            contour = cover[None].expand(batch, -1, -1)
            with torch.no_grad():  # nearest vertex of each contour pixel; gradient via gather
                # argmin |p - c|^2 = argmin |p|^2 - 2 c.p: one batched product, no sqrt
                score = torch.baddbmm((pixels * pixels).sum(-1)[:, None], contour,
                                      pixels.transpose(1, 2), alpha=-2.0)
                nearest = score.argmin(-1)
            closest = torch.gather(pixels, 1, nearest[..., None].expand(-1, -1, 2))
            coverage = coverage + (closest - contour).norm(dim=-1).mean(-1)
    return outside / data.num_masks, coverage / data.num_masks


def _limit_excess(pose: torch.Tensor) -> torch.Tensor:
    """Sum over joints of the squared excess of the anatomical angles over the joint limits:
    pose [B, 48] -> [B] radians^2."""
    from ..handmodel.poses import JOINT_LIMITS, pose_to_angles

    angles = pose_to_angles(pose)  # [B, 15, 3]
    limits = JOINT_LIMITS.to(angles)
    excess = F.relu(limits[..., 0] - angles) + F.relu(angles - limits[..., 1])
    return (excess**2).sum((1, 2))


def _relaxed_fingers(device: torch.device) -> torch.Tensor:
    """[45] finger pose of the named 'relaxed' pose, radians (the start and the prior's mean)."""
    from ..handmodel.poses import named_pose

    return named_pose("relaxed")[3:].to(device)


def _prior_terms(pose: torch.Tensor, betas: torch.Tensor, config: FitImagesConfig,
                 relaxed: torch.Tensor) -> torch.Tensor:
    """Pose and shape priors: pose [B, 48], betas [B, K] -> [B]."""
    total = config.lambda_pose * ((pose[:, 3:] - relaxed) ** 2).mean(-1)
    total = total + config.lambda_betas * (betas**2).mean(-1)
    if config.lambda_limits > 0:
        total = total + config.lambda_limits * _limit_excess(pose)
    return total


# ------------------------------------------------------------------------------------------------
# Stage 1: pose from 2D keypoints and masks


def _random_rotations(num: int, generator: torch.Generator) -> torch.Tensor:
    """[num, 3] axis-angle of uniformly random rotations (unit quaternions)."""
    quat = torch.randn(num, 4, generator=generator, dtype=torch.float64)
    quat = quat / quat.norm(dim=-1, keepdim=True)
    quat = quat * torch.where(quat[:, :1] < 0, -1.0, 1.0)
    half = torch.acos(quat[:, 0].clamp(-1.0, 1.0))
    axis = quat[:, 1:] / torch.sin(half).clamp_min(1e-12)[:, None]
    return (axis * (2.0 * half)[:, None]).float()


def _triangulate(data: _ViewData) -> tuple[torch.Tensor, torch.Tensor]:
    """DLT triangulation of every keypoint seen in two or more views.

    -> points [21, 3] metres, valid [21] bool.
    """
    projections = torch.cat([data.R, data.t[..., None]], dim=-1).double()
    projections = data.K.double() @ projections  # [C, 3, 4]
    keypoints = data.keypoints.double()
    points = torch.zeros(NUM_KEYPOINTS, 3, dtype=torch.float64, device=data.device)
    valid = torch.zeros(NUM_KEYPOINTS, dtype=torch.bool, device=data.device)
    for k in range(NUM_KEYPOINTS):  # 21 tiny SVDs, once per fit
        seen = data.visible[:, k] > 0
        if int(seen.sum()) < 2:
            continue
        proj, uv = projections[seen], keypoints[seen, k]
        rows = torch.cat([uv[:, :1] * proj[:, 2] - proj[:, 0],
                          uv[:, 1:] * proj[:, 2] - proj[:, 1]])  # [2 n, 4]
        rows = rows / rows.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        homogeneous = torch.linalg.svd(rows).Vh[-1]
        if abs(float(homogeneous[3])) < 1e-12:
            continue
        points[k] = homogeneous[:3] / homogeneous[3]
        valid[k] = True
    return points.float(), valid


def _kabsch_rotation(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Rotation (about the centroids) taking source [N, 3] onto target [N, 3] -> [3, 3]."""
    src = source.double() - source.double().mean(0)
    dst = target.double() - target.double().mean(0)
    u, _, vh = torch.linalg.svd(src.T @ dst)
    sign = torch.sign(torch.linalg.det(vh.T @ u.T))
    fix = torch.diag(torch.tensor([1.0, 1.0, float(sign)], dtype=torch.float64,
                                  device=source.device))
    return (vh.T @ fix @ u.T).float()


def _solve_translation(points: torch.Tensor, data: _ViewData, palm_only: bool = False
                       ) -> torch.Tensor:
    """Least-squares translation from keypoints: points [B, 21, 3] (posed, zero translation) ->
    [B, 3] such that ``points + T`` projects onto the visible 2D keypoints (DLT rows; only the
    palm's with ``palm_only``)."""
    kt_r = data.K @ data.R  # [C, 3, 3]
    offset = points[:, None] @ kt_r.transpose(-1, -2)[None] + (data.K @ data.t[..., None])[
        None, :, None, :, 0]  # [B, C, 21, 3]: K (R X + t)
    uv = data.keypoints[None]  # [1, C, 21, 2]
    visible = data.palm_visible if palm_only and data.num_palm_visible >= 3 else data.visible
    weight = visible[None, ..., None]  # [1, C, 21, 1]
    # (u M_2 - M_0) . T = -(u m_2 - m_0), likewise for v; M = K R, m = K (R X + t).
    rows_u = uv[..., :1, None] * kt_r[None, :, None, 2:3] - kt_r[None, :, None, 0:1]
    rows_v = uv[..., 1:, None] * kt_r[None, :, None, 2:3] - kt_r[None, :, None, 1:2]
    rhs_u = -(uv[..., 0] * offset[..., 2] - offset[..., 0])
    rhs_v = -(uv[..., 1] * offset[..., 2] - offset[..., 1])
    rows = torch.cat([rows_u[..., 0, :].expand(offset.shape[0], -1, -1, -1),
                      rows_v[..., 0, :].expand(offset.shape[0], -1, -1, -1)], dim=2)
    rhs = torch.cat([rhs_u, rhs_v], dim=2)  # [B, C, 42]
    weights = torch.cat([weight, weight], dim=2)  # [1, C, 42, 1]
    matrix = (rows * weights).reshape(offset.shape[0], -1, 3).double()
    vector = (rhs * weights[..., 0]).reshape(offset.shape[0], -1).double()
    normal = matrix.transpose(1, 2) @ matrix + 1e-9 * torch.eye(3, dtype=torch.float64,
                                                                 device=points.device)
    return torch.linalg.solve(normal, matrix.transpose(1, 2) @ vector[..., None])[..., 0].float()


_TYPICAL_SILHOUETTE_M2 = 0.006  # silhouette area of an adult hand seen from a random side, m^2


def _translation_from_masks(vertices: torch.Tensor, data: _ViewData) -> torch.Tensor:
    """Translation from the masks alone: the template's centroid goes to the point nearest to
    the rays through the mask centroids (with one mask: at the depth where a hand would cover
    the mask's area). vertices [B, V, 3] (posed, zero translation) -> [B, 3]."""
    origins, directions, depths = [], [], []
    for index, view in enumerate(data.views):
        if view.mask is None:
            continue
        coords = view.mask.nonzero().float()  # [M, 2] (row, col)
        centre = coords.mean(0).flip(0) + 0.5  # (u, v)
        camera = view.camera
        direction = camera.R.T @ torch.linalg.solve(camera.K, torch.cat([centre,
                                                                         centre.new_ones(1)]))
        direction = direction / direction.norm()
        focal = float(camera.K[0, 0] * camera.K[1, 1]) ** 0.5
        depths.append(focal * math.sqrt(_TYPICAL_SILHOUETTE_M2 / float(coords.shape[0])))
        origins.append(camera.center.float())
        directions.append(direction.float())
        del index
    origins_t, directions_t = torch.stack(origins), torch.stack(directions)
    if len(origins) >= 2:
        # argmin_x sum |(I - d d^T)(x - o)|^2
        eye = torch.eye(3, device=origins_t.device)
        projector = eye - directions_t[:, :, None] * directions_t[:, None, :]
        point = torch.linalg.solve(projector.sum(0), (projector @ origins_t[..., None]).sum(0))
        point = point[:, 0]
    else:
        point = origins_t[0] + depths[0] * directions_t[0]
    return point - vertices.mean(1)


@dataclass
class _Stage1State:
    global_orient: torch.Tensor  # [B, 3]
    fingers: torch.Tensor  # [B, 45]
    translation: torch.Tensor  # [B, 3]
    betas: torch.Tensor  # [B, K]

    def pose(self) -> torch.Tensor:
        return torch.cat([self.global_orient, self.fingers], dim=-1)

    def select(self, index: torch.Tensor) -> _Stage1State:
        return _Stage1State(*(value[index].detach().clone() for value in
                              (self.global_orient, self.fingers, self.translation, self.betas)))


def _stage1_objective(template: Any, state: _Stage1State, data: _ViewData,
                      config: FitImagesConfig, relaxed: torch.Tensor, rigid: bool = False
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (loss [B], keypoint error [B] pixels). ``rigid``: only the palm's keypoints count
    (the fingers' pose is not known yet)."""
    pose = state.pose()
    out = template.forward(pose, state.betas, state.translation)
    keypoint_pixels, keypoint_depth = data.project(out.keypoints)
    loss = _keypoint_l1(keypoint_pixels, data, palm_only=rigid)
    vertex_pixels, vertex_depth = data.project(out.vertices)
    if data.num_masks:
        outside, coverage = _silhouette_terms(vertex_pixels, data)
        loss = loss + config.lambda_silhouette * outside + config.lambda_coverage * coverage
    # Keep the hand in front of every camera (5 cm at least): pixels are meaningless behind.
    behind = F.relu(0.05 - vertex_depth).mean((1, 2)) + F.relu(0.05 - keypoint_depth).mean((1, 2))
    loss = loss + 1e4 * behind + _prior_terms(pose, state.betas, config, relaxed)
    return loss, _keypoint_px(keypoint_pixels.detach(), data)


def _decay(optimizer: torch.optim.Optimizer, iterations: int, final_fraction: float):
    gamma = final_fraction ** (1.0 / max(iterations, 1))
    return torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma)


def _progress_bar(enabled: bool, total: int, desc: str):
    if not enabled or total == 0:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="it", leave=False)


def _template_on(template: Any, device: torch.device) -> Any:
    """The template on ``device`` in float32 (the shipped one is float64: twice the work)."""
    if template is None:
        from ..handmodel.template import load_template

        template = load_template()
    if getattr(template, "device", device) != device or getattr(template, "dtype",
                                                                 None) == torch.float64:
        template = template.to(device=device, dtype=torch.float32)
    return template


def _rotation_angles(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Angles (radians) between rotation matrices first [A, 3, 3] and second [B, 3, 3] ->
    [A, B]."""
    trace = torch.einsum("aij,bij->ab", first, second)
    return torch.acos(((trace - 1.0) / 2.0).clamp(-1.0, 1.0))


def _candidate_rotations(template: Any, data: _ViewData, config: FitImagesConfig,
                         relaxed: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """``config.restarts`` starting global rotations [R, 3] axis-angle, best first.

    A pool of ``rotation_pool`` random rotations (plus, with keypoints in two or more views,
    the Kabsch alignment of the template's keypoints with the triangulated ones) is scored
    without optimisation: the relaxed template is turned about its wrist, its translation
    solved in closed form from the palm keypoints (or from the masks), and the palm keypoints'
    L1 reprojection error plus the silhouette terms measured. The best ones, at least
    ``restart_separation_deg`` apart, are kept.
    """
    device = data.device
    num_betas = int(template.num_betas)
    start_pose = torch.cat([torch.zeros(3, device=device), relaxed])[None]
    rest = template.forward(start_pose, torch.zeros(1, num_betas, device=device), None)
    pivot = rest.joints[0, 0]  # the global rotation turns the hand about its wrist joint
    keypoints = rest.keypoints[0] - pivot
    vertices = rest.vertices[0] - pivot
    data.choose_vertices(vertices.shape[0], config.coverage_vertices, generator)
    pool = [_random_rotations(config.rotation_pool, generator).to(device)]
    if data.num_visible:
        points, valid = _triangulate(data)
        if int(valid.sum()) >= 4:
            rotation = _kabsch_rotation(keypoints[valid], points[valid])
            pool.insert(0, matrix_to_axis_angle(rotation)[None])
    pool_aa = torch.cat(pool)
    matrices = axis_angle_to_matrix(pool_aa)
    scores = []
    for begin in range(0, matrices.shape[0], 256):  # bounded memory
        turned = matrices[begin:begin + 256]
        posed_keypoints = torch.einsum("pij,kj->pki", turned, keypoints) + pivot
        posed_vertices = torch.einsum("pij,vj->pvi", turned, vertices) + pivot
        score = posed_keypoints.new_zeros(turned.shape[0])
        if data.num_visible:
            shift = _solve_translation(posed_keypoints, data, palm_only=True)
            pixels, _ = data.project(posed_keypoints + shift[:, None])
            score = score + _keypoint_l1(pixels, data, palm_only=True)
        else:
            shift = _translation_from_masks(posed_vertices, data)
        if data.num_masks:
            pixels, _ = data.project(posed_vertices + shift[:, None])
            outside, coverage = _silhouette_terms(pixels, data)
            score = score + config.lambda_silhouette * outside + config.lambda_coverage * coverage
        scores.append(score)
    order = torch.cat(scores).argsort()
    separation = math.radians(config.restart_separation_deg)
    chosen: list[int] = []
    for index in order.tolist():
        if chosen and bool((_rotation_angles(matrices[index:index + 1], matrices[chosen])
                            < separation).any()):
            continue
        chosen.append(index)
        if len(chosen) == config.restarts:
            break
    return pool_aa[chosen]


_FINGER_KEYPOINTS = {"thumb": (2, 3, 4), "index": (6, 7, 8), "middle": (10, 11, 12),
                     "ring": (14, 15, 16), "pinky": (18, 19, 20)}
"""Keypoints that each finger's pose moves (its knuckle keypoint moves with the palm)."""
_FINGER_STARTS = ("flat", "relaxed", "fist")
"""Named poses whose finger chains restart a badly fitted finger."""


def _finger_residuals(template: Any, state: _Stage1State, data: _ViewData) -> torch.Tensor:
    """Mean keypoint error (pixels) of each finger over its visible keypoints, in
    :data:`lisa_hand.skeleton.FINGER_NAMES` order: [B, 5] (0 where none is visible)."""
    keypoints = template.forward(state.pose(), state.betas, state.translation).keypoints
    pixels, _ = data.project(keypoints)
    distance = (pixels - data.keypoints).norm(dim=-1) * data.visible  # [B, C, 21]
    residuals = []
    for name in FINGER_NAMES:
        index = list(_FINGER_KEYPOINTS[name])
        count = data.visible[:, index].sum().clamp_min(1.0)
        residuals.append(distance[..., index].sum((1, 2)) / count)
    return torch.stack(residuals, dim=-1)


def _restart_fingers(state: _Stage1State, fingers: Sequence[str]) -> _Stage1State:
    """``state`` (batch of one) followed by one copy per finger of ``fingers`` and named pose
    of :data:`_FINGER_STARTS`, with that finger's three joints set to the named pose's."""
    from ..handmodel.poses import named_pose

    rows = [state.fingers[0]]
    for finger in fingers:
        slots = [3 * (joint - 1) + axis for joint in FINGER_JOINTS[finger] for axis in range(3)]
        for name in _FINGER_STARTS:
            start = named_pose(name)[3:].to(state.fingers)
            row = state.fingers[0].clone()
            row[slots] = start[slots]
            rows.append(row)
    count = len(rows)

    def repeat(value: torch.Tensor) -> torch.Tensor:
        return value.expand(count, -1).clone()

    return _Stage1State(repeat(state.global_orient), torch.stack(rows),
                        repeat(state.translation), repeat(state.betas))


def fit_keypoints(
    views: Sequence[ImageView],
    config: FitImagesConfig | None = None,
    template: Any = None,
    progress: bool = False,
) -> PoseFit:
    """Stage 1: pose, translation and template betas from 2D keypoints and masks.

    views: the views (:func:`read_views`), at least one with keypoints or a mask; all tensors on
        one device (the fit's).
    template: the MANO-like template (:func:`lisa_hand.handmodel.template.load_template`, the
        default): ``forward(pose [B, 48], betas [B, K], translation [B, 3])`` with
        ``.vertices`` [B, V, 3] and ``.keypoints`` [B, 21, 3], and ``num_betas``.
    Returns :class:`PoseFit` (see the module docstring for the objective and the restarts).
    """
    config = FitImagesConfig() if config is None else config
    views = _check_views(views)
    device = views[0].rgb.device
    template = _template_on(template, device)
    generator = torch.Generator().manual_seed(config.seed)
    data = _ViewData(views, config, generator)
    relaxed = _relaxed_fingers(device)
    num_betas = int(template.num_betas)

    with torch.no_grad():
        rotations = _candidate_rotations(template, data, config, relaxed, generator)
    count = rotations.shape[0]
    fingers = relaxed.expand(count, -1).clone()
    betas = torch.zeros(count, num_betas, device=device)
    with torch.no_grad():
        posed = template.forward(torch.cat([rotations, fingers], dim=-1), betas, None)
        if data.num_visible:
            translation = _solve_translation(posed.keypoints, data)
        else:
            translation = _translation_from_masks(posed.vertices, data)
    state = _Stage1State(rotations.clone(), fingers, translation, betas)

    total_iters = config.keypoint_iters
    rigid_iters = int(round(config.rigid_fraction * total_iters))
    history: dict[str, list[float]] = {"kp_loss": [], "kp_px": []}
    bar = _progress_bar(progress, total_iters, "keypoints")

    def run(state: _Stage1State, iterations: int, rigid: bool) -> tuple[torch.Tensor,
                                                                        torch.Tensor]:
        free = [state.global_orient, state.translation]
        if not rigid:
            free += [state.fingers, state.betas]
        for value in free:
            value.requires_grad_(True)
        groups = [{"params": [state.global_orient], "lr": config.keypoint_pose_lr},
                  {"params": [state.translation], "lr": config.keypoint_translation_lr}]
        if not rigid:
            groups.append({"params": [state.fingers], "lr": config.keypoint_pose_lr})
            if config.keypoint_betas_lr > 0:
                groups.append({"params": [state.betas], "lr": config.keypoint_betas_lr})
        optimizer = torch.optim.Adam(groups)
        schedule = _decay(optimizer, iterations, config.final_lr_fraction)
        for _ in range(iterations):
            optimizer.zero_grad(set_to_none=True)
            loss, error = _stage1_objective(template, state, data, config, relaxed, rigid)
            loss.sum().backward()
            optimizer.step()
            schedule.step()
            best = int(loss.detach().argmin())
            history["kp_loss"].append(float(loss.detach()[best]))
            history["kp_px"].append(float(error[best]))
            if bar is not None:
                bar.update(1)
                bar.set_postfix(px=f"{float(error[best]):.2f}")
        for value in free:
            value.requires_grad_(False)
        with torch.no_grad():
            return _stage1_objective(template, state, data, config, relaxed, rigid)

    finger_iters = int(round(config.finger_restart_fraction * total_iters))
    loss, _ = run(state, rigid_iters, rigid=True)
    keep = min(config.keep_restarts, count)
    state = state.select(loss.argsort()[:keep])
    loss, error = run(state, total_iters - rigid_iters - finger_iters, rigid=False)
    best = int(loss.argmin())
    if finger_iters > 0:
        # The best candidate goes on, beside copies of it with each badly fitted finger
        # restarted from other poses (a finger bent the wrong way is a local minimum).
        state = state.select(torch.tensor([best], device=device))
        with torch.no_grad():
            bad = _finger_residuals(template, state, data)[0] > config.finger_restart_px
        state = _restart_fingers(state, [name for name, flag in zip(FINGER_NAMES, bad.tolist(),
                                                                     strict=True) if flag])
        loss, error = run(state, finger_iters, rigid=False)
        best = int(loss.argmin())
    if bar is not None:
        bar.close()
    return PoseFit(
        pose=state.pose()[best].detach().clone(),
        translation=state.translation[best].detach().clone(),
        betas=state.betas[best].detach().clone(),
        keypoint_error_px=float(error[best]),
        loss=float(loss[best]),
        candidate=best,
        history=history,
    )


# ------------------------------------------------------------------------------------------------
# Stage 2: pose, shape and colour with volume rendering


def _black_outside(view: ImageView) -> bool:
    """Whether the image is already black outside its mask (beyond a 2-pixel margin: the
    synthetic images and LISA's training images): then it is used as it is, soft edges
    included."""
    from scipy.ndimage import binary_dilation

    if view.mask is None:
        return False
    grown = binary_dilation(view.mask.cpu().numpy(), iterations=2)
    outside = view.rgb.cpu()[torch.from_numpy(~grown)]
    return outside.numel() == 0 or float(outside.max(dim=-1).values.quantile(0.99)) < 0.02


def fit_target(view: ImageView) -> torch.Tensor:
    """[H, W, 3] the colours the fit compares with: the image; with a mask, black outside it
    (pixels outside a mask are background, black as in the training images), unless the image
    is black there already (then its soft edges are kept)."""
    if view.mask is None or _black_outside(view):
        return view.rgb
    return view.rgb * view.mask[..., None]


def _background_colour(view: ImageView) -> torch.Tensor:
    """[3] the view's background: black with a mask (the training images' convention), else
    the median colour of the image border."""
    if view.mask is not None:
        return view.rgb.new_zeros(3)
    border = torch.cat([view.rgb[:_BORDER_PX].reshape(-1, 3), view.rgb[-_BORDER_PX:].reshape(-1, 3),
                        view.rgb[:, :_BORDER_PX].reshape(-1, 3),
                        view.rgb[:, -_BORDER_PX:].reshape(-1, 3)])
    return border.median(dim=0).values


class _RayPool:
    """Candidate rays of all views: the mask plus a band (or, without a mask, a box around the
    projected template), and the background pixels; drawn uniformly within each pool."""

    def __init__(self, views: Sequence[ImageView], config: FitImagesConfig,
                 boxes: Sequence[tuple[float, float, float, float] | None]) -> None:
        from scipy.ndimage import distance_transform_edt

        device = views[0].rgb.device
        world_from_pixel, centres, backgrounds = [], [], []
        near_parts, far_parts = [], []
        for index, (view, box) in enumerate(zip(views, boxes, strict=True)):
            height, width = view.height, view.width
            camera = view.camera
            world_from_pixel.append((camera.R.double().T @ torch.linalg.inv(camera.K.double()))
                                    .float())
            centres.append(camera.center.float())
            backgrounds.append(_background_colour(view))
            if view.mask is not None:
                mask = view.mask.cpu().numpy()
                distance = distance_transform_edt(~mask).reshape(-1)
                near = distance <= config.band_px
                in_mask = mask.reshape(-1)
                target = fit_target(view).reshape(-1, 3)
                has_mask = True
            else:
                columns = np.arange(width) + 0.5
                rows = np.arange(height) + 0.5
                inside_u = (columns >= box[0]) & (columns <= box[2])
                inside_v = (rows >= box[1]) & (rows <= box[3])
                near = (inside_v[:, None] & inside_u[None, :]).reshape(-1)
                in_mask = np.zeros(height * width, dtype=bool)
                target = view.rgb.reshape(-1, 3)
                has_mask = False
            for part, chosen in ((near_parts, near), (far_parts, ~near)):
                pixel = torch.from_numpy(np.flatnonzero(chosen)).to(device)
                part.append((torch.full_like(pixel, index), pixel, target[pixel],
                             torch.from_numpy(in_mask[chosen]).to(device),
                             torch.full(pixel.shape, has_mask, dtype=torch.bool, device=device)))
        self.world_from_pixel = torch.stack(world_from_pixel)  # [C, 3, 3]
        self.centre = torch.stack(centres)  # [C, 3]
        self.background = torch.stack(backgrounds)  # [C, 3]
        self.width = torch.tensor([v.width for v in views], device=device)
        self.near = [torch.cat(values) for values in zip(*near_parts, strict=True)]
        self.far = [torch.cat(values) for values in zip(*far_parts, strict=True)]

    def sample(self, num_rays: int, mask_fraction: float, generator: torch.Generator
               ) -> dict[str, torch.Tensor]:
        """-> origins, directions [R, 3]; target, background [R, 3]; in_mask, has_mask [R]."""
        num_near_pool, num_far_pool = self.near[0].numel(), self.far[0].numel()
        num_near = int(round(mask_fraction * num_rays)) if num_far_pool else num_rays
        if num_near_pool == 0:
            num_near = 0
        picks = []
        for pool, count, size in ((self.near, num_near, num_near_pool),
                                  (self.far, num_rays - num_near, num_far_pool)):
            if count:
                index = torch.randint(0, size, (count,), generator=generator)
                picks.append([value[index.to(value.device)] for value in pool])
        view, pixel, target, in_mask, has_mask = (torch.cat(v) for v in zip(*picks, strict=True))
        width = self.width[view]
        uv = torch.stack([(pixel % width).float() + 0.5,
                          torch.div(pixel, width, rounding_mode="floor").float() + 0.5], dim=-1)
        homogeneous = torch.cat([uv, torch.ones_like(uv[:, :1])], dim=-1)
        directions = (self.world_from_pixel[view] @ homogeneous[..., None])[..., 0]
        directions = directions / directions.norm(dim=-1, keepdim=True)
        return {"origins": self.centre[view], "directions": directions, "target": target,
                "background": self.background[view], "in_mask": in_mask,
                "has_mask": has_mask}


@contextlib.contextmanager
def _frozen(module: torch.nn.Module) -> Iterator[None]:
    """Freeze a module's parameters (no weight gradients are computed) and restore them."""
    flags = [(p, p.requires_grad) for p in module.parameters()]
    for parameter, _ in flags:
        parameter.requires_grad_(False)
    try:
        yield
    finally:
        for parameter, flag in flags:
            parameter.requires_grad_(flag)


def _template_boxes(template: Any, views: Sequence[ImageView], pose: torch.Tensor,
                    translation: torch.Tensor, betas: torch.Tensor, margin: float
                    ) -> list[tuple[float, float, float, float] | None]:
    """For each view without a mask: the box (u0, v0, u1, v1) pixels around the projected
    template, grown by ``margin`` of its size on each side."""
    boxes: list[tuple[float, float, float, float] | None] = []
    with torch.no_grad():
        vertices = template.forward(pose[None], betas[None], translation[None]).vertices[0]
    for view in views:
        if view.mask is not None:
            boxes.append(None)
            continue
        pixels, _ = view.camera.project(vertices)
        low, high = pixels.amin(0), pixels.amax(0)
        grow = margin * (high - low)
        low, high = (low - grow).tolist(), (high + grow).tolist()
        boxes.append((low[0], low[1], high[0], high[1]))
    return boxes


def fit_color(
    model: Any,
    views: Sequence[ImageView],
    start: PoseFit,
    config: FitImagesConfig | None = None,
    template: Any = None,
    progress: bool = False,
) -> tuple[dict[str, torch.Tensor], dict[str, list[float]]]:
    """Stage 2: pose, translation, betas, shape and colour codes from the colour loss.

    model: a :class:`lisa_hand.trained.TrainedModel` with colour, on the views' device.
    views: as for :func:`fit_keypoints`; start: stage 1's result (its pose, translation, betas).
    -> ({"pose" [48], "translation" [3], "betas" [K], "shape_code" [D], "color_code" [D'],
    "rest_joints" [16, 3]}, history).
    """
    from ..model.lisa import region_bounds
    from ..render.renderer import calibrate

    config = FitImagesConfig() if config is None else config
    views = _check_views(views)
    if not model.has_color:
        raise ValueError(f"model {model.source}: it has no colour (a geometry-only prior); "
                         "fitting to images needs a model trained on images (lisa train)")
    device = views[0].rgb.device
    template = _template_on(template, device)
    field_model = model.field
    generator = torch.Generator().manual_seed(config.seed + 1)
    render_generator = torch.Generator(device=device).manual_seed(config.seed + 2)
    data = _ViewData(views, config, generator)
    relaxed = _relaxed_fingers(device)
    pool = _RayPool(views, config, _template_boxes(template, views, start.pose.to(device),
                                                   start.translation.to(device),
                                                   start.betas.to(device),
                                                   config.no_mask_margin))
    density = LaplaceDensity(beta_init=float(model.beta), beta_min=0.0).to(device)
    density.requires_grad_(False)
    gain, bias = model.gain.to(device).float(), model.bias.to(device).float()

    pose = start.pose.to(device).clone().requires_grad_(True)
    translation = start.translation.to(device).clone().requires_grad_(True)
    betas = start.betas.to(device).clone().requires_grad_(config.color_betas_lr > 0)
    shape_code = model.mean_shape_code().to(device).float().clone().requires_grad_(True)
    color_code = model.mean_color_code().to(device).float().clone().requires_grad_(True)
    groups = [{"params": [pose], "lr": config.color_pose_lr},
              {"params": [translation], "lr": config.color_translation_lr},
              {"params": [shape_code, color_code], "lr": config.latent_lr}]
    if config.color_betas_lr > 0:
        groups.append({"params": [betas], "lr": config.color_betas_lr})
    optimizer = torch.optim.Adam(groups)
    schedule = _decay(optimizer, config.color_iters, config.final_lr_fraction)
    history: dict[str, list[float]] = {k: [] for k in ("total", "col", "reg", "joints", "mask",
                                                       "kp_px")}
    bar = _progress_bar(progress, config.color_iters, "colour")
    with _frozen(field_model):
        for _ in range(config.color_iters):
            optimizer.zero_grad(set_to_none=True)
            rest_joints = template.rest_joints(betas[None])
            state = field_model.prepare(pose[None], translation[None], rest_joints,
                                        shape_code[None], color_code[None])
            low, high = region_bounds(state, field_model)
            rays = pool.sample(config.num_rays, config.mask_fraction, generator)
            near, far, hit = ray_box_bounds(rays["origins"], rays["directions"], low[0],
                                            high[0])
            hit = hit & (far > near)
            out = render_rays(field_model.field_fn(state), field_model.sdf_fn(state),
                              rays["origins"], rays["directions"], near, far, config.render,
                              density, hit=hit, background=gain.new_zeros(3),
                              generator=render_generator)
            prediction = calibrate(out.rgb, out.opacity, gain, bias, rays["background"])
            terms = {"col": color_loss(prediction, rays["target"]),
                     "reg": latent_loss(shape_code[None], color_code[None])}
            posed = template.forward(pose[None], betas[None], translation[None])
            pixels, _ = data.project(posed.keypoints)
            terms["joints"] = (_keypoint_l1(pixels, data)
                               + _prior_terms(pose[None], betas[None], config, relaxed))[0]
            has_mask = rays["has_mask"]
            if config.lambda_mask > 0 and bool(has_mask.any()):
                opacity = out.opacity[has_mask].clamp(1e-5, 1.0 - 1e-5)
                terms["mask"] = F.binary_cross_entropy(opacity,
                                                       rays["in_mask"][has_mask].float())
            else:
                terms["mask"] = prediction.new_zeros(())
            total = (config.lambda_col * terms["col"] + config.lambda_reg * terms["reg"]
                     + config.lambda_joints * terms["joints"] + config.lambda_mask * terms["mask"])
            total.backward()
            optimizer.step()
            schedule.step()
            history["total"].append(float(total.detach()))
            for name, value in terms.items():
                history[name].append(float(value.detach()))
            history["kp_px"].append(float(_keypoint_px(pixels.detach(), data)[0]))
            if bar is not None:
                bar.update(1)
                bar.set_postfix(col=f"{history['col'][-1]:.4f}")
    if bar is not None:
        bar.close()
    with torch.no_grad():
        rest_joints = template.rest_joints(betas[None])[0]
    return {"pose": pose.detach(), "translation": translation.detach(), "betas": betas.detach(),
            "shape_code": shape_code.detach(), "color_code": color_code.detach(),
            "rest_joints": rest_joints.detach()}, history


# ------------------------------------------------------------------------------------------------
# The whole fit


def _check_views(views: Sequence[ImageView]) -> list[ImageView]:
    views = list(views)
    if not views:
        raise ValueError("views is empty: at least one view is needed")
    for index, view in enumerate(views):
        if not isinstance(view, ImageView):
            raise TypeError(f"views[{index}] must be an ImageView, got {type(view).__name__}")
    if not any(view.mask is not None or view.has_keypoints for view in views):
        raise ValueError("no view has a mask or keypoints: the hand cannot be located")
    return views


def keypoint_errors(template: Any, views: Sequence[ImageView], pose: torch.Tensor,
                    translation: torch.Tensor, betas: torch.Tensor) -> dict[str, float]:
    """Mean reprojection error (pixels) of the template's keypoints in each view with keypoints.

    pose [48] rad, translation [3] m, betas [K] -> {view name: mean px over visible keypoints}.
    """
    with torch.no_grad():
        keypoints = template.forward(pose[None], betas[None], translation[None]).keypoints[0]
    errors = {}
    for view in views:
        if not view.has_keypoints:
            continue
        pixels, _ = view.camera.project(keypoints.to(view.camera.K))
        distance = (pixels - view.keypoints).norm(dim=-1)[view.visible]
        errors[view.name] = float(distance.mean())
    return errors


def mirror_view(view: ImageView) -> ImageView:
    """The view of the mirrored world (x -> -x, :func:`lisa_hand.skeleton.mirror_points`),
    where a left hand is a right one: the image, mask and keypoints flipped left-right and the
    camera ``K' = K`` with ``cx' = W - cx`` and the skew negated, ``R' = F R M``, ``t' = F t``
    (``M = F = diag(-1, 1, 1)``; ``R'`` is a rotation again). A point ``X`` seen at pixel
    ``(u, v)`` has its mirror ``M X`` seen at ``(W - u, v)``."""
    camera = view.camera
    flip = torch.diag(camera.K.new_tensor([-1.0, 1.0, 1.0]))
    intrinsics = camera.K.clone()
    intrinsics[0, 1] = -camera.K[0, 1]
    intrinsics[0, 2] = camera.width - camera.K[0, 2]
    mirrored = Camera(K=intrinsics, R=flip @ camera.R @ flip, t=flip @ camera.t,
                      width=camera.width, height=camera.height, name=camera.name)
    keypoints = None
    if view.keypoints is not None:
        keypoints = view.keypoints.clone()
        keypoints[:, 0] = torch.where(view.visible, camera.width - keypoints[:, 0],
                                      keypoints[:, 0])
    return ImageView(name=view.name, camera=mirrored, rgb=view.rgb.flip(1),
                     mask=None if view.mask is None else view.mask.flip(1),
                     keypoints=keypoints, visible=view.visible)


def _mirror_params(params: HandParams) -> HandParams:
    """A right hand fitted in the mirrored world as the left hand of the real one."""
    from ..skeleton import mirror_points, mirror_pose

    return dataclasses.replace(params, pose=mirror_pose(params.pose),
                               translation=mirror_points(params.translation),
                               rest_joints=mirror_points(params.rest_joints), side="left")


def fit_images(
    model: Any,
    views: Sequence[ImageView],
    config: FitImagesConfig | None = None,
    progress: bool = False,
    *,
    template: Any = None,
    start: PoseFit | None = None,
) -> FitImagesResult:
    """Fit LISA to calibrated views: stage 1 then stage 2 (see the module docstring).

    model: a :class:`lisa_hand.trained.TrainedModel` with colour (its device is the fit's; the
        views are moved there). A geometry-only model needs ``color_iters=0``.
    views: from :func:`read_views`.
    config: :class:`FitImagesConfig` (default: the CPU-friendly defaults).
    progress: show a progress bar per stage.
    template: the mesh template (default: :func:`lisa_hand.handmodel.template.load_template`).
    start: a stage-1 result of these views (:func:`fit_keypoints`, which depends on the views
        and the template only) to skip stage 1 and reuse it, e.g. for several models.
    -> :class:`FitImagesResult`; ``params.model`` is ``model.source``. A left hand
    (``config.side``) is fitted as the right hand of the mirrored views (:func:`mirror_view`)
    and returned mirrored back (``params.side == "left"``).
    """
    config = FitImagesConfig() if config is None else config
    if not isinstance(config, FitImagesConfig):
        raise TypeError(f"config must be a FitImagesConfig, got {type(config).__name__}")
    views = _check_views(views)
    if config.color_iters > 0 and not model.has_color:
        raise ValueError(f"model {model.source}: it has no colour (a geometry-only prior); "
                         "fitting to images needs a model trained on images (lisa train), or "
                         "color_iters=0")
    device = model.device
    views = [view.to(device) for view in views]
    if config.side == "left":
        views = [mirror_view(view) for view in views]
    template = _template_on(template, device)
    start_time = time.perf_counter()
    with cpu_threads(config.num_threads):
        pose_fit = fit_keypoints(views, config, template, progress) if start is None else start
        stage1 = time.perf_counter() - start_time
        history = dict(pose_fit.history)
        if config.color_iters > 0:
            fitted, color_history = fit_color(model, views, pose_fit, config, template,
                                              progress)
            history.update({("color_kp_px" if k == "kp_px" else k): v
                            for k, v in color_history.items()})
    if config.color_iters == 0:
        with torch.no_grad():
            rest = template.rest_joints(pose_fit.betas[None].to(device))[0]
        fitted = {"pose": pose_fit.pose, "translation": pose_fit.translation,
                  "betas": pose_fit.betas, "shape_code": model.mean_shape_code(),
                  "color_code": model.mean_color_code(), "rest_joints": rest}
    seconds = time.perf_counter() - start_time
    per_view = keypoint_errors(template, views, fitted["pose"], fitted["translation"],
                               fitted["betas"])
    errors = {"keypoints": pose_fit.keypoint_error_px,
              "color": float(np.mean(list(per_view.values()))) if per_view else math.nan}
    params = HandParams(
        pose=fitted["pose"].cpu(),
        translation=fitted["translation"].cpu(),
        rest_joints=fitted["rest_joints"].cpu(),
        shape_code=fitted["shape_code"].cpu(),
        color_code=None if fitted["color_code"] is None else fitted["color_code"].cpu(),
        betas=fitted["betas"].cpu(),
        side="right",
        model=str(model.source),
        extra={
            "fit": "images",
            "views": [view.name for view in views],
            "seconds": seconds,
            "seconds_keypoints": stage1,
            "seconds_color": seconds - stage1,
            "keypoint_iters": config.keypoint_iters,
            "color_iters": config.color_iters,
            "keypoint_error_px_stage1": errors["keypoints"],
            "keypoint_error_px": errors["color"],
            "keypoint_error_px_per_view": per_view,
            "restart": pose_fit.candidate,
        },
    )
    if config.side == "left":
        params = _mirror_params(params)
    return FitImagesResult(params=params, history=history, seconds=seconds,
                           stage_seconds={"keypoints": stage1, "color": seconds - stage1},
                           keypoint_error_px=errors)


# ------------------------------------------------------------------------------------------------
# Evaluation: re-rendered input views


@dataclass
class ViewRender:
    """A fitted hand rendered into one input view.

    name: the view. rgb: [H, W, 3] in [0, 1] (calibrated, over the view's background).
    opacity: [H, W]. target: [H, W, 3] what the fit compared with (:func:`fit_target`).
    mask: [H, W] bool or None.
    """

    name: str
    rgb: torch.Tensor
    opacity: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor | None


def render_fitted_views(model: Any, params: HandParams, views: Sequence[ImageView],
                        samples: int = 32) -> list[ViewRender]:
    """Render the fitted hand into every view with the model's mean colour calibration
    (:func:`lisa_hand.inference.prepare_render`: VolSDF, one occupancy grid for all views),
    over each view's background (black with a mask, else the border's median colour).

    samples: samples per ray in the band around the surface (32: as ``lisa render``). Runs
    under ``torch.no_grad``.
    """
    from ..inference import hand_render_config, prepare_render

    config = hand_render_config(model, normals="none", render=RenderConfig(
        sampler="sphere_traced", num_samples=samples, num_samples_extra=0))
    scene = prepare_render(model, params, config)
    results = []
    for view in views:
        background = tuple(float(c) for c in _background_colour(view))
        view_scene = dataclasses.replace(scene, config=dataclasses.replace(
            config, background=background))
        with torch.no_grad():
            image = view_scene.render(view.camera)
        results.append(ViewRender(name=view.name, rgb=image.rgb.clamp(0.0, 1.0).cpu(),
                                  opacity=image.opacity.cpu(), target=fit_target(view).cpu(),
                                  mask=None if view.mask is None else view.mask.cpu()))
    return results


def view_psnrs(renders: Sequence[ViewRender]) -> dict[str, Any]:
    """PSNR (dB, :func:`lisa_hand.metrics.psnr`) of re-rendered views against what the fit
    compared with: per view over the whole image ("psnr_db") and inside the mask
    ("psnr_mask_db"), and their means over the views (NaN without masks)."""
    from ..metrics import psnr

    per_view: dict[str, dict[str, float]] = {}
    whole, masked = [], []
    for render in renders:
        entry = {"psnr_db": psnr(render.rgb.numpy(), render.target.numpy())}
        whole.append(entry["psnr_db"])
        if render.mask is not None:
            entry["psnr_mask_db"] = psnr(render.rgb.numpy(), render.target.numpy(),
                                         render.mask.numpy())
            masked.append(entry["psnr_mask_db"])
        per_view[render.name] = entry
    return {"psnr_db": float(np.mean(whole)) if whole else math.nan,
            "psnr_mask_db": float(np.mean(masked)) if masked else math.nan,
            "views": per_view}


# ------------------------------------------------------------------------------------------------
# From a frame folder to a fitted hand on disk (``lisa fit-images``)


@dataclass
class FitImagesReport:
    """What :func:`fit_image_folder` did.

    fit: the :class:`FitImagesResult`. mesh: the fitted surface (colours, skinning weights).
    metrics: what ``metrics.json`` holds: keypoint errors (px), PSNR of the re-rendered input
    views (dB; whole image and inside the masks), timings and, with a ground truth, the four
    distances (mm). written: the files written, in order. notes: sentences about fallbacks
    that were used (missing masks or keypoints).
    """

    fit: FitImagesResult
    mesh: Any
    metrics: dict[str, Any]
    written: list[Path]
    notes: list[str]


def input_notes(views: Sequence[ImageView]) -> list[str]:
    """One sentence per fallback the views will use (see the module docstring)."""
    notes = []
    no_mask = [view.name for view in views if view.mask is None]
    no_keypoints = [view.name for view in views if not view.has_keypoints]
    if no_keypoints and len(no_keypoints) == len(views):
        notes.append("no keypoints: the pose comes from the masks alone (restarts over "
                     "rotations); expect a less reliable fit, above all with one view")
    elif no_keypoints:
        notes.append(f"no keypoints for view(s) {', '.join(no_keypoints)}: their masks and "
                     "colours are used")
    if no_mask:
        notes.append(f"no mask for view(s) {', '.join(no_mask)}: their rays cover the box "
                     "around the projected hand and their background colour is the image "
                     "border's median")
    return notes


def fit_image_folder(
    frame_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    views: Sequence[str] | None = None,
    model_path: str | os.PathLike | None = None,
    gt_path: str | os.PathLike | None = None,
    units: str = "auto",
    resolution: int = 128,
    config: FitImagesConfig | None = None,
    device: str = "auto",
    psnr: bool = True,
    progress: bool = False,
    log: Any = None,
) -> FitImagesReport:
    """Read a frame folder, fit the model, write ``params.json``, ``mesh.ply`` and
    ``metrics.json`` into ``out_dir`` (all or nothing, :func:`write_fit_outputs`).

    Every input is checked before the fit (views, ground truth, model, output folder).
    frame_dir: :func:`read_views`'s folder; views: camera names to use (default: all).
    model_path: a trained model (:func:`lisa_hand.trained.load_trained`; None: the shipped one).
    gt_path: a ground-truth mesh or points; units: its unit ("auto", "m", "mm").
    resolution: marching-cubes samples a side of the mesh. config: :class:`FitImagesConfig`.
    device: "auto", "cpu", "cuda" or "cuda:N". psnr: re-render the input views for the PSNR.
    log: called with one line per note (fallbacks, unit guesses).
    """
    from .outputs import prepare_fit

    log = log or (lambda line: None)
    config = FitImagesConfig() if config is None else config
    frame_dir, out_dir = Path(frame_dir), Path(out_dir)
    image_views = read_views(frame_dir, views)
    notes = input_notes(image_views)
    for note in notes:
        log(note)
    truth, model = prepare_fit(out_dir, gt_path, units, model_path, device, log)

    fit = fit_images(model, image_views, config, progress)
    params = fit.params
    params.model = "default" if model_path is None else str(Path(model_path).resolve())
    params.extra["input"] = {"path": str(frame_dir), "notes": notes}
    with cpu_threads(config.num_threads):
        return _finish_folder(model, fit, image_views, out_dir, truth, resolution, psnr, notes)


def _finish_folder(model: Any, fit: FitImagesResult, image_views: Sequence[ImageView],
                   out_dir: Path, truth: Any, resolution: int, psnr: bool,
                   notes: list[str]) -> FitImagesReport:
    """Mesh, metrics and files of :func:`fit_image_folder`."""
    from ..inference import mesh_hand
    from .outputs import ground_truth_metrics, write_fit_outputs

    params = fit.params
    mesh_start = time.perf_counter()
    mesh = mesh_hand(model, params, resolution)
    metrics: dict[str, Any] = {
        "views": [view.name for view in image_views],
        "keypoint_error_px": fit.keypoint_error_px["color"],
        "keypoint_error_px_stage1": fit.keypoint_error_px["keypoints"],
        "keypoint_error_px_per_view": params.extra["keypoint_error_px_per_view"],
        "seconds_fit": fit.seconds,
        "seconds_keypoints": fit.stage_seconds["keypoints"],
        "seconds_color": fit.stage_seconds["color"],
        "seconds_mesh": time.perf_counter() - mesh_start,
    }
    if psnr:
        render_start = time.perf_counter()
        scores = view_psnrs(render_fitted_views(model, params, image_views))
        metrics.update(psnr_db=scores["psnr_db"], psnr_mask_db=scores["psnr_mask_db"],
                       psnr_per_view=scores["views"],
                       seconds_render=time.perf_counter() - render_start)
    if truth is not None:
        metrics.update(ground_truth_metrics(mesh, truth))
        metrics["ground_truth"] = str(truth.path)
    written = write_fit_outputs(out_dir, params, mesh, metrics)
    return FitImagesReport(fit=fit, mesh=mesh, metrics=metrics, written=written, notes=notes)
