"""Fitting LISA to a point cloud (paper Section 4.3, "Reconstruction from point clouds").

The paper minimises ``sum_x |G(x, theta, beta+)| + ||beta+||`` over the pose ``theta`` and the
shape code ``beta+``. The hand in a scan can be anywhere, in any orientation and finger pose,
seen from one side, with noise and outliers, so this fitter adds what the paper leaves out:

1. **Candidates** (``align``, no network). A proxy of the model's surface (points on its zero
   level set at rest, mean shape code, with the field's skinning weights; posed by linear blend
   skinning) is put on the cloud in 24 orientations per initial finger pose (``init_poses``:
   flat, relaxed, fist): the rotations that map the proxy's principal axes onto the cloud's, up
   to the order and the signs of the axes (the 24 rotations of a cube). The cloud's centroid and
   axes come from its dense part (scattered outliers dropped). All candidates are refined at once
   by a rigid alignment of the proxy energy (below); after a third of the iterations only the
   ``align_keep`` best distinct ones go on.
2. **Articulated proxy** (``pose``, no network). The ``num_restarts`` best distinct candidates
   (batched) also fit the finger pose.
3. **Field** (``field``). The same candidates fit the LISA field (all of them batched in one
   evaluation, bones culled): the global rotation, the translation, the finger pose, the shape
   code and the template's betas (whose joint regressor gives the skeleton LISA is conditioned
   on), on ``points_per_iteration`` random points per iteration. The field tells the candidates
   apart much better than the proxy (a hand turned over fits a one-sided scan's proxy almost as
   well), so several go on, and at the fractions ``prune_after`` of the iterations the worse
   ones stop (8 -> 3 -> 1).

Proxy energy (stages 1-2): the robust distance from each of 256 random cloud points to the
nearest proxy point, plus ``coverage_weight`` times a robust distance from each proxy point to
the cloud (a distance grid of the cloud, built once). The first term alone lets extra model
surface go unpunished (a flat finger beside the curled finger of a fist scan); the second is a
bounded Geman-McClure term (scale ``coverage_scale_mm``), so the unseen side of a partial scan
costs little and pulls weakly.

Field energy (stage 3, lengths in metres), per candidate::

    E = mean_i rho(G(x_i))
        + w_n mean_i [rho(G(x_i + eps n_i) - eps) + rho(G(x_i - eps n_i) + eps)] / 2
        + w_s |beta+|^2 + w_p |theta_fingers|^2 + w_l sum (joint-limit excess)^2 + w_b |betas|^2

``rho`` is the paper's ``|r|`` (``robust_loss="l1"``), Huber, or Geman-McClure
``sigma r^2 / (r^2 + sigma^2)`` (the default: bounded by ``sigma``, so an outlier costs at most
``sigma`` and pulls with a force that falls as ``1/r^3``). In the proxy stages ``sigma`` goes
down geometrically from ``robust_scale_start_mm`` to ``robust_scale_mm`` (coarse to fine); the
field stage uses ``robust_scale_mm``. The normal term (only with normals) asks the field to grow
outwards along the normals, which fixes the side of the surface the points are on. Far from the
hand ``G`` does not vanish: outside every bone region the field is the distance to the regions
plus a margin, so far points still pull the hand towards them.

The data term only asks every scan point to be on the surface, never every surface point to be
seen, so partial scans work; what the scan does not see stays near the prior (shape code near
zero, finger pose near rest and within joint limits).

Left hands are not detected: the model is a right hand and a left-hand scan is fitted as a right
hand (mirror it first with :func:`lisa_hand.skeleton.mirror_points`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ..geometry import axis_angle_to_matrix, matrix_to_axis_angle
from ..skeleton import NUM_JOINTS, POSE_DIM, forward_kinematics, linear_blend_skinning
from ..skeleton.params import HandParams

__all__ = [
    "ROBUST_LOSSES",
    "FitPointsConfig",
    "FitStep",
    "FitResult",
    "robust_loss",
    "cube_rotations",
    "principal_axes",
    "candidate_rotations",
    "fit_points",
]

ROBUST_LOSSES = ("geman_mcclure", "huber", "l1")
_FINGER_DIM = POSE_DIM - 3
_MM = 1e-3
_DISTANCE_EPS = 1e-9  # metres^2 inside the square root of a distance (finite gradient at 0)
_PROXY_STAGE_POINTS = 256  # cloud points per iteration of the proxy stages
_DISTINCT_ANGLE = math.radians(30.0)  # candidates closer than this and _DISTINCT_DISTANCE
_DISTINCT_DISTANCE = 0.02  # metres      are the same candidate
_MIN_SHAPE_SCALE = 1e-3  # floor of the shape code's unit
_ALIGN_FIRST = 0.35  # fraction of the align iterations run by every candidate
_ALIGN_FIRST_PROXY = 300  # proxy points in that first part
_GRID_VOXEL = 0.002  # metres, cell of the cloud's distance grid
_GRID_MARGIN = 0.03  # metres around the cloud's bounding box
_GRID_MAX_CELLS = 160  # cells per axis at most (the voxel grows for large clouds)


@dataclass(frozen=True)
class FitPointsConfig:
    """Settings of :func:`fit_points` (defaults: a few seconds on a CPU for a full hand)."""

    align_iterations: int = 40
    """Adam steps of the rigid alignment of the 24 candidate orientations (proxy, no network)."""
    align_keep: int = 16
    """Distinct candidates that finish the alignment (all of them run its first third)."""
    num_restarts: int = 8
    """Distinct candidates (best alignment energies) that go on to the pose and field stages."""
    pose_iterations: int = 60
    """Adam steps of the articulated proxy stage (pose and translation; no network)."""
    iterations: int = 200
    """Adam steps of the field stage (all unknowns, the LISA field)."""
    prune_after: tuple[float, ...] = (0.15, 0.35)
    """Fractions of the field iterations at which the worse candidates stop (by their field
    energy on a fixed subset of the cloud): ``K`` candidates become ``K^(1 - i/n)`` at the
    ``i``-th of ``n`` fractions, so one is left after the last (8 -> 3 -> 1)."""
    points_per_iteration: int = 512
    """Cloud points drawn (without replacement) per iteration; all of them if the cloud is
    smaller."""
    proxy_points: int = 1000
    """Points of the surface proxy used by the first two stages."""
    init_poses: tuple[str, ...] = ("flat", "relaxed", "fist")
    """Finger poses the candidates start from (names of
    :func:`lisa_hand.handmodel.poses.named_pose`, or 'zero'); each is tried in 24
    orientations."""
    coverage_weight: float = 0.5
    """Weight of the proxy-to-cloud term of the first two stages (every proxy point should be
    near the cloud; robust, so the unseen side of a partial scan costs little); 0: off."""
    coverage_scale_mm: float = 10.0
    """Scale of the Geman-McClure penalty of the coverage term, millimetres."""
    lr_rotation: float = 0.02
    """Adam step of the global rotation, radians."""
    lr_translation: float = 0.002
    """Adam step of the translation, metres."""
    lr_pose: float = 0.03
    """Adam step of the finger pose (axis-angle), radians."""
    lr_shape: float = 0.3
    """Adam step of the shape code, in units of the training codes' scale (their root mean
    square entry), so that it suits any model."""
    lr_betas: float = 0.05
    """Adam step of the template's shape coefficients (betas ~ N(0, 1) over subjects)."""
    robust_loss: str = "geman_mcclure"
    """Penalty of a residual: 'geman_mcclure' (robust to outliers), 'huber' or 'l1' (the
    paper's ``|G|``, not robust)."""
    robust_scale_mm: float = 4.0
    """Final scale ``sigma`` of the robust penalty, millimetres (residuals well beyond it count
    as outliers)."""
    robust_scale_start_mm: float = 15.0
    """Scale at the start of each stage, millimetres; it decreases geometrically to
    ``robust_scale_mm`` over the first 60% of the stage."""
    shape_weight: float = 1e-5
    """Weight of the shape code's norm (the paper's latent term) relative to the data term
    (metres): ``shape_weight * mean_k (beta+_k / s)^2``, ``s`` the training codes' root mean
    square entry, so a code of the training subjects' size costs about ``shape_weight``."""
    pose_weight: float = 1e-5
    """Weight of ``|theta_fingers|^2`` (radians^2): keeps unseen fingers near rest."""
    limit_weight: float = 1e-2
    """Weight of the squared excess of the finger joints' anatomical angles over their limits
    (:data:`lisa_hand.handmodel.JOINT_LIMITS`), radians^2."""
    betas_weight: float = 1e-5
    """Weight of ``|betas|^2`` (the template's shape coefficients)."""
    normal_weight: float = 0.5
    """Weight of the offset-point term when the cloud has normals (0 turns it off)."""
    normal_offset_mm: float = 3.0
    """Offset ``eps`` of the normal term's points along the normals, millimetres."""
    fit_shape: bool = True
    """Optimise the shape code (False: keep the training subjects' mean)."""
    fit_betas: bool = True
    """Optimise the template's betas (the skeleton); ignored with a fixed ``rest_joints``."""
    max_points: int = 200_000
    """A larger cloud is randomly subsampled to this many points first."""
    min_points: int = 20
    """Fewer points than this is an error."""
    lr_decay: float = 0.1
    """The learning rates fall (cosine) to this fraction of their value over each stage."""
    device: str | None = None
    """Where to fit ('cpu', 'cuda', ...); None: the model's device."""
    cpu_threads: int | None = 1
    """Torch intra-op threads during a CPU fit (restored afterwards); None keeps the current
    setting. The fit is many small operations: more threads barely help, and on cores shared
    with other processes OpenMP's spinning makes them over ten times slower."""
    seed: int = 0
    """Seed of the random point subsets."""

    def __post_init__(self) -> None:
        for name in ("align_iterations", "pose_iterations", "iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative int, got {value!r}")
        for name in ("align_keep", "num_restarts", "points_per_iteration", "proxy_points",
                     "max_points", "min_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if not self.init_poses:
            raise ValueError("init_poses must name at least one pose")
        for name in self.init_poses:
            _initial_finger_pose(name)  # raises for an unknown name
        if self.robust_loss not in ROBUST_LOSSES:
            raise ValueError(f"robust_loss must be one of {ROBUST_LOSSES}, got "
                             f"{self.robust_loss!r}")
        for name in ("lr_rotation", "lr_translation", "lr_pose", "lr_shape", "lr_betas",
                     "robust_scale_mm", "robust_scale_start_mm", "normal_offset_mm",
                     "coverage_scale_mm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name in ("shape_weight", "pose_weight", "limit_weight", "betas_weight",
                     "normal_weight", "coverage_weight"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {value!r}")
        prune = self.prune_after
        if (not isinstance(prune, tuple) or not prune or any(
                not isinstance(f, (int, float)) or not 0.0 <= f <= 1.0 for f in prune)
                or list(prune) != sorted(prune)):
            raise ValueError(f"prune_after must be a non-empty increasing tuple of fractions in "
                             f"[0, 1], got {prune!r}")
        threads = self.cpu_threads
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ValueError(f"cpu_threads must be a positive int or None, got {threads!r}")
        if not 0.0 < self.lr_decay <= 1.0:
            raise ValueError(f"lr_decay must be in (0, 1], got {self.lr_decay!r}")


@dataclass
class FitStep:
    """What :func:`fit_points` tells its ``callback`` after every iteration.

    stage: 'align', 'pose' or 'field'. iteration: within the stage (from 0); num_iterations: of
    the stage. energy: [K] the energy of each live candidate on this iteration's points (the
    stage's own energy: proxy distances for 'align' and 'pose'). seconds: since the fit started.
    """

    stage: str
    iteration: int
    num_iterations: int
    energy: list[float]
    seconds: float
    _make_params: Callable[[], HandParams] = field(repr=False)

    def params(self) -> HandParams:
        """The current best candidate as :class:`HandParams` (a copy, detached)."""
        return self._make_params()


@dataclass
class FitResult:
    """Result of :func:`fit_points`.

    params: the fitted hand (pose, translation, skeleton, betas, shape and colour codes);
        ``params.extra["fit"]`` holds the numbers below as JSON.
    energy: the field-stage energy of the result over the evaluation subset of the cloud.
    residual_median_mm, residual_mean_mm: median and mean ``|G(x)|`` over the whole cloud, mm.
    inlier_fraction: fraction of points with ``|G(x)| < 3 sigma`` (``sigma = robust_scale_mm``).
    seconds: wall time of the fit; stage_seconds: per stage ('proxy', 'align', 'pose',
        'field', 'finish').
    num_points: points fitted (after ``max_points``).
    candidate_energies: proxy energy of each candidate (24 orientations per initial finger
        pose) after the first part of the alignment.
    history: per iteration ``{"stage", "iteration", "energy" (best live candidate), "seconds"}``.
    """

    params: HandParams
    energy: float
    residual_median_mm: float
    residual_mean_mm: float
    inlier_fraction: float
    seconds: float
    stage_seconds: dict[str, float]
    num_points: int
    candidate_energies: list[float]
    history: list[dict[str, Any]]

    def summary(self) -> dict[str, Any]:
        """The scalar results as a JSON-able dict (what ``params.extra["fit"]`` holds)."""
        return {
            "energy": self.energy,
            "residual_median_mm": self.residual_median_mm,
            "residual_mean_mm": self.residual_mean_mm,
            "inlier_fraction": self.inlier_fraction,
            "seconds": self.seconds,
            "stage_seconds": dict(self.stage_seconds),
            "num_points": self.num_points,
        }


# ---------------------------------------------------------------------------------------------
# Pure functions


def robust_loss(residual: torch.Tensor, kind: str, scale: float) -> torch.Tensor:
    """Penalty of residuals (metres), elementwise.

    residual: [...] metres. kind: 'l1' (``|r|``), 'huber' (``r^2 / (2 sigma)`` for ``|r| <=
    sigma``, else ``|r| - sigma / 2``) or 'geman_mcclure' (``sigma r^2 / (r^2 + sigma^2)``,
    bounded by ``sigma``). scale: ``sigma``, metres. -> [...] metres.
    """
    if kind == "l1":
        return residual.abs()
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    if kind == "huber":
        magnitude = residual.abs()
        return torch.where(magnitude <= scale, 0.5 * residual * residual / scale,
                           magnitude - 0.5 * scale)
    if kind == "geman_mcclure":
        squared = residual * residual
        return scale * squared / (squared + scale * scale)
    raise ValueError(f"kind must be one of {ROBUST_LOSSES}, got {kind!r}")


def cube_rotations(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """The 24 rotations of a cube: signed permutation matrices with determinant +1.

    -> [24, 3, 3]; the first one is the identity.
    """
    import itertools

    rotations = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = torch.zeros(3, 3, dtype=torch.float64)
            for row, col in enumerate(perm):
                matrix[row, col] = signs[row]
            if torch.det(matrix) > 0:
                rotations.append(matrix)
    return torch.stack(rotations).to(dtype)


def principal_axes(points: torch.Tensor) -> torch.Tensor:
    """Principal axes of a point set as a rotation matrix.

    points: [N, 3]. -> [3, 3] whose columns are the unit eigenvectors of the covariance, in
    decreasing order of variance, the third flipped if needed so that the determinant is +1.
    """
    centred = points - points.mean(dim=0)
    covariance = centred.T @ centred / max(points.shape[0], 1)
    _, vectors = torch.linalg.eigh(covariance.double())  # ascending eigenvalues
    axes = vectors.flip(-1)
    if torch.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes.to(points.dtype)


def candidate_rotations(cloud: torch.Tensor, proxy: torch.Tensor) -> torch.Tensor:
    """The 24 rotations ``R = A_cloud C A_proxy^T`` that map the proxy's principal axes onto
    the cloud's, for every cube rotation ``C`` (any order and signs of the axes).

    cloud: [N, 3]; proxy: [P, 3] (any frames). -> [24, 3, 3] rotations (proxy -> cloud).
    """
    cloud_axes = principal_axes(cloud)
    proxy_axes = principal_axes(proxy)
    cubes = cube_rotations(cloud.dtype).to(cloud.device)
    return cloud_axes @ cubes @ proxy_axes.T


# ---------------------------------------------------------------------------------------------
# The fitter


class _Unknowns:
    """The unknowns of K candidates and how they map to LISA's inputs.

    The global rotation is ``exp(delta) R0`` (``delta`` optimised, ``R0`` fixed per stage) about
    the pivot ``c`` (the proxy's rest centroid), which lands at world position ``position``:
    ``x_world = R (x_rest_posed - c) + position``, i.e. MANO's translation
    ``t = position - R c + R j0 - j0`` (``j0`` the rest wrist).
    """

    def __init__(self, base_rotation, position, finger_pose, shape_code, betas, pivot, tag):
        self.tag = tag  # [K] long: which initial finger pose each candidate started from
        self.base_rotation = base_rotation  # [K, 3, 3], fixed
        self.delta = torch.zeros_like(position).requires_grad_(True)  # [K, 3]
        self.position = position.clone().requires_grad_(True)  # [K, 3]
        self.finger_pose = finger_pose.clone().requires_grad_(True)  # [K, 45]
        self.shape_code = shape_code.clone().requires_grad_(True)  # [K, D]
        self.betas = None if betas is None else betas.clone().requires_grad_(True)  # [K, B]
        self.pivot = pivot  # [3]

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def rotation(self) -> torch.Tensor:
        return axis_angle_to_matrix(self.delta) @ self.base_rotation

    def mano(self, rest_joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(pose [K, 48], translation [K, 3]) for rest joints [K, 16, 3]."""
        rotation = self.rotation()
        wrist = rest_joints[:, 0]
        turn = (rotation @ (wrist - self.pivot)[..., None])[..., 0]
        translation = self.position + turn - wrist
        pose = torch.cat([matrix_to_axis_angle(rotation), self.finger_pose], dim=-1)
        return pose, translation

    def optimised(self, with_shape: bool) -> list[torch.Tensor | None]:
        """The tensors of the field stage: rotation, position, finger pose, shape code (or None)
        and betas (or None)."""
        return [self.delta, self.position, self.finger_pose,
                self.shape_code if with_shape else None, self.betas]

    def clear_grads(self) -> None:
        for tensor in (self.delta, self.position, self.finger_pose, self.shape_code, self.betas):
            if tensor is not None:
                tensor.grad = None

    @torch.no_grad()
    def fold(self) -> None:
        """Move ``delta`` into ``base_rotation`` (keeps the axis-angle small between stages)."""
        self.base_rotation = axis_angle_to_matrix(self.delta) @ self.base_rotation
        self.delta.zero_()

    @torch.no_grad()
    def select(self, index: torch.Tensor) -> _Unknowns:
        self.fold()
        return _Unknowns(self.base_rotation[index], self.position[index],
                         self.finger_pose[index], self.shape_code[index],
                         None if self.betas is None else self.betas[index], self.pivot,
                         self.tag[index])

    @torch.no_grad()
    def distinct_best(self, energy: torch.Tensor, count: int) -> torch.Tensor:
        """Indices of the ``count`` lowest energies [K], skipping candidates that repeat a
        better one (same initial finger pose, rotation within 30 degrees, position within 2 cm).
        """
        rotation = self.rotation()
        chosen: list[int] = []
        for index in torch.argsort(energy).tolist():
            if all(int(self.tag[index]) != int(self.tag[other])
                   or _angle(rotation[index], rotation[other]) > _DISTINCT_ANGLE
                   or float((self.position[index] - self.position[other]).norm())
                   > _DISTINCT_DISTANCE for other in chosen):
                chosen.append(index)
            if len(chosen) == count:
                break
        return torch.tensor(chosen, device=energy.device)


class _Skeleton:
    """Rest joints of K candidates: fixed, or ``template.rest_joints(betas)``."""

    def __init__(self, fixed: torch.Tensor | None, template) -> None:
        self.fixed = fixed
        self.template = template

    def __call__(self, unknowns: _Unknowns) -> torch.Tensor:
        if self.fixed is not None:
            return self.fixed.expand(unknowns.count, NUM_JOINTS, 3)
        if unknowns.betas is None:
            zeros = torch.zeros(unknowns.count, self.template.num_betas,
                                dtype=self.template.dtype, device=self.template.device)
            return self.template.rest_joints(zeros)
        return self.template.rest_joints(unknowns.betas)


class _Adam:
    """Adam (Kingma and Ba 2015) on a few tensors, each with its own learning rate.

    The same update as ``torch.optim.Adam`` with default betas and eps; written out because the
    first ``torch.optim`` optimizer of a process imports ``torch._dynamo`` (seconds, the length
    of a whole fit). ``factor`` scales every learning rate (the schedule).
    """

    def __init__(self, groups: list[tuple[torch.Tensor, float]], betas=(0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.groups = groups
        self.betas = betas
        self.eps = eps
        self.factor = 1.0
        self.steps = 0
        self.moments = [(torch.zeros_like(t), torch.zeros_like(t)) for t, _ in groups]

    @torch.no_grad()
    def step(self) -> None:
        """Update the tensors from their ``.grad`` (then cleared)."""
        self.steps += 1
        beta1, beta2 = self.betas
        correction1 = 1.0 - beta1**self.steps
        correction2 = 1.0 - beta2**self.steps
        for (tensor, lr), (mean, square) in zip(self.groups, self.moments, strict=True):
            if tensor.grad is None:
                continue
            grad = tensor.grad
            mean.mul_(beta1).add_(grad, alpha=1.0 - beta1)
            square.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
            denominator = (square / correction2).sqrt_().add_(self.eps)
            tensor.addcdiv_(mean, denominator, value=-lr * self.factor / correction1)
            tensor.grad = None

    def select(self, index: torch.Tensor, tensors: list[torch.Tensor | None]) -> None:
        """Keep the rows ``index`` of every moment and go on with ``tensors`` (the same
        tensors, rows selected, in the order of the groups)."""
        kept = [t for t in tensors if t is not None]
        assert len(kept) == len(self.groups)
        self.groups = [(new, lr) for new, (_, lr) in zip(kept, self.groups, strict=True)]
        self.moments = [(mean[index], square[index]) for mean, square in self.moments]


def _cosine(step: int, total: int, floor: float) -> float:
    if total <= 1:
        return 1.0
    return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * step / (total - 1)))


def _robust_scale(config: FitPointsConfig, step: int, total: int) -> float:
    """Metres: geometric from the start scale to the final one over the first 60% of a stage."""
    start, end = config.robust_scale_start_mm * _MM, config.robust_scale_mm * _MM
    if total <= 1 or start <= end:
        return end
    progress = min(1.0, step / (0.6 * (total - 1)))
    return start * (end / start) ** progress


def _limit_penalty(finger_pose: torch.Tensor) -> torch.Tensor:
    """[K] sum of squared excess (radians^2) of the anatomical angles over the joint limits."""
    from ..handmodel.poses import JOINT_LIMITS, pose_to_angles

    pose = torch.cat([finger_pose.new_zeros(finger_pose.shape[0], 3), finger_pose], dim=-1)
    angles = pose_to_angles(pose)  # [K, 15, 3]
    limits = JOINT_LIMITS.to(angles)
    excess = torch.relu(angles - limits[..., 1]) + torch.relu(limits[..., 0] - angles)
    return (excess * excess).flatten(1).sum(-1)


def _prior(config: FitPointsConfig, unknowns: _Unknowns, shape_scale: float | None
           ) -> torch.Tensor:
    """[K] the regularisers of the energy (the shape code's with its scale, if given)."""
    finger = unknowns.finger_pose
    prior = config.pose_weight * (finger * finger).sum(-1)
    if config.limit_weight > 0:
        prior = prior + config.limit_weight * _limit_penalty(finger)
    if shape_scale is not None:
        code = unknowns.shape_code / shape_scale
        prior = prior + config.shape_weight * (code * code).mean(-1)
    if unknowns.betas is not None:
        prior = prior + config.betas_weight * (unknowns.betas * unknowns.betas).sum(-1)
    return prior


def _nearest_distance(cloud: torch.Tensor, proxy: torch.Tensor) -> torch.Tensor:
    """Distance from each cloud point to its nearest proxy point.

    cloud: [K, N, 3]; proxy: [K, P, 3] -> [K, N] metres (differentiable in both; the nearest
    point is chosen without gradient).
    """
    with torch.no_grad():
        nearest = torch.cdist(cloud, proxy).argmin(dim=-1)  # [K, N]
    matched = torch.gather(proxy, 1, nearest[..., None].expand(-1, -1, 3))
    return ((cloud - matched).square().sum(-1) + _DISTANCE_EPS).sqrt()


class _CloudDistance:
    """Unsigned distance to a point cloud on a grid (built once, differentiable lookups).

    The distance from every cell centre to the nearest occupied cell (Euclidean distance
    transform, scipy), read back with trilinear interpolation: error below about one cell
    (2 mm). Points outside the grid read its border (the margin is 3 cm: beyond it everything
    is far).
    """

    def __init__(self, cloud: torch.Tensor) -> None:
        from scipy.ndimage import distance_transform_edt

        points = cloud.detach().double().cpu().numpy()
        low = points.min(axis=0) - _GRID_MARGIN
        high = points.max(axis=0) + _GRID_MARGIN
        voxel = max(_GRID_VOXEL, float((high - low).max()) / (_GRID_MAX_CELLS - 1))
        dims = np.ceil((high - low) / voxel).astype(np.int64) + 1
        occupied = np.zeros(dims, dtype=bool)
        cells = np.clip(np.rint((points - low) / voxel).astype(np.int64), 0, dims - 1)
        occupied[cells[:, 0], cells[:, 1], cells[:, 2]] = True
        distance = distance_transform_edt(~occupied) * voxel
        # grid_sample reads [N, C, D, H, W] with coordinates (x -> W, y -> H, z -> D): store the
        # x axis last.
        grid = torch.from_numpy(np.ascontiguousarray(distance.transpose(2, 1, 0)))
        self.grid = grid.to(device=cloud.device, dtype=cloud.dtype)[None, None]
        self.low = torch.as_tensor(low, device=cloud.device, dtype=cloud.dtype)
        self.extent = torch.as_tensor((dims - 1) * voxel, device=cloud.device, dtype=cloud.dtype)

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """points: [K, P, 3] metres -> [K, P] metres (differentiable in the points)."""
        count, num = points.shape[:2]
        normalised = 2.0 * (points - self.low) / self.extent - 1.0
        values = torch.nn.functional.grid_sample(
            self.grid.expand(count, -1, -1, -1, -1), normalised[:, :, None, None, :],
            mode="bilinear", padding_mode="border", align_corners=True)
        return values.reshape(count, num)


def _check_model(model) -> None:
    from ..model.trained import TrainedModel

    if not isinstance(model, TrainedModel):
        raise TypeError(f"model must be a lisa_hand.trained.TrainedModel, got "
                        f"{type(model).__name__}")


def _to_tensor(value, name: str, dtype, device, shape_text: str) -> torch.Tensor:
    if isinstance(value, np.ndarray):
        value = torch.from_numpy(np.ascontiguousarray(value))
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"{name} must be a numpy array or torch.Tensor, got "
                        f"{type(value).__name__}")
    if value.dim() != 2 or value.shape[1] != 3:
        raise ValueError(f"{name} must have shape {shape_text}, got {list(value.shape)}")
    if not torch.isfinite(value).all():
        raise ValueError(f"{name} holds NaN or inf (drop those points first, e.g. with "
                         "lisa_hand.fitting.io.prepare_point_cloud)")
    return value.detach().to(device=device, dtype=dtype)


class _Fitter:
    """One run of :func:`fit_points` (holds the cloud, the model and the bookkeeping)."""

    def __init__(self, model, cloud, normals, config, rest_joints, progress, callback):
        self.model = model
        self.field = model.field
        self.config = config
        self.cloud = cloud
        self.normals = normals
        self.device = cloud.device
        self.dtype = cloud.dtype
        self.generator = torch.Generator(device="cpu").manual_seed(config.seed)
        self.callback = callback
        self.start = time.perf_counter()
        self.history: list[dict[str, Any]] = []
        self.stage_seconds: dict[str, float] = {}
        self.bar = None
        if progress:
            from tqdm import tqdm

            total = config.align_iterations + config.pose_iterations + config.iterations
            self.bar = tqdm(total=total, desc="fit", unit="it", leave=False)

        self.shape_mean = model.mean_shape_code().to(device=self.device, dtype=self.dtype)
        # The training codes' root mean square entry: the unit of the shape code's step and
        # prior (floored for a model whose codes are all zero, e.g. a fresh one).
        self.shape_scale = max(float(model.shape_codes.square().mean().sqrt()), _MIN_SHAPE_SCALE)
        color = model.mean_color_code()
        self.color_code = None if color is None else color.to(device=self.device,
                                                              dtype=self.dtype)
        template = None
        if rest_joints is None:
            from ..handmodel.template import load_template

            template = load_template().to(device=self.device, dtype=self.dtype)
        else:
            rest_joints = torch.as_tensor(rest_joints).to(device=self.device, dtype=self.dtype)
            if rest_joints.shape != (NUM_JOINTS, 3) or not torch.isfinite(rest_joints).all():
                raise ValueError(f"rest_joints must be finite with shape [16, 3], got "
                                 f"{list(rest_joints.shape)}")
        self.skeleton = _Skeleton(rest_joints, template)
        self.cloud_distance = _CloudDistance(cloud) if config.coverage_weight > 0 else None
        self.fit_betas = template is not None and config.fit_betas

    # -----------------------------------------------------------------------------------------
    def _sample(self, count: int) -> torch.Tensor:
        num = self.cloud.shape[0]
        if num <= count:
            return torch.arange(num, device=self.device)
        return torch.randperm(num, generator=self.generator)[:count].to(self.device)

    def _record(self, stage: str, iteration: int, total: int, energies: torch.Tensor,
                unknowns: _Unknowns) -> None:
        values = [float(v) for v in energies.detach().cpu()]
        seconds = time.perf_counter() - self.start
        self.history.append({"stage": stage, "iteration": iteration, "energy": min(values),
                             "seconds": seconds})
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(stage=stage, energy_mm=f"{1e3 * min(values):.3f}")
        if self.callback is not None:
            best = int(np.argmin(values))
            self.callback(FitStep(stage, iteration, total, values, seconds,
                                  lambda: self._params(unknowns, best)))

    def _optimizer(self, unknowns: _Unknowns, stage: str) -> _Adam:
        config = self.config
        rates = (config.lr_rotation, config.lr_translation, config.lr_pose,
                 config.lr_shape * self.shape_scale, config.lr_betas)
        tensors = unknowns.optimised(config.fit_shape)
        if stage == "align":
            tensors = tensors[:2]
        elif stage == "pose":
            tensors = tensors[:3]
        return _Adam([(t, lr) for t, lr in zip(tensors, rates, strict=False) if t is not None])

    # -----------------------------------------------------------------------------------------
    @torch.no_grad()
    def build_proxy(self) -> None:
        """Surface points of the model at rest (mean shape code) and their skinning weights."""
        from ..geometry.meshing import extract_mesh

        config = self.config
        field_model = self.field
        rest = self.skeleton.fixed
        if rest is None:
            zeros = torch.zeros(1, self.skeleton.template.num_betas, dtype=self.dtype,
                                device=self.device)
            rest = self.skeleton.template.rest_joints(zeros)[0]
        state = field_model.prepare(
            torch.zeros(1, POSE_DIM, dtype=self.dtype, device=self.device), None, rest[None],
            self.shape_mean[None], None if self.color_code is None else self.color_code[None])
        low, high = _region_box(state, field_model)
        mesh = extract_mesh(field_model.sdf_fn(state), low, high, 64, lipschitz=2.0,
                            device=self.device, dtype=self.dtype)
        vertices = torch.from_numpy(mesh.vertices).to(device=self.device, dtype=self.dtype)
        if vertices.shape[0] == 0:
            raise ValueError("the model's surface at rest is empty: cannot fit with this model")
        if vertices.shape[0] > config.proxy_points:
            pick = torch.randperm(vertices.shape[0], generator=self.generator)
            vertices = vertices[pick[: config.proxy_points].to(self.device)]
        out = field_model.field(state, vertices[None], with_color=False)
        if out.weights is not None:
            weights = out.weights[0]
        else:  # the single-MLP baseline has no skinning weights: the nearest bone region's
            excess = field_model.region_excess(state, vertices[None])[0]
            weights = torch.nn.functional.one_hot(excess.argmin(-1), NUM_JOINTS).to(self.dtype)
        self.proxy_rest = vertices
        self.proxy_weights = weights
        self.proxy_skeleton = rest
        self.pivot = vertices.mean(dim=0)

    def _proxy_local(self, finger_pose: torch.Tensor,
                     subset: torch.Tensor | None = None) -> torch.Tensor:
        """[K, P, 3] the proxy (or its points ``subset``) posed by finger poses [K, 45], zero
        global rotation (rest frame)."""
        count = finger_pose.shape[0]
        pose = torch.cat([finger_pose.new_zeros(count, 3), finger_pose], dim=-1)
        kinematics = forward_kinematics(pose, self.proxy_skeleton)
        rest, weights = self.proxy_rest, self.proxy_weights
        if subset is not None:
            rest, weights = rest[subset], weights[subset]
        return linear_blend_skinning(rest, weights, kinematics.transforms)

    def _proxy_world(self, unknowns: _Unknowns, subset: torch.Tensor | None = None
                     ) -> torch.Tensor:
        """[K, P, 3] the proxy posed by the candidates (on the proxy's own rest skeleton)."""
        local = self._proxy_local(unknowns.finger_pose, subset)
        rotation = unknowns.rotation()
        return (local - self.pivot) @ rotation.transpose(-1, -2) + unknowns.position[:, None]

    # -----------------------------------------------------------------------------------------
    def align(self) -> tuple[_Unknowns, list[float]]:
        """Stage 1: rigid alignment of the proxy in 24 orientations per initial finger pose.

        Every candidate runs the first part of the iterations on a subset of the proxy; the
        ``align_keep`` best distinct ones finish them. -> (the ``num_restarts`` best distinct
        candidates, every candidate's energy after the first part).
        """
        config = self.config
        sample = _dense_points(self.cloud[self._sample(4096)])
        centroid = sample.mean(dim=0)
        rotations, positions, fingers, tags = [], [], [], []
        for number, name in enumerate(config.init_poses):
            finger = _initial_finger_pose(name).to(device=self.device, dtype=self.dtype)
            posed = self._proxy_local(finger[None])[0]
            candidates = candidate_rotations(sample, posed)
            # Put the posed proxy's centroid on the cloud's.
            offset = (candidates @ (posed.mean(dim=0) - self.pivot)[:, None])[..., 0]
            rotations.append(candidates)
            positions.append(centroid - offset)
            fingers.append(finger.expand(candidates.shape[0], -1))
            tags.append(torch.full((candidates.shape[0],), number, device=self.device))
        count = sum(r.shape[0] for r in rotations)
        unknowns = _Unknowns(torch.cat(rotations), torch.cat(positions), torch.cat(fingers),
                             self.shape_mean.expand(count, -1), None, self.pivot, torch.cat(tags))
        first = int(round(_ALIGN_FIRST * config.align_iterations))
        proxy_subset = self._sample_proxy(_ALIGN_FIRST_PROXY)
        energies = self._proxy_stage(unknowns, "align", first, proxy_subset=proxy_subset)
        unknowns = unknowns.select(unknowns.distinct_best(energies, config.align_keep))
        energy = self._proxy_stage(unknowns, "align", config.align_iterations - first,
                                   step_offset=first, total=config.align_iterations)
        picked = unknowns.select(unknowns.distinct_best(energy, config.num_restarts))
        if self.fit_betas:
            picked.betas = torch.zeros(picked.count, self.skeleton.template.num_betas,
                                       dtype=self.dtype, device=self.device).requires_grad_(True)
        return picked, [float(e) for e in energies]

    def _sample_proxy(self, count: int) -> torch.Tensor:
        num = self.proxy_rest.shape[0]
        if num <= count:
            return torch.arange(num, device=self.device)
        return torch.randperm(num, generator=self.generator)[:count].to(self.device)

    def _proxy_stage(self, unknowns: _Unknowns, stage: str, iterations: int, *,
                     proxy_subset: torch.Tensor | None = None, step_offset: int = 0,
                     total: int | None = None) -> torch.Tensor:
        """Adam on the proxy energy (:meth:`_proxy_energy`, + pose prior in the 'pose' stage)
        for steps ``step_offset .. step_offset + iterations`` of a stage of ``total`` steps;
        -> [K] the final proxy energies."""
        config = self.config
        total = iterations if total is None else total
        optimizer = self._optimizer(unknowns, stage)
        energy = None
        for step in range(step_offset, step_offset + iterations):
            optimizer.factor = _cosine(step, total, config.lr_decay)
            energy = self._proxy_energy(unknowns, _robust_scale(config, step, total), proxy_subset)
            loss = energy
            if stage == "pose":
                loss = loss + _prior(config, unknowns, None)
            unknowns.clear_grads()
            loss.sum().backward()
            optimizer.step()
            self._record(stage, step, total, energy, unknowns)
        if energy is None:  # no iteration: score the starting points
            with torch.no_grad():
                energy = self._proxy_energy(unknowns, _robust_scale(config, step_offset, total),
                                            proxy_subset)
        unknowns.fold()
        return energy.detach()

    def _proxy_energy(self, unknowns: _Unknowns, scale: float,
                      proxy_subset: torch.Tensor | None = None) -> torch.Tensor:
        """[K] robust cloud-to-proxy distance of a random subset of the cloud, plus
        ``coverage_weight`` times the robust proxy-to-cloud distance (scale
        ``coverage_scale_mm``, from the cloud's distance grid)."""
        config = self.config
        count = unknowns.count
        proxy = self._proxy_world(unknowns, proxy_subset)
        cloud = self.cloud[self._sample(_PROXY_STAGE_POINTS)]
        distance = _nearest_distance(cloud.expand(count, -1, -1), proxy)
        energy = robust_loss(distance, config.robust_loss, scale).mean(-1)
        if config.coverage_weight > 0:
            uncovered = self.cloud_distance(proxy)
            coverage = robust_loss(uncovered, "geman_mcclure", config.coverage_scale_mm * _MM)
            energy = energy + config.coverage_weight * coverage.mean(-1)
        return energy

    # -----------------------------------------------------------------------------------------
    def _state(self, unknowns: _Unknowns):
        rest_joints = self.skeleton(unknowns)
        pose, translation = unknowns.mano(rest_joints)
        count = unknowns.count
        color = None
        if self.color_code is not None:
            color = self.color_code.expand(count, -1)
        return self.field.prepare(pose, translation, rest_joints, unknowns.shape_code, color)

    def _data_term(self, unknowns: _Unknowns, index: torch.Tensor, scale: float) -> torch.Tensor:
        """[K] mean robust penalty of the field at the cloud points ``index`` (and offsets)."""
        config = self.config
        count = unknowns.count
        state = self._state(unknowns)
        points = self.cloud[index]
        num = points.shape[0]
        use_normals = self.normals is not None and config.normal_weight > 0
        if use_normals:
            offset = config.normal_offset_mm * _MM * self.normals[index]
            points = torch.cat([points, points + offset, points - offset])
        sdf = self.field.field(state, points.expand(count, -1, -1).contiguous(),
                               with_color=False).sdf
        data = robust_loss(sdf[:, :num], config.robust_loss, scale).mean(-1)
        if use_normals:
            eps = config.normal_offset_mm * _MM
            outside = robust_loss(sdf[:, num:2 * num] - eps, config.robust_loss, scale)
            inside = robust_loss(sdf[:, 2 * num:] + eps, config.robust_loss, scale)
            data = data + config.normal_weight * 0.5 * (outside.mean(-1) + inside.mean(-1))
        return data

    def field_stage(self, unknowns: _Unknowns) -> _Unknowns:
        """Stage 3: all unknowns on the LISA field; prunes to the best candidate."""
        config = self.config
        iterations = config.iterations
        # Prune at each fraction of ``prune_after``: K -> K^(1 - i/n) -> ... -> 1 candidates.
        initial = unknowns.count
        prunes = {int(round(fraction * iterations)):
                  max(1, round(initial ** (1.0 - (number + 1) / len(config.prune_after))))
                  for number, fraction in enumerate(config.prune_after)}
        optimizer = self._optimizer(unknowns, "field")
        for step in range(iterations):
            if step in prunes and unknowns.count > prunes[step]:
                best = torch.argsort(self._evaluate(unknowns))[: prunes[step]]
                unknowns = unknowns.select(best)
                optimizer.select(best, unknowns.optimised(config.fit_shape))
            optimizer.factor = _cosine(step, iterations, config.lr_decay)
            scale = config.robust_scale_mm * _MM
            index = self._sample(config.points_per_iteration)
            data = self._data_term(unknowns, index, scale)
            energy = data + _prior(config, unknowns, self.shape_scale if config.fit_shape else None)
            unknowns.clear_grads()
            energy.sum().backward()
            optimizer.step()
            self._record("field", step, iterations, energy, unknowns)
        unknowns.fold()
        if unknowns.count > 1:
            unknowns = unknowns.select(self._best(unknowns).reshape(1))
        return unknowns

    @torch.no_grad()
    def _best(self, unknowns: _Unknowns) -> torch.Tensor:
        energy = self._evaluate(unknowns)
        return torch.argmin(energy)

    @torch.no_grad()
    def _evaluate(self, unknowns: _Unknowns) -> torch.Tensor:
        """[K] field energy at the final robust scale on a fixed subset of the cloud."""
        config = self.config
        generator = torch.Generator(device="cpu").manual_seed(config.seed + 1)
        num = self.cloud.shape[0]
        index = torch.arange(num) if num <= 2048 else torch.randperm(num, generator=generator)[
            :2048]
        data = self._data_term(unknowns, index.to(self.device), config.robust_scale_mm * _MM)
        return data + _prior(config, unknowns, self.shape_scale if config.fit_shape else None)

    @torch.no_grad()
    def residuals(self, unknowns: _Unknowns) -> torch.Tensor:
        """[N] ``|G(x)|`` of the (single) candidate at every cloud point, metres."""
        state = self._state(unknowns)
        parts = [self.field.field(state, chunk[None], with_color=False).sdf[0].abs()
                 for chunk in self.cloud.split(65536)]
        return torch.cat(parts)

    @torch.no_grad()
    def _params(self, unknowns: _Unknowns, index: int) -> HandParams:
        rest_joints = self.skeleton(unknowns)
        pose, translation = unknowns.mano(rest_joints)
        betas = None if unknowns.betas is None else unknowns.betas[index]
        if betas is None and self.skeleton.template is not None:
            betas = torch.zeros(self.skeleton.template.num_betas)
        return HandParams(
            pose=pose[index].detach().cpu().float(),
            translation=translation[index].detach().cpu().float(),
            rest_joints=rest_joints[index].detach().cpu().float(),
            shape_code=unknowns.shape_code[index].detach().cpu().float(),
            color_code=None if self.color_code is None else self.color_code.cpu().float(),
            betas=None if betas is None else betas.detach().cpu().float(),
            side="right",
            model=self.model.source,
        )

    def lap(self, name: str, since: float) -> float:
        now = time.perf_counter()
        self.stage_seconds[name] = now - since
        return now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _dense_points(points: torch.Tensor, neighbours: int = 8, factor: float = 3.0) -> torch.Tensor:
    """The points of a cloud that lie in dense parts (a surface), for a robust centroid and
    principal axes: those whose distance to their ``neighbours``-th nearest neighbour is at most
    ``factor`` times the median of that distance. Scattered outliers have far neighbours.

    points: [N, 3] -> [M, 3] (all of them when N <= neighbours).
    """
    from scipy.spatial import cKDTree

    if points.shape[0] <= neighbours:
        return points
    array = points.detach().cpu().double().numpy()
    distance = cKDTree(array).query(array, k=neighbours + 1)[0][:, -1]
    keep = distance <= factor * np.median(distance)
    return points[torch.from_numpy(keep).to(points.device)]


def _initial_finger_pose(name: str) -> torch.Tensor:
    """[45] finger pose (radians) of a named pose, or zeros for 'zero'."""
    if name == "zero":
        return torch.zeros(_FINGER_DIM)
    from ..handmodel.poses import named_pose

    return named_pose(name)[3:]


def _angle(first: torch.Tensor, second: torch.Tensor) -> float:
    """Angle (radians) of the rotation between two rotation matrices [3, 3]."""
    cosine = (torch.trace(first.T @ second) - 1.0) / 2.0
    return float(torch.arccos(cosine.clamp(-1.0, 1.0)))


def _region_box(state, field_model) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box [3], [3] (metres, numpy) around every bone region of a one-frame state."""
    from ..model.lisa import region_bounds

    low, high = region_bounds(state, field_model)
    return low[0].cpu().double().numpy(), high[0].cpu().double().numpy()


def fit_points(
    model,
    points: np.ndarray | torch.Tensor,
    normals: np.ndarray | torch.Tensor | None = None,
    config: FitPointsConfig | None = None,
    *,
    rest_joints: torch.Tensor | None = None,
    progress: bool = False,
    callback: Callable[[FitStep], None] | None = None,
) -> FitResult:
    """Fit a trained LISA model to a point cloud of a right hand (see the module docstring).

    model: a :class:`lisa_hand.trained.TrainedModel`.
    points: [N, 3] world metres, finite (:func:`lisa_hand.fitting.io.prepare_point_cloud`
        checks files and converts units). Any position and orientation; partial is fine.
    normals: [N, 3] outward normals or None; they add the offset-point term.
    config: :class:`FitPointsConfig` (defaults when None).
    rest_joints: [16, 3] metres, a fixed skeleton; None: the template's
        (:func:`lisa_hand.handmodel.template.load_template`), whose betas are fitted.
    progress: show a progress bar. callback: called with a :class:`FitStep` after every
        iteration (for benchmarks and logging).
    -> :class:`FitResult`. Runs on ``config.device`` (default: the model's), in the model's dtype.
    """
    from ..metrics import detect_length_unit

    config = FitPointsConfig() if config is None else config
    if not isinstance(config, FitPointsConfig):
        raise TypeError(f"config must be a FitPointsConfig, got {type(config).__name__}")
    _check_model(model)
    device = torch.device(config.device) if config.device is not None else model.device
    if device != model.device:
        model = model.to(device)
    dtype = model.field.dtype
    cloud = _to_tensor(points, "points", dtype, device, "[N, 3]")
    if cloud.shape[0] < config.min_points:
        raise ValueError(f"points: {cloud.shape[0]} points, fewer than the {config.min_points} "
                         "needed to fit a hand")
    if detect_length_unit(cloud) == "mm":
        size = float((cloud.amax(0) - cloud.amin(0)).norm())
        raise ValueError(f"points are {size:.4g} units across, which looks like millimetres "
                         "(a hand is about 0.2 m): convert them to metres")
    normal_tensor = None
    if normals is not None:
        normal_tensor = _to_tensor(normals, "normals", dtype, device, "[N, 3]")
        if normal_tensor.shape != cloud.shape:
            raise ValueError(f"normals must have the points' shape {list(cloud.shape)}, got "
                             f"{list(normal_tensor.shape)}")
        normal_tensor = normal_tensor / normal_tensor.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if cloud.shape[0] > config.max_points:
        generator = torch.Generator(device="cpu").manual_seed(config.seed)
        keep = torch.randperm(cloud.shape[0], generator=generator)[: config.max_points]
        keep = keep.to(device)
        cloud = cloud[keep]
        normal_tensor = None if normal_tensor is None else normal_tensor[keep]

    was_training = model.field.training
    model.field.eval()
    # Only the unknowns need gradients, not the network's weights.
    requires_grad = [p.requires_grad for p in model.field.parameters()]
    for weight in model.field.parameters():
        weight.requires_grad_(False)
    previous_threads = torch.get_num_threads()
    if device.type == "cpu" and config.cpu_threads is not None:
        torch.set_num_threads(config.cpu_threads)
    fitter = None
    try:
        fitter = _Fitter(model, cloud, normal_tensor, config, rest_joints, progress, callback)
        since = fitter.start
        fitter.build_proxy()
        since = fitter.lap("proxy", since)
        unknowns, candidate_energies = fitter.align()
        since = fitter.lap("align", since)
        fitter._proxy_stage(unknowns, "pose", config.pose_iterations)
        since = fitter.lap("pose", since)
        unknowns = fitter.field_stage(unknowns)
        since = fitter.lap("field", since)
        energy = float(fitter._evaluate(unknowns)[0])
        residual = fitter.residuals(unknowns)
        params = fitter._params(unknowns, 0)
        fitter.lap("finish", since)
    finally:
        torch.set_num_threads(previous_threads)
        if fitter is not None:
            fitter.close()
        for weight, flag in zip(model.field.parameters(), requires_grad, strict=True):
            weight.requires_grad_(flag)
        model.field.train(was_training)
    seconds = time.perf_counter() - fitter.start
    inlier = 3.0 * config.robust_scale_mm * _MM
    result = FitResult(
        params=params,
        energy=energy,
        residual_median_mm=float(residual.median()) / _MM,
        residual_mean_mm=float(residual.mean()) / _MM,
        inlier_fraction=float((residual < inlier).float().mean()),
        seconds=seconds,
        stage_seconds=fitter.stage_seconds,
        num_points=int(cloud.shape[0]),
        candidate_energies=candidate_energies,
        history=fitter.history,
    )
    params.extra["fit"] = result.summary()
    return result
