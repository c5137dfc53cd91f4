"""Swap or interpolate the shape and colour of two fitted hands (LISA's disentanglement).

The field keeps them disentangled (the SDF never sees the colour code), so a hand can take
another one's skin, or its shape code and skeleton, or anything in between.
"""

from __future__ import annotations

import os

import torch

from ..skeleton import mirror_points
from ..skeleton.params import HandParams

__all__ = ["blend_params"]


def _blend_weight(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a number in [0, 1], got {type(value).__name__}")
    if not 0.0 <= float(value) <= 1.0:
        raise ValueError(f"{name} must be in [0, 1] (0: A's, 1: B's), got {value!r}")
    return float(value)


def _mix(a: torch.Tensor | None, b: torch.Tensor | None, weight: float, name: str):
    """(1 - weight) a + weight b; a missing side is allowed only when its weight is 0."""
    if weight == 0.0:
        return None if a is None else a.clone()
    if weight == 1.0:
        return None if b is None else b.clone()
    if a is None or b is None:
        missing = "A" if a is None else "B"
        raise ValueError(f"cannot interpolate {name}: hand {missing} has none")
    if a.shape != b.shape:
        raise ValueError(f"cannot interpolate {name}: shapes {list(a.shape)} and {list(b.shape)}")
    return torch.lerp(a, b, weight)


def blend_params(
    a: HandParams, b: HandParams, shape: float = 0.0, color: float = 0.0
) -> HandParams:
    """Hand A with the shape and/or colour of hand B, or in between (LISA's disentanglement).

    shape: weight of B's shape, in [0, 1]: the shape code and the skeleton (rest joints and
        template betas) are interpolated linearly, ``(1 - shape) A + shape B``.
    color: weight of B's colour code, in [0, 1].
    Pose, translation and side stay A's (a B of the other side has its skeleton mirrored). 0
    and 1 swap exactly; in between, the codes move along a straight line of the latent space
    (where the auto-decoder's Gaussian prior keeps codes near each other).
    Both hands must come from the same model (equal ``model`` and code sizes).
    -> :class:`HandParams` (its ``extra['blend']`` records the weights and sources).
    """
    shape = _blend_weight(shape, "shape")
    color = _blend_weight(color, "color")
    for name, value in (("a", a), ("b", b)):
        if not isinstance(value, HandParams):
            raise TypeError(f"{name} must be a HandParams, got {type(value).__name__}")
    if os.path.normpath(a.model) != os.path.normpath(b.model):
        raise ValueError(f"the hands were fitted with different models ({a.model!r} and "
                         f"{b.model!r}): their codes cannot be mixed")
    if a.shape_code.shape != b.shape_code.shape:
        raise ValueError(f"shape codes differ in size: {a.shape_code.shape[0]} and "
                         f"{b.shape_code.shape[0]}")
    b_rest = b.rest_joints if b.side == a.side else mirror_points(b.rest_joints)
    if shape in (0.0, 1.0) or (
        a.betas is not None and b.betas is not None and a.betas.shape == b.betas.shape
    ):
        betas = _mix(a.betas, b.betas, shape, "betas")
    else:
        betas = None  # the template's coefficients of one hand only: not known in between
    return HandParams(
        pose=a.pose.clone(),
        translation=a.translation.clone(),
        rest_joints=torch.lerp(a.rest_joints, b_rest, shape),
        shape_code=torch.lerp(a.shape_code, b.shape_code, shape),
        color_code=_mix(a.color_code, b.color_code, color, "color_code"),
        betas=betas,
        side=a.side,
        model=a.model,
        extra={"blend": {"shape": shape, "color": color}},
    )
