"""The geometry guard of the image fit: did the colour stage keep the hand one hand-shaped piece?

:func:`surface_guard` compares the fitted hand's mesh with a reference mesh, the LISA hand where
the colour stage started (the keypoint stage's pose and skeleton with the start shape code,
meshed the same way), by two figures:

* ``pieces``: connected pieces of the fitted surface. Two triangles are connected when they
  share a vertex (vertices at the same position are merged first, so a mesh written with
  duplicated vertices counts the same); pieces whose area is below ``min_piece_fraction`` of the
  surface (specks of marching cubes, smaller than a voxel or two) are not counted, and the
  notes say how many were ignored.
* ``area_ratio``: fitted surface area over the reference's (the sum of the triangles' areas,
  specks included, metres^2 / metres^2).

The fit passes when its area is within ``max_area_change`` of the reference's and it has no more
pieces than the reference (one, for a trained model), or its extra pieces add little floating
area (area outside the largest piece) to the reference's own: at most ``max_area_change`` of
it, the relative change allowed to the area. An untrained field is full of specks (hundreds of
pieces, a few percent of the area) whose count flips around the threshold between two meshes
of the same surface; a trained model's reference is one piece with a tiny fraction of its area
outside it, so that any counted floater fails. On real photos the colour loss can otherwise
grow floaters and lumps where the model's colours cannot match the photo.

:func:`guard_mesh` meshes a hand for the guard (marching cubes at the guard's resolution,
:func:`lisa_hand.inference.mesh_hand` without colours or skinning weights).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ...geometry.pieces import MIN_PIECE_FRACTION, surface_pieces

__all__ = ["GuardReport", "MIN_PIECE_FRACTION", "surface_pieces", "surface_guard",
           "guard_mesh"]


@dataclass(frozen=True)
class GuardReport:
    """What :func:`surface_guard` found.

    pieces: connected pieces of the fitted surface (specks below ``min_piece_fraction`` of its
        area not counted); 0 for an empty mesh.
    area_ratio: fitted surface area / reference surface area (NaN when the reference is empty).
    passed: ``pieces`` is at least 1 and at most the reference's (at least 1), or the extra
        pieces add little floating area (see the module docstring); and
        ``|area_ratio - 1| <= max_area_change``.
    notes: one sentence per finding (the figures, ignored specks, why it failed).
    """

    pieces: int
    area_ratio: float
    passed: bool
    notes: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready values (``params.json`` extra, ``metrics.json``)."""
        values = asdict(self)
        values["notes"] = list(self.notes)
        return values


def _floating(areas: np.ndarray, total: float) -> float:
    """Fraction of the area outside the largest piece (0 for an empty surface)."""
    return float(1.0 - areas[0] / total) if total > 0 else 0.0


def _counted(areas: np.ndarray, total: float, min_piece_fraction: float) -> int:
    return int((areas >= min_piece_fraction * total).sum()) if total > 0 else 0


def surface_guard(reference_mesh: Any, fitted_mesh: Any, max_area_change: float = 0.10,
                  min_piece_fraction: float = MIN_PIECE_FRACTION) -> GuardReport:
    """Judge a fitted surface against the reference (see the module docstring).

    reference_mesh: the hand where the colour stage started (the keypoint stage's pose and
        skeleton, the start shape code), meshed as ``fitted_mesh``; both with ``vertices``
        [V, 3] metres and ``faces`` [F, 3].
    max_area_change: the largest allowed ``|area_ratio - 1|`` (0.10: within 10 %).
    min_piece_fraction: pieces below this fraction of a surface's area are specks, not
        counted (:data:`MIN_PIECE_FRACTION`).
    -> :class:`GuardReport`.
    """
    if not max_area_change >= 0:
        raise ValueError(f"max_area_change must be >= 0, got {max_area_change!r}")
    if not 0 <= min_piece_fraction < 1:
        raise ValueError(f"min_piece_fraction must be in [0, 1), got {min_piece_fraction!r}")
    ref_areas, ref_total = surface_pieces(reference_mesh, "reference_mesh")
    fit_areas, fit_total = surface_pieces(fitted_mesh, "fitted_mesh")
    ref_pieces = _counted(ref_areas, ref_total, min_piece_fraction)
    pieces = _counted(fit_areas, fit_total, min_piece_fraction)
    ratio = fit_total / ref_total if ref_total > 0 else float("nan")
    allowed = max(1, ref_pieces)
    notes = [f"surface: {pieces} piece(s), area {1e4 * fit_total:.1f} cm^2 = {ratio:.3f} x the "
             f"keypoint-stage hand's {1e4 * ref_total:.1f} cm^2 ({ref_pieces} piece(s))"]
    specks = len(fit_areas) - pieces
    if specks:
        notes.append(f"{specks} speck(s) below {100 * min_piece_fraction:g} % of the area "
                     f"ignored ({1e4 * float(fit_areas[pieces:].sum()):.2f} cm^2 in all)")
    # Extra pieces that add no floating area (outside the largest piece) beyond the
    # reference's own are the model's noise (an untrained field's specks hover around the
    # threshold), not floaters grown by the fit.
    floating, ref_floating = _floating(fit_areas, fit_total), _floating(ref_areas, ref_total)
    extra_floating = floating - ref_floating
    tolerance = max_area_change * ref_floating
    pieces_ok = 1 <= pieces and (pieces <= allowed or extra_floating <= tolerance)
    if pieces == 0:
        notes.append("the fitted surface is empty")
    elif pieces > allowed and not pieces_ok:
        notes.append(f"{pieces - allowed} floating piece(s) more than the keypoint-stage hand "
                     f"({100 * floating:.2f} % of the area outside the largest piece)")
    elif pieces > allowed:
        notes.append(f"{pieces - allowed} piece(s) more than the keypoint-stage hand, but no "
                     f"more area outside the largest piece ({100 * floating:.2f} %, "
                     f"{100 * extra_floating:+.2f} %): the model's own specks")
    area_ok = bool(np.isfinite(ratio) and abs(ratio - 1.0) <= max_area_change)
    if ref_total == 0:
        notes.append("the keypoint-stage hand has no surface to compare with")
    elif not area_ok:
        notes.append(f"the area changed by {100 * (ratio - 1.0):+.1f} % (allowed: "
                     f"{100 * max_area_change:g} %)")
    passed = pieces_ok and area_ok
    return GuardReport(pieces=pieces, area_ratio=float(ratio), passed=passed,
                       notes=tuple(notes))


def guard_mesh(model: Any, hand: Any, resolution: int) -> Any:
    """The hand's surface for :func:`surface_guard`: marching cubes at ``resolution`` samples a
    side of the cube around the posed skeleton (:func:`lisa_hand.inference.mesh_hand`, no
    colours or skinning weights).

    model: a :class:`lisa_hand.model.trained.TrainedModel`; hand: a right hand's
    :class:`lisa_hand.skeleton.params.HandParams` of that model.
    -> :class:`lisa_hand.geometry.meshing.Mesh` (world frame, metres); empty (no vertices, no
    faces) when the field has no surface in the grid (a fit can make it vanish).
    """
    import torch

    from ...geometry.meshing import Mesh
    from ...inference import mesh_hand
    from ...inference.mesh import MeshConfig

    try:
        with torch.no_grad():
            return mesh_hand(model, hand, resolution,
                             MeshConfig(colors=False, skin_weights=False))
    except ValueError as exc:
        if "level set" not in str(exc):  # marching cubes found no surface: an empty mesh
            raise
        return Mesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=np.int64))
