"""A MANO-like mesh template of the open hand model: the role MANO plays in the LISA paper.

MANO (Romero et al. 2017) gives LISA a low-resolution hand mesh of fixed topology with linear
blend skinning weights, a joint regressor and a linear shape space. LISA uses it for the
skeleton it is conditioned on, for the pseudo ground truth of its skinning loss (paper Eq. 15:
the weights of the nearest posed MANO vertex) and as the "MANO" baseline. This module builds the
same kind of model from the open hand (:mod:`lisa_hand.handmodel`), so that everything runs
without MANO's licensed file; with the real file, :func:`template_from_mano` puts MANO in the
same role.

How the shipped template (``lisa_hand/assets/template.npz``, :func:`build_template`) is made:

1. Topology: the mean hand (the mean of the sampled subjects' :class:`HandShape` vectors) in the
   rest pose is meshed by marching cubes (2.5 mm voxels) and decimated by shortest-edge collapse
   (point-cloud-utils) to about 800 vertices (watertight, closed genus-0 surface, edges ~8 mm);
   the vertex nearest each fingertip is moved onto it, and all vertices onto the surface by
   Newton steps on the SDF.
2. Skinning weights: the open hand's bone ownership at the vertices (the blend factors of its
   smooth union), smoothed by two Laplacian steps over the mesh so that faces spanning a joint
   stretch less when the finger flexes; rows sum to 1.
3. Correspondences: each vertex is carried to a subject's rest surface by an LBS-like blend of
   per-bone affine maps ``x' = sum_j w_j (M_j x + t_j)``; ``(M_j, t_j)`` is the least-squares
   map of bone ``j``'s control points (its joint and end, each with four points one flesh radius
   away on the dorsal and lateral axes) from the mean skeleton to the subject's, so bone lengths,
   directions and thicknesses follow the subject. Newton steps on the subject's SDF then put the
   vertex on the surface (the blended map lands within ~0.4 mm of it).
4. Shape space: PCA (SVD) of the corresponded vertices of N subjects; ``v_template`` is their
   mean and ``shapedirs[..., k]`` the k-th principal direction times its standard deviation, so
   ``betas ~ N(0, I)`` over the subject distribution (MANO's convention).
5. Joint regressor: per joint, non-negative least squares (with a small ridge term and a
   row-sum-to-1 constraint) over the vertices near the joint, so that ``regressor @ vertices``
   equals the subjects' true rest joints.
6. Fingertips: per finger, the vertex closest (over the subjects) to the open hand's fingertip
   keypoint (the one placed on it in step 1).

A left hand is the mirror image of the right one: its betas are those of its right twin
(:meth:`MeshTemplate.fit_betas` accepts either side) and its joints and vertices the mirrored
ones (``lisa_hand.skeleton.mirror_points``), as for MANO's left model.

Measured (200 subjects, seed 0; 50 held-out subjects): 10 components explain 99.6 % of the
variance; from fitted betas the vertices lie 0.13 mm (mean |SDF|; 0.36 mm 95th percentile) from
the subject's surface, 0.24 mm from their exact correspondences, the rest joints 0.29 mm from
the true ones (the regressor alone: 0.11 mm), the fingertip vertices 0.5 mm from the fingertips.
Build: ~15-30 s on one CPU core; ``fit_betas``: ~0.1-0.2 s.

Units: metres; axes: MANO's right hand (fingers along -x, palm facing -y, thumb on +z).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import sys
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..skeleton.kinematics import (
    check_pose,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
)
from ..skeleton.tree import (
    FINGER_JOINTS,
    FINGER_NAMES,
    MANO_FINGERTIP_VERTEX_IDS,
    NUM_JOINTS,
    PARENTS,
    joints_to_keypoints,
)
from ..utils.io import atomic_path

if TYPE_CHECKING:
    from ..skeleton.mano import ManoData, ManoLayer
    from .hand import OpenHand

__all__ = [
    "MeshTemplate",
    "TemplateOutput",
    "TemplateSource",
    "TemplateFitReport",
    "DEFAULT_TEMPLATE_PATH",
    "load_template",
    "save_template",
    "template_from_mano",
    "build_template",
    "evaluate_template",
    "main",
]

DEFAULT_TEMPLATE_PATH = Path(__file__).resolve().parent.parent / "assets" / "template.npz"
"""The shipped open template (rebuild: ``python -m lisa_hand.handmodel.template --out ...``)."""

_FORMAT_VERSION = 1
_WEIGHT_SMOOTHING_STEPS = 2  # Laplacian steps (lambda = 0.5) over the mesh, see step 2 above
_MESH_VOXEL_SIZE = 0.0025  # marching cubes grid of the mean hand before decimation, metres
_PROJECTION_ITERATIONS = 5  # Newton steps onto the SDF's zero level set
_REGRESSOR_RADIUS = 0.025  # candidate vertices of a joint lie within this distance, metres
_REGRESSOR_RIDGE = 1e-5  # ridge weight (relative to the data term) of the NNLS regressor
_HELD_OUT_SEED_OFFSET = 1_000_003  # held-out subjects are drawn from seed + this


# ----------------------------------------------------------------------------------------------
# Data classes


@dataclass(frozen=True, eq=False)
class TemplateSource:
    """What :meth:`MeshTemplate.fit_betas` needs to carry the template onto an open-hand subject:
    the mean hand's surface vertices and skeleton that the correspondences start from.

    vertices: [V, 3] the template's vertices on the mean hand's rest surface, metres.
    joints, bone_ends: [16, 3] the mean hand's rest joints and bone ends, metres.
    radii: [16, 2] flesh radius at each bone's start and end, metres.
    dorsal, lateral: [16, 3] unit axes of each bone's rest frame (see :mod:`.shape`).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    bone_ends: torch.Tensor
    radii: torch.Tensor
    dorsal: torch.Tensor
    lateral: torch.Tensor


