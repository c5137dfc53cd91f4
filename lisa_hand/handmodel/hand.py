"""The open hand: a subject (shape + appearance + detail seed) and its posed ground truth.

>>> hand = OpenHand()                                  # the average right hand
>>> posed = hand.posed(named_pose("fist"))
>>> mesh = posed.mesh()                                # watertight, >= 100k vertices
>>> sdf, weights = posed.sdf_and_ownership(points)     # points [N, 3] metres

Coordinates: metres, world frame; the rest pose and axes are described in
:mod:`lisa_hand.handmodel.shape` (right hand: wrist at the origin, fingers along -x, palm facing
-y, thumb on +z; a left hand is its mirror image through x = 0). A pose is MANO's 48-D
axis-angle vector in the hand's own side convention (see :mod:`lisa_hand.handmodel.poses`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np
import torch

from ..skeleton.kinematics import check_side, forward_kinematics, mirror_points, mirror_pose
from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS, POSE_DIM, joints_to_keypoints
from .anthropometry import sample_anthropometric_shape
from .appearance import Appearance, albedo, sample_appearance
from .checks import check_query_points, check_vector
from .makehuman import ADULT_AGES, MakeHumanShape, sample_makehuman_shape, skin_tone
from .mesh_hand import PosedMeshHand
from .mesh_rest import MeshRest, build_mesh_rest
from .parts import HandParts, build_hand_parts
from .parts_v2 import build_hand_parts_v2
from .sdf import HandFieldOutput, PosedField, single_threaded
from .shape import HandShape, sample_shape

__all__ = [
    "OpenHand",
    "PosedHand",
    "SurfaceSamples",
    "sample_hand",
    "DEFAULT_VOXELS_PER_LENGTH",
    "HAND_MODELS",
]

DEFAULT_VOXELS_PER_LENGTH = 255
"""Default meshing resolution: voxels per hand length (0.73 mm for an 18.5 cm hand: 100k-150k
vertices in any pose, since the surface area scales with the squared length)."""

HAND_MODELS = ("v1", "v2", "v3")
"""Versions of the open hand model: ``"v1"`` (the default: slab palm, round fingers, independent
clipped-normal shape draws; :mod:`.parts`, :func:`.shape.sample_shape`), ``"v2"`` (rounded,
padded palm, forearm stub, D-shaped fingers; shape draws from adult anthropometry, jointly;
:mod:`.parts_v2`, :mod:`.anthropometry`) and ``"v3"`` (MakeHuman's sculpted hand, its shape a
:class:`~.makehuman.MakeHumanShape` drawn from the same anthropometry, skinned by dual
quaternions; :mod:`.makehuman`, :mod:`.mesh_rest`, :mod:`.mesh_hand`)."""

_MIRROR = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=torch.float64))
# Gradient bound passed to the mesher: the displacements keep |grad sdf| below about 1.1.
_LIPSCHITZ = 1.2


@dataclass(frozen=True)
class OpenHand:
    """One subject of the open hand model.

    shape: the hand's :class:`HandShape` (bone lengths, widths, thickness, ...; v1, v2) or
        :class:`~.makehuman.MakeHumanShape` (MakeHuman's sliders; v3).
    appearance: its skin :class:`Appearance`.
    detail_seed: seeds the fine detail (creases, palm lines, bumps).
    side: 'right' or 'left' (the left hand is the mirror image of the right one).
    model: the hand model version, one of :data:`HAND_MODELS` (default "v1").
    """

    shape: HandShape | MakeHumanShape = field(default_factory=HandShape)
    appearance: Appearance = field(default_factory=Appearance)
    detail_seed: int = 0
    side: str = "right"
    model: str = "v1"

    def __post_init__(self) -> None:
        check_hand_model(self.model)
        expected = MakeHumanShape if self.model == "v3" else HandShape
        if not isinstance(self.shape, expected):
            raise TypeError(f"a {self.model} hand's shape must be a {expected.__name__}, got "
                            f"{type(self.shape).__name__}")
        if not isinstance(self.appearance, Appearance):
            raise TypeError(
                f"appearance must be an Appearance, got {type(self.appearance).__name__}"
            )
        if not isinstance(self.detail_seed, (int, np.integer)) or isinstance(
            self.detail_seed, bool
        ):
            raise TypeError(f"detail_seed must be an int, got {self.detail_seed!r}")
        check_side(self.side)

    @functools.cached_property
    def parts(self) -> HandParts | MeshRest:
        """The right-hand rest hand, with its ``skeleton`` (float64, CPU): the parts and detail
        of :mod:`.parts` (v1) or :mod:`.parts_v2` (v2), the rest mesh of :mod:`.mesh_rest`
        (v3)."""
        if self.model == "v3":
            return build_mesh_rest(self.shape)
        if self.model == "v2":
            return build_hand_parts_v2(self.shape, int(self.detail_seed))
        return build_hand_parts(self.shape, int(self.detail_seed))

    @property
    def rest_joints(self) -> torch.Tensor:
        """[16, 3] float64 rest-pose joints of this side, metres."""
        joints = self.parts.skeleton.joints
        return mirror_points(joints) if self.side == "left" else joints.clone()

    @property
    def rest_fingertips(self) -> torch.Tensor:
        """[5, 3] float64 rest-pose fingertips (thumb, index, middle, ring, pinky) of this side."""
        tips = self.parts.skeleton.fingertips
        return mirror_points(tips) if self.side == "left" else tips.clone()

    def posed(
        self,
        pose: torch.Tensor | None = None,
        translation: torch.Tensor | None = None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> PosedHand | PosedMeshHand:
        """Pose the hand (a :class:`PosedHand`; v3: a :class:`~.mesh_hand.PosedMeshHand`).

        pose: [48] or [1, 48] axis-angle radians in this side's convention; None = rest pose.
        translation: [3] or [1, 3] metres, added after the rotations; None = zero.
        dtype, device: of the field's evaluation (float32 or float64; default CPU).
        """
        if self.model == "v3":
            return PosedMeshHand(self, pose, translation, dtype, device)
        return PosedHand(self, pose, translation, dtype, device)


def check_hand_model(model: str) -> str:
    """``model`` if it is one of :data:`HAND_MODELS`, else ValueError naming the choices."""
    if model not in HAND_MODELS:
        raise ValueError(f"hand model must be one of {', '.join(HAND_MODELS)}, got {model!r}")
    return model


def sample_hand(generator: torch.Generator, side: str = "right", model: str = "v1",
                ages: tuple[float, float] = ADULT_AGES) -> OpenHand:
    """A random subject: shape (:func:`sample_shape` for v1, the anthropometric
    :func:`~lisa_hand.handmodel.anthropometry.sample_anthropometric_shape` for v2,
    :func:`~lisa_hand.handmodel.makehuman.sample_makehuman_shape` for v3), appearance
    (:func:`sample_appearance`; for v3 the skin tone follows the drawn ethnic mix,
    :func:`~lisa_hand.handmodel.makehuman.skin_tone`) and detail seed, all from ``generator``
    (same seed, same subject).

    model: the hand model version, one of :data:`HAND_MODELS`.
    ages: (youngest, oldest) years of a v3 hand (v1 and v2 hands have no age).
    """
    check_side(side)
    check_hand_model(model)
    if model == "v3":
        shape = sample_makehuman_shape(generator, ages)
    elif model == "v2":
        shape = sample_anthropometric_shape(generator)
    else:
        shape = sample_shape(generator)
    appearance = sample_appearance(generator)
    if model == "v3":
        appearance = dataclasses.replace(appearance, skin_tone=skin_tone(shape, generator))
    detail_seed = int(torch.randint(0, 2**31 - 1, (), generator=generator))
    return OpenHand(shape=shape, appearance=appearance, detail_seed=detail_seed, side=side,
                    model=model)


@dataclass(frozen=True)
class SurfaceSamples:
    """Points on a surface with what is known there (world frame): the one type of surface
    samples of the package. The open hand's :meth:`PosedHand.surface_samples` fills ``weights``
    and ``colors`` (torch tensors, on the exact zero level set, |sdf| < 1e-5 m); sampling a mesh
    (:func:`lisa_hand.data.scans.sample_surface`) fills ``face_ids`` (numpy arrays, float32
    points exactly on the faces). Arrays are all torch tensors or all numpy arrays.

    points: [N, 3] metres, on the surface.
    normals: [N, 3] outward unit normals.
    weights: [N, 16] skinning weights (bone ownership), rows summing to 1; None if not known.
    colors: [N, 3] albedo, sRGB in [0, 1]; None if not known.
    face_ids: [N] int64 mesh face of each point; None when not sampled on a mesh.
    """

    points: torch.Tensor | np.ndarray
    normals: torch.Tensor | np.ndarray
    weights: torch.Tensor | np.ndarray | None = None
    colors: torch.Tensor | np.ndarray | None = None
    face_ids: torch.Tensor | np.ndarray | None = None

    def _known(self) -> dict[str, torch.Tensor | np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if getattr(self, f.name) is not None}  # fmt: skip

    def select(self, index) -> SurfaceSamples:
        """The samples ``index`` picks (a boolean mask [N], indices or a slice), with every
        known attribute."""
        return SurfaceSamples(**{name: value[index] for name, value in self._known().items()})

    @staticmethod
    def concatenate(parts: Sequence[SurfaceSamples]) -> SurfaceSamples:
        """The samples of ``parts`` one after the other (all with the same known attributes)."""
        if not parts:
            raise ValueError("concatenate needs at least one SurfaceSamples")
        names = list(parts[0]._known())
        if any(list(part._known()) != names for part in parts):
            raise ValueError("concatenate: the parts know different attributes")
        joined = {}
        for name in names:
            values = [getattr(part, name) for part in parts]
            is_tensor = isinstance(values[0], torch.Tensor)
            joined[name] = torch.cat(values) if is_tensor else np.concatenate(values)
        return SurfaceSamples(**joined)


class PosedHand:
    """A subject in one pose: joints, keypoints, and the exact field (SDF, ownership, albedo).

    Build with :meth:`OpenHand.posed`. Attributes (world frame, this hand's side, float64 CPU):

    joints: [16, 3] posed MANO joints, metres.
    fingertips: [5, 3] surface points at the finger ends (thumb, index, middle, ring, pinky).
    keypoints: [21, 3] OpenPose/MediaPipe keypoints (``joints_to_keypoints``).
    transforms: [16, 4, 4] rest-to-posed bone transforms ``A_j`` (LBS transforms).
    pose: [48], translation: [3] the inputs (float64).
    """

    def __init__(
        self,
        hand: OpenHand,
        pose: torch.Tensor | None,
        translation: torch.Tensor | None,
        dtype: torch.dtype,
        device: torch.device | str | None,
    ) -> None:
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        self.hand = hand
        self.pose = (
            torch.zeros(POSE_DIM, dtype=torch.float64)
            if pose is None
            else check_vector(pose, POSE_DIM, "pose")
        )
        self.translation = (
            torch.zeros(3, dtype=torch.float64)
            if translation is None
            else check_vector(translation, 3, "translation")
        )
        self.dtype = dtype
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self.mirrored = hand.side == "left"
        # Everything is computed on the right hand; a left hand mirrors inputs and outputs.
        pose_right = mirror_pose(self.pose) if self.mirrored else self.pose
        transl_right = mirror_points(self.translation) if self.mirrored else self.translation
        parts = hand.parts
        kinematics = forward_kinematics(pose_right[None], parts.skeleton.joints, transl_right[None])
        transforms_right = kinematics.transforms[0]
        self._field = PosedField(parts, transforms_right.to(self.device, dtype))
        tips_right = self._fingertips(transforms_right)
        joints_right = kinematics.joints[0]
        if self.mirrored:
            self.joints = mirror_points(joints_right)
            self.fingertips = mirror_points(tips_right)
            self.transforms = _MIRROR @ transforms_right @ _MIRROR
        else:
            self.joints, self.fingertips, self.transforms = (
                joints_right,
                tips_right,
                transforms_right,
            )
        self.keypoints = joints_to_keypoints(self.joints, self.fingertips)

    # ------------------------------------------------------------------------------------------
    def _to_field(self, points: torch.Tensor, name: str = "points") -> torch.Tensor:
        points = check_query_points(points, name).to(self.device, self.dtype)
        return mirror_points(points) if self.mirrored else points

    def evaluate(self, points: torch.Tensor, with_features: bool = False) -> HandFieldOutput:
        """The full field output at points (see :class:`HandFieldOutput`); ``rest_points`` are in
        the right hand's rest frame.

        points: [N, 3] world points, metres. Differentiable with respect to ``points``.
        """
        return self._field.evaluate(self._to_field(points), with_features=with_features)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance to the hand surface, negative inside.

        points: [N, 3] world points, metres -> [N] metres (the field's dtype).
        """
        return self.evaluate(points).sdf

    def sdf_and_ownership(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance and skinning weights (which bones own each point).

        points: [N, 3] world points, metres -> (sdf [N] metres, weights [N, 16], rows sum to 1).
        """
        out = self.evaluate(points)
        return out.sdf, out.weights

    def albedo(self, points: torch.Tensor) -> torch.Tensor:
        """Skin colour at (surface) points, a function of their rest-pose position.

        points: [N, 3] world points, metres -> [N, 3] sRGB in [0, 1].
        """
        out = self.evaluate(points, with_features=True)
        return self._albedo(out)

    def _albedo(self, out: HandFieldOutput) -> torch.Tensor:
        return albedo(
            self.hand.appearance, out.rest_points, out.palmar, out.nail, out.nail_along,
            out.crease, out.knuckle,
        )  # fmt: skip

    def normals(self, points: torch.Tensor) -> torch.Tensor:
        """Outward unit normals: the normalised SDF gradient (autograd).

        points: [N, 3] world points, metres -> [N, 3].
        """
        with torch.enable_grad(), single_threaded(self.device):
            query = points.detach().to(self.device, self.dtype).requires_grad_(True)
            values = self.sdf(query)
            (gradient,) = torch.autograd.grad(values.sum(), query)
        return gradient / gradient.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def bounding_box(self, margin: float = 0.004) -> tuple[np.ndarray, np.ndarray]:
        """An axis-aligned box around the whole surface: (min [3], max [3]) metres (float64).

        Built from the posed parts' bounding spheres, so it may be loose by a few mm.
        """
        field = self._field
        centers = torch.cat([field.cone_center, field.slab_center]).double()
        radii = torch.cat([field.parts.cone_bound, field.parts.slab_bound]).double()
        if self.mirrored:
            centers = mirror_points(centers)
        low = (centers - radii[:, None]).amin(0) - margin
        high = (centers + radii[:, None]).amax(0) + margin
        return low.cpu().numpy(), high.cpu().numpy()

    def default_voxel_size(self) -> float:
        """Hand length / :data:`DEFAULT_VOXELS_PER_LENGTH`, metres."""
        return self.hand.shape.hand_length / DEFAULT_VOXELS_PER_LENGTH

    def mesh(
        self,
        voxel_size: float | None = None,
        resolution: int | None = None,
        colors: bool = True,
        skin_weights: bool = True,
    ):
        """Watertight triangle mesh of the surface (marching cubes, coarse to fine).

        voxel_size: grid spacing, metres (default :meth:`default_voxel_size`: about 0.7 mm,
            100k-150k vertices). resolution: alternatively, grid samples along the longest side
            of the bounding box. Give at most one.
        colors: attach per-vertex albedo; skin_weights: attach per-vertex ownership weights.
        -> :class:`lisa_hand.geometry.meshing.Mesh` (world frame, float32 vertices, outward faces).
        """
        from ..geometry.meshing import Mesh, colors_to_uint8, extract_mesh

        if voxel_size is not None and resolution is not None:
            raise ValueError("give voxel_size or resolution, not both")
        low, high = self.bounding_box()
        extent = float((high - low).max())
        if resolution is not None:
            if not isinstance(resolution, int) or resolution < 8:
                raise ValueError(f"resolution must be an int >= 8, got {resolution!r}")
            voxel_size = extent / (resolution - 1)
        elif voxel_size is None:
            voxel_size = self.default_voxel_size()
        if not (isinstance(voxel_size, (int, float)) and 1e-5 <= voxel_size <= 0.05):
            raise ValueError(f"voxel_size must be within [1e-5, 0.05] metres, got {voxel_size!r}")
        samples = int(np.ceil(extent / voxel_size)) + 1
        high = low + (samples - 1) * voxel_size  # a cubic grid of voxel_size cells
        mesh = extract_mesh(
            self.sdf, low, high, samples, lipschitz=_LIPSCHITZ, chunk_size=1 << 22,
            device=self.device, dtype=self.dtype,
        )  # fmt: skip
        if not (colors or skin_weights):
            return mesh
        vertices = torch.from_numpy(mesh.vertices).to(self.device, self.dtype)
        with torch.no_grad():
            out = self.evaluate(vertices, with_features=colors)
        return Mesh(
            vertices=mesh.vertices,
            faces=mesh.faces,
            colors=colors_to_uint8(self._albedo(out)) if colors else None,
            skin_weights=out.weights.float().cpu().numpy() if skin_weights else None,
        )

    def project_to_surface(self, points: torch.Tensor, iterations: int = 3) -> torch.Tensor:
        """Move points onto the zero level set by Newton steps along the SDF gradient.

        points: [N, 3] metres near the surface (within a few mm) -> [N, 3].
        """
        current = points.detach().to(self.device, self.dtype)
        for _ in range(iterations):
            with torch.enable_grad(), single_threaded(self.device):
                query = current.clone().requires_grad_(True)
                values = self.sdf(query)
                (gradient,) = torch.autograd.grad(values.sum(), query)
            step = values.detach() / (gradient * gradient).sum(-1).clamp_min(1e-12)
            current = current - step[:, None] * gradient
        return current

    def surface_samples(
        self, num: int, generator: torch.Generator, voxel_size: float | None = None
    ) -> SurfaceSamples:
        """Points uniformly spread over the surface, projected exactly onto it.

        Faces of a mesh (``voxel_size``, default twice :meth:`default_voxel_size`) are drawn by
        area, points uniformly inside them, then moved onto the zero level set by Newton steps.

        num: number of points (>= 1). generator: a seeded ``torch.Generator`` (CPU).
        """
        if not isinstance(num, int) or num < 1:
            raise ValueError(f"num must be a positive int, got {num!r}")
        if not isinstance(generator, torch.Generator):
            raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
        from ..geometry.meshing import sample_triangles

        mesh = self.mesh(voxel_size or 2.0 * self.default_voxel_size(), colors=False,
                         skin_weights=False)  # fmt: skip
        vertices = torch.from_numpy(mesh.vertices).double()
        corners = vertices[torch.from_numpy(mesh.faces)]  # [F, 3, 3]
        areas = torch.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], dim=-1)
        areas = areas.norm(dim=-1)
        face, u, v = sample_triangles(areas, num, generator)
        chosen = corners[face]
        points = chosen[:, 0] + u[:, None] * (chosen[:, 1] - chosen[:, 0])
        points = points + v[:, None] * (chosen[:, 2] - chosen[:, 0])
        points = self.project_to_surface(points.to(self.dtype))
        normals = self.normals(points)
        with torch.no_grad():
            out = self.evaluate(points, with_features=True)
        return SurfaceSamples(
            points=points, normals=normals, weights=out.weights, colors=self._albedo(out)
        )

    # ------------------------------------------------------------------------------------------
    def _fingertips(self, transforms_right: torch.Tensor) -> torch.Tensor:
        """[5, 3] the surface points where each distal bone's axis leaves the finger (right)."""
        skel = self.hand.parts.skeleton
        distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
        tips_rest = skel.fingertips
        rot = transforms_right[distal, :3, :3]
        tips = (rot @ tips_rest[..., None])[..., 0] + transforms_right[distal, :3, 3]
        directions = (rot @ skel.bone_dirs[distal][..., None])[..., 0]
        field = PosedField(self.hand.parts, transforms_right)
        with torch.no_grad():
            for _ in range(4):  # Newton steps along the bone: the surface normal is ~ the axis
                values = field.evaluate(tips).sdf
                tips = tips - values[:, None] * directions
        return tips

    def __repr__(self) -> str:
        return (
            f"PosedHand(side={self.hand.side!r}, hand_length={self.hand.shape.hand_length:.3f}, "
            f"dtype={self.dtype}, joints={NUM_JOINTS})"
        )
