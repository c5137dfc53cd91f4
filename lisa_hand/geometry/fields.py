"""The field protocol: the callbacks through which renderer, mesher, tracer and data see a field.

Every consumer of a field (the volume renderer and image renderer in :mod:`lisa_hand.render`, the
mesher :mod:`lisa_hand.geometry.meshing`, the sphere tracer :mod:`lisa_hand.geometry.tracing`,
the ground-truth renderer :mod:`lisa_hand.data.images`, the SDF samples of
:mod:`lisa_hand.data.scans`, inference) takes one of these callbacks (nerfacc style), so each is
tested on an analytic sphere before it meets a network, and none imports the model:

    sdf_fn(points [N, 3] metres) -> sdf [N] metres, negative inside
    field_fn(points [N, 3] metres, directions [N, 3] unit) -> (sdf [N] metres, rgb [N, C] in [0, 1])
    normal_fn(points [N, 3] metres) -> normals [N, 3] world frame (any length)

The output contract, checked by :func:`check_sdf_output` through :func:`call_sdf` and
:func:`call_field` (every consumer calls its callback through them): ``sdf`` is a tensor of shape
``[N]``; ``[N, 1]`` (what a network's last linear layer gives) is also accepted, everywhere, and
read as ``[N]``: one rule for all consumers. Anything else is refused with a ``ValueError``
that names the callback, the expected and the received shape, e.g. ``sdf_fn must return [N] or
[N, 1] for points [N, 3] (N = 512), got (512, 3)``; a result that is not a tensor with a
``TypeError``. Values come back in the points' dtype. The
points come in the consumer's dtype and device.

Several fields at once (grouped callbacks): a consumer that renders the rays of several frames in
one pass (image training: every frame of a batch, one hand pose each) is given ``groups [R]``
(long, the field each ray belongs to) and calls its callbacks with one more argument, the group
of every point (:class:`GroupedSdfFn`, :class:`GroupedFieldFn`); :func:`call_sdf` and
:func:`call_field` pass it on when given. One call then evaluates every frame, which on a CPU
saves the per-call overhead of many small evaluations (the sphere tracer's steps).
"""

from __future__ import annotations

from typing import Protocol

import torch

__all__ = [
    "SdfFn",
    "FieldFn",
    "NormalFn",
    "GroupedSdfFn",
    "GroupedFieldFn",
    "check_sdf_output",
    "call_sdf",
    "call_field",
    "call_normals",
]


class SdfFn(Protocol):
    """A signed distance callback."""

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """points: [N, 3] metres (world frame) -> sdf [N] (or [N, 1]) metres, negative inside."""
        ...


