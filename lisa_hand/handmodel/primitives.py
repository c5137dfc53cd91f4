"""Signed distance primitives of the open hand, batched over parts, and the smooth union.

All functions take points already expressed in each part's frame and return exact Euclidean
signed distances (negative inside), so that a smooth union of them stays close to a true distance.
"""

from __future__ import annotations

import torch

__all__ = ["round_cone_sdf", "rounded_polygon_sdf", "smooth_union", "smoothstep"]

# Floor under square roots: keeps gradients finite where a distance is exactly zero.
_SQRT_FLOOR = 1e-20


def _safe_sqrt(values: torch.Tensor) -> torch.Tensor:
    return values.clamp_min(_SQRT_FLOOR).sqrt()


def round_cone_sdf(
    points: torch.Tensor,
    start: torch.Tensor,
    end: torch.Tensor,
    start_radius: torch.Tensor,
    end_radius: torch.Tensor,
) -> torch.Tensor:
    """Exact signed distance to round cones (the convex hull of two spheres), batched over parts.

    Closed form of the distance to the hull of the spheres ``(a, r1)`` and ``(b, r2)``: with
    ``l2 = |b - a|^2``, ``y = (p - a).(b - a)`` and ``q2 = |p - a|^2``, the point is nearest to
    sphere ``a`` if ``y`` is below the tangent cone's start, to sphere ``b`` if beyond its end,
    and otherwise to the cone's side at ``(sqrt((l2 q2 - y^2)(l2 - (r1 - r2)^2)) + y (r1 - r2)) /
    l2 - r1``. Requires ``|r1 - r2| < |b - a|``.

    points: [N, P, 3] metres, point n in part p's frame.
    start, end: [P, 3] sphere centres, metres.
    start_radius, end_radius: [P] radii, metres.
    -> [N, P] signed distances, metres.
    """
    axis = end - start  # [P, 3]
    length_sq = (axis * axis).sum(-1)  # [P]
    radius_diff = start_radius - end_radius
    cone_sq = length_sq - radius_diff * radius_diff  # > 0 by construction
    rel = points - start
    along = (rel * axis).sum(-1)  # y: [N, P]
    rel_sq = (rel * rel).sum(-1)  # q2
    perp = (length_sq * rel_sq - along * along).clamp_min(0.0)  # l2^2 * |p - a|_perp^2 / l2
    beyond = along - length_sq
    limit = torch.sign(radius_diff) * radius_diff * radius_diff * perp
    near_end = torch.sign(beyond) * cone_sq * beyond * beyond > limit
    near_start = torch.sign(along) * cone_sq * along * along < limit
    to_end = _safe_sqrt(rel_sq - 2.0 * along + length_sq) - end_radius
    to_start = _safe_sqrt(rel_sq) - start_radius
    to_side = (_safe_sqrt(perp * cone_sq) + along * radius_diff) / length_sq - start_radius
    return torch.where(near_end, to_end, torch.where(near_start, to_start, to_side))


def rounded_polygon_sdf(
    points_plane: torch.Tensor, vertices: torch.Tensor, radius: torch.Tensor
) -> torch.Tensor:
    """Exact signed distance to flat convex polygons thickened by a ball (rounded slabs).

    The distance to the flat polygon is ``sqrt(d2^2 + h^2)`` with ``d2`` the in-plane distance to
    the polygon (zero inside) and ``h`` the height over its plane; the slab is that minus
    ``radius``: thickness ``2 radius`` with rounded rims.

    points_plane: [N, Q, 3] points in each polygon's plane frame: (a, b) in-plane, third = height.
    vertices: [Q, V, 2] counter-clockwise convex polygons (repeat the last vertex to pad).
    radius: [Q] rounding radius (half thickness), metres.
    -> [N, Q] signed distances, metres.
    """
    planar = points_plane[..., None, :2]  # [N, Q, 1, 2]
    edge_start = vertices
    edge_vec = torch.roll(vertices, shifts=-1, dims=1) - vertices  # [Q, V, 2]
    rel = planar - edge_start  # [N, Q, V, 2]
    edge_sq = (edge_vec * edge_vec).sum(-1).clamp_min(_SQRT_FLOOR)
    t = ((rel * edge_vec).sum(-1) / edge_sq).clamp(0.0, 1.0)
    diff = rel - t[..., None] * edge_vec
    seg_sq = (diff * diff).sum(-1).amin(-1)  # [N, Q]
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
    scaled = -distances / blend
    value = -blend * torch.logsumexp(scaled, dim=-1)
    weights = torch.softmax(scaled, dim=-1)
    return value, weights


def smoothstep(low: float | torch.Tensor, high: float | torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Cubic Hermite step: 0 below ``low``, 1 above ``high`` (``low > high`` gives a falling step)."""
    t = ((x - low) / (high - low)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
