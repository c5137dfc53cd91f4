"""The unknowns of the point fit's stages while they optimise: ``K`` candidate hands batched as
tensors.

A stage takes and returns :class:`~lisa_hand.skeleton.params.HandParams`; inside, it optimises
a :class:`CandidateBatch`, which moves the global rotation about a fixed pivot (the surface
proxy's rest centroid) rather than about the wrist: a rotation step then does not swing the
hand's middle away, so rotation and translation can take Adam steps of their own sizes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch

from ...geometry import axis_angle_to_matrix, matrix_to_axis_angle
from ...skeleton.params import HandParams
from ..terms import HandTerms

__all__ = ["CandidateBatch"]


class CandidateBatch:
    """The unknowns of K candidates and how they map to LISA's inputs.

    The global rotation is ``exp(delta) R0`` (``delta`` optimised, ``R0`` fixed per stage) about
    the pivot ``c`` [3], which lands at world position ``position``:
    ``x_world = R (x_rest_posed - c) + position``, i.e. MANO's translation
    ``t = position - R c + R j0 - j0`` (``j0`` the rest wrist).

    base_rotation: [K, 3, 3]; position: [K, 3] metres; finger_pose: [K, 45] radians;
    shape_code: [K, D]; betas: [K, B] or None (None: not optimised); tag: [K] long or None
    (which initial finger pose each candidate started from); rest_joints: [K, 16, 3] metres or
    None, the candidates' skeletons where they are fixed (not optimised).
    """

    def __init__(self, base_rotation, position, finger_pose, shape_code, betas=None, tag=None,
                 *, pivot: torch.Tensor, rest_joints: torch.Tensor | None = None) -> None:
        self.tag = tag
        self.rest_joints = rest_joints
        self.base_rotation = base_rotation  # fixed within a stage
        self.delta = torch.zeros_like(position).requires_grad_(True)
        # leaves of their own (a batch selected from another must not stay in its graph: the
        # optimiser steps leaves only)
        self.position = position.detach().clone().requires_grad_(True)
        self.finger_pose = finger_pose.detach().clone().requires_grad_(True)
        self.shape_code = shape_code.detach().clone().requires_grad_(True)
        self.betas = None if betas is None else betas.detach().clone().requires_grad_(True)
        self.pivot = pivot

    @classmethod
    @torch.no_grad()
    def from_hands(cls, hands: Sequence[HandParams], pivot: torch.Tensor, *,
                   with_betas: bool = False) -> CandidateBatch:
        """The batch of right hands ``hands`` (their skeletons, ``rest_joints``, define the
        wrists of the translations and are the batch's fixed skeletons), on the pivot's device
        and dtype. with_betas: carry the hands' betas as unknowns (every hand must have them).
        """
        if not hands:
            raise ValueError("hands must hold at least one candidate hand")
        like = dict(device=pivot.device, dtype=pivot.dtype)
        pose = torch.stack([hand.pose for hand in hands]).to(**like)
        translation = torch.stack([hand.translation for hand in hands]).to(**like)
        rest_joints = torch.stack([hand.rest_joints for hand in hands]).to(**like)
        wrist = rest_joints[:, 0]
        rotation = axis_angle_to_matrix(pose[:, :3])
        turn = (rotation @ (wrist - pivot)[..., None])[..., 0]
        position = translation - turn + wrist
        shape_code = torch.stack([hand.shape_code for hand in hands]).to(**like)
        betas = None
        if with_betas:
            if any(hand.betas is None for hand in hands):
                raise ValueError("with_betas needs every hand's betas")
            betas = torch.stack([hand.betas for hand in hands]).to(**like)
        return cls(rotation, position, pose[:, 3:], shape_code, betas, pivot=pivot,
                   rest_joints=rest_joints)

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def rotation(self) -> torch.Tensor:
        """[K, 3, 3] the global rotations."""
        return axis_angle_to_matrix(self.delta) @ self.base_rotation

    def mano(self, rest_joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(pose [K, 48], translation [K, 3]) for rest joints [K, 16, 3]."""
        rotation = self.rotation()
        wrist = rest_joints[:, 0]
        turn = (rotation @ (wrist - self.pivot)[..., None])[..., 0]
        translation = self.position + turn - wrist
        pose = torch.cat([matrix_to_axis_angle(rotation), self.finger_pose], dim=-1)
        return pose, translation

    @torch.no_grad()
    def hand(self, index: int, like: HandParams, rest_joints: torch.Tensor | None = None
             ) -> HandParams:
        """Candidate ``index`` as :class:`HandParams` (a detached CPU copy) on rest joints
        [K, 16, 3] (default: the batch's fixed ones); colour code, side and model come from
        ``like`` (and its betas when the batch has none)."""
        rest_joints = self.rest_joints if rest_joints is None else rest_joints
        pose, translation = self.mano(rest_joints)
        betas = like.betas if self.betas is None else self.betas[index].detach().cpu().float()
        return replace(like, pose=pose[index].detach().cpu().float(),
                       translation=translation[index].detach().cpu().float(),
                       rest_joints=rest_joints[index].detach().cpu().float(),
                       shape_code=self.shape_code[index].detach().cpu().float(), betas=betas,
                       extra={})

    def unknowns(self, with_shape: bool) -> list[torch.Tensor | None]:
        """The optimised tensors: rotation, position, finger pose, shape code (or None) and
        betas (or None)."""
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
    def terms(self) -> HandTerms:
        """What the prior terms read of the batch (:class:`lisa_hand.fitting.terms.HandTerms`):
        the finger pose, the shape code and the betas (None when not carried)."""
        return HandTerms(pose=self.finger_pose, shape_code=self.shape_code, betas=self.betas)

    def select(self, index: torch.Tensor) -> CandidateBatch:
        """A new batch of the candidates ``index`` [K'] (``delta`` folded first)."""
        self.fold()
        return CandidateBatch(self.base_rotation[index], self.position[index],
                              self.finger_pose[index], self.shape_code[index],
                              None if self.betas is None else self.betas[index],
                              None if self.tag is None else self.tag[index], pivot=self.pivot,
                              rest_joints=None if self.rest_joints is None
                              else self.rest_joints[index])
