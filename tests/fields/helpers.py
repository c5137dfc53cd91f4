"""Shared fixtures for the field and model tests: tiny configs, a hand skeleton, frame inputs."""

from __future__ import annotations

import torch

from lisa_hand.fields import FieldConfig
from lisa_hand.skeleton import AVERAGE_REST_JOINTS

TINY = {
    "sdf_hidden": 16,
    "sdf_depth": 2,
    "color_hidden": 8,
    "color_depth": 1,
    "skinning_hidden": 16,
    "skinning_depth": 2,
    "pe_frequencies": 2,
    "shape_dim": 4,
    "color_dim": 3,
}


def tiny_config(**overrides) -> FieldConfig:
    """A field small enough for fast tests (same structure as the default)."""
    return FieldConfig(**{**TINY, **overrides})


def rest_joints(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """[16, 3] metres, an average adult right hand."""
    return torch.tensor(AVERAGE_REST_JOINTS, dtype=dtype)


def frame_inputs(config: FieldConfig, batch: int, seed: int, dtype=torch.float64) -> dict:
    """Per-frame inputs with different hand sizes per frame (keyword arguments of prepare)."""
    gen = torch.Generator().manual_seed(seed)
    sizes = 1.0 + 0.08 * torch.arange(batch, dtype=dtype)
    pose = 0.3 * torch.randn(batch, 48, generator=gen, dtype=dtype)
    return {
        "pose": pose,
        "translation": 0.05 * torch.randn(batch, 3, generator=gen, dtype=dtype),
        "rest_joints": rest_joints(dtype)[None] * sizes[:, None, None],
        "shape_code": 0.3 * torch.randn(batch, config.shape_dim, generator=gen, dtype=dtype),
        "color_code": 0.3 * torch.randn(batch, config.color_dim, generator=gen, dtype=dtype),
    }


def sample_points(state, num: int, seed: int) -> torch.Tensor:
    """[B, num, 3] world points: half near the posed joints (1.5 cm noise), half uniform in a
    12 cm box around the wrist (many outside every region)."""
    gen = torch.Generator().manual_seed(seed)
    joints = state.kinematics.joints
    batch, dtype = joints.shape[0], joints.dtype
    near_count = num // 2
    index = torch.randint(0, 16, (batch, near_count), generator=gen)
    near = torch.gather(joints, 1, index[..., None].expand(-1, -1, 3))
    near = near + 0.015 * torch.randn(batch, near_count, 3, generator=gen, dtype=dtype)
    box = joints[:, :1] + 0.12 * (
        2.0 * torch.rand(batch, num - near_count, 3, generator=gen, dtype=dtype) - 1.0
    )
    return torch.cat([near, box], dim=1)


def perturb_(module: torch.nn.Module, seed: int, std: float = 0.05) -> None:
    """Add seeded noise to every parameter (a model away from its special initialisation)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for param in module.parameters():
            noise = torch.randn(param.shape, generator=gen, dtype=torch.float64)
            param.add_(std * noise.to(param.dtype))