@dataclass
class TemplateOutput:
    """Result of :meth:`MeshTemplate.forward` (world frame, metres).

    vertices: [B, V, 3] posed vertices, translation included.
    joints: [B, 16, 3] posed joints in MANO order.
    keypoints: [B, 21, 3] joints plus fingertip vertices in OpenPose/MediaPipe order.
    transforms: [B, 16, 4, 4] rest-to-posed bone transforms ``A_j`` (translation included).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    keypoints: torch.Tensor
    transforms: torch.Tensor


@dataclass(frozen=True, eq=False)
class MeshTemplate:
    """A MANO-like hand template: mesh, LBS weights, joint regressor and linear shape space.

    Right hand in MANO's axes (fingers -x, palm -y, thumb +z), metres. The shaped rest mesh is
    ``T(beta) = v_template + shapedirs . beta``, its joints ``J(beta) = joint_regressor T(beta)``;
    :meth:`forward` poses it with forward kinematics and linear blend skinning (paper Eq. 2),
    without pose blend shapes.
    """

    v_template: torch.Tensor
    """[V, 3] mean right hand at rest, metres."""
    faces: torch.Tensor
    """[F, 3] int64 vertex indices, counter-clockwise seen from outside (watertight for the open
    template; MANO's mesh is open at the wrist)."""
    weights: torch.Tensor
    """[V, 16] LBS weights, non-negative, rows sum to 1."""
    joint_regressor: torch.Tensor
    """[16, V] rows sum to 1 (non-negative for the open template)."""
    shapedirs: torch.Tensor
    """[V, 3, K] metres per unit beta; betas ~ N(0, I) over the subject distribution."""
    fingertip_ids: tuple[int, ...]
    """5 vertex ids (thumb, index, middle, ring, pinky): the fingertip keypoints."""
    name: str = "open-template"
    """"open-template" (built from the open hand) or "mano"."""
    source: TemplateSource | None = field(default=None, compare=False, repr=False)
    """Correspondence data for :meth:`fit_betas` (open template only)."""
    info: dict = field(default_factory=dict, compare=False, repr=False)
    """Build information (subjects, seed, explained variance, fit errors), JSON-serialisable."""

    def __post_init__(self) -> None:
        _check_layout(self, "MeshTemplate")

    # ------------------------------------------------------------------------------------------
    @property
    def num_betas(self) -> int:
        """Number of shape coefficients K."""
        return int(self.shapedirs.shape[-1])

    @property
    def num_vertices(self) -> int:
        """Number of vertices V."""
        return int(self.v_template.shape[0])

    @property
    def dtype(self) -> torch.dtype:
        """The floating dtype of the template's tensors (and of its outputs)."""
        return self.v_template.dtype

    @property
    def device(self) -> torch.device:
        """The device of the template's tensors; inputs must be on it."""
        return self.v_template.device

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> MeshTemplate:
        """A copy on ``device`` with floating tensors in ``dtype`` (faces stay int64)."""
        if dtype is not None and dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")

        def convert(value: torch.Tensor) -> torch.Tensor:
            if value.is_floating_point():
                return value.to(device=device, dtype=dtype)
            return value.to(device=device)

        source = self.source
        if source is not None:
            source = TemplateSource(
                **{f.name: convert(getattr(source, f.name)) for f in dataclasses.fields(source)}
            )
        return dataclasses.replace(
            self,
            v_template=convert(self.v_template),
            faces=convert(self.faces),
            weights=convert(self.weights),
            joint_regressor=convert(self.joint_regressor),
            shapedirs=convert(self.shapedirs),
            source=source,
        )

    # ------------------------------------------------------------------------------------------
    def _as_batch(self, value: torch.Tensor, width: int, name: str, allow_1d: bool) -> torch.Tensor:
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        if allow_1d and value.dim() == 1:
            value = value[None]
        if value.dim() != 2 or value.shape[1] != width:
            shapes = f"[B, {width}]" + (f" or [{width}]" if allow_1d else "")
            raise ValueError(f"{name} must have shape {shapes}, got {tuple(value.shape)}")
        if not value.is_floating_point():
            raise TypeError(f"{name} must be a floating point tensor, got {value.dtype}")
        if value.device != self.device:
            raise ValueError(
                f"{name} is on {value.device} but the template is on {self.device} "
                "(move one of them, e.g. template.to(device))"
            )
        if not torch.isfinite(value).all():
            raise ValueError(f"{name} contains NaN or inf values")
        return value.to(self.dtype)

    def rest_vertices(self, betas: torch.Tensor) -> torch.Tensor:
        """The shaped template at rest, ``v_template + shapedirs . beta``.

        betas: [B, K] or [K] shape coefficients (cast to the template's dtype).
        -> [B, V, 3] metres (B = 1 for [K]).
        """
        betas = self._as_batch(betas, self.num_betas, "betas", allow_1d=True)
        return self.v_template + torch.einsum("bk,vck->bvc", betas, self.shapedirs)

    def rest_joints(self, betas: torch.Tensor) -> torch.Tensor:
        """Rest joints of the shaped template, ``joint_regressor @ rest_vertices(betas)``.

        betas: [B, K] or [K] -> [B, 16, 3] metres.
        """
        return torch.einsum("jv,bvc->bjc", self.joint_regressor, self.rest_vertices(betas))

    def forward(
        self,
        pose: torch.Tensor,
        betas: torch.Tensor,
        translation: torch.Tensor | None = None,
    ) -> TemplateOutput:
        """Shape, pose and skin the template (LBS, paper Eq. 2; no pose blend shapes).

        pose: [B, 48] axis-angle radians (global orientation + 15 finger joints; a zero pose is
            the flat hand, as MANO with ``flat_hand_mean=True``).
        betas: [B, K] shape coefficients. translation: [B, 3] metres, or None.
        Inputs must be on the template's device; they are cast to its dtype.
        """
        pose = check_pose(pose)
        pose = self._as_batch(pose.reshape(pose.shape[0], -1), 3 * NUM_JOINTS, "pose", False)
        betas = self._as_batch(betas, self.num_betas, "betas", allow_1d=False)
        if betas.shape[0] != pose.shape[0]:
            raise ValueError(f"betas has batch size {betas.shape[0]} but pose has {pose.shape[0]}")
        if translation is not None:
            translation = self._as_batch(translation, 3, "translation", allow_1d=False)
        vertices_rest = self.rest_vertices(betas)
        joints_rest = torch.einsum("jv,bvc->bjc", self.joint_regressor, vertices_rest)
        kinematics = forward_kinematics(pose, joints_rest, translation)
        vertices = linear_blend_skinning(vertices_rest, self.weights, kinematics.transforms)
        tips = vertices[:, list(self.fingertip_ids)]
        return TemplateOutput(
            vertices=vertices,
            joints=kinematics.joints,
            keypoints=joints_to_keypoints(kinematics.joints, tips),
            transforms=kinematics.transforms,
        )

    __call__ = forward

    def skinning_weights_at(
        self, points: torch.Tensor, posed_vertices: torch.Tensor
    ) -> torch.Tensor:
        """Skinning weights of the nearest posed template vertex (paper Eq. 15's pseudo ground
        truth for the skinning network). Not differentiable.

        points: [N, 3] metres. posed_vertices: [V, 3] the posed template (same frame), metres.
        -> [N, 16] on the points' device, in the template's dtype.
        """
        from scipy.spatial import cKDTree

        for name, value, shape_text in (
            ("points", points, "[N, 3]"),
            ("posed_vertices", posed_vertices, f"[{self.num_vertices}, 3]"),
        ):
            if not isinstance(value, torch.Tensor):
                raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
            if value.dim() != 2 or value.shape[1] != 3:
                raise ValueError(f"{name} must have shape {shape_text}, got {tuple(value.shape)}")
        if posed_vertices.shape[0] != self.num_vertices:
            raise ValueError(
                f"posed_vertices must have shape [{self.num_vertices}, 3], "
                f"got {tuple(posed_vertices.shape)}"
            )
        if points.shape[0] == 0:
            return self.weights.new_zeros((0, NUM_JOINTS)).to(points.device)
        tree = cKDTree(posed_vertices.detach().double().cpu().numpy())
        _, nearest = tree.query(points.detach().double().cpu().numpy())
        index = torch.from_numpy(np.asarray(nearest, dtype=np.int64)).to(self.device)
        return self.weights[index].to(points.device)

    def fit_betas(self, hand: OpenHand, iterations: int = _PROJECTION_ITERATIONS) -> torch.Tensor:
        """Least-squares betas of one open-hand subject.

        The template is carried onto the subject's rest surface as when the shape space was
        built (per-bone affine maps blended by the skinning weights, then ``iterations`` Newton
        steps on the subject's SDF), and the displacement from ``v_template`` is projected on
        the shape space (least squares over all vertices). A left hand is fitted through its
        mirror image (betas describe the shape, not the side). Takes ~0.1-0.2 s (one CPU core).

        hand: an :class:`~lisa_hand.handmodel.OpenHand`. -> [K] float64 betas (CPU).
        """
        from .hand import OpenHand

        if not isinstance(hand, OpenHand):
            raise TypeError(f"hand must be an OpenHand, got {type(hand).__name__}")
        if self.source is None:
            raise ValueError(
                f"fit_betas needs an open template with correspondence data; this {self.name!r} "
                "template has none"
            )
        if not isinstance(iterations, int) or iterations < 0:
            raise ValueError(f"iterations must be a non-negative int, got {iterations!r}")
        source = _source_numpy(self.source)
        weights = self.weights.detach().double().cpu().numpy()
        corresponded = _correspond(source, weights, hand, iterations)
        return _project_betas(
            corresponded,
            self.v_template.detach().double().cpu().numpy(),
            self.shapedirs.detach().double().cpu().numpy(),
        )


@dataclass
class TemplateFitReport:
    """How well a template fits held-out open-hand subjects (all distances in millimetres).

    num_subjects: held-out subjects evaluated.
    reconstruction_mm: mean vertex distance between the corresponded vertices and their
        reconstruction from the fitted betas (the shape space's truncation error).
    v2s_mm: mean |SDF| of the fitted template's vertices on the subject's rest surface.
    v2s_p95_mm: its 95th percentile.
    joint_mm: mean distance of ``rest_joints(fitted betas)`` to the subject's true rest joints.
    joint_regressor_mm: the same with the regressor applied to the exact correspondences (the
        regressor's own error).
    fingertip_mm: mean distance of the fingertip vertices to the subject's fingertips.
    fit_seconds: mean time of :meth:`MeshTemplate.fit_betas`.
    """

    num_subjects: int
    reconstruction_mm: float
    v2s_mm: float
    v2s_p95_mm: float
    joint_mm: float
    joint_regressor_mm: float
    fingertip_mm: float
    fit_seconds: float


# ----------------------------------------------------------------------------------------------
# Validation


def _check_layout(template: MeshTemplate, where: str) -> None:
    """Shapes, dtypes and invariants of a template's tensors; ValueError naming ``where``."""
    tensors = {
        "v_template": template.v_template,
        "faces": template.faces,
        "weights": template.weights,
        "joint_regressor": template.joint_regressor,
        "shapedirs": template.shapedirs,
    }
    for name, value in tensors.items():
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{where}: {name} must be a torch.Tensor, got {type(value).__name__}")
    num_v = template.v_template.shape[0] if template.v_template.dim() == 2 else -1
    expected = {
        "v_template": (num_v, 3),
        "weights": (num_v, NUM_JOINTS),
        "joint_regressor": (NUM_JOINTS, num_v),
    }
    if template.v_template.dim() != 2 or template.v_template.shape[1] != 3 or num_v < 4:
        raise ValueError(
            f"{where}: v_template must have shape [V, 3] with V >= 4, "
            f"got {tuple(template.v_template.shape)}"
        )
    for name, shape in expected.items():
        if tuple(tensors[name].shape) != shape:
            raise ValueError(f"{where}: {name} must have shape {list(shape)}, got "
                             f"{tuple(tensors[name].shape)}")  # fmt: skip
    if template.shapedirs.dim() != 3 or template.shapedirs.shape[:2] != (num_v, 3):
        raise ValueError(
            f"{where}: shapedirs must have shape [{num_v}, 3, K], "
            f"got {tuple(template.shapedirs.shape)}"
        )
    faces = template.faces
    if faces.dim() != 2 or faces.shape[1] != 3 or faces.shape[0] < 4:
        raise ValueError(f"{where}: faces must have shape [F, 3], got {tuple(faces.shape)}")
    if faces.dtype != torch.int64:
        raise ValueError(f"{where}: faces must be int64, got {faces.dtype}")
    if int(faces.min()) < 0 or int(faces.max()) >= num_v:
        raise ValueError(f"{where}: faces must index vertices in [0, {num_v})")
    for name, value in tensors.items():
        if name != "faces" and not (value.is_floating_point() and torch.isfinite(value).all()):
            raise ValueError(f"{where}: {name} must be finite floating point values")
    for name in ("weights", "joint_regressor"):
        sums = tensors[name].sum(-1)
        if not torch.allclose(sums, torch.ones_like(sums), atol=1e-4):
            raise ValueError(f"{where}: the rows of {name} must sum to 1")
    if bool((template.weights < -1e-6).any()):
        raise ValueError(f"{where}: weights must be non-negative")
    tips = template.fingertip_ids
    if (
        not isinstance(tips, tuple)
        or len(tips) != 5
        or not all(isinstance(i, int) and 0 <= i < num_v for i in tips)
    ):
        raise ValueError(f"{where}: fingertip_ids must be 5 vertex ids in [0, {num_v}), got {tips}")
    if template.name not in ("open-template", "mano"):
        raise ValueError(f"{where}: name must be 'open-template' or 'mano', got {template.name!r}")
    if template.source is not None:
        source_shapes = {"vertices": (num_v, 3), "joints": (NUM_JOINTS, 3),
                         "bone_ends": (NUM_JOINTS, 3), "radii": (NUM_JOINTS, 2),
                         "dorsal": (NUM_JOINTS, 3), "lateral": (NUM_JOINTS, 3)}  # fmt: skip
        for name, shape in source_shapes.items():
            value = getattr(template.source, name)
            if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape:
                got = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value)
                raise ValueError(f"{where}: source.{name} must have shape {list(shape)}, got {got}")


