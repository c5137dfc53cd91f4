"""MANO interop: pose the official MANO model (:class:`ManoLayer`, :func:`mano_forward`); the file
reader is :mod:`.mano_file` (re-exported here).

The maths follows smplx's MANO exactly (Loper et al. SMPL, Eq. 1-4; MANO, Sec. 3):

* shaped template ``T(beta) = T_bar + S beta`` (``shapedirs``),
* rest joints ``J(beta) = J_regressor T(beta)``,
* pose corrective ``P(theta) = posedirs . vec(R_j(theta) - I)`` over the 15 finger joints (135-D),
* forward kinematics and linear blend skinning of ``T(beta) + P(theta)``, then the translation.

The layer works in the units of the file (metres for the official files).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .kinematics import check_side, forward_kinematics, linear_blend_skinning
from .mano_file import NUM_MANO_VERTICES, POSE_FEATURE_DIM, ManoData, load_mano_pkl
from .tree import MANO_FINGERTIP_VERTEX_IDS, POSE_DIM, joints_to_keypoints

__all__ = [
    "NUM_MANO_VERTICES",
    "NUM_HAND_POSE",
    "POSE_FEATURE_DIM",
    "ManoData",
    "ManoOutput",
    "ManoLayer",
    "load_mano_pkl",
    "mano_full_pose",
    "mano_pose_features",
    "mano_forward",
]

NUM_HAND_POSE = POSE_DIM - 3  # 45: the 15 finger joints' axis-angles


# --------------------------------------------------------------------------------------------------
# Plain functions


@dataclass
class ManoOutput:
    """Result of :func:`mano_forward` / :class:`ManoLayer` (world frame, units of the file: metres).

    vertices: [B, 778, 3] posed vertices, translation included.
    joints: [B, 16, 3] posed joints in MANO order (wrist, index, middle, pinky, ring, thumb).
    keypoints: [B, 21, 3] the 16 joints plus the fingertip vertices
        (:data:`MANO_FINGERTIP_VERTEX_IDS`) in the OpenPose/MediaPipe order of
        :func:`joints_to_keypoints`.
    transforms: [B, 16, 4, 4] rest-to-posed bone transforms ``A_j`` (translation included).
    full_pose: [B, 48] axis-angle radians actually applied: global orientation plus the finger
        pose after PCA and the mean hand (smplx's ``full_pose``).
    bone_frames: [B, 16, 4, 4] world-from-bone frames (:attr:`Kinematics.bone_frames`).
    rest_joints: [B, 16, 3] joints of the shaped template in the rest pose (``J(beta)``).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    keypoints: torch.Tensor
    transforms: torch.Tensor
    full_pose: torch.Tensor
    bone_frames: torch.Tensor
    rest_joints: torch.Tensor


def mano_full_pose(
    global_orient: torch.Tensor,
    hand_pose: torch.Tensor,
    hand_mean: torch.Tensor,
    hand_components: torch.Tensor | None = None,
) -> torch.Tensor:
    """smplx's MANO pose: ``cat(global_orient, hand_pose @ components (PCA) + hand_mean)``.

    global_orient: [B, 3] axis-angle radians.
    hand_pose: [B, 45] axis-angle radians, or [B, n] PCA coefficients when ``hand_components``.
    hand_mean: [45] radians (zeros for a flat hand).
    hand_components: [n, 45] the first n rows of ``hands_components``, or None.
    -> [B, 48]
    """
    if hand_components is not None:
        hand_pose = hand_pose @ hand_components
    return torch.cat([global_orient, hand_pose + hand_mean], dim=-1)


def mano_pose_features(rotmats: torch.Tensor) -> torch.Tensor:
    """MANO's pose-corrective feature ``vec(R_j - I)`` over the 15 finger joints.

    rotmats: [B, 16, 3, 3] relative joint rotations -> [B, 135] (joint-major, then row, column)
    """
    eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
    return (rotmats[:, 1:] - eye).reshape(rotmats.shape[0], POSE_FEATURE_DIM)


def mano_forward(
    full_pose: torch.Tensor,
    betas: torch.Tensor,
    translation: torch.Tensor | None,
    *,
    template_vertices: torch.Tensor,
    shape_dirs: torch.Tensor,
    pose_dirs: torch.Tensor,
    joint_template: torch.Tensor,
    joint_shape_dirs: torch.Tensor,
    skinning_weights: torch.Tensor,
    fingertip_vertex_ids: torch.Tensor,
) -> ManoOutput:
    """Shape, pose-correct, pose and skin MANO (SMPL Eq. 1-4 with MANO's tree).

    full_pose: [B, 48] axis-angle radians (global orientation + 15 finger joints).
    betas: [B, S] shape coefficients.
    translation: [B, 3] metres, or None.
    template_vertices: [V, 3] metres. shape_dirs: [V, 3, S]. pose_dirs: [135, V * 3] (the file's
        ``posedirs`` reshaped to [V * 3, 135] and transposed).
    joint_template: [16, 3] ``J_regressor @ template_vertices``.
    joint_shape_dirs: [16, 3, S] ``J_regressor`` applied to each shape direction, so that the
        rest joints ``J_regressor @ T(beta)`` cost 16 rows instead of 778.
    skinning_weights: [V, 16]. fingertip_vertex_ids: [5] long (thumb, index, middle, ring, pinky).
    """
    batch = full_pose.shape[0]
    shaped = template_vertices + torch.einsum("bs,vcs->bvc", betas, shape_dirs)
    rest_joints = joint_template + torch.einsum("bs,jcs->bjc", betas, joint_shape_dirs)
    kinematics = forward_kinematics(full_pose, rest_joints, translation)
    offsets = (mano_pose_features(kinematics.rotmats) @ pose_dirs).reshape(batch, -1, 3)
    vertices = linear_blend_skinning(shaped + offsets, skinning_weights, kinematics.transforms)
    fingertips = vertices.index_select(1, fingertip_vertex_ids)
    return ManoOutput(
        vertices=vertices,
        joints=kinematics.joints,
        keypoints=joints_to_keypoints(kinematics.joints, fingertips),
        transforms=kinematics.transforms,
        full_pose=full_pose,
        bone_frames=kinematics.bone_frames,
        rest_joints=rest_joints,
    )


# --------------------------------------------------------------------------------------------------
# Layer


class ManoLayer(nn.Module):
    """MANO as an ``nn.Module`` holding only buffers; the maths is :func:`mano_forward`.

    Semantics match ``smplx.MANO``: ``hand_pose`` is the 45-D finger pose, or ``num_pca_comps``
    coefficients of ``hands_components`` when ``use_pca``; unless ``flat_hand_mean`` the file's
    ``hands_mean`` is added to the finger pose (after PCA), so a zero pose is MANO's mean hand.
    Defaults differ from smplx in one place: ``use_pca=False``.

    Left hands: the official ``MANO_LEFT.pkl`` has a shape-direction quirk (see
    :func:`load_mano_pkl`, ``fix_left_shapedirs``); by default the file is used as it is.

    The buffers are not part of ``state_dict`` (``persistent=False``): MANO's licensed arrays never
    end up in a checkpoint. Move the layer with ``.to(device)``; inputs must be on its device and
    of its dtype.
    """

    def __init__(
        self,
        model: str | os.PathLike | ManoData,
        side: str | None = None,
        *,
        use_pca: bool = False,
        num_pca_comps: int = 6,
        flat_hand_mean: bool = False,
        fix_left_shapedirs: bool = False,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        """
        model: path of a MANO ``.pkl`` or an already loaded :class:`ManoData`.
        side: 'right'/'left' (see :func:`load_mano_pkl`); must match ``model.side`` for ManoData.
        use_pca: ``hand_pose`` holds PCA coefficients instead of 45 axis-angle values.
        num_pca_comps: number of PCA components (1 to 45), used only with ``use_pca``.
        flat_hand_mean: a zero finger pose is the flat hand (True) or MANO's mean hand (False).
        fix_left_shapedirs: negate the left model's ``shapedirs[:, 0, :]`` (see the loader).
        dtype: torch.float32 or torch.float64, for the buffers and the computation.
        """
        super().__init__()
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        if isinstance(model, ManoData):
            if side is not None and check_side(side) != model.side:
                raise ValueError(f"side={side!r} but the ManoData is a {model.side} hand")
            if fix_left_shapedirs:
                raise ValueError(
                    "fix_left_shapedirs applies when loading; pass it to load_mano_pkl instead"
                )
            data = model
        else:
            data = load_mano_pkl(model, side, fix_left_shapedirs=fix_left_shapedirs)
        if use_pca and not 1 <= int(num_pca_comps) <= NUM_HAND_POSE:
            raise ValueError(f"num_pca_comps must be in [1, 45], got {num_pca_comps}")

        self.side = data.side
        self.use_pca = bool(use_pca)
        self.num_pca_comps = int(num_pca_comps)
        self.hand_pose_dim = self.num_pca_comps if self.use_pca else NUM_HAND_POSE
        self.flat_hand_mean = bool(flat_hand_mean)
        self.num_betas = data.num_betas

        def buffer(name: str, array: np.ndarray, as_dtype: torch.dtype = dtype) -> None:
            self.register_buffer(name, torch.as_tensor(array).to(as_dtype), persistent=False)

        regressor = data.joint_regressor
        buffer("template_vertices", data.template_vertices)
        buffer("shape_dirs", data.shape_dirs)
        buffer("pose_dirs", data.pose_dirs.reshape(-1, POSE_FEATURE_DIM).T.copy())
        buffer("joint_template", regressor @ data.template_vertices)
        buffer("joint_shape_dirs", np.einsum("jv,vcs->jcs", regressor, data.shape_dirs))
        buffer("skinning_weights", data.skinning_weights)
        buffer("faces", data.faces, torch.long)
        buffer("fingertip_vertex_ids", np.asarray(MANO_FINGERTIP_VERTEX_IDS), torch.long)
        hand_mean = np.zeros(NUM_HAND_POSE) if flat_hand_mean else data.hands_mean
        buffer("hand_mean", hand_mean)
        if self.use_pca:
            buffer("hand_components", data.hands_components[: self.num_pca_comps])
        else:
            self.register_buffer("hand_components", None, persistent=False)

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the buffers and of the computation (follows ``.to(dtype)``)."""
        return self.template_vertices.dtype

    @property
    def device(self) -> torch.device:
        """The device of the buffers; inputs must be on it."""
        return self.template_vertices.device

    def extra_repr(self) -> str:
        pca = (
            f"use_pca=True, num_pca_comps={self.num_pca_comps}" if self.use_pca else "use_pca=False"
        )
        return (
            f"side={self.side!r}, {pca}, flat_hand_mean={self.flat_hand_mean}, "
            f"num_betas={self.num_betas}, dtype={self.dtype}"
        )

    def _check_input(self, value: torch.Tensor | None, name: str, width: int) -> None:
        if value is None:
            return
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        if value.dim() != 2 or value.shape[1] != width:
            raise ValueError(f"{name} must have shape [B, {width}], got {tuple(value.shape)}")
        if value.dtype != self.dtype:
            raise TypeError(
                f"{name} has dtype {value.dtype} but the layer computes in {self.dtype} "
                "(cast the input or convert the layer with .to(dtype))"
            )
        if value.device != self.device:
            raise ValueError(
                f"{name} is on {value.device} but the layer is on {self.device} (move one of them)"
            )
        if not torch.isfinite(value).all():
            raise ValueError(f"{name} contains NaN or inf values")

    def forward(
        self,
        hand_pose: torch.Tensor | None = None,
        global_orient: torch.Tensor | None = None,
        betas: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
    ) -> ManoOutput:
        """Pose the hand; a missing input is zeros (batch size from the others, else 1).

        hand_pose: [B, 45] axis-angle radians, or [B, num_pca_comps] PCA coefficients (use_pca).
        global_orient: [B, 3] axis-angle radians, rotation about the wrist joint.
        betas: [B, num_betas] shape coefficients.
        transl: [B, 3] metres, added last.
        """
        pose_width = self.hand_pose_dim
        inputs = {
            "hand_pose": (hand_pose, pose_width),
            "global_orient": (global_orient, 3),
            "betas": (betas, self.num_betas),
            "transl": (transl, 3),
        }
        batch = None
        for name, (value, width) in inputs.items():
            self._check_input(value, name, width)
            if value is None:
                continue
            if batch is None:
                batch = value.shape[0]
            elif value.shape[0] != batch:
                raise ValueError(f"{name} has batch size {value.shape[0]}, other inputs {batch}")
        batch = 1 if batch is None else batch
        device = self.device

        def zeros(width: int) -> torch.Tensor:
            return torch.zeros(batch, width, dtype=self.dtype, device=device)

        hand_pose = zeros(pose_width) if hand_pose is None else hand_pose
        global_orient = zeros(3) if global_orient is None else global_orient
        betas = zeros(self.num_betas) if betas is None else betas
        full_pose = mano_full_pose(global_orient, hand_pose, self.hand_mean, self.hand_components)
        return mano_forward(
            full_pose,
            betas,
            transl,
            template_vertices=self.template_vertices,
            shape_dirs=self.shape_dirs,
            pose_dirs=self.pose_dirs,
            joint_template=self.joint_template,
            joint_shape_dirs=self.joint_shape_dirs,
            skinning_weights=self.skinning_weights,
            fingertip_vertex_ids=self.fingertip_vertex_ids,
        )
