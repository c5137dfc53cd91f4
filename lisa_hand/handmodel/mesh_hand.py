"""Hand model v3 in a pose: the rest mesh of :mod:`.mesh_rest` skinned by dual quaternions, and
its exact ground truth.

:class:`PosedMeshHand` has the interface of :class:`~.hand.PosedHand` (joints, keypoints,
transforms; ``sdf``, ``evaluate``, ``albedo``, ``normals``, ``mesh``, ``surface_samples``,
``project_to_surface``), so the data generator, the template fit and the previews take either.
Its surface is the skinned mesh itself, so the ground truth is exact for it: the signed distance
is the distance to the closest point of the mesh with the winding number's sign
(:mod:`lisa_hand.geometry.mesh_distance`), skinning weights, colour and surface features are the
closest point's (barycentric), and :meth:`PosedMeshHand.mesh` returns the mesh (no marching
cubes).

Skinning artefacts at strong flexion are corrected twice: dual quaternion skinning keeps a
twisted joint's thickness and part of a flexed joint's volume, where linear blend skinning
shrinks them (``skinning="linear"`` for the comparison); and a pose corrective
(:func:`knuckle_corrective`, as MANO's pose blend shapes but in closed form) pushes the skin on
the outside of each bent joint away from the bone's axis, in the rest pose before skinning, by
``KNUCKLE_BULGE r_j b (1 - cos theta_j)``: ``r_j`` the joint's flesh radius, ``b = 4 w_parent
w_j`` where the two bones' weights blend, ``theta_j`` the joint's rotation angle, only on the
dorsal half (the palmar half folds and touches itself, as skin does). Not differentiable: the SDF
and its normals are numpy computations.
"""

from __future__ import annotations

import numpy as np
import torch

from ..skeleton.kinematics import (
    dual_quaternion_skinning,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
    mirror_pose,
)
from ..skeleton.tree import (
    FINGER_JOINTS,
    FINGER_NAMES,
    NUM_JOINTS,
    PARENTS,
    POSE_DIM,
    joints_to_keypoints,
)
from .appearance import albedo
from .checks import check_query_points, check_vector
from .mesh_rest import MeshRest, build_mesh_rest
from .sdf import HandFieldOutput

__all__ = ["PosedMeshHand", "SKINNING_METHODS", "KNUCKLE_BULGE", "knuckle_corrective"]

SKINNING_METHODS = ("dual_quaternion", "linear")
"""How the rest mesh follows the bones: ``"dual_quaternion"`` (default) or ``"linear"``."""

KNUCKLE_BULGE = 1.0
"""Strength of :func:`knuckle_corrective` (flesh radii per unit of ``1 - cos theta``): the value
that brings the bent named poses closest to the rest hand's volume with none above it
(``python -m lisa_hand.handmodel.volume`` prints the volume change per pose); 0 turns it off."""

_MIRROR = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=torch.float64))
_FEATURES = ("nail", "nail_along", "crease", "palmar", "knuckle")


def knuckle_corrective(rest: MeshRest, pose: torch.Tensor,
                       strength: float = KNUCKLE_BULGE) -> np.ndarray:
    """[V, 3] rest-pose offsets of the skin for a right-hand ``pose`` [48] (see the module
    docstring): outward from each bent joint's bone axis on its dorsal half, metres."""
    angles = pose.reshape(NUM_JOINTS, 3).norm(dim=1).numpy()
    skeleton = rest.skeleton
    joints, dirs = skeleton.joints.numpy(), skeleton.bone_dirs.numpy()
    dorsal, radii = skeleton.dorsal.numpy(), skeleton.radii.numpy().mean(axis=1)
    offsets = np.zeros_like(rest.vertices)
    if strength == 0:
        return offsets
    for joint in range(1, NUM_JOINTS):
        bend = 1.0 - np.cos(angles[joint])
        if bend < 1e-6:
            continue
        blend = np.clip(4.0 * rest.weights[:, PARENTS[joint]] * rest.weights[:, joint], 0.0, 1.0)
        near = np.flatnonzero(blend > 1e-3)
        relative = rest.vertices[near] - joints[joint]
        radial = relative - (relative @ dirs[joint])[:, None] * dirs[joint]
        radial /= np.linalg.norm(radial, axis=1, keepdims=True).clip(1e-9)
        outside = np.clip(radial @ dorsal[joint], 0.0, 1.0)
        size = strength * radii[joint] * bend * blend[near] * outside
        offsets[near] += size[:, None] * radial
    return offsets


