"""The real MANO right hand as the mesh template (a
:class:`~lisa_hand.handmodel.template.MeshTemplate` with ``name == "mano"``), for users who have
MANO's licensed file."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import torch

from ..skeleton.tree import MANO_FINGERTIP_VERTEX_IDS, NUM_JOINTS
from .template import MeshTemplate

if TYPE_CHECKING:
    from ..skeleton.mano import ManoData, ManoLayer

__all__ = ["template_from_mano"]


def template_from_mano(
    path_or_layer: str | os.PathLike | ManoData | ManoLayer, num_betas: int = 10
) -> MeshTemplate:
    """The real MANO right hand as the template (``name == "mano"``, float64 CPU).

    Uses MANO's ``v_template``, ``faces``, ``weights``, dense ``J_regressor``, the first
    ``num_betas`` shape directions and the fingertip vertices
    :data:`~lisa_hand.skeleton.MANO_FINGERTIP_VERTEX_IDS`. MANO's pose blend shapes
    (``posedirs``) are ignored: :meth:`MeshTemplate.forward` is plain LBS, so posed vertices
    differ from MANO's by its pose correctives (joints and rest shapes are identical). The pose
    is MANO's full 48-D pose with a flat hand mean (``ManoLayer(flat_hand_mean=True)``).

    path_or_layer: ``MANO_RIGHT.pkl``, a loaded :class:`~lisa_hand.skeleton.ManoData`, or a
        :class:`~lisa_hand.skeleton.ManoLayer`. A layer keeps no joint regressor, only the
        regressed joints of the template and of each shape direction; the template then gets
        the minimum-norm regressor (rows summing to 1) that reproduces them exactly, so its rest
        joints equal the layer's for every betas (its entries may be negative).
    num_betas: shape directions kept (1 to the file's count, 10 for MANO).
    """
    from ..skeleton.mano import ManoData, ManoLayer, load_mano_pkl

    if isinstance(path_or_layer, ManoLayer):
        layer = path_or_layer
        side = layer.side
        vertices = layer.template_vertices.detach().double().cpu()
        shapedirs = layer.shape_dirs.detach().double().cpu()
        weights = layer.skinning_weights.detach().double().cpu()
        faces = layer.faces.detach().long().cpu()
        regressor = None
    else:
        data = path_or_layer if isinstance(path_or_layer, ManoData) else None
        if data is None:
            if not isinstance(path_or_layer, (str, os.PathLike)):
                raise TypeError(
                    "path_or_layer must be a path, a ManoData or a ManoLayer, got "
                    f"{type(path_or_layer).__name__}"
                )
            data = load_mano_pkl(path_or_layer, side="right")
        side = data.side
        vertices = torch.from_numpy(data.template_vertices).double()
        shapedirs = torch.from_numpy(data.shape_dirs).double()
        weights = torch.from_numpy(data.skinning_weights).double()
        faces = torch.from_numpy(data.faces).long()
        regressor = torch.from_numpy(data.joint_regressor).double()
    if side != "right":
        raise ValueError(
            "template_from_mano needs MANO's right hand (MANO_RIGHT.pkl); the template is a "
            f"right hand and left hands are its mirror image, got a {side} model"
        )
    total = int(shapedirs.shape[-1])
    if not isinstance(num_betas, int) or not 1 <= num_betas <= total:
        raise ValueError(f"num_betas must be an int in [1, {total}], got {num_betas!r}")
    if regressor is None:
        regressor = _regressor_from_layer(path_or_layer, vertices, shapedirs)
    return MeshTemplate(
        v_template=vertices,
        faces=faces,
        weights=weights,
        joint_regressor=regressor,
        shapedirs=shapedirs[..., :num_betas].contiguous(),
        fingertip_ids=tuple(int(i) for i in MANO_FINGERTIP_VERTEX_IDS),
        name="mano",
    )


def _regressor_from_layer(
    layer: ManoLayer, vertices: torch.Tensor, shapedirs: torch.Tensor
) -> torch.Tensor:
    """Minimum-norm ``R`` [16, V] with ``R T = J_T``, ``R S_k = J_k`` (every shape direction and
    coordinate) and rows summing to 1: the layer's joints for every betas."""
    basis = torch.cat(
        [vertices, shapedirs.reshape(vertices.shape[0], -1), vertices.new_ones(len(vertices), 1)],
        dim=1,
    )  # [V, 3 + 3S + 1]
    joints = layer.joint_template.detach().double().cpu()
    joint_dirs = layer.joint_shape_dirs.detach().double().cpu()
    target = torch.cat(
        [joints, joint_dirs.reshape(NUM_JOINTS, -1), joints.new_ones(NUM_JOINTS, 1)], dim=1
    )
    return target @ torch.linalg.pinv(basis)