class FieldFn(Protocol):
    """A signed distance and colour callback (the field a volume renderer composites)."""

    def __call__(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """points: [N, 3] metres; directions: [N, 3] unit viewing directions ->
        ``(sdf [N] (or [N, 1]) metres, negative inside; rgb [N, C] in [0, 1])``."""
        ...


class NormalFn(Protocol):
    """A surface normal callback (e.g. an analytic normal, instead of the SDF gradient)."""

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """points: [N, 3] metres -> normals [N, 3], world frame, any length (normalised later)."""
        ...


class GroupedSdfFn(Protocol):
    """A signed distance callback of several fields (one per group, e.g. a frame)."""

    def __call__(self, points: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
        """points: [N, 3] metres; groups: [N] long, the field of each point -> sdf [N] metres."""
        ...


class GroupedFieldFn(Protocol):
    """A signed distance and colour callback of several fields (one per group)."""

    def __call__(
        self, points: torch.Tensor, directions: torch.Tensor, groups: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """points: [N, 3] metres; directions: [N, 3] unit; groups: [N] long ->
        ``(sdf [N] metres, rgb [N, C] in [0, 1])``."""
        ...


def _shape_of(value) -> str:
    shape = getattr(value, "shape", None)
    return str(tuple(shape)) if shape is not None else type(value).__name__


def check_sdf_output(values, num_points: int, name: str = "sdf_fn") -> torch.Tensor:
    """The contract on a callback's signed distances: ``[N]`` or ``[N, 1]`` -> ``[N]``.

    values: what the callback returned for ``num_points`` points. name: the callback's name in the
    error message. Raises TypeError when ``values`` is not a tensor, ValueError on another shape.
    """
    if not isinstance(values, torch.Tensor):
        raise TypeError(f"{name} must return a torch.Tensor, got {type(values).__name__}")
    if values.dim() == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.shape != (num_points,):
        raise ValueError(
            f"{name} must return [N] or [N, 1] for points [N, 3] (N = {num_points}), got "
            f"{tuple(values.shape)}"
        )
    return values


def call_sdf(
    sdf_fn: SdfFn | GroupedSdfFn,
    points: torch.Tensor,
    chunk_size: int | None = None,
    name: str = "sdf_fn",
    groups: torch.Tensor | None = None,
) -> torch.Tensor:
    """``sdf_fn`` on points [N, 3] metres -> sdf [N] metres in the points' dtype.

    chunk_size: most points per call (None: one call, even for N = 0; an int: no call for
    N = 0). The output of every call is checked by :func:`check_sdf_output`. Gradients flow as
    the callback allows (no ``no_grad`` here). groups: [N] long, passed on to a
    :class:`GroupedSdfFn` (None: ``sdf_fn`` is an :class:`SdfFn`).
    """

    def evaluate(rows: slice) -> torch.Tensor:
        chunk = points[rows]
        values = sdf_fn(chunk) if groups is None else sdf_fn(chunk, groups[rows])
        return check_sdf_output(values, chunk.shape[0], name).to(points.dtype)

    if chunk_size is None:
        return evaluate(slice(None))
    values = [evaluate(slice(start, start + chunk_size))
              for start in range(0, points.shape[0], chunk_size)]
    return torch.cat(values) if values else points.new_zeros(0)


def call_field(
    field_fn: FieldFn | GroupedFieldFn,
    points: torch.Tensor,
    directions: torch.Tensor,
    num_channels: int | None = None,
    chunk_size: int | None = None,
    name: str = "field_fn",
    groups: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``field_fn`` on points [N, 3] metres seen along directions [N, 3] -> (sdf [N], rgb [N, C]).

    The sdf follows :func:`check_sdf_output`; rgb must be a tensor [N, C] (``C = num_channels``
    when given). Both come back in the points' dtype. chunk_size: most points per call (None: one
    call, even for N = 0; an int: no call for N = 0). Differentiable as the callback is.
    groups: [N] long, passed on to a :class:`GroupedFieldFn` (None: a :class:`FieldFn`).
    """
    if chunk_size is None:
        return _checked_field(field_fn, points, directions, num_channels, name, groups)
    sdf_parts, rgb_parts = [], []
    for start in range(0, points.shape[0], chunk_size):
        rows = slice(start, start + chunk_size)
        sdf, rgb = _checked_field(field_fn, points[rows], directions[rows], num_channels, name,
                                  None if groups is None else groups[rows])
        sdf_parts.append(sdf)
        rgb_parts.append(rgb)
    if not sdf_parts:
        return points.new_zeros(0), points.new_zeros(0, num_channels or 0)
    return torch.cat(sdf_parts), torch.cat(rgb_parts)


def _checked_field(field_fn, points, directions, num_channels, name, groups=None):
    count = points.shape[0]
    out = field_fn(points, directions) if groups is None else field_fn(points, directions, groups)
    if not isinstance(out, (tuple, list)) or len(out) != 2:
        raise TypeError(f"{name} must return a pair (sdf [N], rgb [N, C]), got {_shape_of(out)}")
    sdf, rgb = out
    if not isinstance(sdf, torch.Tensor) or not isinstance(rgb, torch.Tensor):
        raise TypeError(
            f"{name} must return torch.Tensors (sdf [N], rgb [N, C]), got "
            f"{type(sdf).__name__} and {type(rgb).__name__}"
        )
    if sdf.dim() == 2 and sdf.shape[1] == 1:
        sdf = sdf[:, 0]
    channels = rgb.shape[-1] if num_channels is None and rgb.dim() == 2 else num_channels
    if sdf.shape != (count,) or rgb.shape != (count, channels):
        expected_c = "C" if num_channels is None else str(num_channels)
        raise ValueError(
            f"{name} must return sdf [N] (or [N, 1]) and rgb [N, C] for N = {count}"
            f"{'' if num_channels is None else f', C = {expected_c}'}, got "
            f"{tuple(sdf.shape)} and {tuple(rgb.shape)}"
        )
    return sdf.to(points.dtype), rgb.to(points.dtype)


def call_normals(normal_fn: NormalFn, points: torch.Tensor) -> torch.Tensor:
    """``normal_fn`` on points [N, 3] -> unit normals [N, 3] in the points' dtype (zero where the
    callback gives a zero vector). Raises TypeError / ValueError on a non-tensor or another
    shape."""
    values = normal_fn(points)
    if not isinstance(values, torch.Tensor):
        raise TypeError(f"normal_fn must return a torch.Tensor, got {type(values).__name__}")
    if values.shape != points.shape:
        raise ValueError(
            f"normal_fn must return [N, 3]=({points.shape[0]}, 3), got {tuple(values.shape)}"
        )
    values = values / values.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return values.to(points.dtype)
