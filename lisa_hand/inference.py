"""Inference with a trained LISA model: mesh, render, re-pose and mix fitted hands.

What ``lisa mesh``, ``lisa render``, ``lisa animate`` and ``lisa blend`` do, as functions over a
:class:`~lisa_hand.trained.TrainedModel` and a :class:`~lisa_hand.params.HandParams` (the
``params.json`` of a fitted hand):

* :func:`hand_state` prepares one frame of the field and gives its callbacks (``sdf_fn``, the
  colour-calibrated ``field_fn``, per-point colours and skinning weights) in the world frame.
  A left hand is the mirror image of a right one (x -> -x, as MANO's left model): the field, a
  right hand, is evaluated at mirrored points with the mirrored pose and skeleton.
* :func:`hand_bounds` is a sphere that holds the zero level set: the posed bone regions
  (capsules around the bone segments) plus a margin. Outside every region LISA's SDF is the
  positive distance to the nearest region (:mod:`lisa_hand.model`), so the surface cannot leave
  them. :func:`skeleton_box` is the tighter box where a hand's surface is expected.
* :func:`mesh_hand`: coarse-to-fine marching cubes (:func:`lisa_hand.meshing.extract_mesh`) on a
  cubic grid around the skeleton box, then per-vertex colours (with the model's mean gain and
  bias, LISA Section 4.2) and skinning weights (dense correspondences across poses and
  subjects: vertex ``v`` of any hand belongs to bone ``j`` with weight ``w_j(v)``).
* :func:`prepare_render` / :func:`render_hand`: novel views with
  :func:`lisa_hand.render.image.render_image` (rays that miss the occupancy grid cost nothing,
  samples gather in a band around the surface), one grid shared by all views of a frame;
  :func:`orbit_views` places a turntable around the hand's own finger axis.
* :func:`animate_hand` re-poses a hand along a pose sequence (:func:`read_pose_sequence`,
  :func:`motion_poses`), writing a mesh and a frame per pose from one fixed camera.
* :func:`blend_params` swaps or interpolates the shape (code and skeleton) and colour codes of
  two fitted hands; the field keeps them disentangled (the SDF never sees the colour code).

Nothing here is differentiable: everything runs under ``torch.no_grad`` (normals use autograd
through the SDF inside the renderer).
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .fields.bones import SEGMENT_BONES, bone_segments
from .fields.config import FieldConfig
from .geometry.cameras import Camera
from .geometry.meshing import Mesh, MeshExtraction, colors_to_uint8, extract_mesh_with_stats
from .model.lisa import FrameState
from .model.trained import TrainedModel, load_trained
from .render.density import LaplaceDensity
from .render.image import (
    ImageOutput,
    ImageRenderConfig,
    OccupancyGrid,
    render_image,
)
from .render.turntable import orbit_cameras, shared_grid
from .skeleton import (
    NUM_JOINTS,
    POSE_DIM,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
    mirror_pose,
)
from .skeleton.params import HandParams, read_params

__all__ = [
    "GEOMETRY_ONLY_GREY",
    "MESH_MODES",
    "HandState",
    "check_params",
    "hand_state",
    "resolve_model_path",
    "load_hand",
    "hand_bounds",
    "skeleton_box",
    "MeshConfig",
    "HandMesh",
    "mesh_hand",
    "mesh_hand_with_stats",
    "repose_mesh",
    "hand_render_config",
    "HandScene",
    "prepare_render",
    "render_hand",
    "orbit_views",
    "RenderResult",
    "mp4_available",
    "render_to_folder",
    "parse_image_size",
    "scale_camera",
    "file_stem",
    "PoseSequence",
    "read_pose_sequence",
    "resolve_poses",
    "motion_poses",
    "AnimationResult",
    "animate_hand",
    "blend_params",
]

GEOMETRY_ONLY_GREY = 0.7
"""Albedo given to a geometry-only model (a shape prior) when it is rendered or meshed."""

MESH_MODES = ("field", "skinning")
"""How :func:`animate_hand` makes each frame's mesh: marching cubes of the field in that pose,
or the first pose's mesh re-posed by linear blend skinning (same vertices and faces)."""

SdfFn = Callable[[torch.Tensor], torch.Tensor]
FieldFn = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


# ----------------------------------------------------------------------------------------------
# One hand of a trained model


