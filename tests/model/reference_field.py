"""LISA written the straightforward way (:class:`ReferenceField`): an independent second
implementation of the field, to check the optimised :class:`lisa_hand.model.lisa.LisaModel`
against (``tests/model/test_lisa.py``) and, in the field benchmark (``python -m benchmarks field``
from the repository root), to time it against. Test code, not part of the package.
"""

from __future__ import annotations

import torch
from torch import nn

from lisa_hand.fields import bone_segments, capsule_distance, masked_softmax, pose_features
from lisa_hand.fields.bones import SEGMENT_BONES, bone_centres
from lisa_hand.fields.encoding import positional_encoding
from lisa_hand.model.lisa import FieldOutput, LisaModel
from lisa_hand.skeleton import NUM_JOINTS

__all__ = ["ReferenceField"]


class ReferenceField(nn.Module):
    """The straightforward implementation (for timing and checking; per-bone compositions).

    16 ``nn.Sequential`` SDF MLPs and 16 colour MLPs whose first layer reads
    ``concat(PE(x_j), pose_j, shape[, color])`` for every point, a skinning ``nn.Sequential``,
    and a Python loop over the bones. Weights are copied from ``model``.
    """

    def __init__(self, model: LisaModel) -> None:
        super().__init__()
        config = model.config
        if not config.per_bone or config.composition != "lisa":
            raise ValueError("the reference implements the 'lisa' composition")
        self.config = config
        self.sdf = nn.ModuleList(
            [
                _sequential(model.sdf_mlp, j, nn.Softplus(beta=config.softplus_beta))
                for j in range(16)
            ]
        )
        self.color = None
        if model.color_mlp is not None:
            self.color = nn.ModuleList(
                [_sequential(model.color_mlp, j, nn.ReLU()) for j in range(16)]
            )
        self.skinning = _sequential(model.skinning_mlp, 0, nn.Softplus(beta=config.softplus_beta))
        self.radius = model.region_radii

    def forward(
        self,
        points: torch.Tensor,
        pose: torch.Tensor,
        kinematics,
        rest_joints: torch.Tensor,
        shape_code: torch.Tensor,
        color_code: torch.Tensor | None,
        pose_mask: torch.Tensor,
    ) -> FieldOutput:
        """points: [1, N, 3] world metres; the rest as for :meth:`LisaModel.prepare`."""
        config = self.config
        scale = config.coordinate_scale
        num = points.shape[1]
        features = pose_features(pose, kinematics.rotmats, config.pose_conditioning, pose_mask)
        centres = bone_centres(rest_joints, config.tip_extension)
        start, end = bone_segments(rest_joints, config.tip_extension)
        locals_, excess = [], []
        for j in range(NUM_JOINTS):
            transform = kinematics.transforms[0, j]
            rest = (points[0] - transform[:3, 3]) @ transform[:3, :3]  # R^T (x - t)
            locals_.append((rest - centres[0, j]) / scale)
            segments = [s for s, owner in enumerate(SEGMENT_BONES) if owner == j]
            distances = []
            for s in segments:
                vec = end[0, s] - start[0, s]
                length = vec.norm()
                distances.append(
                    capsule_distance(rest, start[0, s], vec / length, length.expand(num))
                )
            excess.append(torch.stack(distances, -1).amin(-1) - self.radius[j])
        excess = torch.stack(excess, dim=-1)  # [N, J] metres
        active = excess < 0
        fallback = excess.argmin(dim=-1)
        bone_sdf, colors = [], []
        for j in range(NUM_JOINTS):
            encoded = positional_encoding(locals_[j], config.pe_frequencies)
            cond = torch.cat([features[0, j], shape_code[0]]).expand(num, -1)
            value = self.sdf[j](torch.cat([encoded, cond], dim=-1))[:, 0] * scale
            bone_sdf.append(torch.where(active[:, j], value, excess[:, j] + config.outside_margin))
            if self.color is not None and color_code is not None:
                cond = torch.cat([features[0, j], shape_code[0], color_code[0]]).expand(num, -1)
                color = torch.sigmoid(self.color[j](torch.cat([encoded, cond], dim=-1)))
                colors.append(torch.where(active[:, j, None], color, 0.5))
        bone_sdf = torch.stack(bone_sdf, dim=-1)
        skin_in = torch.cat([torch.cat(locals_, dim=-1), bone_sdf / scale], dim=-1)
        weights = masked_softmax(self.skinning(skin_in), active, fallback)
        sdf = (weights * bone_sdf).sum(-1)
        rgb = None
        if colors:
            rgb = (weights[..., None] * torch.stack(colors, dim=-2)).sum(-2)[None]
        return FieldOutput(
            sdf=sdf[None],
            rgb=rgb,
            weights=weights[None],
            bone_sdf=bone_sdf[None],
            region_mask=active[None],
        )


def _sequential(mlp, group: int, activation: nn.Module) -> nn.Sequential:
    """One group of a :class:`StackedMLP` as an ``nn.Sequential`` on ``concat(point, cond)``."""
    first_weight = mlp.point_weight[group]
    if mlp.cond_weight is not None:
        first_weight = torch.cat([first_weight, mlp.cond_weight[group]], dim=0)
    weights = [(first_weight, mlp.first_bias[group])]
    weights += [(w[group], b[group]) for w, b in mlp.layers()]
    modules: list[nn.Module] = []
    for index, (weight, bias) in enumerate(weights):
        linear = nn.Linear(
            weight.shape[0], weight.shape[1], dtype=weight.dtype, device=weight.device
        )
        with torch.no_grad():
            linear.weight.copy_(weight.t())
            linear.bias.copy_(bias)
        modules.append(linear)
        if index < len(weights) - 1:
            modules.append(activation)
    return nn.Sequential(*modules)
