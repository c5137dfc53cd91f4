"""The proxy stages' data terms as objects (:class:`lisa_hand.fitting.terms.Term`).

Each reads one :class:`ProxySample`: the surface proxy posed by every candidate, the cloud
points drawn for this evaluation and the robust scale, and returns [K] or None where it does not
apply (a cloud without a sensor position has no free space; without a support plane, no bound).
:func:`proxy_terms` makes the terms from the settings; :func:`.proxy.proxy_energy` sums them.

- 'distance' (weight 1): the robust distance from each drawn cloud point to the nearest proxy
  point, mostly along that point's normal (``proxy_tangent_weight``).
- 'coverage' (``coverage_weight``): a bounded Geman-McClure distance (``coverage_scale_mm``)
  from each proxy point to the cloud (its distance grid), for a one-view scan asked only of the
  points the sensor could have returned (``coverage_seen_only``).
- 'free_space' (``free_space_weight``, not in the global search): the bounded penalty of how
  far each proxy point lies in the space the sensor saw to be empty (not beyond the wrist).
- 'support' (``support_weight``): the bounded penalty of how far each proxy point lies beyond
  the surface the hand rests on (2 mm allowed).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from ..robust import robust_loss
from ..terms import Energy, Term
from .cloud import TargetCloud, nearest_distance

__all__ = ["ProxySample", "ScanDistance", "Coverage", "ProxyFreeSpace", "SupportBound",
           "proxy_terms"]

_MM = 1e-3
_SUPPORT_MARGIN_M = 0.002  # proxy points may sink this far into a support (noise, flesh)


@dataclass(frozen=True)
class ProxySample:
    """What the proxy terms read at one evaluation.

    proxy: the :class:`~.proxy.SurfaceProxy`; cloud: the :class:`~.cloud.TargetCloud`;
    points: [K, P, 3] the proxy points posed by each candidate, world metres; normals: [K, P, 3]
    their unit normals, or None when no term needs them; rest: [P, 3] the same points at rest;
    targets: [N, 3] the cloud points drawn for this evaluation; scale: the robust scale, metres;
    config: the :class:`~.config.FitPointsConfig`.
    """

    proxy: Any
    cloud: TargetCloud
    points: torch.Tensor
    normals: torch.Tensor | None
    rest: torch.Tensor
    targets: torch.Tensor
    scale: float
    config: Any

    @property
    def count(self) -> int:
        """K, the candidates."""
        return self.points.shape[0]

    @property
    def device(self) -> torch.device:
        return self.points.device


@dataclass(frozen=True)
class ScanDistance(Term):
    """Robust distance from each drawn cloud point to the nearest posed proxy point."""

    tangent: float = 1.0

    def value(self, sample: ProxySample) -> torch.Tensor:
        config = sample.config
        distance = nearest_distance(sample.targets.expand(sample.count, -1, -1), sample.points,
                                    sample.normals if self.tangent != 1.0 else None,
                                    self.tangent)
        return robust_loss(distance, config.robust_loss, sample.scale).mean(-1)


@dataclass(frozen=True)
class Coverage(Term):
    """Bounded distance from each posed proxy point to the cloud (only the points the sensor
    could have returned, with ``seen_only`` and a sensor position)."""

    scale_m: float = 0.01
    seen_only: bool = True

    def value(self, sample: ProxySample) -> torch.Tensor:
        cloud = sample.cloud
        uncovered = cloud.distance_grid(sample.points)
        coverage = robust_loss(uncovered, "geman_mcclure", self.scale_m)
        if cloud.depth is not None and self.seen_only:
            # a one-view scan shows only what faces its sensor and is not hidden behind what it
            # returned: the rest of the hand need not be near a scan point
            normals = None if sample.normals is None else sample.normals.detach()
            coverage = coverage * cloud.depth.could_see(sample.points.detach(), normals)
        return coverage.mean(-1)


@dataclass(frozen=True)
class ProxyFreeSpace(Term):
    """Bounded depth of each posed proxy point in the space the sensor saw to be empty (points
    beyond the wrist joint, towards the forearm, not asked: a scan may stop there)."""

    scale_m: float = 0.01

    def value(self, sample: ProxySample) -> torch.Tensor | None:
        depth = sample.cloud.depth
        if depth is None:
            return None
        hand_side = (sample.rest[:, 0] <= sample.proxy.rest_joints[0, 0]).to(sample.points.dtype)
        seen = robust_loss(depth.violation(sample.points), "geman_mcclure", self.scale_m)
        return (seen * hand_side).mean(-1)


@dataclass(frozen=True)
class SupportBound(Term):
    """Bounded distance of each posed proxy point beyond the support plane (a margin
    allowed): the hand stays on its side of the surface it rests on."""

    scale_m: float = 0.01

    def value(self, sample: ProxySample) -> torch.Tensor | None:
        if sample.cloud.support is None:
            return None
        origin, normal = sample.cloud.support
        beyond = (-((sample.points - origin) @ normal) - _SUPPORT_MARGIN_M).clamp(min=0.0)
        return robust_loss(beyond, "geman_mcclure", self.scale_m).mean(-1)


def proxy_terms(config, free_space: bool = True) -> Energy:
    """The proxy energy's terms from ``config`` (a :class:`~.config.FitPointsConfig`);
    free_space: with the free-space term (every stage but the global search)."""
    scale = config.coverage_scale_mm * _MM
    terms: list[Term] = [
        ScanDistance("distance", 1.0, config.proxy_tangent_weight),
        Coverage("coverage", config.coverage_weight, scale, config.coverage_seen_only)]
    if free_space:
        terms.append(ProxyFreeSpace("free_space", config.free_space_weight, scale))
    terms.append(SupportBound("support", config.support_weight, scale))
    return Energy(tuple(terms))