# ----------------------------------------------------------------------------------------------
# Files

_SOURCE_KEYS = ("vertices", "joints", "bone_ends", "radii", "dorsal", "lateral")


def save_template(template: MeshTemplate, path: str | os.PathLike) -> Path:
    """Write a template as a compressed ``.npz`` (atomically; float64 arrays).

    MANO's arrays are licensed: a ``name == "mano"`` template is refused (never redistribute it).
    """
    if not isinstance(template, MeshTemplate):
        raise TypeError(f"template must be a MeshTemplate, got {type(template).__name__}")
    if template.name == "mano":
        raise ValueError("refusing to save a MANO template: MANO's arrays are licensed")
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"{path}: a template file must end in .npz")

    def array(value: torch.Tensor, dtype=np.float64) -> np.ndarray:
        return value.detach().cpu().numpy().astype(dtype)

    arrays = {
        "format_version": np.array(_FORMAT_VERSION),
        "name": np.array(template.name),
        "v_template": array(template.v_template),
        "faces": array(template.faces, np.int32),
        "weights": array(template.weights),
        "joint_regressor": array(template.joint_regressor),
        "shapedirs": array(template.shapedirs),
        "fingertip_ids": np.asarray(template.fingertip_ids, dtype=np.int64),
        "info": np.array(json.dumps(template.info)),
    }
    if template.source is not None:
        for key in _SOURCE_KEYS:
            arrays[f"source_{key}"] = array(getattr(template.source, key))
    with atomic_path(path) as tmp, tmp.open("wb") as handle:
        np.savez_compressed(handle, **arrays)
    return path


