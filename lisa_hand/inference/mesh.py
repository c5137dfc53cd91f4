"""A hand's surface as a triangle mesh: :func:`mesh_hand`, and :func:`repose_mesh` by skinning.

Coarse-to-fine marching cubes (:func:`lisa_hand.geometry.meshing.extract_mesh_with_stats`) on a
cubic grid around the skeleton box, then per-vertex colours (with the model's mean gain and bias,
LISA Section 4.2) and skinning weights (dense correspondences across poses and subjects: vertex
``v`` of any hand belongs to bone ``j`` with weight ``w_j(v)``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.meshing import Mesh, MeshExtraction, colors_to_uint8, extract_mesh_with_stats
from ..geometry.planes import Plane, clip_mesh
from ..model.trained import TrainedModel
from ..skeleton import NUM_JOINTS, POSE_DIM, forward_kinematics, linear_blend_skinning
from ..skeleton.params import HandParams
from .bounds import hand_bounds, skeleton_box
from .hand_field import HandField, hand_field

__all__ = [
    "MeshConfig",
    "HandMesh",
    "check_resolution",
    "mesh_hand",
    "mesh_hand_with_stats",
    "mesh_attributes",
    "mirror_mesh",
    "repose_mesh",
]


@dataclass(frozen=True)
class MeshConfig:
    """How :func:`mesh_hand` extracts a hand's mesh."""

    padding: float = 0.03
    """Metres added on every side of the posed skeleton's box (:func:`skeleton_box`) to make
    the grid. A surface that reaches the box's side is never cut: the grid then grows, at the
    same voxel size, to the cube of the bone regions (:func:`hand_bounds`)."""
    lipschitz: float = 2.0
    """Bound on the learned SDF's gradient norm: the coarse-to-fine pass skips a block only when
    this bound proves it far from the surface. Up to ~1.7 on a geometric-init LISA;
    a trained field is close to 1 (Eikonal loss). Larger only costs evaluations."""
    coarse_to_fine: bool = True
    """Evaluate the grid coarse to fine (False: every grid point, the dense reference)."""
    colors: bool = True
    """Attach per-vertex colours (calibrated; grey for a geometry-only model)."""
    skin_weights: bool = True
    """Attach per-vertex skinning weights [V, 16]."""
    chunk_size: int = 65536
    """Most points per field call (bounds memory)."""

    def __post_init__(self) -> None:
        if not self.padding >= 0:
            raise ValueError(f"padding must be >= 0 (metres), got {self.padding!r}")
        if not self.lipschitz >= 1:
            raise ValueError(f"lipschitz must be >= 1, got {self.lipschitz!r}")
        chunk = self.chunk_size
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise ValueError(f"chunk_size must be a positive int, got {chunk!r}")


@dataclass
class HandMesh:
    """Result of :func:`mesh_hand_with_stats`.

    mesh: the hand's mesh (world frame, float32 metres, outward faces, colours and weights).
    extraction: counts and timings of marching cubes
        (:class:`lisa_hand.geometry.meshing.MeshExtraction`; of the last pass when the grid grew).
    box_low, box_high: [3] metres, the cubic grid's corners. voxel_size: metres.
    grown: the surface reached the skeleton box's side and the grid grew to the bone regions.
    seconds_attributes, seconds_total: wall times.
    """

    mesh: Mesh
    extraction: MeshExtraction
    box_low: np.ndarray
    box_high: np.ndarray
    voxel_size: float
    grown: bool
    seconds_attributes: float
    seconds_total: float


def check_resolution(resolution: int) -> int:
    """A grid resolution (samples per side, an int >= 8), or TypeError / ValueError."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise TypeError(f"resolution must be an int, got {type(resolution).__name__}")
    if resolution < 8:
        raise ValueError(f"resolution must be >= 8 grid samples per side, got {resolution}")
    return int(resolution)


def _touches_box(vertices: np.ndarray, low: np.ndarray, high: np.ndarray, voxel: float) -> bool:
    """Marching cubes puts vertices on the grid's side only where the surface is cut there."""
    tolerance = 1e-3 * voxel
    return bool(
        (np.abs(vertices - low) <= tolerance).any() or (np.abs(vertices - high) <= tolerance).any()
    )


