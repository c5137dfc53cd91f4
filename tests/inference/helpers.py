"""A tiny trained model and hands for the inference tests.

The model is a tiny LisaModel at its geometric initialisation (a blob of a hand on the average
skeleton): untrained, but a closed surface with colours and skinning weights, which is all the
inference code needs.
"""

from __future__ import annotations

import torch

from lisa_hand.fields import FieldConfig
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel
from lisa_hand.skeleton import AVERAGE_REST_JOINTS, mirror_points, mirror_pose
from lisa_hand.skeleton.params import HandParams

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8,
                  palm_region_radius=0.07, finger_region_radius=0.035)
REST = torch.tensor(AVERAGE_REST_JOINTS)
GAIN, BIAS = (1.1, 0.9, 1.0), (0.05, -0.02, 0.0)
"""The calibration of the shared ``model`` fixture."""

# The geometric-init blob reaches 7 cm past the skeleton (a trained hand some 2 cm).
PADDING = 0.08


def tiny_model(gain=(1.0, 1.0, 1.0), bias=(0.0, 0.0, 0.0), seed: int = 0) -> TrainedModel:
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    field = LisaModel(FieldConfig(**TINY_FIELD), init_rest_joints=REST).eval()
    return TrainedModel(
        field=field, shape_codes=0.1 * torch.randn(2, 8, generator=generator),
        color_codes=torch.randn(2, 8, generator=generator), subject_ids=["s0", "s1"],
        beta=0.002, gain=torch.tensor(gain), bias=torch.tensor(bias), source="tiny",
    )  # fmt: skip


def geometry_only_model() -> TrainedModel:
    """A shape prior: the tiny field without colour."""
    torch.manual_seed(1)
    field = LisaModel(FieldConfig(use_color=False, **TINY_FIELD), init_rest_joints=REST).eval()
    return TrainedModel(field=field, shape_codes=torch.zeros(1, 8), color_codes=None,
                        subject_ids=["s0"], beta=0.002, gain=torch.ones(3), bias=torch.zeros(3),
                        source="prior")


def hand_params(model: TrainedModel, row: int = 0, side: str = "right") -> HandParams:
    pose = torch.zeros(48)
    pose[:3] = torch.tensor([0.3, -0.2, 0.1])
    pose[3:] = 0.08
    translation = torch.tensor([0.02, -0.01, 0.4])
    rest = REST
    if side == "left":
        pose, translation, rest = mirror_pose(pose), mirror_points(translation), mirror_points(REST)
    return HandParams(pose=pose, translation=translation, rest_joints=rest,
                      shape_code=model.shape_codes[row], color_code=model.color_codes[row],
                      side=side)