@functools.lru_cache(maxsize=1)
def _load_default() -> MeshTemplate:
    return _read_template(DEFAULT_TEMPLATE_PATH)


def load_template(path: str | os.PathLike | None = None) -> MeshTemplate:
    """Read a template written by :func:`save_template` (float64, CPU).

    path: an ``.npz`` file; None = the shipped open template (read once, then cached: do not
        modify its tensors in place).
    Raises FileNotFoundError for a missing file and ValueError (naming the file) for a corrupt
    one or one in another layout.
    """
    if path is None:
        return _load_default()
    return _read_template(Path(path))


def _read_template(path: Path) -> MeshTemplate:
    if not path.is_file():
        hint = (
            f" (rebuild it: python -m lisa_hand.handmodel.template --out {path})"
            if path == DEFAULT_TEMPLATE_PATH
            else ""
        )
        raise FileNotFoundError(f"{path}: no such template file{hint}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        detail = f"{type(exc).__name__}: {exc}"
        raise ValueError(f"{path}: not a readable template .npz ({detail})") from None
    required = ("format_version", "name", "v_template", "faces", "weights", "joint_regressor",
                "shapedirs", "fingertip_ids")  # fmt: skip
    missing = [key for key in required if key not in arrays]
    if missing:
        raise ValueError(f"{path}: not a template file, missing array(s) {', '.join(missing)}")
    try:
        version = int(arrays["format_version"])
    except (TypeError, ValueError):
        version = None
    if version != _FORMAT_VERSION:
        raise ValueError(f"{path}: template format version {version}, expected {_FORMAT_VERSION}")

    def tensor(key: str, dtype=torch.float64) -> torch.Tensor:
        value = arrays[key]
        if not (np.issubdtype(value.dtype, np.number)):
            raise ValueError(f"{path}: array {key!r} is not numeric ({value.dtype})")
        return torch.from_numpy(np.ascontiguousarray(value)).to(dtype)

    source = None
    if all(f"source_{key}" in arrays for key in _SOURCE_KEYS):
        source = TemplateSource(**{key: tensor(f"source_{key}") for key in _SOURCE_KEYS})
    info = {}
    if "info" in arrays:
        try:
            info = json.loads(str(arrays["info"]))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: the template's info is not valid JSON ({exc})") from None
    tips = arrays["fingertip_ids"]
    if tips.shape != (5,) or not np.issubdtype(tips.dtype, np.integer):
        raise ValueError(f"{path}: fingertip_ids must be 5 integers, got {tips.shape} {tips.dtype}")
    try:
        return MeshTemplate(
            v_template=tensor("v_template"),
            faces=tensor("faces", torch.int64),
            weights=tensor("weights"),
            joint_regressor=tensor("joint_regressor"),
            shapedirs=tensor("shapedirs"),
            fingertip_ids=tuple(int(i) for i in tips),
            name=str(arrays["name"]),
            source=source,
            info=info,
        )
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None


# ----------------------------------------------------------------------------------------------
# MANO as the template


def template_from_mano(
    path_or_layer: str | os.PathLike | ManoData | ManoLayer, num_betas: int = 10
) -> MeshTemplate:
    """The real MANO right hand as the template (``name == "mano"``, float64 CPU).

    Uses MANO's ``v_template``, ``faces``, ``weights``, dense ``J_regressor``, the first
    ``num_betas`` shape directions and the fingertip vertices
    :data:`~lisa_hand.skeleton.MANO_FINGERTIP_VERTEX_IDS`. MANO's pose blend shapes
    (``posedirs``) are ignored: :meth:`MeshTemplate.forward` is plain LBS, so posed vertices
    differ from MANO's by its pose correctives (joints and rest shapes are identical). The pose
    is MANO's full 48-D pose with a flat hand mean (``ManoLayer(flat_hand_mean=True)``).

    path_or_layer: ``MANO_RIGHT.pkl``, a loaded :class:`~lisa_hand.skeleton.ManoData`, or a
        :class:`~lisa_hand.skeleton.ManoLayer`. A layer keeps no joint regressor, only the
        regressed joints of the template and of each shape direction; the template then gets
        the minimum-norm regressor (rows summing to 1) that reproduces them exactly, so its rest
        joints equal the layer's for every betas (its entries may be negative).
    num_betas: shape directions kept (1 to the file's count, 10 for MANO).
    """
    from ..skeleton.mano import ManoData, ManoLayer, load_mano_pkl

    if isinstance(path_or_layer, ManoLayer):
        layer = path_or_layer
        side = layer.side
        vertices = layer.template_vertices.detach().double().cpu()
        shapedirs = layer.shape_dirs.detach().double().cpu()
        weights = layer.skinning_weights.detach().double().cpu()
        faces = layer.faces.detach().long().cpu()
        regressor = None
    else:
        data = path_or_layer if isinstance(path_or_layer, ManoData) else None
        if data is None:
            if not isinstance(path_or_layer, (str, os.PathLike)):
                raise TypeError(
                    "path_or_layer must be a path, a ManoData or a ManoLayer, got "
                    f"{type(path_or_layer).__name__}"
                )
            data = load_mano_pkl(path_or_layer, side="right")
        side = data.side
        vertices = torch.from_numpy(data.template_vertices).double()
        shapedirs = torch.from_numpy(data.shape_dirs).double()
        weights = torch.from_numpy(data.skinning_weights).double()
        faces = torch.from_numpy(data.faces).long()
        regressor = torch.from_numpy(data.joint_regressor).double()
    if side != "right":
        raise ValueError(
            "template_from_mano needs MANO's right hand (MANO_RIGHT.pkl); the template is a "
            f"right hand and left hands are its mirror image, got a {side} model"
        )
    total = int(shapedirs.shape[-1])
    if not isinstance(num_betas, int) or not 1 <= num_betas <= total:
        raise ValueError(f"num_betas must be an int in [1, {total}], got {num_betas!r}")
    if regressor is None:
        regressor = _regressor_from_layer(path_or_layer, vertices, shapedirs)
    return MeshTemplate(
        v_template=vertices,
        faces=faces,
        weights=weights,
        joint_regressor=regressor,
        shapedirs=shapedirs[..., :num_betas].contiguous(),
        fingertip_ids=tuple(int(i) for i in MANO_FINGERTIP_VERTEX_IDS),
        name="mano",
    )


def _regressor_from_layer(
    layer: ManoLayer, vertices: torch.Tensor, shapedirs: torch.Tensor
) -> torch.Tensor:
    """Minimum-norm ``R`` [16, V] with ``R T = J_T``, ``R S_k = J_k`` (every shape direction and
    coordinate) and rows summing to 1: the layer's joints for every betas."""
    basis = torch.cat(
        [vertices, shapedirs.reshape(vertices.shape[0], -1), vertices.new_ones(len(vertices), 1)],
        dim=1,
    )  # [V, 3 + 3S + 1]
    joints = layer.joint_template.detach().double().cpu()
    joint_dirs = layer.joint_shape_dirs.detach().double().cpu()
    target = torch.cat(
        [joints, joint_dirs.reshape(NUM_JOINTS, -1), joints.new_ones(NUM_JOINTS, 1)], dim=1
    )
    return target @ torch.linalg.pinv(basis)


# ----------------------------------------------------------------------------------------------
# Correspondences: the template carried onto a subject's rest surface


def _source_numpy(source: TemplateSource) -> dict[str, np.ndarray]:
    return {key: getattr(source, key).detach().double().cpu().numpy() for key in _SOURCE_KEYS}


def _skeleton_arrays(hand: OpenHand) -> dict[str, np.ndarray]:
    """The right-hand rest skeleton of a subject (whatever its side) as float64 arrays."""
    skel = hand.template.skeleton
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


def _correspond(
    source: dict[str, np.ndarray], weights: np.ndarray, hand: OpenHand, iterations: int
) -> np.ndarray:
    """[V, 3] the template's vertices carried onto ``hand``'s right-hand rest surface.

    source: the mean hand's vertices [V, 3] and skeleton arrays. weights: [V, 16] LBS weights.
    """
    maps = _bone_maps(source, _skeleton_arrays(hand))
    vertices = source["vertices"]
    homogeneous = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1)
    mapped = np.einsum("vj,vk,jkc->vc", weights, homogeneous, maps)
    if iterations == 0:
        return mapped
    posed = hand.posed(dtype=torch.float64)
    points = torch.from_numpy(mapped)
    if hand.side == "left":  # the left hand's field is the mirror image of the right hand's
        points = mirror_points(points)
    projected = _project(posed, points, iterations)
    if hand.side == "left":
        projected = mirror_points(projected)
    return projected.cpu().numpy()