class PosedMeshHand:
    """A hand model v3 subject in one pose (world frame, its side; float64 CPU attributes).

    joints: [16, 3] posed MANO joints, metres. fingertips: [5, 3] on the skin (thumb .. pinky).
    keypoints: [21, 3]. transforms: [16, 4, 4] rest-to-posed bone transforms.
    vertices: [V, 3] float64 posed mesh; faces: [F, 3] int64, outward for this side.
    pose: [48], translation: [3] the inputs.
    skinning: one of :data:`SKINNING_METHODS`; corrective: :func:`knuckle_corrective`'s
    strength (0: none).
    """

    def __init__(self, hand, pose: torch.Tensor | None, translation: torch.Tensor | None,
                 dtype: torch.dtype = torch.float32, device: torch.device | str | None = None,
                 skinning: str = "dual_quaternion", corrective: float = KNUCKLE_BULGE) -> None:
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        if skinning not in SKINNING_METHODS:
            raise ValueError(f"skinning must be one of {SKINNING_METHODS}, got {skinning!r}")
        self.hand = hand
        self.pose = (torch.zeros(POSE_DIM, dtype=torch.float64) if pose is None
                     else check_vector(pose, POSE_DIM, "pose"))
        self.translation = (torch.zeros(3, dtype=torch.float64) if translation is None
                            else check_vector(translation, 3, "translation"))
        self.dtype = dtype
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self.mirrored = hand.side == "left"
        rest: MeshRest = build_mesh_rest(hand.shape)
        self.rest = rest
        pose_right = mirror_pose(self.pose) if self.mirrored else self.pose
        shift_right = mirror_points(self.translation) if self.mirrored else self.translation
        kinematics = forward_kinematics(pose_right[None], rest.skeleton.joints, shift_right[None])
        transforms = kinematics.transforms[0]
        skin = dual_quaternion_skinning if skinning == "dual_quaternion" else (
            lambda points, weights, bones: linear_blend_skinning(points, weights, bones[None])[0])
        shaped = rest.vertices + knuckle_corrective(rest, pose_right, corrective)
        vertices = skin(torch.from_numpy(shaped), torch.from_numpy(rest.weights),
                        transforms).numpy()
        distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
        tips = rest.skeleton.fingertips
        tips = (transforms[distal, :3, :3] @ tips[..., None])[..., 0] + transforms[distal, :3, 3]
        joints = kinematics.joints[0]
        if self.mirrored:
            vertices = vertices * np.array([-1.0, 1.0, 1.0])
            joints, tips = mirror_points(joints), mirror_points(tips)
            transforms = _MIRROR @ transforms @ _MIRROR
            self.faces = rest.faces[:, ::-1].copy()
        else:
            self.faces = rest.faces
        self.vertices = vertices
        self.joints, self.transforms = joints, transforms
        self.fingertips = torch.from_numpy(self._closest(tips.numpy()).closest)
        self.keypoints = joints_to_keypoints(self.joints, self.fingertips)

    # ------------------------------------------------------------------------------------------
    def _closest(self, points: np.ndarray):
        from ..geometry.mesh_distance import mesh_distance

        return mesh_distance(points, self.vertices, self.faces)

    def _query(self, points: torch.Tensor, name: str = "points") -> np.ndarray:
        return check_query_points(points, name).detach().double().cpu().numpy()

    def _out(self, array: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(array, dtype=self.dtype, device=self.device)

    def evaluate(self, points: torch.Tensor, with_features: bool = False) -> HandFieldOutput:
        """The ground truth at points: ``sdf`` and skinning ``weights``, and with
        ``with_features`` the closest rest-surface point (``rest_points``, right-hand rest
        frame) and its surface features (:class:`~.sdf.HandFieldOutput`).

        points: [N, 3] world points, metres. Not differentiable.
        """
        where = self._closest(self._query(points))
        rest = self.rest
        weights = where.interpolate(self.faces, rest.weights)
        weights = weights / weights.sum(axis=1, keepdims=True)
        out = HandFieldOutput(sdf=self._out(where.sdf), weights=self._out(weights))
        if with_features:
            out.rest_points = self._out(where.interpolate(self.faces, rest.vertices))
            for name in _FEATURES:
                setattr(out, name, self._out(where.interpolate(self.faces, rest.features[name])))
        return out

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance to the skin, negative inside: [N, 3] metres -> [N] metres."""
        return self._out(self._closest(self._query(points)).sdf)

    def sdf_and_ownership(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(sdf [N] metres, skinning weights [N, 16]) at [N, 3] world points."""
        out = self.evaluate(points)
        return out.sdf, out.weights

    def albedo(self, points: torch.Tensor) -> torch.Tensor:
        """Skin colour at (surface) points: [N, 3] metres -> [N, 3] sRGB in [0, 1]."""
        return self._albedo(self.evaluate(points, with_features=True))

    def _albedo(self, out: HandFieldOutput) -> torch.Tensor:
        return albedo(self.hand.appearance, out.rest_points, out.palmar, out.nail,
                      out.nail_along, out.crease, out.knuckle)

    def normals(self, points: torch.Tensor) -> torch.Tensor:
        """Outward unit normals: the SDF's gradient, ``sign(sdf) (p - closest) / |p - closest|``,
        or the closest face's normal on the surface itself. [N, 3] -> [N, 3]."""
        query = self._query(points)
        where = self._closest(query)
        offset = query - where.closest
        length = np.linalg.norm(offset, axis=1, keepdims=True)
        corners = self.vertices[self.faces[where.face]]
        face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True).clip(1e-30)
        gradient = np.where(length > 1e-7, np.sign(where.sdf)[:, None] * offset
                            / length.clip(1e-30), face_normal)
        return self._out(gradient)

    def project_to_surface(self, points: torch.Tensor, iterations: int = 3) -> torch.Tensor:
        """The closest points of the skin (exact; ``iterations`` is unused): [N, 3] -> [N, 3]."""
        return self._out(self._closest(self._query(points)).closest)

    def bounding_box(self, margin: float = 0.004) -> tuple[np.ndarray, np.ndarray]:
        """(min [3], max [3]) metres around the skin, ``margin`` added."""
        return self.vertices.min(0) - margin, self.vertices.max(0) + margin

    def default_voxel_size(self) -> float:
        """Hand length / 255 metres (the meshing grid of the other hand models)."""
        return self.hand.shape.hand_length / 255

    def mesh(self, voxel_size: float | None = None, resolution: int | None = None,
             colors: bool = True, skin_weights: bool = True):
        """The skinned mesh itself (closed, about 27k vertices 1-2 mm apart, outward), with
        per-vertex albedo and skinning weights. ``voxel_size`` and ``resolution`` (the other
        models' marching-cubes grid) do not apply: this surface needs no extraction.
        -> :class:`lisa_hand.geometry.meshing.Mesh` (world frame)."""
        from ..geometry.meshing import Mesh, colors_to_uint8

        rest = self.rest
        color = None
        if colors:
            features = {name: torch.from_numpy(rest.features[name]) for name in _FEATURES}
            color = colors_to_uint8(albedo(self.hand.appearance, torch.from_numpy(rest.vertices),
                                           features["palmar"], features["nail"],
                                           features["nail_along"], features["crease"],
                                           features["knuckle"]))
        return Mesh(vertices=self.vertices.astype(np.float32), faces=self.faces, colors=color,
                    skin_weights=rest.weights.astype(np.float32) if skin_weights else None)

    def surface_samples(self, num: int, generator: torch.Generator,
                        voxel_size: float | None = None):
        """Points uniformly spread over the skin (faces drawn by area), with the faces' normals,
        weights and albedo. num: >= 1. generator: a seeded ``torch.Generator``."""
        from ..geometry.meshing import sample_triangles
        from .hand import SurfaceSamples

        if not isinstance(num, int) or num < 1:
            raise ValueError(f"num must be a positive int, got {num!r}")
        if not isinstance(generator, torch.Generator):
            raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
        corners = torch.from_numpy(self.vertices[self.faces])
        cross = torch.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], dim=-1)
        face, u, v = sample_triangles(cross.norm(dim=-1), num, generator)
        chosen = corners[face]
        points = chosen[:, 0] + u[:, None] * (chosen[:, 1] - chosen[:, 0])
        points = points + v[:, None] * (chosen[:, 2] - chosen[:, 0])
        normals = cross[face] / cross[face].norm(dim=-1, keepdim=True)
        out = self.evaluate(points, with_features=True)
        return SurfaceSamples(points=self._out(points.numpy()), normals=self._out(normals.numpy()),
                              weights=out.weights, colors=self._albedo(out))

    def volume(self) -> float:
        """The closed mesh's volume, cubic metres (divergence theorem)."""
        corners = self.vertices[self.faces]
        return float(np.einsum("fi,fi->f", corners[:, 0],
                               np.cross(corners[:, 1], corners[:, 2])).sum() / 6.0)

    def __repr__(self) -> str:
        return (f"PosedMeshHand(side={self.hand.side!r}, vertices={len(self.vertices)}, "
                f"joints={NUM_JOINTS})")
