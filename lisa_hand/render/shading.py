"""Deferred headlight shading: the rendered albedo times a Lambert term at the ray's surface point.

LISA's colour networks give a colour per point and nothing else: no normal, no view direction.
Images of a hand lit from the camera (a flash, a ring light; the synthetic datasets of
``lisa synth``, lit from beside each camera) then show a shading that changes with pose and view,
and a colour field trained on them can only average it into its albedo (issue 15: on the demo's
hand the shading was 60% of the colour variance inside the mask). :class:`HeadlightShading`
models it per ray, after volume rendering::

    c = albedo * (ambient + diffuse * max(0, n . -d))

with ``albedo = sum_i w_i c_i`` the composited field colour (over black), ``d`` the ray's unit
direction (the light sits at the camera: it shines along the ray) and ``n`` the unit outward
normal of the SDF at the ray's expected surface point ``o + depth d``
(:func:`surface_normals`: one gradient evaluation a ray, not one a sample; detached, so the
colour loss does not bend the geometry through the normals). ``ambient`` and ``diffuse`` are
learned per channel, non-negative, and start at 0.5 each (a surface facing the camera keeps its
albedo, one seen edge-on half of it).
A ray's weights sit within a few ``beta`` of its surface, so one normal a ray is what the samples
would have given (the Lambert term is linear in the colour).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..geometry.fields import SdfFn

__all__ = ["SHADING_MODES", "HeadlightShading", "surface_normals", "shade_foreground"]

SHADING_MODES = ("none", "headlight")
"""``"none"``: colours as the field gives them (the paper); ``"headlight"``:
:class:`HeadlightShading`."""


def _inverse_softplus(value: float) -> float:
    """x with softplus(x) = value (> 0)."""
    return float(value + torch.log(-torch.expm1(torch.tensor(-float(value)))))


class HeadlightShading(nn.Module):
    """A Lambert term lit from the camera, per channel (see the module docstring).

    ``ambient = softplus(ambient_raw)``, ``diffuse = softplus(diffuse_raw)`` ([3] each,
    unitless): non-negative and smooth in the raw parameters (whose gradients stay of order one
    from the start values).
    """

    def __init__(self, ambient: float = 0.5, diffuse: float = 0.5) -> None:
        super().__init__()
        if not (ambient > 0 and diffuse > 0):
            raise ValueError(f"ambient and diffuse must be > 0, got {ambient}, {diffuse}")
        self.ambient_raw = nn.Parameter(torch.full((3,), _inverse_softplus(ambient)))
        self.diffuse_raw = nn.Parameter(torch.full((3,), _inverse_softplus(diffuse)))

    @property
    def ambient(self) -> torch.Tensor:
        """[3] unitless (differentiable)."""
        return F.softplus(self.ambient_raw)

    @property
    def diffuse(self) -> torch.Tensor:
        """[3] unitless (differentiable)."""
        return F.softplus(self.diffuse_raw)

    def factor(self, normals: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """normals: [R, 3] unit (zero: no surface, ambient only); directions: [R, 3] unit ray
        directions -> [R, 3] the shading factor ``ambient + diffuse * max(0, n . -d)``."""
        cosine = (-(normals * directions).sum(-1, keepdim=True)).clamp_min(0.0)
        return self.ambient.to(cosine.dtype) + self.diffuse.to(cosine.dtype) * cosine

    def forward(self, albedo: torch.Tensor, normals: torch.Tensor,
                directions: torch.Tensor) -> torch.Tensor:
        """albedo: [R, 3] composited colours over black (``sum_i w_i c_i``) -> [R, 3] shaded."""
        return albedo * self.factor(normals, directions)

    def values(self) -> dict[str, torch.Tensor]:
        """{"ambient": [3], "diffuse": [3]} float32 CPU tensors, detached (for files)."""
        return {"ambient": self.ambient.detach().cpu().float(),
                "diffuse": self.diffuse.detach().cpu().float()}

    @classmethod
    def from_values(cls, ambient: torch.Tensor, diffuse: torch.Tensor) -> HeadlightShading:
        """The shading with these ``ambient`` and ``diffuse`` [3] (> 0; :meth:`values`)."""
        ambient, diffuse = torch.as_tensor(ambient).float(), torch.as_tensor(diffuse).float()
        if ambient.shape != (3,) or diffuse.shape != (3,):
            raise ValueError(f"ambient and diffuse must have shape [3], got "
                             f"{list(ambient.shape)} and {list(diffuse.shape)}")
        if not (torch.isfinite(ambient).all() and torch.isfinite(diffuse).all()
                and (ambient > 0).all() and (diffuse > 0).all()):
            raise ValueError("ambient and diffuse must be finite and > 0")
        shading = cls()
        with torch.no_grad():
            shading.ambient_raw.copy_(ambient + torch.log(-torch.expm1(-ambient)))
            shading.diffuse_raw.copy_(diffuse + torch.log(-torch.expm1(-diffuse)))
        return shading


def surface_normals(
    sdf_fn: SdfFn,
    origins: torch.Tensor,
    directions: torch.Tensor,
    depth: torch.Tensor,
    opacity: torch.Tensor,
    groups: torch.Tensor | None = None,
    min_opacity: float = 1e-3,
) -> torch.Tensor:
    """Unit outward normals of the SDF at each ray's expected surface point ``o + depth d``.

    One autograd gradient a ray (rays with ``opacity < min_opacity`` get a zero normal and no
    evaluation). Not differentiable: the normals are detached, and the gradient does not reach
    the field's parameters.

    sdf_fn: points [N, 3] metres -> sdf [N] (``groups``: a grouped callback, called with the
    rays' groups). origins, directions: [R, 3]; depth, opacity: [R] (a
    :class:`~lisa_hand.render.composite.RenderOutput`'s); groups: [R] long or None.
    -> [R, 3] unit vectors (zeros where skipped or where the gradient vanishes).
    """
    normals = torch.zeros_like(origins)
    rows = torch.nonzero(opacity.detach() >= min_opacity).squeeze(-1)
    if rows.numel() == 0:
        return normals
    with torch.enable_grad():
        points = (origins[rows] + depth[rows, None] * directions[rows]).detach()
        points.requires_grad_(True)
        sdf = sdf_fn(points) if groups is None else sdf_fn(points, groups[rows])
        (gradient,) = torch.autograd.grad(sdf.sum(), points)
    normals[rows] = F.normalize(gradient.detach(), dim=-1).to(normals.dtype)
    return normals


def shade_foreground(
    rgb: torch.Tensor,
    opacity: torch.Tensor,
    background: torch.Tensor,
    factor: torch.Tensor,
    bias: torch.Tensor | None = None,
) -> torch.Tensor:
    """Shade the hand's part of already composited (and calibrated) colours.

    ``rgb = g * albedo + b * opacity + (1 - opacity) * background`` becomes
    ``g * albedo * factor + b * opacity + (1 - opacity) * background``.
    rgb: [..., 3]; opacity: [...]; background: [3] or [..., 3]; factor: [..., 3];
    bias: [3] the calibration's bias (None: 0). -> [..., 3].
    """
    alpha = opacity[..., None]
    offset = (1.0 - alpha) * background
    if bias is not None:
        offset = offset + alpha * bias
    return (rgb - offset) * factor + offset
