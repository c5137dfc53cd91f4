"""Where hands meet: each hand as a body the others must not enter (:class:`HandBody`), and
how deep they do (:func:`penetration_depths`).

A hand is LISA's field of its right hand (a left hand is fitted as its mirror image, as every
fitter does: :mod:`lisa_hand.fitting.sides`), so its inside is known everywhere at once: the
field's SDF at another hand's surface points says which of them are inside it and how deep.
A hand's surface points are the vertices of its fitted mesh (decimated to ``max_faces``, then
moved onto the field's own zero level: marching cubes leaves them up to a millimetre inside it),
skinned to its pose (:class:`lisa_hand.inference.skinned.SkinnedMesh`), so both are
differentiable in both hands' poses, translations and (for the field) shape codes. Points
outside a hand's bone regions (its box, :func:`lisa_hand.model.frame.region_bounds`) are outside
it and cost no network.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...geometry.meshing import Mesh
from ...skeleton import mirror_points
from ...skeleton.params import HandParams
from ..sides import mirror_hand

__all__ = ["HandBody", "penetration_depths"]


@dataclass
class HandBody:
    """One hand as the joint fit moves it: its RIGHT hand's parameters (``right``: a left
    hand's mirror image), whether the world sees it mirrored (``flip``), its surface (the
    right hand's mesh, skinned) and the rows of the surface samples."""

    right: HandParams
    flip: bool
    surface: object
    rows: torch.Tensor

    @classmethod
    def of(cls, model: object, params: HandParams, mesh: Mesh, samples: int, seed: int,
           max_faces: int = 8000) -> HandBody:
        """A hand (either side, world frame) and its mesh (with skinning weights, world) ->
        its body with ``samples`` surface samples (a fixed random subset of the vertices of the
        mesh decimated to ``max_faces`` and moved onto the field's zero level)."""
        from ...geometry.decimation import decimate_mesh
        from ...inference.mesh import mirror_mesh
        from ...inference.skinned import SkinnedMesh

        flip = params.side == "left"
        right = mirror_hand(params) if flip else params
        mesh = decimate_mesh(mirror_mesh(mesh) if flip else mesh, max_faces)
        body = cls(right=right, flip=False, surface=None, rows=torch.zeros(0, dtype=torch.long))
        snapped = body.onto_surface(model, torch.as_tensor(mesh.vertices, dtype=torch.float64))
        surface = SkinnedMesh(Mesh(vertices=snapped.numpy(), faces=mesh.faces,
                                   colors=mesh.colors, skin_weights=mesh.skin_weights), right)
        count = surface.rest_vertices.shape[0]
        generator = torch.Generator().manual_seed(seed)
        rows = torch.randperm(count, generator=generator)[:min(samples, count)]
        return cls(right=right, flip=flip, surface=surface, rows=rows)

    def onto_surface(self, model: object, points: torch.Tensor, steps: int = 2) -> torch.Tensor:
        """World points [N, 3] near the hand moved onto its field's zero level (Newton steps
        along the SDF's gradient, at the body's own parameters) -> [N, 3] float64."""
        right = self.right
        for _ in range(steps):
            moving = points.detach().clone().requires_grad_(True)
            sdf = self.sdf(model, right.pose, right.translation, right.shape_code, moving)
            (gradient,) = torch.autograd.grad(sdf.sum(), moving)
            gradient = gradient.double()
            step = sdf.detach().double() / gradient.square().sum(-1).clamp_min(1e-6)
            points = moving.detach() - step[:, None] * gradient
        return points.detach()

    def to_world(self, points: torch.Tensor) -> torch.Tensor:
        """Points of the right hand's frame [..., 3] -> the world's (mirrored for a left hand);
        its own inverse."""
        return mirror_points(points) if self.flip else points

    def surface_points(self, pose: torch.Tensor, translation: torch.Tensor,
                       every: bool = False) -> torch.Tensor:
        """The surface samples (every vertex with ``every``) in the world [S, 3] metres, float64,
        for the right hand's ``pose`` [48] and ``translation`` [3]."""
        rows = None if every else self.rows
        points = self.surface.vertices(pose.double()[None], translation.double()[None], rows)[0]
        return self.to_world(points)

    def sdf(self, model: object, pose: torch.Tensor, translation: torch.Tensor,
            shape_code: torch.Tensor, points: torch.Tensor, margin_m: float = 0.01
            ) -> torch.Tensor:
        """This hand's SDF at world ``points`` [N, 3] -> [N] metres (negative inside), for the
        right hand's ``pose`` [48], ``translation`` [3] and ``shape_code`` [D]; points beyond
        ``margin_m`` of its bone regions' box get the distance to that box (outside, no
        network)."""
        from ...model.frame import region_bounds

        field = model.field
        dtype = next(field.parameters()).dtype
        state = field.prepare(pose.to(dtype)[None], translation.to(dtype)[None],
                              self.right.rest_joints.to(dtype)[None], shape_code.to(dtype)[None],
                              None if model.color_codes is None
                              else self.right.color_code.to(dtype)[None])
        local = self.to_world(points).to(dtype)
        low, high = region_bounds(state, field)
        outside = (torch.relu(low[0] - margin_m - local) + torch.relu(local - high[0] - margin_m))
        far = outside.norm(dim=-1)
        near = far == 0
        sdf = far + margin_m
        if bool(near.any()):
            sdf = sdf.clone()
            sdf[near] = field.field(state, local[near][None], with_color=False).sdf[0].reshape(-1)
        return sdf


@torch.no_grad()
def penetration_depths(model: object, bodies: list[HandBody]) -> np.ndarray:
    """[K, K] millimetres: entry (a, b) the deepest point of hand a's whole surface (every
    vertex) inside hand b (0 when none is; the diagonal 0), at the bodies' own parameters."""
    count = len(bodies)
    depths = np.zeros((count, count))
    for a, body in enumerate(bodies):
        points = body.surface_points(body.right.pose, body.right.translation, every=True)
        for b, other in enumerate(bodies):
            if a == b:
                continue
            sdf = other.sdf(model, other.right.pose, other.right.translation,
                            other.right.shape_code, points)
            depths[a, b] = 1000.0 * float(torch.relu(-sdf).max()) if len(sdf) else 0.0
    return depths