def _project(posed, points: torch.Tensor, iterations: int) -> torch.Tensor:
    """Newton steps onto the surface; a point whose SDF gradient is undefined (exactly on a
    fingertip's axis) is retried a micrometre away."""
    projected = posed.project_to_surface(points, iterations=iterations)
    bad = ~torch.isfinite(projected).all(dim=1)
    if bool(bad.any()):
        nudged = points[bad] + points.new_tensor([0.0, 1e-6, 1e-6])
        projected[bad] = posed.project_to_surface(nudged, iterations=iterations)
    return projected


def _project_betas(
    vertices: np.ndarray, v_template: np.ndarray, shapedirs: np.ndarray
) -> torch.Tensor:
    """[K] float64 least-squares betas of ``vertices`` [V, 3] in the shape space."""
    basis = shapedirs.reshape(-1, shapedirs.shape[-1])
    betas, *_ = np.linalg.lstsq(basis, (vertices - v_template).ravel(), rcond=None)
    return torch.from_numpy(betas)


# ----------------------------------------------------------------------------------------------
# Building the open template


def _mean_shape(shapes: list):
    """The HandShape whose every parameter is the mean over ``shapes``."""
    from .shape import HandShape

    names = [f.name for f in dataclasses.fields(HandShape)]
    vectors = np.stack([shape.as_vector() for shape in shapes])
    return HandShape(**{name: float(value) for name, value in zip(names, vectors.mean(0),
                                                                   strict=True)})  # fmt: skip


