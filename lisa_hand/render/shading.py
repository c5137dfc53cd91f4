"""Deferred headlight shading: the rendered albedo times a Lambert term at the ray's surface point.

LISA's colour networks give a colour per point and nothing else: no normal, no view direction.
Images of a hand lit from the camera (a flash, a ring light; the synthetic datasets of
``lisa synth``, lit from beside each camera) then show a shading that changes with pose and view,
and a colour field trained on them can only average it into its albedo (on synthetic hands it
is a large share of the colour variance inside the mask). :class:`HeadlightShading`
models it per ray, after volume rendering::

    c = albedo * ((1 - k) + k * max(0, n . -d))

with ``albedo = sum_i w_i c_i`` the composited field colour (over black), ``d`` the ray's unit
direction (the light sits at the camera: it shines along the ray) and ``n`` the unit outward
normal of the SDF at the ray's expected surface point ``o + depth d``
(:func:`surface_normals`: one gradient evaluation a ray, not one a sample; detached, so the
colour loss does not bend the geometry through the normals). ``k``, the light's diffuse
fraction, is learned (one number) and starts at 0.5: a surface facing the camera keeps its
albedo, one seen edge-on half of it.

A ray's weights sit within a few ``beta`` of its surface, so one normal a ray is what the samples
would have given (the Lambert term is linear in the colour).

``shading="camera_light"`` is the same term with the light's direction learned too: a directional
light fixed to the camera (a flash or ring light beside the lens, a studio light that moves with
the camera) at an unknown offset, ``c = albedo * ((1 - k) + k * max(0, n . R^T l))`` with ``l``
the unit direction towards the light in the camera frame (x right, y down, z forward; starts at
``(0, 0, -1)``, the camera's axis) and ``R`` each ray's world-to-camera rotation. Three more
numbers; it needs the rays' camera rotations wherever it is rendered.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from ..geometry.fields import SdfFn
from ..geometry.tracing import sdf_normals

__all__ = [
    "SHADING_MODES", "CAMERA_AXIS_LIGHT", "HeadlightShading", "surface_normals",
    "shade_foreground",
]

SHADING_MODES = ("none", "headlight", "camera_light")
"""``"none"``: colours as the field gives them (the paper); ``"headlight"``:
:class:`HeadlightShading` lit along each ray; ``"camera_light"``: lit from a learned direction
fixed to the camera (``HeadlightShading(learn_light=True)``)."""

CAMERA_AXIS_LIGHT = (0.0, 0.0, -1.0)
"""The camera-frame direction towards a light on the camera's axis (where ``camera_light``
starts)."""


class HeadlightShading(nn.Module):
    """A white Lambert term lit from the camera (see the module docstring), one number:

    ``factor = (1 - k) + k max(0, n . -d)`` with ``k = sigmoid(diffuse_raw)`` in (0, 1), the
    diffuse fraction of the light (``ambient = 1 - k``, ``diffuse = k``): a surface facing the
    camera keeps its albedo. One grey number, not one per channel and not a free scale: a per-
    channel or unnormalised term is a colour gain, which the colour field and the cameras'
    calibration already have (trained per channel, it went to ambient 0.98 / 0.80 / 0.71, a red
    cast, with the diffuse part shrinking).

    With ``learn_light`` (``shading="camera_light"``) the light is not at the camera but in a
    learned direction fixed to it, :attr:`light` (``light_raw`` normalised, camera frame), and
    :meth:`factor` needs each ray's camera rotation.
    """

    def __init__(self, diffuse: float = 0.5, learn_light: bool = False,
                 light: Sequence[float] = CAMERA_AXIS_LIGHT) -> None:
        super().__init__()
        if not 0.0 < diffuse < 1.0:
            raise ValueError(f"diffuse must be in (0, 1), got {diffuse}")
        self.diffuse_raw = nn.Parameter(torch.tensor(math.log(diffuse / (1.0 - diffuse))))
        light_raw = None
        if learn_light:
            direction = torch.as_tensor(light, dtype=torch.float32).flatten()
            if direction.numel() != 3 or not bool(torch.isfinite(direction).all()) \
                    or float(direction.norm()) == 0.0:
                raise ValueError(f"light must be a finite non-zero 3-vector, got "
                                 f"{direction.tolist()}")
            light_raw = nn.Parameter(direction / direction.norm())
        self.register_parameter("light_raw", light_raw)

    @property
    def learns_light(self) -> bool:
        """True for ``camera_light`` (a learned direction), False for the light at the camera."""
        return self.light_raw is not None

    @property
    def light(self) -> torch.Tensor | None:
        """[3] unit direction towards the light in the camera frame (differentiable), or None
        for the light at the camera."""
        if self.light_raw is None:
            return None
        return self.light_raw / self.light_raw.norm().clamp_min(1e-12)

    @property
    def diffuse(self) -> torch.Tensor:
        """[] the diffuse fraction ``k`` in (0, 1), unitless (differentiable)."""
        return torch.sigmoid(self.diffuse_raw)

    def factor(self, normals: torch.Tensor, directions: torch.Tensor,
               rotations: torch.Tensor | None = None) -> torch.Tensor:
        """normals: [R, 3] unit (zero: no surface, ambient only); directions: [R, 3] unit ray
        directions; rotations: [R, 3, 3] (or [3, 3], one camera) each ray's world-to-camera
        rotation, needed with a learned light -> [R, 1] the shading factor
        ``1 - k + k max(0, n . l)``, ``l = -d`` (light at the camera) or ``R^T light``."""
        if self.light_raw is None:
            towards = -directions
        else:
            if rotations is None:
                raise ValueError("a learned camera light needs the rays' camera rotations")
            light = self.light.to(normals.dtype)
            towards = torch.einsum("...ij,i->...j", rotations.to(normals.dtype), light)
        cosine = (normals * towards).sum(-1, keepdim=True).clamp_min(0.0)
        diffuse = self.diffuse.to(cosine.dtype)
        return 1.0 - diffuse + diffuse * cosine

    def forward(self, albedo: torch.Tensor, normals: torch.Tensor, directions: torch.Tensor,
                rotations: torch.Tensor | None = None) -> torch.Tensor:
        """albedo: [R, 3] composited colours over black (``sum_i w_i c_i``) -> [R, 3] shaded
        (the other arguments as in :meth:`factor`)."""
        return albedo * self.factor(normals, directions, rotations)

    def values(self) -> dict[str, torch.Tensor]:
        """{"diffuse": [], and "light": [3] with a learned light} float32 CPU tensors,
        detached (for files)."""
        values = {"diffuse": self.diffuse.detach().cpu().float()}
        if self.light is not None:
            values["light"] = self.light.detach().cpu().float()
        return values

    @classmethod
    def from_values(cls, diffuse: torch.Tensor | float,
                    light: torch.Tensor | Sequence[float] | None = None) -> HeadlightShading:
        """The shading with this diffuse fraction (in (0, 1)) and, if given, this learned light
        direction ([3], camera frame; :meth:`values`)."""
        value = torch.as_tensor(diffuse, dtype=torch.float64)
        if value.numel() != 1 or not bool(torch.isfinite(value).all()):
            raise ValueError(f"diffuse must be one finite number, got {value.tolist()}")
        if light is None:
            return cls(float(value))
        return cls(float(value), learn_light=True, light=torch.as_tensor(light).tolist())

    @classmethod
    def for_mode(cls, mode: str) -> HeadlightShading | None:
        """The untrained shading of a :data:`SHADING_MODES` name (None for "none")."""
        if mode not in SHADING_MODES:
            raise ValueError(f"shading must be one of {SHADING_MODES}, got {mode!r}")
        return None if mode == "none" else cls(learn_light=mode == "camera_light")


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
    points = (origins[rows] + depth[rows, None] * directions[rows]).detach()
    row_sdf = sdf_fn if groups is None else (lambda p: sdf_fn(p, groups[rows]))
    # One chunk: a grouped callback needs the rows' groups in step with the points.
    normals[rows] = sdf_normals(row_sdf, points, "autograd",
                                chunk_size=points.shape[0]).to(normals.dtype)
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
    rgb: [..., 3]; opacity: [...]; background: [3] or [..., 3]; factor: [..., 3] or [..., 1];
    bias: [3] the calibration's bias (None: 0). -> [..., 3].
    """
    alpha = opacity[..., None]
    offset = (1.0 - alpha) * background
    if bias is not None:
        offset = offset + alpha * bias
    return (rgb - offset) * factor + offset
