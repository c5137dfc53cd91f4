"""The end-to-end demo (``lisa demo``). Until the fitting pipeline lands it runs what exists."""

from __future__ import annotations

from pathlib import Path

import torch

from .skeleton import KEYPOINT_NAMES, forward_kinematics

__all__ = ["run_demo"]


def run_demo(out_dir: Path, seed: int = 0) -> dict:
    """Run the demo and return its summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    generator = torch.Generator().manual_seed(seed)
    pose = 0.3 * torch.randn(1, 48, generator=generator)
    rest = torch.randn(16, 3, generator=generator) * 0.05
    kin = forward_kinematics(pose, rest)
    print("lisa demo: the full demo (fitting, meshing, rendering) is not built yet;")
    print(f"lisa demo: posed a random skeleton: {kin.joints.shape[1]} joints, "
          f"{len(KEYPOINT_NAMES)} keypoints")
    return {"joints": kin.joints}
