"""The settings of ``lisa fit-video`` (:class:`FitVideoConfig`): detection and tracking, the
keyframe fit (a photo fit, :class:`~lisa_hand.fitting.photo.config.FitPhotoConfig`), the
motion fit (:class:`MotionConfig`) and the outputs. The fit is
:mod:`lisa_hand.fitting.video.fit`."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..photo.config import FitPhotoConfig

__all__ = ["MotionConfig", "FitVideoConfig"]


@dataclass(frozen=True)
class MotionConfig:
    """The per-frame pose and translation fit of a tracked hand
    (:func:`lisa_hand.fitting.video.motion.fit_motion`), in windows of frames.

    The energy of a window: the keypoints' reprojection (pseudo-Huber, in percent of the hand's
    size in the image, weighed by the detector's score; bridged frames have none), the finger
    pose prior and joint limits of every fitter (:func:`lisa_hand.fitting.terms.hand_prior`),
    and the motion prior: the 3D keypoints' velocity and acceleration (m/s, m/s^2) and the
    joints' turning speed above ``max_joint_speed``.
    """

    window: int = 40
    """Frames a window holds (its first ``overlap`` already fitted, held fixed)."""
    overlap: int = 4
    """Frames each window shares with the one before: they carry the motion across."""
    window_iters: int = 25
    """Adam steps a window: the windows only bring every frame near its pose; the pass over
    all frames converges."""
    refine_iters: int = 400
    """Iterations of the final pass over every frame of a segment at once."""
    pose_lr: float = 0.02
    translation_lr: float = 0.004
    final_lr_fraction: float = 0.2
    keypoint_scale: float = 1.0
    """The pseudo-Huber scale of the keypoint residuals, percent of the hand's size."""
    keypoint_weight: float = 1.0
    pose_weight: float = 0.02
    """The finger-pose prior's weight (toward the relaxed hand)."""
    limit_weight: float = 10.0
    """The joint limits' weight."""
    betas_lr: float = 0.1
    """Adam learning rate of the skeleton's template betas in the final pass over every frame:
    the clip's one skeleton, fitted on all its frames, starting from the keyframe's (the
    tracked fit only; 0: the keyframe's kept)."""
    betas_weight: float = 1.0
    """x the mean square of the skeleton's template betas (with ``betas_lr``)."""
    velocity_weight: float = 1e-4
    """x the mean squared velocity of the 3D keypoints, (m/s)^2."""
    acceleration_weight: float = 1e-3
    """x the mean squared acceleration of the 3D keypoints, (m/s^2)^2."""
    articulation_weight: float = 5e-3
    """x the mean squared acceleration of the 3D keypoints relative to the wrist across their
    camera rays, (m/s^2)^2: the hand's own motion as the image sees it."""
    depth_articulation_weight: float = 5e-3
    """x the same along the camera rays: the hand's own motion in depth, which one view leaves
    open; smoothing it costs less agreement with the detections than smoothing across."""
    landmark_weight: float = 30.0
    """x the mean over the 20 bones of 1 - cos(angle) between the fitted bone and the one of
    the detector's 3D landmarks (:func:`lisa_hand.fitting.images.terms.direction_misfit`):
    which way each finger bends in depth, which the keypoints' pixels leave open."""
    max_joint_speed: float = 25.0
    """rad/s: a finger joint turning faster than this is penalised."""
    joint_speed_weight: float = 1e-3
    prior_pose: str = "relaxed"
    """The named pose the finger prior pulls toward."""

    def __post_init__(self) -> None:
        if isinstance(self.refine_iters, bool) or not isinstance(self.refine_iters, int) \
                or self.refine_iters < 0:
            raise ValueError(f"refine_iters must be an integer >= 0, got {self.refine_iters!r}")
        for name in ("window", "window_iters"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not 0 <= self.overlap < self.window:
            raise ValueError(f"overlap must be in [0, window), got {self.overlap}")
        if not self.betas_lr >= 0:
            raise ValueError(f"betas_lr must be >= 0, got {self.betas_lr!r}")
        for name in ("pose_lr", "translation_lr", "keypoint_scale", "max_joint_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("keypoint_weight", "pose_weight", "limit_weight", "betas_weight",
                     "velocity_weight", "acceleration_weight", "articulation_weight",
                     "depth_articulation_weight", "landmark_weight", "joint_speed_weight"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0 < self.final_lr_fraction <= 1:
            raise ValueError(f"final_lr_fraction must be in (0, 1], got {self.final_lr_fraction}")


@dataclass(frozen=True)
class FitVideoConfig:
    """Settings of :func:`lisa_hand.fitting.video.fit.fit_video`."""

    keyframe: FitPhotoConfig = field(default_factory=FitPhotoConfig)
    """The fit of each hand's keyframes (shape, skeleton, colour; a photo fit)."""
    keyframes: int = 3
    """At most this many keyframes a hand (the best-seen frame, and the best-seen of each
    other part of the clip), fitted together: one shape, skeleton and colour, a pose each."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """The per-frame pose fit."""
    max_side: int = 1280
    """Frames are downscaled to at most this long side for detection and fitting, pixels
    (results are given in the clip's own pixels)."""
    max_hands: int = 2
    """At most this many hands are followed."""
    detection_confidence: float = 0.5
    """MediaPipe's palm-detection threshold."""
    tracking_confidence: float = 0.5
    """MediaPipe's landmark-tracking threshold (below it the palm detector runs again)."""
    model_complexity: int = 1
    """MediaPipe's landmark model: 0 (lite) or 1 (full)."""
    bridge_s: float = 0.5
    """Dropouts of the detector up to this long are bridged, seconds; a longer gap ends a
    segment (the hand is absent there)."""
    match_fraction: float = 1.0
    """A detection further than this from a track's last keypoints (mean distance over the
    hand's size) is another hand."""
    min_frames: int = 3
    """A track with fewer detected frames is dropped (a false detection)."""
    min_hand_px: float = 16.0
    """A keyframe's hand must be at least this large (wrist-to-knuckle length, pixels)."""
    independent: bool = False
    """Every frame fitted alone (no motion prior, no bridging; each frame starts from the
    previous frame's fit): the reference of the benchmark."""
    overlay_alpha: float = 0.75
    """The rendered hand's opacity in ``overlay.mp4``."""
    overlay_faces: int = 5000
    """The hand's mesh is decimated to this many faces for ``overlay.mp4`` and the report's
    frames (``mesh.ply`` and ``hand.glb`` keep every face)."""
    overlay_max_side: int = 256
    """Each hand is rendered into ``overlay.mp4`` at most this many pixels a side, then
    resized to its place (the time a frame takes stays that of a small hand's)."""
    overlay_supersample: int = 1
    """Rays a pixel side of the overlay's rendering."""
    report_frames: int = 4
    """Frames shown in ``report.html``."""
    num_threads: int = 2
    """CPU threads of the fit."""

    def __post_init__(self) -> None:
        if not isinstance(self.keyframe, FitPhotoConfig):
            raise TypeError(f"keyframe must be a FitPhotoConfig, got {type(self.keyframe)}")
        if not isinstance(self.motion, MotionConfig):
            raise TypeError(f"motion must be a MotionConfig, got {type(self.motion)}")
        for name in ("keyframes", "max_side", "max_hands", "min_frames", "overlay_faces",
                     "overlay_max_side",
                     "overlay_supersample",
                     "report_frames", "num_threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("detection_confidence", "tracking_confidence"):
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"{name} must be in (0, 1), got {getattr(self, name)!r}")
        if self.model_complexity not in (0, 1):
            raise ValueError(f"model_complexity must be 0 or 1, got {self.model_complexity!r}")
        for name in ("bridge_s", "match_fraction", "min_hand_px"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0 <= self.overlay_alpha <= 1:
            raise ValueError(f"overlay_alpha must be in [0, 1], got {self.overlay_alpha!r}")
