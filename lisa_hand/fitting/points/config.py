"""Settings of the point-cloud fit (:func:`lisa_hand.fitting.points.fit.fit_points`) and of its
stages: one frozen dataclass, named as the image fitter's (``*_weight``, ``*_iters``,
``num_threads``, ``device``, ``seed``, ``prior_pose``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from ...utils.config import check_int_fields
from ..pair.config import JointConfig
from ..priors import PRIOR_POSES
from ..robust import ROBUST_LOSSES
from .analysis import AnalysisConfig

__all__ = ["POINT_STAGES", "ScanHandsConfig", "FitPointsConfig"]

POINT_STAGES = ("align", "pose", "size", "unseen", "fingers", "coverage", "field", "second")
"""The point fit's stages in the one order they may run (:mod:`.stages`)."""


@dataclass(frozen=True)
class ScanHandsConfig:
    """How :func:`lisa_hand.fitting.points.hands.fit_scan_hands` splits and fits a scan of
    several hands (``FitPointsConfig.hands``)."""

    rounds: int = 1
    """Fits of every hand again after the points were split by the previous fits."""
    far_mm: float = 15.0
    """Points farther than this from every fitted hand's surface belong to none."""
    candidate_iters: int = 30
    """Field-stage iterations of the quick fits that choose between the cuts of touching hands
    (:func:`~lisa_hand.fitting.points.hands.choose_split`; 0: no quick fits, the cut
    :func:`~lisa_hand.fitting.points.hands.initial_split` guesses)."""
    candidate_rounds: int = 3
    """At most this many quick fits again of the chosen cut's hands, each on the points the
    last gave it, while the hands come nearer the scan
    (:func:`~lisa_hand.fitting.points.hands.choose_split`)."""
    joint: JointConfig = field(default_factory=JointConfig)
    """The joint fit of all hands at the end (``joint.iters=0``: none)."""
    mesh_resolution: int = 64
    """Marching-cubes samples a side of the meshes whose vertices are the joint fit's surface
    samples."""

    def __post_init__(self) -> None:
        if isinstance(self.rounds, bool) or not isinstance(self.rounds, int) or self.rounds < 0:
            raise ValueError(f"rounds must be an integer >= 0, got {self.rounds!r}")
        for name in ("candidate_iters", "candidate_rounds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        if not self.far_mm > 0:
            raise ValueError(f"far_mm must be positive, got {self.far_mm!r}")


@dataclass(frozen=True)
class FitPointsConfig:
    """Settings of :func:`lisa_hand.fitting.points.fit.fit_points` (defaults: a few seconds on a
    CPU for a full hand)."""

    RENAMED: ClassVar[dict[str, str]] = {
        "lr_rotation": "rotation_lr", "lr_translation": "translation_lr", "lr_pose": "pose_lr",
        "lr_shape": "shape_lr", "lr_betas": "betas_lr", "num_restarts": "restarts",
        "lr_decay": "final_lr_fraction"}
    """Settings by their former names (refused, naming the new one)."""

    stages: tuple[str, ...] = POINT_STAGES
    """The stages that run, in order (:mod:`.stages`): a subsequence of
    :data:`POINT_STAGES` holding 'align' and 'field' (e.g. without 'size' and 'fingers')."""
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)
    """How the scan is analysed before the stages (:mod:`.analysis`: the support plane, the
    sensor position, other pieces)."""
    hands: ScanHandsConfig = field(default_factory=ScanHandsConfig)
    """A scan of several hands that may touch (``lisa fit-points --hands N``,
    :func:`lisa_hand.fitting.points.hands.fit_scan_hands`): how its points are split and its
    hands fitted together, e.g. ``--set hands.candidate_iters=60 --set hands.joint.iters=0``."""
    align_iters: int = 40
    """Adam steps of the rigid alignment of the 24 candidate orientations (proxy, no network)."""
    align_keep: int = 16
    """Distinct candidates that finish the alignment (all of them run its first third)."""
    restarts: int = 8
    """Distinct candidates (best alignment energies) that go on to the pose and field stages."""
    pose_iters: int = 60
    """Adam steps of the articulated proxy stage (pose and translation; no network)."""
    sizes: tuple[float, ...] = (0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2)
    """Hand sizes (times the template's mean skeleton) the size search tries after the
    articulated stage (:mod:`.size_search`); one size (``(1.0,)``), a fixed skeleton or
    ``fit_betas=False`` turns it off."""
    size_iters: int = 15
    """Proxy steps of the best candidate's pose at each size of ``sizes``."""
    finger_iters: int = 30
    """Per-finger restarts after the articulated stage (:mod:`.finger_search`): proxy steps of
    the best candidate's copies with one finger restarted from flat, relaxed, pinch and fist
    (the thumb also from the opposed ok thumb); 0 turns them off."""
    field_iters: int = 200
    """Adam steps of the field stage (all unknowns, the LISA field)."""
    second_pass_iters: int = 100
    """The fingers' second chance, after the field stage (:func:`.stages.second_finger_pass`):
    the per-finger restarts again on a proxy of the fitted hand's own shape and skeleton, and,
    when a finger changes, this many field steps of the changed hand beside the fitted one (the
    better one is kept); 0 turns it off."""
    prune_after: tuple[float, ...] = (0.15, 0.35)
    """Fractions of the field iterations at which the worse candidates stop (by their field
    energy on a fixed subset of the cloud): ``K`` candidates become ``K^(1 - i/n)`` at the
    ``i``-th of ``n`` fractions, so one is left after the last (8 -> 3 -> 1)."""
    points_per_iteration: int = 512
    """Cloud points drawn (without replacement) per iteration; all of them if the cloud is
    smaller."""
    proxy_points: int = 1000
    """Points of the surface proxy used by the first two stages."""
    proxy_tangent_weight: float = 0.1
    """How much of a cloud point's offset from its nearest proxy point counts along the proxy's
    surface (its tangent plane) in the proxy stages: the distance is
    ``sqrt((n . r)^2 + w |r - (n . r) n|^2)``, ``r`` the offset, ``n`` the proxy point's normal.
    1 is the plain point-to-point distance, which the proxy's spacing (about 6 mm between 1000
    points) fills with a floor of several millimetres that hides a curled finger (a finger
    curled far scores no better than a straight one); 0 is point-to-plane (ICP's), which lets
    points slide past a fingertip."""
    init_poses: tuple[str, ...] = ("flat", "relaxed", "fist")
    """Finger poses the candidates start from (names of
    :func:`lisa_hand.handmodel.poses.named_pose`, or 'zero'); each is tried in 24
    orientations."""
    coverage_weight: float = 0.5
    """Weight of the proxy-to-cloud term of the first two stages (every proxy point should be
    near the cloud; robust, so the unseen side of a partial scan costs little); 0: off."""
    coverage_scale_mm: float = 10.0
    """Scale of the Geman-McClure penalty of the coverage term, millimetres."""
    coverage_seen_only: bool = True
    """For a one-view scan whose sensor position is known: ask coverage only of the proxy
    points the sensor could have returned (facing it, not behind the scan's nearest return:
    :meth:`.free_space.DepthImage.could_see`); False: of every proxy point."""
    rotation_lr: float = 0.02
    """Adam step of the global rotation, radians."""
    translation_lr: float = 0.002
    """Adam step of the translation, metres."""
    pose_lr: float = 0.03
    """Adam step of the finger pose (axis-angle), radians."""
    shape_lr: float = 0.3
    """Adam step of the shape code, in units of the training codes' scale (their root mean
    square entry), so that it suits any model."""
    betas_lr: float = 0.05
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
    covered_shape_weight: float = 3e-6
    """``shape_weight`` of the surface stages when the scan covers the hand all round: at least
    ``covered_fraction`` of the best candidate's proxy points within ``covered_mm`` of a scan
    point after the per-finger restarts (a scan from all sides covers about three quarters or
    more, one side about half or less). Where the scan shows the whole surface it, not the
    prior, should set the shape; where it shows one side the prior is what guesses the other."""
    covered_fraction: float = 2.0 / 3.0
    """Share of the proxy within ``covered_mm`` of the scan above which the scan counts as
    covering the hand (1 or more: never)."""
    covered_mm: float = 4.0
    """Distance, millimetres, within which a proxy point counts as covered by the scan (or twice
    the cloud's median point spacing where that is larger: a sparse cloud)."""
    pose_weight: float = 4.5e-4
    """Weight of the finger-pose prior (:func:`lisa_hand.fitting.priors.finger_pose_prior`:
    the mean over the 45 finger values of the squared difference from ``prior_pose``,
    radians^2): keeps unseen fingers near that pose."""
    coupling_weight: float = 3e-4
    """For a one-view scan whose sensor position is known: weight of the flexion coupling of
    the fingers the sensor could not see to their neighbours' (:func:`lisa_hand.fitting.priors.
    finger_coupling`, weighted by :func:`.proxy.unseen_fingers`), radians^2; 0: off."""
    unseen_thumb_weight: float = 3e-4
    """For a one-view scan whose sensor position is known: weight of the unseen thumb's pull
    toward ``prior_pose`` (:func:`lisa_hand.fitting.priors.thumb_pose_prior`, weighted by the
    thumb's :func:`.proxy.unseen_fingers` weight), radians^2; 0: off. The thumb has no
    neighbour to follow, and without this pull the free space pushes a thumb hidden behind the
    palm anywhere the sensor could not see, such as tucked under the palm."""
    unseen_share: float = 0.2
    """A finger of which less than this share of the surface could have been seen by the sensor
    counts as unseen (linearly: none seen, fully)."""
    prior_pose: str = "relaxed"
    """The pose the finger-pose prior pulls toward ('relaxed' or 'flat'): what a finger the
    scan does not show is guessed to be. Relaxed by default: a finger hidden in a one-view scan
    is more often half bent than straight."""
    limit_weight: float = 1e-2
    """Weight of the squared excess of the finger joints' anatomical angles over their limits
    (:func:`lisa_hand.fitting.priors.joint_limit_excess`), radians^2."""
    betas_weight: float = 1e-4
    """Weight of the mean square of the template's shape coefficients (betas)."""
    normal_weight: float = 0.5
    """Weight of the offset-point term when the cloud has normals (0 turns it off)."""
    free_space_weight: float = 1.0
    """Weight of the free-space term of the surface stage, for a one-view scan whose sensor
    position is known (``fit_points(viewpoint=...)``, ``lisa fit-points --viewpoint``): the
    robust penalty of the field being inside at points the sensor saw to be empty
    (:mod:`.free_space`); 0: off."""
    support_weight: float = 1.0
    """Weight of the support bound, for a scan of a hand resting on a surface that was found
    in it (``fit_points(support="auto")``, :mod:`.support`): the proxy stages' robust penalty of
    proxy points beyond the plane; the surface stage gets points just beyond it under the hand
    among its free-space points (weighted by ``free_space_weight``). 0: neither (the plane's
    points are still left out)."""
    free_space_points: int = 4096
    """Free-space points drawn once per fit over the whole view, and as many near the surface
    stage's candidates (``points_per_iteration`` of all of them each iteration)."""
    free_near_every: int = 25
    """Surface-stage steps between two draws of the free-space points near the candidates'
    surfaces (also drawn at each pruning), so that they follow a finger that moves."""
    normal_offset_mm: float = 3.0
    """Offset ``eps`` of the normal term's points along the normals, millimetres."""
    fit_shape: bool = True
    """Optimise the shape code (False: keep the training subjects' mean)."""
    fit_betas: bool = True
    """Optimise the template's betas (the skeleton); ignored with a fixed ``rest_joints``."""
    wrist_clip_m: float | None = 0.01
    """Where the hand ends: points farther than this beyond the fitted wrist joint, towards the
    forearm, are left out of the fit (a forearm in the scan), and the surface proxy's own stub
    beyond it is not asked to be covered (a scan cut short); metres, the plane of
    :func:`lisa_hand.skeleton.wrist.wrist_plane` (:data:`~lisa_hand.skeleton.wrist.WRIST_CLIP_M`
    by default). The written mesh and the metrics cut at the same plane. None: every point
    counts, nothing is cut."""
    wrist_margin_m: float = 0.03
    """After the global-pose search, whose wrist is known only roughly, points are dropped only
    beyond ``wrist_clip_m + wrist_margin_m``; after the articulated stage, beyond
    ``wrist_clip_m``."""
    max_points: int = 200_000
    """A larger cloud is randomly subsampled to this many points first."""
    min_points: int = 20
    """Fewer points than this is an error."""
    final_lr_fraction: float = 0.1
    """The learning rates fall (cosine) to this fraction of their value over each stage."""
    device: str | None = None
    """Where to fit ('cpu', 'cuda', ...); None: the model's device."""
    num_threads: int | None = 1
    """Torch intra-op threads during a CPU fit (restored afterwards); None keeps the current
    setting. The fit is many small operations: more threads barely help, and on cores shared
    with other processes OpenMP's spinning makes them over ten times slower."""
    seed: int = 0
    """Seed of the random point subsets."""
    tries: int = 1
    """Fits from seeds ``seed``, ``seed + 1``, ...; the one nearest the scan is kept
    (:func:`lisa_hand.fitting.points.hypotheses.best_of`; ``lisa fit-points --tries``)."""

    def __post_init__(self) -> None:
        from .global_pose import initial_finger_pose

        stages = self.stages
        if (not isinstance(stages, tuple) or "align" not in stages or "field" not in stages
                or any(name not in POINT_STAGES for name in stages)
                or [POINT_STAGES.index(name) for name in stages]
                != sorted({POINT_STAGES.index(name) for name in stages})):
            raise ValueError(f"stages must name, in the order {', '.join(POINT_STAGES)}, "
                             f"each at most once, a set holding align and field; got {stages!r}")
        check_int_fields(self, ("align_iters", "pose_iters", "finger_iters", "field_iters",
                                "second_pass_iters", "size_iters"), 0)
        sizes = self.sizes
        if (not isinstance(sizes, tuple) or not sizes or any(
                isinstance(f, bool) or not isinstance(f, (int, float)) or not 0.5 <= f <= 2.0
                for f in sizes)):
            raise ValueError(f"sizes must be a non-empty tuple of hand sizes in [0.5, 2], got "
                             f"{sizes!r}")
        check_int_fields(self, ("free_space_points", "free_near_every", "align_keep",
                                "restarts", "points_per_iteration", "proxy_points",
                                "max_points", "min_points", "tries"), 1)
        if not self.init_poses:
            raise ValueError("init_poses must name at least one pose")
        for name in self.init_poses:
            initial_finger_pose(name)  # raises for an unknown name
        if self.robust_loss not in ROBUST_LOSSES:
            raise ValueError(f"robust_loss must be one of {ROBUST_LOSSES}, got "
                             f"{self.robust_loss!r}")
        if self.prior_pose not in PRIOR_POSES:
            raise ValueError(f"prior_pose must be one of {PRIOR_POSES}, got {self.prior_pose!r}")
        for name in ("rotation_lr", "translation_lr", "pose_lr", "shape_lr", "betas_lr",
                     "robust_scale_mm", "robust_scale_start_mm", "normal_offset_mm",
                     "coverage_scale_mm", "unseen_share"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        clip = self.wrist_clip_m
        if clip is not None and not (isinstance(clip, (int, float)) and math.isfinite(clip)):
            raise ValueError(f"wrist_clip_m must be a number of metres or None, got {clip!r}")
        for name in ("shape_weight", "covered_shape_weight", "covered_fraction", "covered_mm",
                     "pose_weight", "limit_weight", "betas_weight",
                     "normal_weight", "free_space_weight", "support_weight", "coverage_weight",
                     "wrist_margin_m", "coupling_weight", "unseen_thumb_weight",
                     "proxy_tangent_weight"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {value!r}")
        prune = self.prune_after
        if (not isinstance(prune, tuple) or not prune or any(
                not isinstance(f, (int, float)) or not 0.0 <= f <= 1.0 for f in prune)
                or list(prune) != sorted(prune)):
            raise ValueError(f"prune_after must be a non-empty increasing tuple of fractions in "
                             f"[0, 1], got {prune!r}")
        threads = self.num_threads
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ValueError(f"num_threads must be a positive int or None, got {threads!r}")
        if not 0.0 < self.final_lr_fraction <= 1.0:
            raise ValueError(f"final_lr_fraction must be in (0, 1], got {self.final_lr_fraction!r}")
