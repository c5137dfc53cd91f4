"""Settings of the image fit (:class:`FitImagesConfig`), shared by its stages.

Names follow the fitters' common scheme (:class:`lisa_hand.fitting.points.config.
FitPointsConfig` and :class:`lisa_hand.fitting.photo.config.FitPhotoConfig` too):
``<term>_weight`` for the weight of a loss term, ``pose_weight`` / ``limit_weight`` /
``betas_weight`` for the priors of :mod:`lisa_hand.fitting.priors`, ``shape_weight`` for the
shape code's Gaussian prior, ``prior_pose`` for the finger prior's mean, ``<stage>_iters`` for
the iterations of a stage, ``<unknown>_lr`` for a learning rate (``<stage>_<unknown>_lr`` when
a stage has its own), ``final_lr_fraction`` for where the rates' decay ends, ``restarts`` for
the candidates optimised, ``num_threads``, ``device`` and ``seed``. Renamed fields are listed
in :attr:`FitImagesConfig.RENAMED` (an old name is refused naming the new one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from ...render import RenderConfig
from ...utils.config import check_int_fields
from ..pair.config import JointConfig
from ..priors import PRIOR_POSES

__all__ = ["IMAGE_STAGES", "SHAPE_FITS", "FitImagesConfig", "default_render"]

SHAPE_FITS = ("space", "free", "fixed")
"""Values of :attr:`FitImagesConfig.shape_fit`."""


def default_render() -> RenderConfig:
    """The colour stage's ray sampling: a band of 16 samples around the sphere-traced surface
    (16 tracing steps) + 8 uniform ones, stratified."""
    return RenderConfig(sampler="sphere_traced", num_samples=16, num_samples_extra=8,
                        sphere_num_steps=16, stratified=True)


IMAGE_STAGES = ("keypoints", "color", "guard")
"""The image fit's stages in the one order they may run."""


