"""Carrying the MANO-like mesh template onto an open-hand subject's rest surface.

Each template vertex is moved by an LBS-like blend of per-bone affine maps
``x' = sum_j w_j (M_j x + t_j)``; ``(M_j, t_j)`` is the least-squares map of bone ``j``'s control
points (its joint and end, each with four points one flesh radius away on the dorsal and lateral
axes) from the mean skeleton to the subject's, so bone lengths, directions and thicknesses follow
the subject. Newton steps on the subject's SDF then put the vertex on the surface (the blended
map lands within ~0.4 mm of it). Used to build the template's shape space
(:mod:`.template_build`) and to fit a subject's betas (:meth:`.MeshTemplate.fit_betas`).

Arrays are float64 numpy, metres, MANO's right-hand axes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from ..skeleton.kinematics import mirror_points
from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS

if TYPE_CHECKING:
    from .hand import OpenHand, PosedHand

__all__ = [
    "PROJECTION_ITERATIONS",
    "skeleton_arrays",
    "correspond",
    "project_onto_surface",
    "project_betas",
]

PROJECTION_ITERATIONS = 5
"""Newton steps onto the SDF's zero level set."""


def skeleton_arrays(hand: OpenHand) -> dict[str, np.ndarray]:
    """The right-hand rest skeleton of a subject (whatever its side) as float64 arrays:
    ``joints``, ``bone_ends`` [16, 3], ``radii`` [16, 2], ``dorsal``, ``lateral`` [16, 3]."""
    skel = hand.parts.skeleton
    return {
        key: getattr(skel, key).detach().double().cpu().numpy()
        for key in ("joints", "bone_ends", "radii", "dorsal", "lateral")
    }


def _control_points(skeleton: dict[str, np.ndarray]) -> list[np.ndarray]:
    """Per bone, points that pin its affine map: the joint and the bone end, each with four
    points one flesh radius away along +-dorsal and +-lateral. The palm (bone 0) also gets those
    of the five finger bases (MCP joints and the thumb's CMC joint), which span its breadth."""
    joints, ends, radii = skeleton["joints"], skeleton["bone_ends"], skeleton["radii"]
    dorsal, lateral = skeleton["dorsal"], skeleton["lateral"]

    def around(center: np.ndarray, radius: float, bone: int) -> list[np.ndarray]:
        up, side = radius * dorsal[bone], radius * lateral[bone]
        return [center, center + up, center - up, center + side, center - side]

    controls = []
    for bone in range(NUM_JOINTS):
        points = around(joints[bone], radii[bone, 0], bone)
        points += around(ends[bone], radii[bone, 1], bone)
        if bone == 0:
            for base in (FINGER_JOINTS[name][0] for name in FINGER_NAMES):
                points += around(joints[base], radii[base, 0], base)
        controls.append(np.stack(points))
    return controls


def _bone_maps(source: dict[str, np.ndarray], target: dict[str, np.ndarray]) -> np.ndarray:
    """[16, 4, 3] least-squares affine maps (homogeneous rows) of each bone's control points."""
    maps = []
    for src, dst in zip(_control_points(source), _control_points(target), strict=True):
        homogeneous = np.concatenate([src, np.ones((len(src), 1))], axis=1)
        solution, *_ = np.linalg.lstsq(homogeneous, dst, rcond=None)
        maps.append(solution)
    return np.stack(maps)


def correspond(
    source: dict[str, np.ndarray], weights: np.ndarray, hand: OpenHand, iterations: int
) -> np.ndarray:
    """[V, 3] the template's vertices carried onto ``hand``'s right-hand rest surface.

    source: the mean hand's ``vertices`` [V, 3] and skeleton arrays (:func:`skeleton_arrays`).
    weights: [V, 16] LBS weights. iterations: Newton steps onto the surface (0: the blended
    affine maps only).
    """
    maps = _bone_maps(source, skeleton_arrays(hand))
    vertices = source["vertices"]
    homogeneous = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1)
    mapped = np.einsum("vj,vk,jkc->vc", weights, homogeneous, maps)
    if iterations == 0:
        return mapped
    posed = hand.posed(dtype=torch.float64)
    points = torch.from_numpy(mapped)
    if hand.side == "left":  # the left hand's field is the mirror image of the right hand's
        points = mirror_points(points)
    projected = project_onto_surface(posed, points, iterations)
    if hand.side == "left":
        projected = mirror_points(projected)
    return projected.cpu().numpy()


def project_onto_surface(posed: PosedHand, points: torch.Tensor, iterations: int) -> torch.Tensor:
    """Newton steps onto the surface (:meth:`PosedHand.project_to_surface`); a point whose SDF
    gradient is undefined (exactly on a fingertip's axis) is retried a micrometre away.

    points: [N, 3] metres -> [N, 3]."""
    projected = posed.project_to_surface(points, iterations=iterations)
    bad = ~torch.isfinite(projected).all(dim=1)
    if bool(bad.any()):
        nudged = points[bad] + points.new_tensor([0.0, 1e-6, 1e-6])
        projected[bad] = posed.project_to_surface(nudged, iterations=iterations)
    return projected


def project_betas(
    vertices: np.ndarray, v_template: np.ndarray, shapedirs: np.ndarray
) -> torch.Tensor:
    """[K] float64 least-squares betas of ``vertices`` [V, 3] in the shape space
    (``v_template`` [V, 3], ``shapedirs`` [V, 3, K])."""
    basis = shapedirs.reshape(-1, shapedirs.shape[-1])
    betas, *_ = np.linalg.lstsq(basis, (vertices - v_template).ravel(), rcond=None)
    return torch.from_numpy(betas)