def _skeleton_cube(
    params: HandParams, model: TrainedModel, resolution: int, padding: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """A cube around the skeleton's box: isotropic voxels, ``resolution`` samples a side.
    -> (box_low [3], box_high [3] float64 metres, voxel metres)"""
    low, high = skeleton_box(params, model.config, padding)
    middle = 0.5 * (low + high)
    extent = float((high - low).max())
    voxel = extent / (resolution - 1)
    return middle - 0.5 * extent, middle + 0.5 * extent, voxel


def _bone_region_cube(
    params: HandParams, model: TrainedModel, voxel: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """The cube of the bone regions (it holds the whole surface) at voxel size ``voxel``.
    -> (box_low [3], box_high [3] float64 metres, samples a side)"""
    center, radius = hand_bounds(params, model.config)
    samples = math.ceil(2.0 * radius / voxel) + 1
    half = 0.5 * (samples - 1) * voxel
    return center.double().numpy() - half, center.double().numpy() + half, samples


def _vertex_attributes(mesh: Mesh, hand: HandField, config: MeshConfig) -> Mesh:
    """``mesh`` with the colours and skinning weights ``config`` asks for, evaluated at its
    vertices in chunks of ``config.chunk_size``."""
    field = hand.model.field
    vertices = torch.from_numpy(mesh.vertices).to(field.device, field.dtype)
    colors, weights = [], []
    for begin in range(0, vertices.shape[0], config.chunk_size):
        rgb, skin = hand.attributes(
            vertices[begin : begin + config.chunk_size], config.colors, config.skin_weights
        )
        colors.append(rgb)
        weights.append(skin)
    return Mesh(
        vertices=mesh.vertices,
        faces=mesh.faces,
        colors=colors_to_uint8(torch.cat(colors)) if config.colors else None,
        skin_weights=None if weights[0] is None else torch.cat(weights).float().cpu(),
    )


def mesh_hand_with_stats(
    model: TrainedModel,
    params: HandParams,
    resolution: int = 128,
    config: MeshConfig | None = None,
    *,
    hand: HandField | None = None,
    progress: bool = False,
    clip: Plane | None = None,
) -> HandMesh:
    """:func:`mesh_hand` with the grid, counts and timings (for benchmarks and reports)."""
    start = time.perf_counter()
    config = MeshConfig() if config is None else config
    resolution = check_resolution(resolution)
    hand = hand_field(model, params) if hand is None else hand
    field = model.field
    sdf_fn = hand.sdf_fn()

    def extract(box_low, box_high, samples):
        return extract_mesh_with_stats(
            sdf_fn, box_low, box_high, samples,
            coarse_resolution=None if config.coarse_to_fine else samples,
            lipschitz=config.lipschitz, chunk_size=config.chunk_size, device=field.device,
            dtype=field.dtype, progress=progress,
        )  # fmt: skip

    box_low, box_high, voxel = _skeleton_cube(params, model, resolution, config.padding)
    extraction = extract(box_low, box_high, resolution)
    grown = _touches_box(extraction.mesh.vertices, box_low, box_high, voxel)
    if grown:
        box_low, box_high, samples = _bone_region_cube(params, model, voxel)
        extraction = extract(box_low, box_high, samples)
    mesh = extraction.mesh
    if clip is not None:
        mesh = Mesh(*clip_mesh(mesh.vertices, mesh.faces, clip))
    attributes_start = time.perf_counter()
    if config.colors or config.skin_weights:
        mesh = _vertex_attributes(mesh, hand, config)
    now = time.perf_counter()
    return HandMesh(
        mesh=mesh,
        extraction=extraction,
        box_low=box_low,
        box_high=box_high,
        voxel_size=voxel,
        grown=grown,
        seconds_attributes=now - attributes_start,
        seconds_total=now - start,
    )


def mesh_hand(
    model: TrainedModel,
    params: HandParams,
    resolution: int = 128,
    config: MeshConfig | None = None,
    *,
    hand: HandField | None = None,
    progress: bool = False,
    clip: Plane | None = None,
) -> Mesh:
    """The hand's surface as a triangle mesh with calibrated colours and skinning weights.

    The grid is the cube around the posed skeleton's box plus ``config.padding``
    (:func:`skeleton_box`) with ``resolution`` samples a side (grown at the same voxel size to
    the bone regions if the surface reaches its side), evaluated coarse to fine: full resolution
    only near the zero level set, equal to dense evaluation when ``config.lipschitz`` bounds the
    field's gradient (:func:`lisa_hand.geometry.meshing.extract_mesh`).

    model, params: the trained model and the hand (:func:`load_hand`). resolution: grid samples
    per side (>= 8). hand: a prepared :func:`hand_field` of the same model and params (reused).
    clip: a :class:`lisa_hand.geometry.planes.Plane` (e.g. the fit's wrist cut,
    :func:`lisa_hand.skeleton.wrist.wrist_plane`): the surface is cut along it, open there, and
    only its kept side returned; None: the whole surface.
    -> :class:`lisa_hand.geometry.meshing.Mesh`: world-frame float32 metres, outward faces, uint8
    colours [V, 3], skinning weights [V, 16] (rows sum to 1).
    """
    return mesh_hand_with_stats(
        model, params, resolution, config, hand=hand, progress=progress, clip=clip
    ).mesh


def mesh_attributes(
    model: TrainedModel,
    params: HandParams,
    mesh: Mesh,
    config: MeshConfig | None = None,
    *,
    hand: HandField | None = None,
) -> Mesh:
    """``mesh`` (a surface of this hand already extracted, e.g. by :func:`mesh_hand` with
    ``colors=False, skin_weights=False``) with the colours and skinning weights ``config`` asks
    for, as :func:`mesh_hand` attaches them: the same mesh as :func:`mesh_hand` would return
    for that surface, without extracting it again.

    model, params: the trained model and the hand; hand: a prepared :func:`hand_field` of them.
    mesh: world frame, metres. -> a new :class:`lisa_hand.geometry.meshing.Mesh`.
    """
    config = MeshConfig() if config is None else config
    hand = hand_field(model, params) if hand is None else hand
    if not (config.colors or config.skin_weights) or len(mesh.vertices) == 0:
        return Mesh(vertices=mesh.vertices, faces=mesh.faces)
    return _vertex_attributes(Mesh(vertices=mesh.vertices, faces=mesh.faces), hand, config)


def mirror_mesh(mesh: Mesh) -> Mesh:
    """``mesh`` mirrored through the x = 0 plane (a right hand's surface <-> the left hand's,
    :func:`lisa_hand.skeleton.kinematics.mirror_points`), faces turned so that they stay
    counter-clockwise seen from outside; colours and skinning weights kept."""
    vertices = mesh.vertices * np.array([-1.0, 1.0, 1.0], dtype=np.float32)
    return Mesh(vertices=vertices, faces=np.ascontiguousarray(mesh.faces[:, ::-1]),
                colors=mesh.colors, skin_weights=mesh.skin_weights)


def repose_mesh(
    mesh: Mesh, params: HandParams, pose: torch.Tensor, translation: torch.Tensor | None = None
) -> Mesh:
    """Move a hand's mesh from the pose of ``params`` to ``pose`` by linear blend skinning.

    Each vertex is unposed with its blended transform ``sum_j w_j A_j`` of the mesh's pose and
    posed with that of the new one (paper Eq. 2), so every frame has the same vertices and faces
    (dense correspondences); the field's own surface in the new pose is :func:`mesh_hand`'s.

    mesh: with skinning weights [V, 16]. params: the hand the mesh was made from.
    pose: [48] radians (the hand's side). translation: [3] metres (default: the params').
    """
    if mesh.skin_weights is None or mesh.skin_weights.shape[1] != NUM_JOINTS:
        raise ValueError("repose_mesh needs a mesh with skinning weights [V, 16]")
    pose = torch.as_tensor(pose, dtype=torch.float64)
    if pose.shape != (POSE_DIM,):
        raise ValueError(f"pose must have shape [{POSE_DIM}], got {list(pose.shape)}")
    translation = params.translation if translation is None else translation
    translation = torch.as_tensor(translation, dtype=torch.float64)
    rest = params.rest_joints[None].double()
    old_translation = params.translation[None].double()
    with torch.no_grad():
        old = forward_kinematics(params.pose[None].double(), rest, old_translation)
        new = forward_kinematics(pose[None], rest, translation.reshape(1, 3))
        weights = torch.from_numpy(mesh.skin_weights).double()
        blended_old = torch.einsum("vj,jrc->vrc", weights, old.transforms[0])  # [V, 4, 4]
        vertices = torch.from_numpy(mesh.vertices).double()
        homogeneous = torch.cat([vertices, vertices.new_ones(vertices.shape[0], 1)], dim=1)
        rest_vertices = torch.linalg.solve(blended_old, homogeneous)[:, :3]
        posed = linear_blend_skinning(rest_vertices, weights, new.transforms)[0]
    return Mesh(vertices=posed.float().numpy(), faces=mesh.faces, colors=mesh.colors,
                skin_weights=mesh.skin_weights)