@dataclass(frozen=True)
class FitImagesConfig:
    """Settings of :func:`lisa_hand.fitting.images.fit.fit_images` (defaults: about 1-2 minutes on
    2 CPU cores)."""

    RENAMED: ClassVar[dict[str, str]] = {"latent_lr": "code_lr", "latent_weight": "code_weight",
                                         "shape_prior_weight": "shape_weight"}
    """Former field names -> the present ones (:func:`lisa_hand.utils.config.renamed_field`)."""

    stages: tuple[str, ...] = IMAGE_STAGES
    """The stages that run, in order (:mod:`lisa_hand.fitting.images.fit`): 'keypoints', then
    optionally 'color', then optionally 'guard' (which judges the colour stage's surface)."""
    keypoint_iters: int = 400
    """Keypoint stage iterations (pose from keypoints and masks; the paper uses 1000)."""
    color_iters: int = 300
    """Colour stage iterations (pose, shape and colour; the paper uses 5000). 0 skips it."""
    num_rays: int = 512
    """Colour stage: camera rays rendered per iteration, over all views."""
    mask_fraction: float = 0.9
    """Colour stage: fraction of the rays through the mask and the band around it (the rest
    through the background)."""
    band_px: int = 4
    """Colour stage: width of the band around the mask, pixels."""
    no_mask_margin: float = 0.15
    """Colour stage, views without a mask: rays are drawn in the box around the projected
    template grown by this fraction of its size on each side."""
    render: RenderConfig = field(default_factory=default_render)
    """Colour stage: ray sampling (VolSDF; default: :func:`default_render`)."""
    rotation_pool: int = 2048
    """Keypoint stage: random global rotations scored (without optimisation) to choose the
    restarts."""
    restarts: int = 12
    """Keypoint stage: the best-scoring rotations of the pool that are optimised (rigidly
    first)."""
    restart_separation_deg: float = 20.0
    """Keypoint stage: the restarts differ by at least this angle, degrees."""
    keep_restarts: int = 3
    """Keypoint stage: candidates kept after the rigid phase."""
    rigid_fraction: float = 0.3
    """Keypoint stage: fraction of the iterations with only rotation and translation free."""
    finger_restart_fraction: float = 0.25
    """Keypoint stage: fraction of the iterations, at the end, in which every finger whose
    keypoints are off by more than ``finger_restart_px`` is also restarted from the flat,
    relaxed and fist poses (the best of these and of the unchanged hand wins)."""
    depth_factors: tuple[float, ...] = (0.71, 0.84, 1.19, 1.41)
    """Keypoint stage, one view: the best candidate is also restarted at these multiples of its
    distance from the camera (moved along the ray through its keypoints' centre; ``2^(k/4)``,
    k = -2, -1, 1, 2), and the lowest objective without the silhouette terms wins (the
    unmoved hand, as it was, when it ranks first). One view leaves the depth to the priors and
    the silhouette, and the fit can stop at a depth the objective does not prefer (centimetres
    off, the keypoints still matched to a fraction of a pixel). () turns it off."""
    depth_restart_fraction: float = 0.2
    """Keypoint stage, one view: the depth restarts (``depth_factors``) take this fraction of
    ``keypoint_iters`` more iterations, before the finger restarts."""
    finger_restart_px: float = 0.0
    """Keypoint stage: mean error (pixels) of a finger's visible keypoints that triggers its
    restart. 0 (the default) restarts every finger: one that fits its keypoints to the pixel can
    still be bent the wrong way in depth, and restarting every finger costs about a second a
    fit."""
    keypoint_pose_lr: float = 0.03
    """Keypoint stage: Adam learning rate of the pose, radians."""
    keypoint_translation_lr: float = 0.005
    """Keypoint stage: Adam learning rate of the translation, metres."""
    keypoint_betas_lr: float = 0.05
    """Keypoint stage: Adam learning rate of the template's betas."""
    color_pose_lr: float = 0.004
    """Colour stage: Adam learning rate of the pose, radians."""
    color_translation_lr: float = 0.0005
    """Colour stage: Adam learning rate of the translation, metres."""
    color_betas_lr: float = 0.0
    """Colour stage: Adam learning rate of the betas (0, the default: the skeleton stays the
    keypoint stage's; the keypoints are its only evidence, and with the colour stage's small
    keypoint weight Adam lets it drift toward the priors)."""
    code_lr: float = 0.01
    """Colour stage: Adam learning rate of the codes: the colour code's, and the shape code's
    with ``shape_fit="free"`` (with "space" the shape's is ``shape_lr``)."""
    shape_fit: str = "space"
    """Colour stage: how the shape code is fitted. "space": the coefficients of the top
    ``shape_dims`` principal directions of the model's training codes, in standard deviations,
    clamped to the training codes' range along each direction (widened by
    ``shape_range_margin``), with the Gaussian prior ``shape_weight * 0.5 |c|^2``
    (:class:`lisa_hand.fitting.images.shape_prior.ShapeSpace`); "free": every dimension (the
    paper; on real photos it can break the surface into lumps and floaters); "fixed": kept at
    the start (the mean code)."""
    shape_dims: int = 20
    """Colour stage, ``shape_fit="space"``: principal directions used (at most S - 1 for S
    training subjects)."""
    shape_range_margin: float = 0.0
    """Colour stage, ``shape_fit="space"``: standard deviations added on both sides of the
    training codes' range along each direction (0: never beyond the most extreme training
    subject; the shipped model's first direction breaks into pieces at +3)."""
    shape_lr: float = 0.05
    """Colour stage, ``shape_fit="space"``: Adam learning rate of the shape code's coefficients
    (standard deviations; with "free" the shape code's rate is ``code_lr``)."""
    shape_weight: float = 1e-3
    """Colour stage, ``shape_fit="space"``: weight of the shape code's Gaussian prior
    ``0.5 |c|^2`` (the squared Mahalanobis distance of the code to the training codes' mean,
    halved), beside ``code_weight``'s norm of both codes."""
    final_lr_fraction: float = 0.1
    """The learning rates fall to this fraction of their value over each stage (a cosine,
    :func:`lisa_hand.fitting.optim.lr_schedule`)."""
    silhouette_weight: float = 0.2
    """Keypoint stage: weight of the mean outside-mask distance of the projected template
    vertices (pixels)."""
    coverage_weight: float = 0.1
    """Keypoint stage: weight of the mean distance from mask contour pixels to the nearest
    projected template vertex (pixels)."""
    landmark_weight: float = 100.0
    """Keypoint stage: weight of the bones' misfit against the detector's 3D landmarks, where a
    view has them (:attr:`lisa_hand.fitting.images.views.ImageView.landmarks_3d`;
    :func:`lisa_hand.fitting.images.terms.direction_misfit`, unitless, against the keypoints'
    pixels): which way each finger bends in depth, which one view leaves open."""
    coverage_pixels: int = 64
    """Keypoint stage: mask contour pixels per view for the coverage term (chosen once,
    seeded)."""
    coverage_vertices: int = 256
    """Keypoint stage: template vertices (a fixed random subset) for the coverage term."""
    limit_weight: float = 100.0
    """Weight of the squared excess over the joint limits (radians^2, summed over joints;
    :func:`lisa_hand.fitting.priors.joint_limit_excess`)."""
    pose_weight: float = 0.2
    """Weight of the mean squared finger-pose difference from ``prior_pose`` (radians^2;
    :func:`lisa_hand.fitting.priors.finger_pose_prior`)."""
    prior_pose: str = "relaxed"
    """Mean of the finger-pose prior: a name of :data:`lisa_hand.fitting.priors.PRIOR_POSES`."""
    betas_weight: float = 0.5
    """Weight of the mean squared template betas."""
    size_weight: float = 0.05
    """Weight of the hand-size prior ``(21 / n) ((size - mean) / std)^2`` (``n`` visible
    keypoints over all views), the summed bone length of the template's skeleton against the
    training subjects' (0.725 +- 0.045 m;
    :class:`lisa_hand.fitting.images.shape_prior.HandSizePrior`), both stages. One view cannot
    tell a large hand far away from a small one nearby: the prior and the betas' prior set its
    depth. 0.05 = b / 42: the Gaussian prior beside the keypoints' Laplace likelihood of scale
    b = 2 px."""
    rgb_weight: float = 1.0
    """Colour stage: weight of L_col (L1 over RGB per ray, Eq. 13)."""
    code_weight: float = 1e-3
    """Colour stage: weight of the paper's latent term L_reg = |beta+|_2 + |gamma|_2 (Eq. 16),
    the norms of the shape code and of the colour code."""
    joints_weight: float = 1e-2
    """Colour stage: weight of the keypoint loss (pixels) and its priors (the joint loss)."""
    mask_weight: float = 0.0
    """Colour stage: weight of the opacity/mask BCE (not in the paper; 0 turns it off)."""
    view_calibration: bool = True
    """Colour stage: fit each input view's colour response (a per-channel gain and bias relative
    to the model's mean calibration, :class:`lisa_hand.fitting.images.calibration.ViewCalibration`)
    beside the colour code, so that the code does not absorb the input cameras' responses (not
    in the paper; False: every view with the model's mean calibration; only with at least
    ``view_calibration_min_views`` views)."""
    view_calibration_min_views: int = 2
    """Colour stage, ``view_calibration``: fit the responses only with at least this many views.
    One view's response cannot be told from the hand's colour: fitted from one view, it makes
    both the novel views and the surface worse; from two views on it helps."""
    view_gain_std: float = 0.087
    """Colour stage, ``view_calibration``: the spread of the cameras' gains (unitless) the
    per-view gains are measured in (0.087: a gain uniform in 1 +- 0.15, ``lisa synth``'s)."""
    view_bias_std: float = 0.029
    """Colour stage, ``view_calibration``: the spread of the cameras' biases (colour units,
    [0, 1] scale; 0.029: uniform in +- 0.05, ``lisa synth``'s)."""
    view_calibration_lr: float = 0.03
    """Colour stage, ``view_calibration``: Adam learning rate of the per-view gains and biases,
    in standard deviations (``view_gain_std``, ``view_bias_std``)."""
    view_calibration_weight: float = 1e-3
    """Colour stage, ``view_calibration``: weight of their Gaussian prior
    ``0.5 mean_v |z_v|^2`` (``z``: the gains' and biases' offsets in standard deviations)."""
    guard: bool = True
    """After the colour stage, mesh the hand (``guard_resolution``) and compare it with the
    colour stage's start (:func:`lisa_hand.fitting.images.guard.surface_guard`); when it has
    more pieces or its area changed by more than ``max_area_change``, shrink its change of pose
    and shape (``guard_shrink``), then fit again with the shape code and the skeleton fixed
    (pose and colour only), and if that fails too, keep the start's geometry. What happened is
    in the result's ``guard`` and notes."""
    guard_shrink: tuple[float, ...] = (0.5, 0.25)
    """Fractions of the colour stage's change of pose, translation, shape code and skeleton
    tried in order (colour kept; meshing only, no refit) when it fails the guard; () goes
    straight to the pose-and-colour refit."""
    guard_resolution: int = 128
    """Marching-cubes samples a side of the guard's meshes: that of the written mesh
    (``lisa fit-images --res``, default 128, about 1.7 mm voxels, ~2 s a mesh on one CPU
    thread). Coarser grids miss floaters: one that is clear at 128 can shrink to a speck at 96
    and vanish at 64."""
    max_area_change: float = 0.10
    """The guard's largest allowed relative change of the surface area."""
    joint: JointConfig = field(default_factory=JointConfig)
    """Several hands (of one photo, or seen by the same cameras): each fitted alone, then all
    together (:class:`lisa_hand.fitting.pair.config.JointConfig`; ``joint.iters=0``: alone
    only)."""
    num_threads: int | None = 1
    """CPU threads of torch during the fit (restored afterwards); None keeps torch's setting.
    The fit runs many small operations: on a busy 2-core machine one thread is 2x (colour
    stage) to 10x (keypoint stage) faster than two."""
    device: str | None = None
    """Where to fit ('cpu', 'cuda', 'cuda:1', ...); None: the model's device."""
    seed: int = 0
    """Seed of every random choice (restarts, rays, stratified samples)."""

    def __post_init__(self) -> None:
        if self.stages not in (IMAGE_STAGES[:1], IMAGE_STAGES[:2], IMAGE_STAGES):
            raise ValueError(f"stages must be one of {IMAGE_STAGES[:1]}, {IMAGE_STAGES[:2]} or "
                             f"{IMAGE_STAGES}, got {self.stages!r}")
        check_int_fields(self, ("keypoint_iters", "color_iters", "band_px", "coverage_pixels",
                                "coverage_vertices", "seed"), 0)
        check_int_fields(self, ("num_rays", "rotation_pool", "restarts", "keep_restarts",
                                "shape_dims", "view_calibration_min_views"), 1)
        check_int_fields(self, ("guard_resolution",), 8)
        for name in ("mask_fraction", "rigid_fraction", "finger_restart_fraction",
                     "depth_restart_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if self.rigid_fraction + self.finger_restart_fraction > 1.0:
            raise ValueError(f"rigid_fraction + finger_restart_fraction must be <= 1, got "
                             f"{self.rigid_fraction} + {self.finger_restart_fraction}")
        factors = self.depth_factors
        if not isinstance(factors, tuple) or not all(
                isinstance(value, (int, float)) and not isinstance(value, bool)
                and math.isfinite(value) and value > 0 for value in factors):
            raise ValueError(f"depth_factors must be a tuple of positive numbers, got "
                             f"{factors!r}")
        if not 0.0 < self.final_lr_fraction <= 1.0:
            raise ValueError(f"final_lr_fraction must be in (0, 1], got "
                             f"{self.final_lr_fraction!r}")
        shrink = self.guard_shrink
        if not isinstance(shrink, tuple) or not all(
                isinstance(value, (int, float)) and not isinstance(value, bool)
                and 0.0 <= value < 1.0 for value in shrink):
            raise ValueError(f"guard_shrink must be a tuple of fractions in [0, 1), got "
                             f"{shrink!r}")
        if self.shape_fit not in SHAPE_FITS:
            raise ValueError(f"shape_fit must be one of {', '.join(SHAPE_FITS)}, got "
                             f"{self.shape_fit!r}")
        for name in ("keypoint_pose_lr", "keypoint_translation_lr", "color_pose_lr",
                     "color_translation_lr", "code_lr", "shape_lr", "view_calibration_lr"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("keypoint_betas_lr", "color_betas_lr", "no_mask_margin",
                     "restart_separation_deg", "finger_restart_px", "silhouette_weight",
                     "coverage_weight", "landmark_weight", "limit_weight", "pose_weight",
                     "betas_weight", "size_weight", "rgb_weight", "code_weight", "joints_weight",
                     "mask_weight", "shape_weight", "max_area_change", "shape_range_margin",
                     "view_gain_std", "view_bias_std", "view_calibration_weight"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not isinstance(self.view_calibration, bool):
            raise TypeError(f"view_calibration must be True or False, got "
                            f"{self.view_calibration!r}")
        if not isinstance(self.render, RenderConfig):
            raise TypeError(f"render must be a RenderConfig, got {type(self.render).__name__}")
        if self.prior_pose not in PRIOR_POSES:
            raise ValueError(f"prior_pose must be one of {', '.join(PRIOR_POSES)}, got "
                             f"{self.prior_pose!r}")
        if self.num_threads is not None and (isinstance(self.num_threads, bool) or not isinstance(
                self.num_threads, int) or self.num_threads < 1):
            raise ValueError(f"num_threads must be an int >= 1 or None, got {self.num_threads!r}")
        if self.device is not None and not isinstance(self.device, str):
            raise TypeError(f"device must be a string like 'cpu' or 'cuda', or None, got "
                            f"{self.device!r}")
