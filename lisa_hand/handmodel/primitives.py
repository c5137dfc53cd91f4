"""Signed distance primitives of the open hand, batched over parts, and the smooth union.

All functions take points already expressed in each part's frame and return exact Euclidean
signed distances (negative inside), so that a smooth union of them stays close to a true distance.
"""

from __future__ import annotations

import math

import torch

__all__ = ["round_cone_sdf", "rounded_polygon_sdf", "smooth_union", "smoothstep", "gaussian"]

# Floor under square roots: keeps gradients finite where a distance is exactly zero.
_SQRT_FLOOR = 1e-20
_LOG2_E = 1.0 / math.log(2.0)
_LN_2 = math.log(2.0)
# Smallest exponent of two used: 2^-100 ~ 8e-31 stays a normal float32.
_MIN_EXP2 = -100.0


def _safe_sqrt(values: torch.Tensor) -> torch.Tensor:
    return values.clamp_min(_SQRT_FLOOR).sqrt()


def round_cone_sdf(
    along: torch.Tensor,
    radial_sq: torch.Tensor,
    length: torch.Tensor,
    start_radius: torch.Tensor,
    end_radius: torch.Tensor,
) -> torch.Tensor:
    """Exact signed distance to round cones (the convex hull of two spheres), batched over parts.

    In each cone's frame the axis runs from the origin to ``(length, 0, 0)``; a point is given by
    its coordinate along the axis ``u`` and its squared distance from the axis ``rho^2``. The cone
    is the union of the spheres centred at ``(h, 0)`` with radius ``r(h) = r1 - h sin a``
    (``sin a = (r1 - r2) / length``); the side's outward normal is ``(sin a, cos a)``, so the
    sphere nearest to ``(u, rho)`` is the one at ``h = clamp(u - rho tan a, 0, length)`` and the
    distance is ``sqrt((u - h)^2 + rho^2) - r(h)`` (branch-free; equal to ``u sin a + rho cos a -
    r1`` on the side and to the end spheres' distances past them). Requires
    ``|r1 - r2| < length``.

    along: [N, P] u, metres; radial_sq: [N, P] rho^2, m^2.
    length, start_radius, end_radius: [P] metres.
    -> [N, P] signed distances, metres.
    """
    sin_a = (start_radius - end_radius) / length
    tan_a = sin_a / (1.0 - sin_a * sin_a).sqrt()
    radial = _safe_sqrt(radial_sq)
    center = torch.minimum((along - radial * tan_a).clamp_min(0.0), length)
    offset = along - center
    return _safe_sqrt(offset * offset + radial_sq) - (start_radius - center * sin_a)


def rounded_polygon_sdf(
    points_plane: torch.Tensor, vertices: torch.Tensor, radius: float | torch.Tensor
) -> torch.Tensor:
    """Exact signed distance to flat convex polygons thickened by a ball (rounded slabs).

    The distance to the flat polygon is ``sqrt(d2^2 + h^2)`` with ``d2`` the in-plane distance to
    the polygon (zero inside) and ``h`` the height over its plane; the slab is that minus
    ``radius``: thickness ``2 radius`` with rounded rims.

    points_plane: [N, 3] points in the polygon's plane frame: (a, b) in-plane, third = height.
    vertices: [V, 2] counter-clockwise convex polygon, metres.
    radius: rounding radius (half thickness), metres.
    -> [N] signed distances, metres.
    """
    planar = points_plane[:, None, :2]  # [N, 1, 2]
    edge_vec = torch.roll(vertices, shifts=-1, dims=0) - vertices  # [V, 2]
    rel = planar - vertices  # [N, V, 2]
    edge_sq = (edge_vec * edge_vec).sum(-1).clamp_min(_SQRT_FLOOR)
    t = ((rel * edge_vec).sum(-1) / edge_sq).clamp(0.0, 1.0)
    diff = rel - t[..., None] * edge_vec
    seg_sq = (diff * diff).sum(-1).amin(-1)  # [N]
    cross = edge_vec[..., 0] * rel[..., 1] - edge_vec[..., 1] * rel[..., 0]
    inside = (cross >= 0.0).all(-1)
    planar_sq = torch.where(inside, torch.zeros_like(seg_sq), seg_sq)
    height = points_plane[..., 2]
    return _safe_sqrt(planar_sq + height * height) - radius


def smooth_union(distances: torch.Tensor, blend: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Smooth minimum ``-k log sum_i exp(-d_i / k)`` over the last axis, and its blend weights.

    The weights ``softmax(-d / k)`` are the derivatives of the result with respect to each
    ``d_i`` (they sum to 1), so ``grad s = sum_i w_i grad d_i``: ``|grad s| = 1`` where one part
    dominates, slightly less inside a blend (a fillet of about ``2-3 k`` metres).

    distances: [N, P] metres; blend: k, metres.
    -> (smooth minimum [N] metres, weights [N, P])
    """
    # exp(x) = 2^(x log2 e); arguments are clamped above the float32 denormal range (denormal
    # results are an order of magnitude slower on CPUs and weigh nothing).
    nearest = distances.amin(dim=-1, keepdim=True).detach()
    exponent = ((nearest - distances) * (_LOG2_E / blend)).clamp_min(_MIN_EXP2)
    terms = torch.exp2(exponent)
    total = terms.sum(-1, keepdim=True)
    value = nearest[..., 0] - (blend * _LN_2) * torch.log2(total[..., 0])
    return value, terms / total


def smoothstep(
    low: float | torch.Tensor, high: float | torch.Tensor, x: torch.Tensor
) -> torch.Tensor:
    """Cubic Hermite step: 0 below ``low``, 1 above ``high`` (``low > high``: a falling step)."""
    t = ((x - low) / (high - low)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def gaussian(scaled: torch.Tensor) -> torch.Tensor:
    """``exp(-scaled^2 / 2)``, computed as a power of two and flushed to 0 beyond ~11.7 widths."""
    return torch.exp2((scaled * scaled).clamp(max=2.0 * -_MIN_EXP2 / _LOG2_E) * (-0.5 * _LOG2_E))