@dataclass
class HandState:
    """One frame of one hand, ready to evaluate (:func:`hand_state`).

    model: the trained model. params: the hand (its side, pose and codes).
    frame: the field's per-frame state, of the right hand (mirrored inputs for a left hand).
    mirrored: True for a left hand: world points are mirrored (x -> -x) before evaluation.
    """

    model: TrainedModel
    params: HandParams
    frame: FrameState
    mirrored: bool

    @property
    def has_color(self) -> bool:
        return self.model.has_color

    def _field_points(self, points: torch.Tensor) -> torch.Tensor:
        return mirror_points(points) if self.mirrored else points

    def sdf_fn(self) -> SdfFn:
        """``points [N, 3] world metres -> sdf [N] metres`` (negative inside)."""
        base = self.model.field.sdf_fn(self.frame)

        def sdf(points: torch.Tensor) -> torch.Tensor:
            return base(self._field_points(points))

        return sdf

    def field_fn(self) -> FieldFn:
        """``(points [N, 3] metres, directions [N, 3]) -> (sdf [N] metres, rgb [N, 3])``.

        Colours are calibrated with the model's mean gain and bias, ``rgb * gain + bias`` (LISA's
        inference-time calibration; per sample, which composites to the same image as calibrating
        the rendered colour). A geometry-only model is :data:`GEOMETRY_ONLY_GREY` everywhere.
        """
        if not self.has_color:
            sdf_fn = self.sdf_fn()

            def grey(points: torch.Tensor, directions: torch.Tensor):
                sdf = sdf_fn(points)
                return sdf, sdf.new_full((points.shape[0], 3), GEOMETRY_ONLY_GREY)

            return grey
        base = self.model.field.field_fn(self.frame)
        gain, bias = self.model.gain, self.model.bias

        def calibrated(points: torch.Tensor, directions: torch.Tensor):
            sdf, rgb = base(self._field_points(points), self._field_points(directions))
            return sdf, rgb * gain.to(rgb.dtype) + bias.to(rgb.dtype)

        return calibrated

    def attributes(
        self, points: torch.Tensor, colors: bool = True, skin_weights: bool = True
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """Calibrated colours and skinning weights at world points.

        points: [N, 3] metres (the model's dtype and device).
        -> (rgb [N, 3] in [0, 1] or None, weights [N, 16] or None). Colours are None when not
        asked; a geometry-only model gives :data:`GEOMETRY_ONLY_GREY`. Weights are None when
        not asked or for the 'single' composition (no bones).
        """
        field = self.model.field
        with torch.no_grad():
            out = field.field(
                self.frame, self._field_points(points)[None], with_color=colors and self.has_color
            )
        rgb = weights = None
        if colors:
            if self.has_color:
                rgb = (out.rgb[0] * self.model.gain + self.model.bias).clamp(0.0, 1.0)
            else:
                rgb = points.new_full((points.shape[0], 3), GEOMETRY_ONLY_GREY)
        if skin_weights and out.weights is not None:
            weights = out.weights[0]
        return rgb, weights


def check_params(model: TrainedModel, params: HandParams, source: str | None = None) -> None:
    """Check that the codes of ``params`` fit ``model`` (ValueError naming ``source`` if not)."""
    prefix = f"{source}: " if source else ""
    config = model.config
    if not isinstance(params, HandParams):
        raise TypeError(f"{prefix}params must be a HandParams, got {type(params).__name__}")
    if params.shape_code.shape != (config.shape_dim,):
        raise ValueError(
            f"{prefix}shape_code has {params.shape_code.shape[0]} entries but the model "
            f"({model.source}) has shape codes of {config.shape_dim}"
        )
    if (
        params.color_code is not None
        and model.has_color
        and params.color_code.shape != (config.color_dim,)
    ):
        raise ValueError(
            f"{prefix}color_code has {params.color_code.shape[0]} entries but the model "
            f"({model.source}) has colour codes of {config.color_dim}"
        )


def hand_state(model: TrainedModel, params: HandParams) -> HandState:
    """Prepare the field of ``model`` for the hand ``params`` (one frame).

    A hand without a colour code takes the model's mean colour code. The state lives on the
    model's device and dtype.
    """
    if not isinstance(model, TrainedModel):
        raise TypeError(f"model must be a TrainedModel, got {type(model).__name__}")
    check_params(model, params)
    field = model.field
    device, dtype = field.device, field.dtype
    mirrored = params.side == "left"
    pose, translation, rest_joints = params.pose, params.translation, params.rest_joints
    if mirrored:
        pose, translation = mirror_pose(pose), mirror_points(translation)
        rest_joints = mirror_points(rest_joints)
    color_code = None
    if field.color_mlp is not None:
        color_code = params.color_code if model.has_color else None
        if color_code is None:
            mean = model.mean_color_code()
            color_code = mean if mean is not None else torch.zeros(model.config.color_dim)

    def one(value: torch.Tensor | None) -> torch.Tensor | None:
        return None if value is None else value[None].to(device=device, dtype=dtype)

    with torch.no_grad():
        frame = field.prepare(
            one(pose), one(translation), one(rest_joints), one(params.shape_code), one(color_code)
        )
    return HandState(model=model, params=params, frame=frame, mirrored=mirrored)


def resolve_model_path(
    params: HandParams, params_path: str | os.PathLike | None, model: str | os.PathLike | None
) -> Path | None:
    """The model to load for a hand: ``model`` when given; else the one ``params`` names
    (``"default"``: the shipped model, returned as None), tried as given and then relative to
    the params file's folder."""
    if model is not None:
        return Path(model)
    if params.model in ("", "default"):
        return None
    named = Path(params.model)
    if not named.exists() and not named.is_absolute() and params_path is not None:
        beside = Path(params_path).parent / named
        if beside.exists():
            return beside
    return named


def load_hand(
    params_path: str | os.PathLike,
    model: str | os.PathLike | None = None,
    device: torch.device | str = "cpu",
) -> tuple[TrainedModel, HandParams]:
    """Read ``params.json`` and load the model its codes belong to (``model`` overrides the one
    it names); errors name the file. -> (model, params)"""
    params = read_params(params_path)
    model_path = resolve_model_path(params, params_path, model)
    trained = load_trained(model_path, device)
    check_params(trained, params, source=str(params_path))
    return trained, params


# ----------------------------------------------------------------------------------------------
# Where the hand is


def _posed_segments(params: HandParams, config: FieldConfig):
    """The posed region segments of the hand, world frame: (start [20, 3], end [20, 3]) float64
    metres (owners :data:`SEGMENT_BONES`)."""
    with torch.no_grad():
        rest = params.rest_joints[None].double()
        kinematics = forward_kinematics(
            params.pose[None].double(), rest, params.translation[None].double()
        )
        start, end = bone_segments(rest, config.tip_extension)
        transforms = kinematics.transforms[0, list(SEGMENT_BONES)]
        rot, trans = transforms[:, :3, :3], transforms[:, :3, 3]
        start = (rot @ start[0, :, :, None])[..., 0] + trans
        end = (rot @ end[0, :, :, None])[..., 0] + trans
    return start, end


def hand_bounds(
    params: HandParams, config: FieldConfig | None = None, margin: float = 0.005
) -> tuple[torch.Tensor, float]:
    """A sphere that holds the hand's surface: the posed bone regions plus ``margin``.

    Each bone's region is a capsule of radius ``palm_region_radius`` (wrist bone) or
    ``finger_region_radius`` around its segments (fingertips extended by ``tip_extension``);
    LISA's zero level set lies inside their union (:mod:`lisa_hand.model`). The margin covers
    the renderer's shell around the surface.

    params: the hand (world frame, either side). config: the field's architecture (default
    ``FieldConfig()``). margin: metres.
    -> (center [3] float32 metres, radius metres)
    """
    config = FieldConfig() if config is None else config
    if not margin >= 0:
        raise ValueError(f"margin must be >= 0 (metres), got {margin!r}")
    start, end = _posed_segments(params, config)
    radii = torch.tensor(
        [config.palm_region_radius if b == 0 else config.finger_region_radius
         for b in SEGMENT_BONES], dtype=torch.float64,
    )  # fmt: skip
    ends = torch.cat([start, end])
    center = 0.5 * (ends.amin(dim=0) + ends.amax(dim=0))
    reach = torch.maximum((start - center).norm(dim=-1), (end - center).norm(dim=-1)) + radii
    return center.float(), float(reach.max()) + float(margin)


def skeleton_box(
    params: HandParams, config: FieldConfig | None = None, padding: float = 0.03
) -> tuple[np.ndarray, np.ndarray]:
    """The box of the posed skeleton (joints and fingertips, extended by the field's
    ``tip_extension``) grown by ``padding`` on every side: where a hand's surface is expected
    (a palm is some 3 cm thick around its joints). -> (low [3], high [3]) float64 metres"""
    config = FieldConfig() if config is None else config
    if not padding >= 0:
        raise ValueError(f"padding must be >= 0 (metres), got {padding!r}")
    start, end = _posed_segments(params, config)
    ends = torch.cat([start, end])
    low = ends.amin(dim=0).numpy() - padding
    high = ends.amax(dim=0).numpy() + padding
    return low, high


def _grid_box(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
    """The box of the grid's cells that may hold the zero level set (their distance bound
    within ``lipschitz`` half diagonals), grown by one cell. -> (low [3], high [3]) float64"""
    half_diagonal = 0.5 * math.sqrt(3.0) * grid.cell_size
    index = torch.nonzero(grid.distance_bound <= grid.lipschitz * half_diagonal)
    if index.numel() == 0:
        raise ValueError(
            "the hand's surface was not found inside its bone regions (the field is positive "
            "everywhere): check the model and the hand's codes"
        )
    low = grid.low.detach().double().cpu()
    first = index.amin(dim=0).double().cpu() - 1.0
    last = index.amax(dim=0).double().cpu() + 2.0
    return (low + grid.cell_size * first).numpy(), (low + grid.cell_size * last).numpy()


# ----------------------------------------------------------------------------------------------
# Meshing


@dataclass(frozen=True)
class MeshConfig:
    """How :func:`mesh_hand` extracts a hand's mesh."""

    padding: float = 0.03
    """Metres added on every side of the posed skeleton's box (:func:`skeleton_box`) to make
    the grid. A surface that reaches the box's side is never cut: the grid then grows, at the
    same voxel size, to the cube of the bone regions (:func:`hand_bounds`)."""
    lipschitz: float = 2.0
    """Bound on the learned SDF's gradient norm: the coarse-to-fine pass skips a block only when
    this bound proves it far from the surface. Measured up to ~1.7 on a geometric-init LISA;
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
    extraction: counts and timings of marching cubes (:class:`lisa_hand.meshing.MeshExtraction`;
        of the last pass when the grid grew).
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


def _check_resolution(resolution: int) -> int:
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


def mesh_hand_with_stats(
    model: TrainedModel,
    params: HandParams,
    resolution: int = 128,
    config: MeshConfig | None = None,
    *,
    hand: HandState | None = None,
    progress: bool = False,
) -> HandMesh:
    """:func:`mesh_hand` with the grid, counts and timings (for benchmarks and reports)."""
    start = time.perf_counter()
    config = MeshConfig() if config is None else config
    resolution = _check_resolution(resolution)
    hand = hand_state(model, params) if hand is None else hand
    field = model.field
    sdf_fn = hand.sdf_fn()

    def extract(box_low, box_high, samples):
        return extract_mesh_with_stats(
            sdf_fn, box_low, box_high, samples,
            coarse_resolution=None if config.coarse_to_fine else samples,
            lipschitz=config.lipschitz, chunk_size=config.chunk_size, device=field.device,
            dtype=field.dtype, progress=progress,
        )  # fmt: skip

    # A cube around the skeleton's box: isotropic voxels, ``resolution`` samples a side.
    low, high = skeleton_box(params, model.config, config.padding)
    middle = 0.5 * (low + high)
    extent = float((high - low).max())
    voxel = extent / (resolution - 1)
    box_low, box_high = middle - 0.5 * extent, middle + 0.5 * extent
    extraction = extract(box_low, box_high, resolution)
    grown = _touches_box(extraction.mesh.vertices, box_low, box_high, voxel)
    if grown:
        # The cube of the bone regions holds the whole surface; same voxel size.
        center, radius = hand_bounds(params, model.config)
        samples = math.ceil(2.0 * radius / voxel) + 1
        half = 0.5 * (samples - 1) * voxel
        box_low, box_high = center.double().numpy() - half, center.double().numpy() + half
        extraction = extract(box_low, box_high, samples)
    mesh = extraction.mesh
    attributes_start = time.perf_counter()
    if config.colors or config.skin_weights:
        vertices = torch.from_numpy(mesh.vertices).to(field.device, field.dtype)
        colors, weights = [], []
        for begin in range(0, vertices.shape[0], config.chunk_size):
            rgb, skin = hand.attributes(
                vertices[begin : begin + config.chunk_size], config.colors, config.skin_weights
            )
            colors.append(rgb)
            weights.append(skin)
        mesh = Mesh(
            vertices=mesh.vertices,
            faces=mesh.faces,
            colors=colors_to_uint8(torch.cat(colors)) if config.colors else None,
            skin_weights=None if weights[0] is None else torch.cat(weights).float().cpu(),
        )
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
    hand: HandState | None = None,
    progress: bool = False,
) -> Mesh:
    """The hand's surface as a triangle mesh with calibrated colours and skinning weights.

    The grid is the cube around the posed skeleton's box plus ``config.padding``
    (:func:`skeleton_box`) with ``resolution`` samples a side (grown at the same voxel size to
    the bone regions if the surface reaches its side), evaluated coarse to fine: full resolution
    only near the zero level set, equal to dense evaluation when ``config.lipschitz`` bounds the
    field's gradient (:func:`lisa_hand.meshing.extract_mesh`).

    model, params: the trained model and the hand (:func:`load_hand`). resolution: grid samples
    per side (>= 8). hand: a prepared :func:`hand_state` of the same model and params (reused).
    -> :class:`lisa_hand.meshing.Mesh`: world-frame float32 metres, outward faces, uint8 colours
    [V, 3], skinning weights [V, 16] (rows sum to 1).
    """
    return mesh_hand_with_stats(
        model, params, resolution, config, hand=hand, progress=progress
    ).mesh


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


# ----------------------------------------------------------------------------------------------
# Rendering


def hand_render_config(model: TrainedModel, **overrides) -> ImageRenderConfig:
    """The image settings for a trained hand: volume mode with the model's ``beta``, autograd
    normals, Lipschitz allowance 1.5 for a learned SDF; ``overrides`` replace any field."""
    values = dict(beta=float(model.beta), lipschitz=1.5, normals="autograd")
    values.update(overrides)
    return ImageRenderConfig(**values)


@dataclass
class HandScene:
    """A hand ready to be rendered from any camera (:func:`prepare_render`).

    hand: the prepared hand. config: image settings. density: VolSDF density (the model's beta).
    center [3], radius: metres, the bounding sphere (:func:`hand_bounds`).
    grid: the occupancy grid shared by all views (None with sphere culling).
    """

    hand: HandState
    config: ImageRenderConfig
    density: LaplaceDensity
    center: torch.Tensor
    radius: float
    grid: OccupancyGrid | None

    def render(self, camera: Camera, progress: bool = False) -> ImageOutput:
        """Render one camera (its width x height pixels) -> :class:`ImageOutput`."""
        field = self.hand.model.field
        camera = camera.to(device=field.device, dtype=field.dtype)
        return render_image(
            self.hand.field_fn(), self.hand.sdf_fn(), camera, self.center, self.radius,
            self.config, self.density, progress=progress, grid=self.grid,
        )  # fmt: skip

    def framing_sphere(self) -> tuple[torch.Tensor, float]:
        """A tight sphere around the surface (the occupied grid cells' box): where to aim and
        how far to stand. -> (center [3] float64 CPU metres, radius metres)"""
        if self.grid is not None:
            low, high = _grid_box(self.grid)
        else:
            low, high = skeleton_box(self.hand.params, self.hand.model.config)
        low64, high64 = torch.from_numpy(low), torch.from_numpy(high)
        return 0.5 * (low64 + high64), 0.5 * float((high64 - low64).norm())

    def hand_axes(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The posed hand's finger direction (wrist to middle-finger base) and palm normal
        (MANO rest palm faces -y, either side), unit [3] float64 world vectors."""
        params = self.hand.params
        rest = params.rest_joints.double()
        kinematics = forward_kinematics(params.pose[None].double(), rest[None])
        root = kinematics.transforms[0, 0, :3, :3]
        fingers = root @ (rest[4] - rest[0])
        palm = root @ torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
        return fingers / fingers.norm(), palm


def prepare_render(
    model: TrainedModel,
    params: HandParams,
    config: ImageRenderConfig | None = None,
    *,
    hand: HandState | None = None,
) -> HandScene:
    """Prepare a hand for rendering: its state, bounding sphere, density and the occupancy grid
    shared by every view. config: default :func:`hand_render_config`."""
    config = hand_render_config(model) if config is None else config
    hand = hand_state(model, params) if hand is None else hand
    field = model.field
    center, radius = hand_bounds(params, model.config)
    center = center.to(field.device, field.dtype)
    density = LaplaceDensity(beta_init=float(model.beta), beta_min=0.0).to(field.device)
    grid = shared_grid(hand.sdf_fn(), center, radius, config, density)
    return HandScene(hand=hand, config=config, density=density, center=center, radius=radius,
                     grid=grid)


def render_hand(
    model: TrainedModel,
    params: HandParams,
    cameras: Sequence[Camera],
    config: ImageRenderConfig | None = None,
    *,
    progress: bool = False,
) -> list[ImageOutput]:
    """Render a hand from every camera (one occupancy grid shared by all).

    Colours are calibrated with the model's mean gain and bias; ``config`` defaults to
    :func:`hand_render_config` (volume rendering, normals). -> one :class:`ImageOutput` per
    camera (rgb [H, W, 3], opacity, depth metres, normals, mask).
    """
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    scene = prepare_render(model, params, config)
    return [scene.render(camera, progress=progress) for camera in cameras]


@dataclass
class RenderResult:
    """What :func:`render_to_folder` wrote.

    views: per camera, the paths by kind ('rgb', 'normals', 'mask', 'depth').
    cameras_path: ``cameras.json`` with the cameras used. gif_path, video_path: the turntable
    (None when not asked, or no MP4 backend). seconds: wall time of the renders.
    """

    views: list[dict[str, Path]]
    cameras_path: Path
    gif_path: Path | None
    video_path: Path | None
    seconds: float


def mp4_available() -> bool:
    """Whether imageio can write MP4 here (the ``av`` or ``imageio-ffmpeg`` package)."""
    import importlib.util

    return any(importlib.util.find_spec(name) is not None for name in ("av", "imageio_ffmpeg"))


def render_to_folder(
    scene: HandScene,
    cameras: Sequence[Camera],
    out_dir: str | os.PathLike,
    *,
    turntable: bool = False,
    fps: float = 12.0,
    log: Callable[[str], None] | None = None,
) -> RenderResult:
    """Render every camera of ``scene`` and write, per camera ``NAME``
    (:func:`file_stem`), ``NAME_rgb.png``, ``NAME_normals.png`` (world-frame ``(n + 1) / 2``,
    when the config computes normals), ``NAME_mask.png`` and ``NAME_depth.npy`` (metres along
    the ray), plus ``cameras.json``; with ``turntable``, the RGB views as ``turntable.gif`` and,
    when an MP4 backend is installed, ``turntable.mp4``. All writes are atomic."""
    from .geometry.cameras import save_cameras
    from .render.image import image_to_uint8, save_image_outputs
    from .render.turntable import save_gif, save_video

    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    log = log or (lambda message: None)
    out_dir = Path(out_dir)
    start = time.perf_counter()
    views, frames = [], []
    for index, (camera, stem) in enumerate(
        zip(cameras, file_stem([c.name for c in cameras]), strict=True)
    ):
        output = scene.render(camera)
        views.append(save_image_outputs(out_dir, output, stem))
        frames.append(image_to_uint8(output.rgb[..., :3]))
        log(f"view {index + 1}/{len(cameras)}: {views[-1]['rgb']} "
            f"({int(output.mask.sum())} hand pixels)")
    seconds = time.perf_counter() - start
    cameras_path = save_cameras(out_dir / "cameras.json", cameras)
    gif_path = video_path = None
    if turntable:
        gif_path = save_gif(out_dir / "turntable.gif", frames, fps)
        if mp4_available():
            video_path = save_video(out_dir / "turntable.mp4", frames, fps)
    return RenderResult(views=views, cameras_path=cameras_path, gif_path=gif_path,
                        video_path=video_path, seconds=seconds)


def _fit_distance(radius: float, width: int, height: int, fov_deg: float) -> float:
    """Camera distance at which a sphere of ``radius`` fills the smaller image side (5 % margin)."""
    focal = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    half_angle = math.atan(0.5 * min(width, height) / focal)
    return 1.05 * radius / math.sin(half_angle)


def orbit_views(
    scene: HandScene,
    num_views: int,
    width: int = 512,
    height: int = 512,
    *,
    elevation_deg: float = 15.0,
    fov_deg: float = 30.0,
    framing: tuple[torch.Tensor, float] | None = None,
) -> list[Camera]:
    """``num_views`` cameras on a circle around the hand's finger axis (image up = fingers),
    the first one facing the palm, all framing the hand's surface.

    framing: (center [3], radius) metres of the sphere to frame (default the scene's
    :meth:`HandScene.framing_sphere`). -> cameras ``orbit000``... in the model's dtype.
    """
    center, radius = scene.framing_sphere() if framing is None else framing
    fingers, palm = scene.hand_axes()
    distance = _fit_distance(radius, width, height, fov_deg)
    cameras = orbit_cameras(
        num_views, center, distance, elevation_deg, width, height, fov_deg, up=fingers,
        front=palm, dtype=scene.hand.model.field.dtype,
    )  # fmt: skip
    return cameras


def parse_image_size(text: str, name: str = "resolution") -> tuple[int, int]:
    """``"1024x667"`` -> ``(1024, 667)`` (width, height in pixels; ValueError naming ``name``)."""
    parts = str(text).lower().strip().split("x")
    try:
        width, height = (int(part) for part in parts)
    except ValueError:
        raise ValueError(f"{name} must look like WIDTHxHEIGHT, e.g. 512x512, got {text!r}") \
            from None
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise ValueError(f"{name} must be between 1x1 and 16384x16384 pixels, got {text!r}")
    return width, height


def scale_camera(camera: Camera, width: int, height: int) -> Camera:
    """The camera rendering ``width x height`` pixels of the same view (intrinsics scaled)."""
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive int (pixels), got {value!r}")
    if (width, height) == (camera.width, camera.height):
        return camera
    scale = torch.tensor([width / camera.width, height / camera.height, 1.0],
                         dtype=camera.dtype, device=camera.device)
    return Camera(K=camera.K * scale[:, None], R=camera.R, t=camera.t, width=width,
                  height=height, name=camera.name)


_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def file_stem(names: Sequence[str | None], default: str = "view") -> list[str]:
    """File-name-safe, unique stems for cameras: the name with unsafe characters replaced by
    ``_`` (``{default}{index:03d}`` when there is none), an index appended to repeats."""
    stems, seen = [], set()
    for index, name in enumerate(names):
        stem = _UNSAFE.sub("_", name).strip("._") if name else ""
        stem = stem or f"{default}{index:03d}"
        if stem in seen:
            stem = f"{stem}_{index:03d}"
        seen.add(stem)
        stems.append(stem)
    return stems


# ----------------------------------------------------------------------------------------------
# Pose sequences and animation


@dataclass
class PoseSequence:
    """Poses to animate a hand with (:func:`read_pose_sequence`).

    poses: [T, 48] (global rotation + 15 joints) or [T, 45] (finger joints only: the global
    rotation of the hand is kept), axis-angle radians, the hand's side.
    translations: [T, 3] metres, or None (the hand's translation is kept).
    """

    poses: torch.Tensor
    translations: torch.Tensor | None = None


def read_pose_sequence(path: str | os.PathLike) -> PoseSequence:
    """Read a pose sequence (JSON): a list of poses, or ``{"poses": [...], "translations":
    [...]}`` (translations optional). Each pose is 48 numbers (global rotation then 15 joints,
    axis-angle radians, MANO order) or 45 (the 15 finger joints; the global rotation of the hand
    being animated is kept); translations are 3 numbers (metres) per pose. Errors name the
    file."""
    from .utils.io import read_json

    path = Path(path)
    data = read_json(path)
    translations = None
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"poses", "translations"})
        if unknown or "poses" not in data:
            raise ValueError(f"{path}: expected a list of poses or an object with keys 'poses' "
                             f"and optionally 'translations', got keys {sorted(data)}")
        translations = data.get("translations")
        data = data["poses"]
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a non-empty list of poses")
    try:
        poses = torch.tensor(data, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{path}: poses must be lists of 48 (or 45) numbers each") from None
    if poses.dim() != 2 or poses.shape[1] not in (POSE_DIM, POSE_DIM - 3):
        raise ValueError(f"{path}: poses must have shape [T, 48] or [T, 45], got "
                         f"{list(poses.shape)}")
    if not torch.isfinite(poses).all():
        raise ValueError(f"{path}: poses hold NaN or inf")
    if translations is not None:
        try:
            translations = torch.tensor(translations, dtype=torch.float32)
        except (TypeError, ValueError, RuntimeError):
            raise ValueError(f"{path}: translations must be lists of 3 numbers each") from None
        if translations.shape != (poses.shape[0], 3) or not torch.isfinite(translations).all():
            raise ValueError(f"{path}: translations must have shape [T, 3] = "
                             f"[{poses.shape[0]}, 3] with finite values, got "
                             f"{list(translations.shape)}")
    return PoseSequence(poses=poses, translations=translations)


def resolve_poses(
    params: HandParams, sequence: PoseSequence
) -> tuple[torch.Tensor, torch.Tensor]:
    """Complete a sequence with the hand's global rotation (45-D poses) and translation.

    -> (poses [T, 48] radians, translations [T, 3] metres)
    """
    poses = sequence.poses.float()
    num = poses.shape[0]
    if poses.shape[1] == POSE_DIM - 3:
        poses = torch.cat([params.pose[:3].expand(num, 3), poses], dim=1)
    translations = sequence.translations
    if translations is None:
        translations = params.translation.expand(num, 3)
    return poses.clone(), translations.float().clone()


def motion_poses(params: HandParams, name: str, frames_per_segment: int = 8) -> torch.Tensor:
    """From the hand's pose to a named pose (:data:`lisa_hand.handmodel.poses.POSE_NAMES`: flat,
    relaxed, fist, point, pinch, ok) and back, keeping its global rotation; finger joints move
    linearly in anatomical angles. -> [2 * frames_per_segment + 1, 48] radians"""
    from .handmodel.poses import named_pose, pose_sequence

    target = named_pose(name, side=params.side).clone()
    target[:3] = params.pose[:3]
    return pose_sequence([params.pose, target, params.pose], frames_per_segment, params.side)


@dataclass
class AnimationResult:
    """What :func:`animate_hand` wrote.

    mesh_paths, frame_paths: one per pose (empty when not asked). gif_path: the animation (or
    None). camera: the fixed camera of the frames (or None). poses [T, 48], translations [T, 3].
    seconds: wall time.
    """

    mesh_paths: list[Path]
    frame_paths: list[Path]
    gif_path: Path | None
    camera: Camera | None
    poses: torch.Tensor
    translations: torch.Tensor
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)


def animate_hand(
    model: TrainedModel,
    params: HandParams,
    poses: torch.Tensor,
    translations: torch.Tensor | None,
    out_dir: str | os.PathLike,
    *,
    mesh_resolution: int | None = 128,
    mesh_suffix: str = ".ply",
    mesh_mode: str = "field",
    mesh_config: MeshConfig | None = None,
    frames: bool = True,
    camera: Camera | None = None,
    width: int = 512,
    height: int = 512,
    render_config: ImageRenderConfig | None = None,
    fps: float = 12.0,
    log: Callable[[str], None] | None = None,
) -> AnimationResult:
    """Re-pose a hand along ``poses``; write its meshes, frames and a GIF into ``out_dir``.

    Files: ``meshes/frame_000.ply`` ... (``mesh_suffix``), ``frames/frame_000.png`` ...,
    ``animation.gif``, ``camera.json`` (the fixed camera) and ``poses.json`` (``{"poses",
    "translations"}``, readable by :func:`read_pose_sequence`). Every file is written atomically.

    poses: [T, 48] radians (the hand's side). translations: [T, 3] metres or None (the hand's).
    mesh_resolution: grid samples per side, or None for no meshes. mesh_mode: 'field' (marching
    cubes of the field in each pose) or 'skinning' (the first pose's mesh re-posed by
    :func:`repose_mesh`: same vertices and faces in every frame).
    frames: render the frames (from ``camera``, default a palm-side view framing every pose,
    ``width`` x ``height``). The shape and colour codes stay those of ``params``.
    """
    from .data.meshio import MESH_SUFFIXES, save_mesh
    from .geometry.cameras import save_cameras
    from .render.image import image_to_uint8
    from .render.turntable import save_gif
    from .utils.io import write_json

    start = time.perf_counter()
    log = log or (lambda message: None)
    poses = torch.as_tensor(poses, dtype=torch.float32)
    if poses.dim() != 2 or poses.shape[1] != POSE_DIM or poses.shape[0] < 1:
        raise ValueError(f"poses must have shape [T, 48] with T >= 1, got {list(poses.shape)}")
    num = poses.shape[0]
    if translations is None:
        translations = params.translation.expand(num, 3).clone()
    translations = torch.as_tensor(translations, dtype=torch.float32)
    if translations.shape != (num, 3):
        raise ValueError(f"translations must have shape [T, 3] = [{num}, 3], got "
                         f"{list(translations.shape)}")
    if mesh_mode not in MESH_MODES:
        raise ValueError(f"mesh_mode must be one of {MESH_MODES}, got {mesh_mode!r}")
    if mesh_suffix not in MESH_SUFFIXES:
        raise ValueError(f"mesh_suffix must be one of {MESH_SUFFIXES}, got {mesh_suffix!r}")
    if mesh_resolution is not None:
        mesh_resolution = _check_resolution(mesh_resolution)
    if mesh_resolution is None and not frames:
        raise ValueError("nothing to write: no meshes (mesh_resolution None) and no frames")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    mesh_config = MeshConfig() if mesh_config is None else mesh_config
    if mesh_suffix != ".ply":  # only PLY stores weights; skinning mode still needs them
        mesh_config = replace(mesh_config, skin_weights=mesh_mode == "skinning")
    out_dir = Path(out_dir)
    frame_params = [params.with_pose(poses[i], translations[i]) for i in range(num)]

    mesh_paths: list[Path] = []
    if mesh_resolution is not None:
        first = None
        for index, frame in enumerate(frame_params):
            if mesh_mode == "skinning" and first is not None:
                mesh = repose_mesh(first, params=frame_params[0], pose=frame.pose,
                                   translation=frame.translation)
            else:
                mesh = mesh_hand(model, frame, mesh_resolution, mesh_config)
                first = mesh
            if mesh_suffix != ".ply" and mesh.skin_weights is not None:
                mesh = Mesh(vertices=mesh.vertices, faces=mesh.faces, colors=mesh.colors)
            path = save_mesh(out_dir / "meshes" / f"frame_{index:03d}{mesh_suffix}", mesh)
            mesh_paths.append(path)
            log(f"mesh {index + 1}/{num}: {path} ({mesh.num_vertices} vertices)")

    frame_paths: list[Path] = []
    gif_path = None
    if frames:
        import imageio.v3 as iio

        from .utils.io import atomic_path

        render_config = hand_render_config(model) if render_config is None else render_config
        scenes = [prepare_render(model, frame, render_config) for frame in frame_params]
        if camera is None:
            camera = orbit_views(scenes[0], 1, width, height, elevation_deg=10.0,
                                 framing=_union_sphere([s.framing_sphere() for s in scenes]))[0]
            camera = Camera(K=camera.K, R=camera.R, t=camera.t, width=camera.width,
                            height=camera.height, name="animation")
        images = []
        for index, scene in enumerate(scenes):
            output = scene.render(camera)
            image = image_to_uint8(output.rgb[..., :3])
            path = out_dir / "frames" / f"frame_{index:03d}.png"
            with atomic_path(path) as tmp:
                iio.imwrite(tmp, image, extension=".png")
            images.append(image)
            frame_paths.append(path)
            log(f"frame {index + 1}/{num}: {path}")
        gif_path = save_gif(out_dir / "animation.gif", images, fps)
        save_cameras(out_dir / "camera.json", [camera])
    write_json(out_dir / "poses.json",
               {"poses": poses.tolist(), "translations": translations.tolist()})
    return AnimationResult(
        mesh_paths=mesh_paths, frame_paths=frame_paths, gif_path=gif_path, camera=camera,
        poses=poses, translations=translations, seconds=time.perf_counter() - start,
    )  # fmt: skip


def _union_sphere(spheres: list[tuple[torch.Tensor, float]]) -> tuple[torch.Tensor, float]:
    """A sphere holding all the given (center [3], radius) spheres (centred on their box)."""
    centers = torch.stack([c.double() for c, _ in spheres])
    radii = torch.tensor([r for _, r in spheres], dtype=torch.float64)
    low = (centers - radii[:, None]).amin(dim=0)
    high = (centers + radii[:, None]).amax(dim=0)
    middle = 0.5 * (low + high)
    return middle, float(((centers - middle).norm(dim=-1) + radii).max())


# ----------------------------------------------------------------------------------------------
# Disentanglement


def _blend_weight(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a number in [0, 1], got {type(value).__name__}")
    if not 0.0 <= float(value) <= 1.0:
        raise ValueError(f"{name} must be in [0, 1] (0: A's, 1: B's), got {value!r}")
    return float(value)


def _mix(a: torch.Tensor | None, b: torch.Tensor | None, weight: float, name: str):
    """(1 - weight) a + weight b; a missing side is allowed only when its weight is 0."""
    if weight == 0.0:
        return None if a is None else a.clone()
    if weight == 1.0:
        return None if b is None else b.clone()
    if a is None or b is None:
        missing = "A" if a is None else "B"
        raise ValueError(f"cannot interpolate {name}: hand {missing} has none")
    if a.shape != b.shape:
        raise ValueError(f"cannot interpolate {name}: shapes {list(a.shape)} and {list(b.shape)}")
    return torch.lerp(a, b, weight)


def blend_params(
    a: HandParams, b: HandParams, shape: float = 0.0, color: float = 0.0
) -> HandParams:
    """Hand A with the shape and/or colour of hand B, or in between (LISA's disentanglement).

    shape: weight of B's shape, in [0, 1]: the shape code and the skeleton (rest joints and
        template betas) are interpolated linearly, ``(1 - shape) A + shape B``.
    color: weight of B's colour code, in [0, 1].
    Pose, translation and side stay A's (a B of the other side has its skeleton mirrored). 0
    and 1 swap exactly; in between, the codes move along a straight line of the latent space
    (where the auto-decoder's Gaussian prior keeps codes near each other).
    Both hands must come from the same model (equal ``model`` and code sizes).
    -> :class:`HandParams` (its ``extra['blend']`` records the weights and sources).
    """
    shape = _blend_weight(shape, "shape")
    color = _blend_weight(color, "color")
    for name, value in (("a", a), ("b", b)):
        if not isinstance(value, HandParams):
            raise TypeError(f"{name} must be a HandParams, got {type(value).__name__}")
    if os.path.normpath(a.model) != os.path.normpath(b.model):
        raise ValueError(f"the hands were fitted with different models ({a.model!r} and "
                         f"{b.model!r}): their codes cannot be mixed")
    if a.shape_code.shape != b.shape_code.shape:
        raise ValueError(f"shape codes differ in size: {a.shape_code.shape[0]} and "
                         f"{b.shape_code.shape[0]}")
    b_rest = b.rest_joints if b.side == a.side else mirror_points(b.rest_joints)
    if shape in (0.0, 1.0) or (
        a.betas is not None and b.betas is not None and a.betas.shape == b.betas.shape
    ):
        betas = _mix(a.betas, b.betas, shape, "betas")
    else:
        betas = None  # the template's coefficients of one hand only: not known in between
    return HandParams(
        pose=a.pose.clone(),
        translation=a.translation.clone(),
        rest_joints=torch.lerp(a.rest_joints, b_rest, shape),
        shape_code=torch.lerp(a.shape_code, b.shape_code, shape),
        color_code=_mix(a.color_code, b.color_code, color, "color_code"),
        betas=betas,
        side=a.side,
        model=a.model,
        extra={"blend": {"shape": shape, "color": color}},
    )