def _laplacian_smooth(
    values: np.ndarray, faces: np.ndarray, steps: int, lam: float = 0.5
) -> np.ndarray:
    """``steps`` uniform Laplacian steps ``x <- (1 - lam) x + lam mean(neighbours)`` over a mesh."""
    import scipy.sparse as sparse

    num = values.shape[0]
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adjacency = sparse.coo_matrix(
        (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(num, num)
    ).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    average = sparse.diags(1.0 / degree) @ adjacency
    for _ in range(steps):
        values = (1.0 - lam) * values + lam * (average @ values)
    return values


def _template_mesh(mean_hand: OpenHand, target_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The mean hand's rest surface as a watertight mesh of ``target_vertices`` vertices (on the
    surface) -> (vertices [V, 3] float64, faces [F, 3] int64)."""
    import point_cloud_utils as pcu
    import trimesh

    posed = mean_hand.posed(dtype=torch.float64)
    dense = posed.mesh(voxel_size=_MESH_VOXEL_SIZE, colors=False, skin_weights=False)
    # A closed genus-0 triangle mesh has F = 2 V - 4 faces.
    vertices, faces, _, _ = pcu.decimate_triangle_mesh(
        dense.vertices.astype(np.float64), dense.faces.astype(np.int32), 2 * target_vertices - 4
    )
    faces = faces.astype(np.int64)
    # Put one vertex exactly on each fingertip (the open hand's keypoint): the nearest one, a few
    # mm from it at this resolution, is moved there.
    tips = mean_hand.template.skeleton.fingertips.numpy()
    nearest = np.linalg.norm(vertices[:, None] - tips[None], axis=-1).argmin(0)
    if len(set(nearest.tolist())) == len(nearest):
        # A hair off the distal bone's axis, where the open hand's SDF gradient is undefined.
        distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
        vertices[nearest] = tips + 1e-6 * mean_hand.template.skeleton.dorsal[distal].numpy()
    vertices = _project(posed, torch.from_numpy(vertices), _PROJECTION_ITERATIONS)
    vertices = vertices.numpy()
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise RuntimeError("the decimated template mesh is not watertight and outward")
    return vertices, faces


def _fit_regressor(
    vertices: np.ndarray, joints: np.ndarray, rest_vertices: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Non-negative joint regressor [16, V] with rows summing to 1.

    vertices: [N, V, 3] corresponded subjects; joints: [N, 16, 3] their true rest joints.
    rest_vertices: [V, 3] the mean vertices; weights: [V, 16] LBS weights. Joint ``j`` regresses
    from the vertices within ``_REGRESSOR_RADIUS`` of its mean position that bone ``j`` or its
    parent owns; NNLS solves ``sum_v r_v x_v = J`` over the subjects and coordinates, with a
    ridge term ``mu |r|^2`` (spreads the weights, steadier on new shapes) and a heavily weighted
    row ``sum_v r_v = 1``.
    """
    from scipy.optimize import nnls

    num_subjects, num_v = vertices.shape[:2]
    regressor = np.zeros((NUM_JOINTS, num_v))
    mean_joints = joints.mean(0)
    for joint in range(NUM_JOINTS):
        owner = weights[:, joint] + (weights[:, PARENTS[joint]] if joint > 0 else 0.0)
        distance = np.linalg.norm(rest_vertices - mean_joints[joint], axis=1)
        candidates = np.flatnonzero((distance < _REGRESSOR_RADIUS) & (owner > 0.3))
        if len(candidates) < 12:  # fall back on the nearest vertices
            candidates = np.argsort(distance)[:24]
        # Rows: subjects x coordinates, relative to the mean joint (translation-invariant once
        # the weights sum to 1), scaled to unit RMS so the ridge weight is relative.
        design = vertices[:, candidates] - mean_joints[joint]  # [N, C, 3]
        design = design.transpose(0, 2, 1).reshape(-1, len(candidates))
        target = (joints[:, joint] - mean_joints[joint]).reshape(-1)
        scale = 1.0 / max(float(np.sqrt((design**2).mean())), 1e-9)
        ridge = math.sqrt(_REGRESSOR_RIDGE * len(target)) * np.eye(len(candidates))
        constraint = 1e3 * np.ones((1, len(candidates)))
        system = np.concatenate([design * scale, ridge, constraint])
        rhs = np.concatenate([target * scale, np.zeros(len(candidates)), [1e3]])
        solution, _ = nnls(system, rhs, maxiter=50 * len(candidates))
        regressor[joint, candidates] = solution / solution.sum()
    return regressor


def _subjects(seed: int, count: int) -> list:
    from .hand import sample_hand

    generator = torch.Generator().manual_seed(int(seed))
    return [sample_hand(generator) for _ in range(count)]


def _progress(items, enabled: bool, desc: str):
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, leave=False)


