"""A fitted hand's mesh moved to any pose by linear blend skinning (:class:`SkinnedMesh`).

The mesh is unposed once (:func:`lisa_hand.inference.mesh.repose_mesh` to the zero pose); each
new pose is then one forward kinematics and one skinning of its vertices, differentiable in the
pose and translation. The video overlay poses the keyframe's mesh in every frame with it, and
the two-hand fit moves each hand's surface samples with it (a hand's surface where the other
hand's field is evaluated).
"""

from __future__ import annotations

import numpy as np
import torch

from ..geometry.meshing import Mesh
from ..skeleton.params import HandParams

__all__ = ["SkinnedMesh"]


class SkinnedMesh:
    """A hand's mesh ready to be posed. mesh: with skinning weights [V, 16]; params: the hand
    the mesh was made from (either side: a left hand's mesh is posed with its own, mirrored,
    skeleton). max_faces: the mesh decimated to at most this many faces first
    (:func:`lisa_hand.geometry.decimation.decimate_mesh`; None: as it is)."""

    def __init__(self, mesh: Mesh, params: HandParams, max_faces: int | None = None) -> None:
        from ..geometry.decimation import decimate_mesh
        from .mesh import repose_mesh

        self.params = params
        if max_faces is not None:
            mesh = decimate_mesh(mesh, max_faces)
        self.rest = repose_mesh(mesh, params, torch.zeros(48), torch.zeros(3))
        self.rest_vertices = torch.from_numpy(self.rest.vertices).double()
        """[V, 3] metres: the mesh at the zero pose and translation."""
        self.weights = torch.from_numpy(self.rest.skin_weights).double()
        """[V, 16] the vertices' skinning weights."""

    def vertices(self, pose: torch.Tensor, translation: torch.Tensor,
                 rows: torch.Tensor | None = None) -> torch.Tensor:
        """pose [B, 48] radians, translation [B, 3] metres (float64; gradients flow) -> the
        vertices [B, V, 3] metres in those poses (only vertices ``rows`` [S] when given)."""
        from ..skeleton import forward_kinematics, linear_blend_skinning

        rest, weights = self.rest_vertices, self.weights
        if rows is not None:
            rest, weights = rest[rows], weights[rows]
        joints = self.params.rest_joints.double()[None].expand(pose.shape[0], -1, -1)
        kinematics = forward_kinematics(pose, joints, translation)
        return linear_blend_skinning(rest, weights, kinematics.transforms)

    def posed(self, pose: np.ndarray, translation: np.ndarray) -> Mesh:
        """pose [48] radians, translation [3] metres -> the mesh in that pose."""
        with torch.no_grad():
            vertices = self.vertices(torch.as_tensor(pose, dtype=torch.float64)[None],
                                     torch.as_tensor(translation, dtype=torch.float64)[None])[0]
        return Mesh(vertices=vertices.float().numpy(), faces=self.rest.faces,
                    colors=self.rest.colors)
