"""The settings of the joint fit of several hands (:class:`JointConfig`)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["JointConfig"]


@dataclass(frozen=True)
class JointConfig:
    """How :func:`lisa_hand.fitting.pair.joint.fit_hands_together` refines hands fitted alone.

    The same vocabulary as every fitter (``*_iters``, ``*_lr``, ``*_weight``); the prior's
    weights are :func:`lisa_hand.fitting.terms.hand_prior`'s."""

    iters: int = 150
    """Adam steps of the joint stage; 0: the hands stay as fitted alone (the reference)."""
    pose_lr: float = 0.01
    translation_lr: float = 0.0005
    shape_lr: float = 0.01
    final_lr_fraction: float = 0.2
    keypoint_weight: float = 1.0
    """Each hand's 2D keypoints, pseudo-Huber of the distance in percent of its size."""
    keypoint_scale: float = 2.0
    """Where the keypoints' pseudo-Huber turns linear, percent of the hand's size."""
    scan_weight: float = 1.0
    """A scan's points: each hand's SDF at its own points, pseudo-Huber in mm."""
    scan_scale_mm: float = 2.0
    """Where the scan term's pseudo-Huber turns linear, mm."""
    scan_points: int = 2000
    """At most this many of a hand's scan points are used (a fixed random subset)."""
    stay_weight: float = 1.0
    """The finger pose (radians^2) and shape code (in units of the training codes' spread)
    toward the hand's own fit: the joint stage moves them only as far as the contact needs."""
    place_weight: float = 0.01
    """The translation toward the hand's own fit (mm^2): a hand moves out of another only as
    far as it must (nothing else holds its depth in one photo)."""
    penetration_weight: float = 20.0
    """Squared depth (mm^2) of each hand's surface samples inside another hand, averaged over
    the samples."""
    contact_mm: float = 0.5
    """Depth inside another hand allowed before it counts: touching is contact, not overlap."""
    order_weight: float = 1.0
    """Squared depth error (mm^2) of a hand's samples seen in another hand's mask but not
    behind it (the masks say which hand is in front)."""
    order_radius_px: float = 3.0
    """The hand in front's depth at a pixel: its samples projecting this close to it."""
    order_margin_px: float = 3.0
    """Only samples this far inside the other hand's mask count (a mask's edge is uncertain by a
    few pixels)."""
    order_scale_mm: float = 2.0
    """Where the order term's pseudo-Huber turns linear, mm (a sample far on the wrong side
    costs in proportion, not its square)."""
    samples: int = 1000
    """Surface samples a hand (vertices of its mesh)."""
    pose_weight: float = 0.02
    limit_weight: float = 10.0
    betas_weight: float = 0.0
    prior_pose: str = "relaxed"
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("iters", "samples", "scan_points", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        for name in ("pose_lr", "translation_lr", "shape_lr", "keypoint_scale",
                     "scan_scale_mm", "order_radius_px", "order_scale_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("final_lr_fraction", "keypoint_weight", "scan_weight", "stay_weight",
                     "place_weight", "order_margin_px",
                     "penetration_weight", "contact_mm", "order_weight", "pose_weight",
                     "limit_weight", "betas_weight"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