def build_template(
    num_subjects: int = 200,
    target_vertices: int = 800,
    num_betas: int = 10,
    seed: int = 0,
    progress: bool = True,
) -> MeshTemplate:
    """Build the open template from ``num_subjects`` random subjects (see the module docstring).

    num_subjects: subjects of the shape space and joint regressor (>= num_betas + 2).
    target_vertices: vertices of the mesh (decimation target; >= 100).
    num_betas: principal components kept (K). seed: subjects are ``sample_hand`` draws from
        ``torch.Generator().manual_seed(seed)``; the same arguments give the same template.
    progress: show a progress bar over subjects.
    About 0.1 s per subject on one CPU core.
    """
    from .hand import OpenHand

    minimums = {"num_betas": (num_betas, 1), "num_subjects": (num_subjects, num_betas + 2),
                "target_vertices": (target_vertices, 100)}  # fmt: skip
    for name, (value, low) in minimums.items():
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
    subjects = _subjects(seed, num_subjects)
    mean_hand = OpenHand(shape=_mean_shape([hand.shape for hand in subjects]))
    vertices, faces = _template_mesh(mean_hand, target_vertices)
    num_v = len(vertices)

    posed_mean = mean_hand.posed(dtype=torch.float64)
    with torch.no_grad():
        _, ownership = posed_mean.sdf_and_ownership(torch.from_numpy(vertices))
    weights = _laplacian_smooth(ownership.numpy(), faces, _WEIGHT_SMOOTHING_STEPS)
    weights = np.clip(weights, 0.0, None)
    weights /= weights.sum(axis=1, keepdims=True)

    source = {"vertices": vertices, **_skeleton_arrays(mean_hand)}
    corresponded = np.empty((num_subjects, num_v, 3))
    joints = np.empty((num_subjects, NUM_JOINTS, 3))
    tips = np.empty((num_subjects, 5, 3))
    for i, hand in enumerate(_progress(subjects, progress, "template subjects")):
        corresponded[i] = _correspond(source, weights, hand, _PROJECTION_ITERATIONS)
        joints[i] = hand.template.skeleton.joints.numpy()
        tips[i] = hand.template.skeleton.fingertips.numpy()

    # PCA: shapedirs = principal directions x standard deviations (unit-variance betas).
    flat = corresponded.reshape(num_subjects, -1)
    mean = flat.mean(0)
    _, singular, directions = np.linalg.svd(flat - mean, full_matrices=False)
    std = singular / math.sqrt(num_subjects - 1)
    if num_betas > len(std):
        raise ValueError(f"num_betas={num_betas} exceeds the {len(std)} available components")
    shapedirs = (directions[:num_betas] * std[:num_betas, None]).T.reshape(num_v, 3, num_betas)
    # Sign convention (deterministic across LAPACKs): each direction's largest entry positive.
    flat_dirs = shapedirs.reshape(-1, num_betas)
    signs = np.sign(flat_dirs[np.abs(flat_dirs).argmax(0), np.arange(num_betas)])
    shapedirs = shapedirs * signs
    variance = std**2
    v_template = mean.reshape(num_v, 3)

    regressor = _fit_regressor(corresponded, joints, v_template, weights)
    tip_distance = np.linalg.norm(corresponded[:, :, None] - tips[:, None], axis=-1).mean(0)
    fingertip_ids = tuple(int(i) for i in tip_distance.argmin(0))

    info = {
        "num_subjects": num_subjects,
        "seed": seed,
        "target_vertices": target_vertices,
        "mean_shape": _mean_shape([hand.shape for hand in subjects]).as_vector().tolist(),
        "explained_variance_ratio": (variance[:num_betas] / variance.sum()).tolist(),
        "weight_smoothing_steps": _WEIGHT_SMOOTHING_STEPS,
    }
    as_tensor = functools.partial(torch.as_tensor, dtype=torch.float64)
    return MeshTemplate(
        v_template=as_tensor(v_template),
        faces=torch.as_tensor(faces, dtype=torch.int64),
        weights=as_tensor(weights),
        joint_regressor=as_tensor(regressor),
        shapedirs=as_tensor(shapedirs),
        fingertip_ids=fingertip_ids,
        name="open-template",
        source=TemplateSource(**{key: as_tensor(value) for key, value in source.items()}),
        info=info,
    )


