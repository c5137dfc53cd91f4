"""A MANO-like mesh template of the open hand model: the role MANO plays in the LISA paper.

MANO (Romero et al. 2017) gives LISA a low-resolution hand mesh of fixed topology with linear
blend skinning weights, a joint regressor and a linear shape space. LISA uses it for the
skeleton it is conditioned on, for the pseudo ground truth of its skinning loss (paper Eq. 15:
the weights of the nearest posed MANO vertex) and as the "MANO" baseline. The open hand
(:mod:`lisa_hand.handmodel`) gives the same kind of model, so that everything runs without
MANO's licensed file; with the real file,
:func:`lisa_hand.handmodel.template_mano.template_from_mano` puts MANO in the same role.

This module holds the template itself (:class:`MeshTemplate`: shaping, posing, skinning weights
at points, fitting an open-hand subject's betas) and its file (:func:`save_template`,
:func:`load_template`; the shipped ``lisa_hand/assets/template.npz``). How that file is built:
:mod:`lisa_hand.handmodel.template_build`; rebuilding it:
``python -m lisa_hand.handmodel.build_template_asset``.

A left hand is the mirror image of the right one: its betas are those of its right twin
(:meth:`MeshTemplate.fit_betas` accepts either side) and its joints and vertices the mirrored
ones (``lisa_hand.skeleton.mirror_points``), as for MANO's left model.

Units: metres; axes: MANO's right hand (fingers along -x, palm facing -y, thumb on +z).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..skeleton.kinematics import check_pose, forward_kinematics, linear_blend_skinning
from ..skeleton.tree import NUM_JOINTS, joints_to_keypoints
from ..utils.io import atomic_path
from .template_correspondence import PROJECTION_ITERATIONS, correspond, project_betas

if TYPE_CHECKING:
    from .hand import OpenHand

__all__ = [
    "MeshTemplate",
    "TemplateOutput",
    "TemplateSource",
    "DEFAULT_TEMPLATE_PATH",
    "load_template",
    "save_template",
]

DEFAULT_TEMPLATE_PATH = Path(__file__).resolve().parent.parent / "assets" / "template.npz"
"""The shipped open template (rebuild:
``python -m lisa_hand.handmodel.build_template_asset --out ...``)."""

_FORMAT_VERSION = 1
_SOURCE_KEYS = ("vertices", "joints", "bone_ends", "radii", "dorsal", "lateral")
_REBUILD_COMMAND = "python -m lisa_hand.handmodel.build_template_asset"


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

    def arrays(self) -> dict[str, np.ndarray]:
        """The fields as float64 CPU numpy arrays keyed by field name (they share memory with
        float64 CPU tensors: read them, do not modify them)."""
        return {key: getattr(self, key).detach().double().cpu().numpy() for key in _SOURCE_KEYS}

    def clone(self) -> TemplateSource:
        """A copy with new tensors."""
        return TemplateSource(**{key: getattr(self, key).clone() for key in _SOURCE_KEYS})


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

    def clone(self) -> MeshTemplate:
        """A copy with new tensors and a new ``info`` dict (safe to modify in place)."""
        return dataclasses.replace(
            self,
            v_template=self.v_template.clone(),
            faces=self.faces.clone(),
            weights=self.weights.clone(),
            joint_regressor=self.joint_regressor.clone(),
            shapedirs=self.shapedirs.clone(),
            source=None if self.source is None else self.source.clone(),
            info=copy.deepcopy(self.info),
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

    def fit_betas(self, hand: OpenHand, iterations: int = PROJECTION_ITERATIONS) -> torch.Tensor:
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
        source = self.source.arrays()
        weights = self.weights.detach().double().cpu().numpy()
        corresponded = correspond(source, weights, hand, iterations)
        return project_betas(
            corresponded,
            self.v_template.detach().double().cpu().numpy(),
            self.shapedirs.detach().double().cpu().numpy(),
        )



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
def _read_default() -> MeshTemplate:
    """The shipped template, read once; only :func:`load_template` sees it (and copies it)."""
    return _read_template(DEFAULT_TEMPLATE_PATH)


def load_template(path: str | os.PathLike | None = None) -> MeshTemplate:
    """Read a template written by :func:`save_template` (float64, CPU).

    path: an ``.npz`` file; None = the shipped open template (read from disk once; every call
        returns its own copy, so modifying one in place changes no other caller's).
    Raises FileNotFoundError for a missing file and ValueError (naming the file) for a corrupt
    one or one in another layout.
    """
    if path is None:
        return _read_default().clone()
    return _read_template(Path(path))


def _read_template(path: Path) -> MeshTemplate:
    if not path.is_file():
        hint = (
            f" (rebuild it: {_REBUILD_COMMAND} --out {path})"
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
