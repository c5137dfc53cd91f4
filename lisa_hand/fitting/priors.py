"""The one pose prior and the one joint-limit term, shared by every fitter (points, images, the
MANO-like template).

* :func:`joint_limit_excess`: sum over the 15 finger joints of the squared excess of the anatomical
  angles (flexion, spread, twist of :func:`lisa_hand.handmodel.poses.pose_to_angles`) over
  :data:`~lisa_hand.handmodel.poses.JOINT_LIMITS`, radians^2; zero inside the limits.
* :func:`finger_pose_prior`: mean over the 45 finger values of the squared difference from a
  named mean pose (radians^2): a weak pull of the fingers toward a natural pose where the data
  says little (occluded fingers, one view).
* :func:`finger_coupling`: the squared difference of chosen fingers' flexion from their
  neighbours' (radians^2): an unseen finger curls as the fingers beside it do.
* :func:`thumb_pose_prior`: the thumb's part of :func:`finger_pose_prior` (radians^2): an unseen
  thumb, which has no neighbour to follow, is guessed to be in the mean pose.

All are differentiable and batched; the global rotation (pose[:, :3]) is never penalised.
"""

from __future__ import annotations

import torch

from ..skeleton import FINGER_JOINTS, POSE_DIM

__all__ = ["PRIOR_POSES", "COUPLED_FINGERS", "prior_mean_fingers", "joint_limit_excess",
           "finger_pose_prior", "finger_coupling", "thumb_pose_prior", "UNSEEN_FINGERS"]

PRIOR_POSES = ("relaxed", "flat")
"""Named poses a finger-pose prior may pull toward (:func:`lisa_hand.handmodel.named_pose`)."""

_FINGER_DIM = POSE_DIM - 3

COUPLED_FINGERS = ("index", "middle", "ring", "pinky")
"""The fingers :func:`finger_coupling` weighs, in the order of its weights; each one's
neighbours are the fingers beside it in this order."""
_NEIGHBOUR_MEAN = torch.tensor([[0.0, 1.0, 0.0, 0.0],
                                [0.5, 0.0, 0.5, 0.0],
                                [0.0, 0.5, 0.0, 0.5],
                                [0.0, 0.0, 1.0, 0.0]])
"""[4, 4] row f: the mean over finger f's neighbours in :data:`COUPLED_FINGERS`."""
UNSEEN_FINGERS = COUPLED_FINGERS + ("thumb",)
"""The fingers whose unseen weights a one-view fit carries (:func:`lisa_hand.fitting.points.proxy.
unseen_fingers`), in this order: those of :func:`finger_coupling`, then the thumb's, for
:func:`thumb_pose_prior`."""
_THUMB_VALUES = [3 * (joint - 1) + axis for joint in FINGER_JOINTS["thumb"] for axis in range(3)]
"""The thumb's 9 values among the 45 finger values."""
_COUPLED_JOINTS = [joint for name in COUPLED_FINGERS for joint in FINGER_JOINTS[name]]
"""The 12 joints of :data:`COUPLED_FINGERS`, three a finger, in that order."""


def prior_mean_fingers(name: str = "relaxed", device: torch.device | str = "cpu",
                       dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """[45] finger pose (radians) of the named pose ``name`` (one of :data:`PRIOR_POSES`)."""
    from ..handmodel.poses import named_pose

    if name not in PRIOR_POSES:
        raise ValueError(f"prior pose must be one of {', '.join(PRIOR_POSES)}, got {name!r}")
    return named_pose(name)[3:].to(device=device, dtype=dtype)


def _full_pose(pose: torch.Tensor) -> torch.Tensor:
    if pose.dim() != 2 or pose.shape[-1] not in (POSE_DIM, _FINGER_DIM):
        raise ValueError(f"pose must have shape [B, {POSE_DIM}] or [B, {_FINGER_DIM}] (finger "
                         f"values only), got {list(pose.shape)}")
    if pose.shape[-1] == _FINGER_DIM:
        pose = torch.cat([pose.new_zeros(pose.shape[0], 3), pose], dim=-1)
    return pose


def joint_limit_excess(pose: torch.Tensor) -> torch.Tensor:
    """Squared excess over the joint limits.

    pose: [B, 48] axis-angle radians, or [B, 45] finger values only -> [B] radians^2.
    """
    from ..handmodel.poses import JOINT_LIMITS, pose_to_angles

    angles = pose_to_angles(_full_pose(pose))  # [B, 15, 3]
    limits = JOINT_LIMITS.to(angles)
    excess = torch.relu(limits[..., 0] - angles) + torch.relu(angles - limits[..., 1])
    return (excess * excess).flatten(1).sum(-1)


def _from_mean(pose: torch.Tensor, mean_fingers: torch.Tensor) -> torch.Tensor:
    """[B, 45] the finger values of ``pose`` ([B, 48] or [B, 45]) minus ``mean_fingers`` [45]."""
    fingers = _full_pose(pose)[:, 3:]
    if mean_fingers.shape != (_FINGER_DIM,):
        raise ValueError(f"mean_fingers must have shape [{_FINGER_DIM}], got "
                         f"{list(mean_fingers.shape)}")
    return fingers - mean_fingers.to(fingers)


def finger_pose_prior(pose: torch.Tensor, mean_fingers: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of the finger values from ``mean_fingers``.

    pose: [B, 48] or [B, 45] radians; mean_fingers: [45] radians (:func:`prior_mean_fingers`)
    -> [B] radians^2.
    """
    return _from_mean(pose, mean_fingers).square().mean(-1)


def finger_coupling(pose: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Flexion of fingers pulled toward their neighbours'.

    For each finger ``f`` of :data:`COUPLED_FINGERS` with weight ``w_f`` (weights: [4], 0-1),
    ``w_f`` times the mean over its three joints of the squared difference between its flexion
    (the joint's axis-angle about the local z axis, the curl of :func:`lisa_hand.handmodel.
    named_pose`'s poses) and the mean flexion of the fingers beside it at the same joint, the
    neighbours taken as they are (no gradient flows into them: an unseen finger follows the seen
    ones, not the reverse).

    pose: [B, 48] or [B, 45] radians (a right hand's) -> [B] radians^2.
    """
    if weights.shape != (len(COUPLED_FINGERS),):
        raise ValueError(f"weights must have shape [{len(COUPLED_FINGERS)}], got "
                         f"{list(weights.shape)}")
    flexion = _full_pose(pose).reshape(pose.shape[0], -1, 3)[..., 2]  # [B, 16]
    chains = flexion[:, _COUPLED_JOINTS].reshape(pose.shape[0], len(COUPLED_FINGERS), 3)
    beside = torch.einsum("fg,bgj->bfj", _NEIGHBOUR_MEAN.to(chains), chains.detach())
    return ((chains - beside).square().mean(-1) * weights.to(chains)).sum(-1)


def thumb_pose_prior(pose: torch.Tensor, mean_fingers: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of the thumb's 9 values from those of ``mean_fingers``.

    pose: [B, 48] or [B, 45] radians; mean_fingers: [45] radians (:func:`prior_mean_fingers`)
    -> [B] radians^2.
    """
    return _from_mean(pose, mean_fingers)[:, _THUMB_VALUES].square().mean(-1)