def evaluate_template(
    template: MeshTemplate, num_subjects: int = 20, seed: int = 0, progress: bool = False
) -> TemplateFitReport:
    """Fit ``num_subjects`` held-out subjects (drawn from ``seed + 1_000_003``, disjoint from the
    build's stream) with :meth:`MeshTemplate.fit_betas` and measure the errors (millimetres)."""
    if not isinstance(num_subjects, int) or num_subjects < 1:
        raise ValueError(f"num_subjects must be a positive int, got {num_subjects!r}")
    if template.source is None:
        raise ValueError("evaluate_template needs an open template with correspondence data")
    template = template.to("cpu", torch.float64)
    source = _source_numpy(template.source)
    weights = template.weights.numpy()
    recon, v2s, joint, joint_reg, tip, seconds = [], [], [], [], [], []
    for hand in _progress(_subjects(seed + _HELD_OUT_SEED_OFFSET, num_subjects), progress,
                          "held-out subjects"):  # fmt: skip
        begin = time.perf_counter()
        betas = template.fit_betas(hand)
        seconds.append(time.perf_counter() - begin)
        exact = _correspond(source, weights, hand, _PROJECTION_ITERATIONS)
        fitted = template.rest_vertices(betas)[0]
        recon.append(np.linalg.norm(fitted.numpy() - exact, axis=1).mean())
        with torch.no_grad():
            sdf = hand.posed(dtype=torch.float64).sdf(fitted).abs().numpy()
        v2s.append(sdf)
        true_joints = hand.template.skeleton.joints.numpy()
        joint.append(np.linalg.norm(template.rest_joints(betas)[0].numpy() - true_joints, axis=1))
        joint_reg.append(
            np.linalg.norm(template.joint_regressor.numpy() @ exact - true_joints, axis=1)
        )
        tips = fitted.numpy()[list(template.fingertip_ids)]
        tip.append(np.linalg.norm(tips - hand.template.skeleton.fingertips.numpy(), axis=1))
    v2s_all = np.concatenate(v2s)
    return TemplateFitReport(
        num_subjects=num_subjects,
        reconstruction_mm=float(np.mean(recon) * 1e3),
        v2s_mm=float(v2s_all.mean() * 1e3),
        v2s_p95_mm=float(np.percentile(v2s_all, 95) * 1e3),
        joint_mm=float(np.mean(joint) * 1e3),
        joint_regressor_mm=float(np.mean(joint_reg) * 1e3),
        fingertip_mm=float(np.mean(tip) * 1e3),
        fit_seconds=float(np.mean(seconds)),
    )


# ----------------------------------------------------------------------------------------------
# Command line


def main(argv: list[str] | None = None) -> int:
    """``python -m lisa_hand.handmodel.template --out lisa_hand/assets/template.npz``."""
    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.handmodel.template",
        description="Build the open hand's MANO-like mesh template and report its fit errors.",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_TEMPLATE_PATH, help="output .npz")
    parser.add_argument("--subjects", type=int, default=200, help="subjects of the shape space")
    parser.add_argument("--seed", type=int, default=0, help="seed of the subjects")
    parser.add_argument("--vertices", type=int, default=800, help="mesh vertices")
    parser.add_argument("--betas", type=int, default=10, help="shape components")
    parser.add_argument("--held-out", type=int, default=20, help="held-out subjects to evaluate")
    args = parser.parse_args(argv)
    try:
        start = time.perf_counter()
        template = build_template(args.subjects, args.vertices, args.betas, args.seed)
        built = time.perf_counter() - start
        report = evaluate_template(template, args.held_out, args.seed) if args.held_out else None
        info = dict(template.info)
        if report is not None:  # timings left out: the file is a deterministic function of args
            info["held_out"] = {key: value for key, value in dataclasses.asdict(report).items()
                                if key != "fit_seconds"}  # fmt: skip
        template = dataclasses.replace(template, info=info)
        save_template(template, args.out)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    ratios = template.info["explained_variance_ratio"]
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB): "
          f"{template.num_vertices} vertices, {template.faces.shape[0]} faces, "
          f"{template.num_betas} betas, built in {built:.1f} s")  # fmt: skip
    print(f"explained variance: {sum(ratios):.4f} "
          f"({', '.join(f'{r:.3f}' for r in ratios)})")  # fmt: skip
    if report is not None:
        for name, value in dataclasses.asdict(report).items():
            print(f"  {name}: {value:.4g}" if isinstance(value, float) else f"  {name}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
