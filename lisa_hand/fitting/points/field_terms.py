"""The field stages' data terms as objects (:class:`lisa_hand.fitting.terms.Term`).

Each term asks for the field's value at points of its own (:meth:`FieldTerm.queries`; None where
it does not apply: a cloud without normals, without free space); the field stage evaluates all of
them in one batched call and each term reads its share (:class:`FieldSample`). Per candidate,
lengths in metres, ``rho`` the robust penalty at the sample's scale, means over the points on the
candidate's own side of its wrist cut:

- 'surface' (weight 1): ``mean rho(G(x_i))``: every scan point on the surface.
- 'normals' (``normal_weight``): ``mean [rho(G(x_i + eps n_i) - eps) + rho(G(x_i - eps n_i) +
  eps)] / 2``: the field grows outwards along the normals, which fixes the side of the surface
  the points are on.
- 'free_space' (``free_space_weight``): ``mean rho(min(G(f_j), 0))``: outside where the sensor
  saw nothing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import torch

from ..robust import robust_loss
from ..terms import Energy, Term
from .cloud import TargetCloud

__all__ = ["FieldSample", "FieldTerm", "SurfaceDistance", "NormalOffsets", "FieldFreeSpace",
           "field_terms", "field_energy"]

_MM = 1e-3


@dataclass(frozen=True)
class FieldSample:
    """What the field terms read at one evaluation.

    cloud: the :class:`~.cloud.TargetCloud`; index: [N] its points drawn; free_index: [M] its
    free points drawn, or None; keep, free_keep: [K, N], [K, M] 1 where a candidate counts a
    point (its side of its wrist cut), or None (all); scale: the robust scale, metres;
    robust: the penalty's name; count: K; sdf: {term name: [K, its queries]} the field at each
    term's points (filled by :func:`field_energy`).
    """

    cloud: TargetCloud
    index: torch.Tensor
    free_index: torch.Tensor | None
    keep: torch.Tensor | None
    free_keep: torch.Tensor | None
    scale: float
    robust: str
    count: int
    sdf: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def device(self) -> torch.device:
        return self.cloud.points.device


def _mean(values: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
    """[K] the mean of values [K, N] over the entries ``keep`` [K, N] (0/1; None: all)."""
    if keep is None:
        return values.mean(-1)
    return (values * keep).sum(-1) / keep.sum(-1).clamp(min=1.0)


@dataclass(frozen=True)
class FieldTerm(Term):
    """A term of the field's values at points of its own."""

    def queries(self, sample: FieldSample) -> torch.Tensor | None:
        """[Q, 3] world metres where the term needs the field, or None (it does not apply)."""
        raise NotImplementedError


@dataclass(frozen=True)
class SurfaceDistance(FieldTerm):
    """Every drawn scan point on the surface."""

    def queries(self, sample: FieldSample) -> torch.Tensor:
        return sample.cloud.points[sample.index]

    def value(self, sample: FieldSample) -> torch.Tensor:
        sdf = sample.sdf[self.name]
        return _mean(robust_loss(sdf, sample.robust, sample.scale), sample.keep)


@dataclass(frozen=True)
class NormalOffsets(FieldTerm):
    """The field ``eps`` outside along each drawn point's normal and ``eps`` inside against
    it."""

    offset_m: float = 0.003

    def queries(self, sample: FieldSample) -> torch.Tensor | None:
        normals = sample.cloud.normals
        if normals is None:
            return None
        points = sample.cloud.points[sample.index]
        offset = self.offset_m * normals[sample.index]
        return torch.cat([points + offset, points - offset])

    def value(self, sample: FieldSample) -> torch.Tensor | None:
        sdf = sample.sdf.get(self.name)
        if sdf is None:
            return None
        outside, inside = sdf.chunk(2, dim=-1)
        eps = self.offset_m
        return 0.5 * (_mean(robust_loss(outside - eps, sample.robust, sample.scale), sample.keep)
                      + _mean(robust_loss(inside + eps, sample.robust, sample.scale),
                              sample.keep))


@dataclass(frozen=True)
class FieldFreeSpace(FieldTerm):
    """The field outside (>= 0) at the drawn points the sensor saw to be empty."""

    def queries(self, sample: FieldSample) -> torch.Tensor | None:
        if sample.free_index is None or sample.free_index.numel() == 0:
            return None
        return sample.cloud.free[sample.free_index]

    def value(self, sample: FieldSample) -> torch.Tensor | None:
        sdf = sample.sdf.get(self.name)
        if sdf is None:
            return None
        inside = sdf.clamp(max=0.0)
        return _mean(robust_loss(inside, sample.robust, sample.scale), sample.free_keep)


def field_terms(config) -> Energy:
    """The field stage's data terms from ``config`` (a :class:`~.config.FitPointsConfig`)."""
    return Energy((SurfaceDistance("surface", 1.0),
                   NormalOffsets("normals", config.normal_weight,
                                 config.normal_offset_mm * _MM),
                   FieldFreeSpace("free_space", config.free_space_weight)))


def field_energy(terms: Energy, sample: FieldSample,
                 evaluate: Any) -> torch.Tensor:
    """[K] the data energy: every applying term's points evaluated at once (``evaluate``:
    points [Q, 3] -> field values [K, Q]), each term's share handed to it."""
    queries = {}
    for term in terms.terms:
        if term.weight > 0:
            points = term.queries(sample)
            if points is not None:
                queries[term.name] = points
    values = evaluate(torch.cat(list(queries.values())))
    sizes = [points.shape[0] for points in queries.values()]
    sample = dataclasses.replace(sample, sdf=dict(zip(queries, values.split(sizes, dim=-1),
                                                      strict=True)))
    return terms(sample)
