"""MANO interop: read the official MANO_RIGHT.pkl / MANO_LEFT.pkl without chumpy, and pose them.

The official model files (MANO v1.2, Romero et al., SIGGRAPH Asia 2017) are Python-2 pickles. Most
arrays are plain NumPy arrays, ``J_regressor`` is a ``scipy.sparse`` CSC matrix and ``shapedirs`` is
a ``chumpy.ch.Ch`` object. :func:`load_mano_pkl` reads them with a restricted unpickler: chumpy and
scipy.sparse classes are replaced by inert stand-ins that only keep their pickled state (chumpy is
never imported and need not be installed), and any other global a MANO file never contains is
refused, so loading a file never runs code from it.

The maths follows smplx's MANO exactly (Loper et al. SMPL, Eq. 1-4; MANO, Sec. 3):

* shaped template ``T(beta) = T_bar + S beta`` (``shapedirs``),
* rest joints ``J(beta) = J_regressor T(beta)``,
* pose corrective ``P(theta) = posedirs . vec(R_j(theta) - I)`` over the 15 finger joints (135-D),
* forward kinematics and linear blend skinning of ``T(beta) + P(theta)``, then the translation.

The layer works in the units of the file (metres for the official files).
"""

from __future__ import annotations

import functools
import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .kinematics import check_side, forward_kinematics, linear_blend_skinning
from .tree import MANO_FINGERTIP_VERTEX_IDS, NUM_JOINTS, PARENTS, POSE_DIM, joints_to_keypoints

__all__ = [
    "NUM_MANO_VERTICES",
    "NUM_HAND_POSE",
    "POSE_FEATURE_DIM",
    "ManoData",
    "ManoOutput",
    "ManoLayer",
    "load_mano_pkl",
    "mano_full_pose",
    "mano_pose_features",
    "mano_forward",
]

NUM_MANO_VERTICES = 778
NUM_HAND_POSE = POSE_DIM - 3  # 45: the 15 finger joints' axis-angles
POSE_FEATURE_DIM = 9 * (NUM_JOINTS - 1)  # 135: vec(R_j - I) over the 15 finger joints

_REQUIRED_KEYS = (
    "v_template",
    "weights",
    "J_regressor",
    "shapedirs",
    "posedirs",
    "f",
    "kintree_table",
    "hands_components",
    "hands_mean",
)


# --------------------------------------------------------------------------------------------------
# Restricted unpickling


class _ChumpyStub:
    """Inert stand-in for a pickled chumpy object: keeps the pickled state, runs no chumpy code."""

    pickled_name = "chumpy"  # the stubbed global, e.g. "chumpy.ch.Ch" (set per stub class)
    stub_state: dict = {}  # replaced (never mutated) by __setstate__

    def __new__(cls, *args, **kwargs):
        return object.__new__(cls)

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        object.__setattr__(self, "stub_state", _state_dict(state))


class _SparseStub(_ChumpyStub):
    """Inert stand-in for a pickled ``scipy.sparse`` matrix (read back with NumPy only)."""


def _state_dict(state) -> dict:
    """A pickled object's state as one dict (``(dict_state, slot_state)`` pairs are merged)."""
    if isinstance(state, dict):
        return state
    if isinstance(state, tuple) and len(state) == 2:
        merged = {}
        for part in state:
            if isinstance(part, dict):
                merged.update(part)
        return merged
    return {"state": state}


@functools.lru_cache(maxsize=1)
def _allowed_globals() -> dict[tuple[str, str], object]:
    """The globals a MANO pickle may name: NumPy's array reconstructors (old and new module
    names), ``copyreg._reconstructor``, ``_codecs.encode`` and a few inert builtins."""
    import builtins
    import collections
    import copyreg

    reconstruct = np.empty(0).__reduce__()[0]
    scalar = np.float64(0.0).__reduce__()[0]
    frombuffer = np.empty(0).__reduce_ex__(5)[0]
    table: dict[tuple[str, str], object] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
    }
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = reconstruct
        table[(f"{core}.multiarray", "scalar")] = scalar
        table[(f"{core}.numeric", "_frombuffer")] = frombuffer
    table[("copyreg", "_reconstructor")] = copyreg._reconstructor
    table[("_codecs", "encode")] = _latin1_encode
    table[("collections", "OrderedDict")] = collections.OrderedDict
    for builtin in ("object", "set", "frozenset", "slice", "complex", "bytearray"):
        table[("builtins", builtin)] = getattr(builtins, builtin)
    return table


_PY2_MODULES = {"__builtin__": "builtins", "copy_reg": "copyreg"}  # Python 2 names -> Python 3


class _ManoUnpickler(pickle.Unpickler):
    """Unpickler that allows only what a MANO model file holds (see the module docstring)."""

    _stub_classes: dict[str, type] = {}

    def find_class(self, module: str, name: str):
        module = _PY2_MODULES.get(module, module)
        allowed = _allowed_globals()
        if (module, name) in allowed:
            return allowed[(module, name)]
        if module == "chumpy" or module.startswith("chumpy."):
            return self._stub(f"{module}.{name}", _ChumpyStub)
        if module.startswith("scipy.sparse"):
            return self._stub(f"{module}.{name}", _SparseStub)
        raise pickle.UnpicklingError(
            f"the pickle refers to {module}.{name}, which a MANO model file never contains"
        )

    @classmethod
    def _stub(cls, full_name: str, base: type) -> type:
        if full_name not in cls._stub_classes:
            stub = type(base.__name__, (base,), {"pickled_name": full_name})
            cls._stub_classes[full_name] = stub
        return cls._stub_classes[full_name]


def _latin1_encode(text, encoding: str = "latin1", errors: str = "strict") -> bytes:
    """``_codecs.encode`` as Python 3 writes bytes in protocol-2 pickles (text codecs only)."""
    if not isinstance(text, str):
        raise pickle.UnpicklingError("_codecs.encode expects a str in a MANO pickle")
    return text.encode(encoding, errors)


def _unpickle(path: Path):
    try:
        with path.open("rb") as handle:
            return _ManoUnpickler(handle, encoding="latin1").load()
    except OSError:
        raise
    except Exception as exc:  # a corrupt or hostile pickle can raise almost anything
        detail = str(exc) or type(exc).__name__
        raise ValueError(
            f"{path}: not a readable MANO model pickle ({type(exc).__name__}: {detail})"
        ) from None


# --------------------------------------------------------------------------------------------------
# From pickled objects to arrays


def _evaluate_chumpy(obj: _ChumpyStub, path: Path, key: str, depth: int = 0) -> np.ndarray:
    """Recover the array a pickled chumpy object holds (plain ``Ch`` and simple reorderings)."""
    if depth > 32:
        raise ValueError(f"{path}: key {key!r} is a chumpy expression nested too deeply")
    name = obj.pickled_name
    kind = name.rsplit(".", 1)[-1]
    state = obj.stub_state

    def inner(attr: str) -> np.ndarray:
        return _to_array(state[attr], path, key, depth + 1)

    if "a" not in state and "x" in state:  # chumpy.ch.Ch: the value is the term ``x``
        return inner("x")
    if kind == "Reshape" and "a" in state and "newshape" in state:
        return inner("a").reshape(state["newshape"])
    if kind == "Select" and "a" in state and "idxs" in state:
        picked = inner("a").ravel()[np.asarray(state["idxs"], dtype=np.int64)]
        shape = state.get("preferred_shape")
        return picked.reshape(shape) if shape is not None else picked
    if kind == "transpose" and "a" in state:
        return np.transpose(inner("a"), axes=state.get("axes"))
    raise ValueError(
        f"{path}: key {key!r} is a chumpy object {name} whose value cannot be recovered without "
        "chumpy (only chumpy.ch.Ch arrays and Reshape/Select/transpose of them are supported)"
    )


def _sparse_to_dense(obj: _SparseStub, path: Path, key: str) -> np.ndarray:
    """Densify a pickled scipy.sparse CSC, CSR or COO matrix from its state, with NumPy only."""
    state = obj.stub_state
    shape = state.get("_shape", state.get("shape"))
    try:
        rows, cols = (int(size) for size in shape)
        data = np.asarray(state["data"], dtype=np.float64).ravel()
        dense = np.zeros((rows, cols), dtype=np.float64)
        fmt = str(state.get("format", obj.pickled_name.rsplit(".", 1)[-1][:3]))
        if fmt in ("csc", "csr"):
            indices = np.asarray(state["indices"], dtype=np.int64)
            indptr = np.asarray(state["indptr"], dtype=np.int64)
            major = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
            row_idx, col_idx = (indices, major) if fmt == "csc" else (major, indices)
        elif fmt == "coo":
            coords = state.get("coords", (state.get("row"), state.get("col")))
            row_idx, col_idx = (np.asarray(c, dtype=np.int64) for c in coords)
        else:
            raise ValueError(f"unsupported sparse format {fmt!r}")
        np.add.at(dense, (row_idx, col_idx), data)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ValueError(
            f"{path}: key {key!r} is a scipy.sparse matrix ({obj.pickled_name}) that cannot be "
            f"read ({type(exc).__name__}: {exc})"
        ) from None
    return dense


def _to_array(value, path: Path, key: str, depth: int = 0) -> np.ndarray:
    if isinstance(value, _SparseStub):
        return _sparse_to_dense(value, path, key)
    if isinstance(value, _ChumpyStub):
        return _evaluate_chumpy(value, path, key, depth)
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: key {key!r} is not an array ({exc})") from None
    if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise ValueError(
            f"{path}: key {key!r} is not a numeric array (got {type(value).__name__} of "
            f"dtype {array.dtype})"
        )
    return array


def _float_array(raw: dict, key: str, shape: tuple, path: Path, shape_text: str) -> np.ndarray:
    array = _to_array(raw[key], path, key)
    if array.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(array.shape, shape, strict=False)
    ):
        raise ValueError(f"{path}: key {key!r} must have shape {shape_text}, got {array.shape}")
    array = array.astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f"{path}: key {key!r} contains NaN or inf values")
    return array


def _side_from_name(path: Path) -> str | None:
    stem = path.stem.upper()
    is_left, is_right = "LEFT" in stem, "RIGHT" in stem
    if is_left != is_right:
        return "left" if is_left else "right"
    return None


# --------------------------------------------------------------------------------------------------
# Loader


@dataclass(frozen=True, eq=False)
class ManoData:
    """The arrays of a MANO model file, validated, as float64 / int64 NumPy arrays.

    MANO's arrays are licensed: keep them out of anything this package writes or redistributes.
    """

    path: Path
    """The file the model was read from."""
    side: str
    """'right' or 'left'."""
    template_vertices: np.ndarray
    """[778, 3] rest-pose mean-shape vertices, metres (``v_template``)."""
    shape_dirs: np.ndarray
    """[778, 3, S] shape blend shapes per unit beta, metres (``shapedirs``; S = 10 in MANO)."""
    pose_dirs: np.ndarray
    """[778, 3, 135] pose blend shapes per unit of ``vec(R_j - I)`` (``posedirs``)."""
    joint_regressor: np.ndarray
    """[16, 778] dense joint regressor, rows summing to 1 (``J_regressor``)."""
    skinning_weights: np.ndarray
    """[778, 16] LBS weights, rows summing to 1 (``weights``)."""
    faces: np.ndarray
    """[F, 3] int64 triangle vertex indices (``f``; F = 1538 in MANO)."""
    hands_components: np.ndarray
    """[45, 45] PCA basis of the finger pose, one component a row (``hands_components``)."""
    hands_mean: np.ndarray
    """[45] mean finger pose, axis-angle radians (``hands_mean``)."""

    @property
    def num_betas(self) -> int:
        """Number of shape coefficients (10 in MANO)."""
        return int(self.shape_dirs.shape[-1])


def load_mano_pkl(
    path: str | os.PathLike,
    side: str | None = None,
    *,
    fix_left_shapedirs: bool = False,
) -> ManoData:
    """Read an official MANO model pickle (v1.2 layout) without chumpy.

    path: ``MANO_RIGHT.pkl`` or ``MANO_LEFT.pkl`` (or any file in that layout).
    side: 'right' or 'left'; None to read it from the file name (which must then contain exactly
        one of 'right'/'left', any case). An explicit side that contradicts the name is an error.
    fix_left_shapedirs: known quirk of the official ``MANO_LEFT.pkl``: the x components of its
        shape directions (``shapedirs[:, 0, :]``, every beta) carry the right hand's sign instead of
        the mirrored one, so one ``betas`` gives a left hand that is not the mirror of the right
        hand (smplx issue #48). True negates ``shapedirs[:, 0, :]`` of a left model; it has no
        effect on a right model. Default False: exactly what the file says (as smplx and manopth).

    Raises FileNotFoundError for a missing file, ValueError (naming the file and the problem) for a
    file that is not a readable pickle or not in MANO's layout.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such MANO model file (MANO_RIGHT.pkl / MANO_LEFT.pkl come from "
            "https://mano.is.tue.mpg.de)"
        )
    named_side = _side_from_name(path)
    if side is None:
        if named_side is None:
            raise ValueError(
                f"{path}: cannot tell the hand side from the file name; pass side='right' or "
                "side='left'"
            )
        side = named_side
    check_side(side)
    if named_side is not None and named_side != side:
        raise ValueError(f"{path}: side={side!r} contradicts the file name ({named_side} hand)")

    raw = _unpickle(path)
    if not isinstance(raw, dict):
        raise ValueError(
            f"{path}: not a MANO model (expected a dict of arrays, got {type(raw).__name__})"
        )
    missing = [key for key in _REQUIRED_KEYS if key not in raw]
    if missing:
        raise ValueError(f"{path}: not a MANO model, missing key(s) {', '.join(missing)}")

    for key, expected in (("bs_style", "lbs"), ("bs_type", "lrotmin")):  # informational keys
        value = raw.get(key, expected)
        value = value.decode("latin1") if isinstance(value, bytes) else value
        if isinstance(value, str) and value != expected:
            raise ValueError(
                f"{path}: {key}={value!r} is not supported (MANO uses {key}={expected!r})"
            )

    num_v = NUM_MANO_VERTICES
    template = _float_array(raw, "v_template", (num_v, 3), path, f"[{num_v}, 3]")
    shape_dirs = _float_array(raw, "shapedirs", (num_v, 3, None), path, f"[{num_v}, 3, S]")
    pose_dirs = _float_array(
        raw, "posedirs", (num_v, 3, POSE_FEATURE_DIM), path, f"[{num_v}, 3, {POSE_FEATURE_DIM}]"
    )
    regressor = _float_array(raw, "J_regressor", (NUM_JOINTS, num_v), path, f"[16, {num_v}]")
    weights = _float_array(raw, "weights", (num_v, NUM_JOINTS), path, f"[{num_v}, 16]")
    components = _float_array(raw, "hands_components", (45, 45), path, "[45, 45]")
    hands_mean = _float_array(raw, "hands_mean", (45,), path, "[45]")
    if shape_dirs.shape[-1] < 1:
        raise ValueError(f"{path}: key 'shapedirs' has no shape directions")

    faces = _to_array(raw["f"], path, "f")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 1:
        raise ValueError(f"{path}: key 'f' must have shape [F, 3], got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer) or faces.min() < 0 or faces.max() >= num_v:
        raise ValueError(f"{path}: key 'f' must hold integer vertex indices in [0, {num_v})")
    kintree = _to_array(raw["kintree_table"], path, "kintree_table")
    if kintree.shape != (2, NUM_JOINTS):
        raise ValueError(
            f"{path}: key 'kintree_table' must have shape [2, 16], got {kintree.shape}"
        )
    # The root's parent is stored as -1 or as 2**32 - 1 (an unsigned -1); only MANO's tree is valid.
    parents = [int(p) if 0 <= int(p) < NUM_JOINTS else -1 for p in kintree[0]]
    if list(kintree[1]) != list(range(NUM_JOINTS)) or tuple(parents) != PARENTS:
        raise ValueError(
            f"{path}: key 'kintree_table' is not MANO's kinematic tree (parents {parents}, "
            f"expected {list(PARENTS)})"
        )

    if fix_left_shapedirs and side == "left":
        shape_dirs = shape_dirs.copy()
        shape_dirs[:, 0, :] *= -1.0
    return ManoData(
        path=path,
        side=side,
        template_vertices=template,
        shape_dirs=shape_dirs,
        pose_dirs=pose_dirs,
        joint_regressor=regressor,
        skinning_weights=weights,
        faces=faces.astype(np.int64),
        hands_components=components,
        hands_mean=hands_mean,
    )


# --------------------------------------------------------------------------------------------------
# Plain functions


@dataclass
class ManoOutput:
    """Result of :func:`mano_forward` / :class:`ManoLayer` (world frame, units of the file: metres).

    vertices: [B, 778, 3] posed vertices, translation included.
    joints: [B, 16, 3] posed joints in MANO order (wrist, index, middle, pinky, ring, thumb).
    keypoints: [B, 21, 3] the 16 joints plus the fingertip vertices
        (:data:`MANO_FINGERTIP_VERTEX_IDS`) in the OpenPose/MediaPipe order of
        :func:`joints_to_keypoints`.
    transforms: [B, 16, 4, 4] rest-to-posed bone transforms ``A_j`` (translation included).
    full_pose: [B, 48] axis-angle radians actually applied: global orientation plus the finger
        pose after PCA and the mean hand (smplx's ``full_pose``).
    bone_frames: [B, 16, 4, 4] world-from-bone frames (:attr:`Kinematics.bone_frames`).
    rest_joints: [B, 16, 3] joints of the shaped template in the rest pose (``J(beta)``).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    keypoints: torch.Tensor
    transforms: torch.Tensor
    full_pose: torch.Tensor
    bone_frames: torch.Tensor
    rest_joints: torch.Tensor


def mano_full_pose(
    global_orient: torch.Tensor,
    hand_pose: torch.Tensor,
    hand_mean: torch.Tensor,
    hand_components: torch.Tensor | None = None,
) -> torch.Tensor:
    """smplx's MANO pose: ``cat(global_orient, hand_pose @ components (PCA) + hand_mean)``.

    global_orient: [B, 3] axis-angle radians.
    hand_pose: [B, 45] axis-angle radians, or [B, n] PCA coefficients when ``hand_components``.
    hand_mean: [45] radians (zeros for a flat hand).
    hand_components: [n, 45] the first n rows of ``hands_components``, or None.
    -> [B, 48]
    """
    if hand_components is not None:
        hand_pose = hand_pose @ hand_components
    return torch.cat([global_orient, hand_pose + hand_mean], dim=-1)


def mano_pose_features(rotmats: torch.Tensor) -> torch.Tensor:
    """MANO's pose-corrective feature ``vec(R_j - I)`` over the 15 finger joints.

    rotmats: [B, 16, 3, 3] relative joint rotations -> [B, 135] (joint-major, then row, column)
    """
    eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
    return (rotmats[:, 1:] - eye).reshape(rotmats.shape[0], POSE_FEATURE_DIM)


def mano_forward(
    full_pose: torch.Tensor,
    betas: torch.Tensor,
    translation: torch.Tensor | None,
    *,
    template_vertices: torch.Tensor,
    shape_dirs: torch.Tensor,
    pose_dirs: torch.Tensor,
    joint_template: torch.Tensor,
    joint_shape_dirs: torch.Tensor,
    skinning_weights: torch.Tensor,
    fingertip_vertex_ids: torch.Tensor,
) -> ManoOutput:
    """Shape, pose-correct, pose and skin MANO (SMPL Eq. 1-4 with MANO's tree).

    full_pose: [B, 48] axis-angle radians (global orientation + 15 finger joints).
    betas: [B, S] shape coefficients.
    translation: [B, 3] metres, or None.
    template_vertices: [V, 3] metres. shape_dirs: [V, 3, S]. pose_dirs: [135, V * 3] (the file's
        ``posedirs`` reshaped to [V * 3, 135] and transposed).
    joint_template: [16, 3] ``J_regressor @ template_vertices``.
    joint_shape_dirs: [16, 3, S] ``J_regressor`` applied to each shape direction, so that the
        rest joints ``J_regressor @ T(beta)`` cost 16 rows instead of 778.
    skinning_weights: [V, 16]. fingertip_vertex_ids: [5] long (thumb, index, middle, ring, pinky).
    """
    batch = full_pose.shape[0]
    shaped = template_vertices + torch.einsum("bs,vcs->bvc", betas, shape_dirs)
    rest_joints = joint_template + torch.einsum("bs,jcs->bjc", betas, joint_shape_dirs)
    kinematics = forward_kinematics(full_pose, rest_joints, translation)
    offsets = (mano_pose_features(kinematics.rotmats) @ pose_dirs).reshape(batch, -1, 3)
    vertices = linear_blend_skinning(shaped + offsets, skinning_weights, kinematics.transforms)
    fingertips = vertices.index_select(1, fingertip_vertex_ids)
    return ManoOutput(
        vertices=vertices,
        joints=kinematics.joints,
        keypoints=joints_to_keypoints(kinematics.joints, fingertips),
        transforms=kinematics.transforms,
        full_pose=full_pose,
        bone_frames=kinematics.bone_frames,
        rest_joints=rest_joints,
    )


# --------------------------------------------------------------------------------------------------
# Layer


class ManoLayer(nn.Module):
    """MANO as an ``nn.Module`` holding only buffers; the maths is :func:`mano_forward`.

    Semantics match ``smplx.MANO``: ``hand_pose`` is the 45-D finger pose, or ``num_pca_comps``
    coefficients of ``hands_components`` when ``use_pca``; unless ``flat_hand_mean`` the file's
    ``hands_mean`` is added to the finger pose (after PCA), so a zero pose is MANO's mean hand.
    Defaults differ from smplx in one place: ``use_pca=False``.

    Left hands: the official ``MANO_LEFT.pkl`` has a shape-direction quirk (see
    :func:`load_mano_pkl`, ``fix_left_shapedirs``); by default the file is used as it is.

    The buffers are not part of ``state_dict`` (``persistent=False``): MANO's licensed arrays never
    end up in a checkpoint. Move the layer with ``.to(device)``; inputs must be on its device and
    of its dtype.
    """

    def __init__(
        self,
        model: str | os.PathLike | ManoData,
        side: str | None = None,
        *,
        use_pca: bool = False,
        num_pca_comps: int = 6,
        flat_hand_mean: bool = False,
        fix_left_shapedirs: bool = False,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        """
        model: path of a MANO ``.pkl`` or an already loaded :class:`ManoData`.
        side: 'right'/'left' (see :func:`load_mano_pkl`); must match ``model.side`` for ManoData.
        use_pca: ``hand_pose`` holds PCA coefficients instead of 45 axis-angle values.
        num_pca_comps: number of PCA components (1 to 45), used only with ``use_pca``.
        flat_hand_mean: a zero finger pose is the flat hand (True) or MANO's mean hand (False).
        fix_left_shapedirs: negate the left model's ``shapedirs[:, 0, :]`` (see the loader).
        dtype: torch.float32 or torch.float64, for the buffers and the computation.
        """
        super().__init__()
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        if isinstance(model, ManoData):
            if side is not None and check_side(side) != model.side:
                raise ValueError(f"side={side!r} but the ManoData is a {model.side} hand")
            if fix_left_shapedirs:
                raise ValueError(
                    "fix_left_shapedirs applies when loading; pass it to load_mano_pkl instead"
                )
            data = model
        else:
            data = load_mano_pkl(model, side, fix_left_shapedirs=fix_left_shapedirs)
        if use_pca and not 1 <= int(num_pca_comps) <= NUM_HAND_POSE:
            raise ValueError(f"num_pca_comps must be in [1, 45], got {num_pca_comps}")

        self.side = data.side
        self.use_pca = bool(use_pca)
        self.num_pca_comps = int(num_pca_comps)
        self.hand_pose_dim = self.num_pca_comps if self.use_pca else NUM_HAND_POSE
        self.flat_hand_mean = bool(flat_hand_mean)
        self.num_betas = data.num_betas

        def buffer(name: str, array: np.ndarray, as_dtype: torch.dtype = dtype) -> None:
            self.register_buffer(name, torch.as_tensor(array).to(as_dtype), persistent=False)

        regressor = data.joint_regressor
        buffer("template_vertices", data.template_vertices)
        buffer("shape_dirs", data.shape_dirs)
        buffer("pose_dirs", data.pose_dirs.reshape(-1, POSE_FEATURE_DIM).T.copy())
        buffer("joint_template", regressor @ data.template_vertices)
        buffer("joint_shape_dirs", np.einsum("jv,vcs->jcs", regressor, data.shape_dirs))
        buffer("skinning_weights", data.skinning_weights)
        buffer("faces", data.faces, torch.long)
        buffer("fingertip_vertex_ids", np.asarray(MANO_FINGERTIP_VERTEX_IDS), torch.long)
        hand_mean = np.zeros(NUM_HAND_POSE) if flat_hand_mean else data.hands_mean
        buffer("hand_mean", hand_mean)
        if self.use_pca:
            buffer("hand_components", data.hands_components[: self.num_pca_comps])
        else:
            self.register_buffer("hand_components", None, persistent=False)

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the buffers and of the computation (follows ``.to(dtype)``)."""
        return self.template_vertices.dtype

    @property
    def device(self) -> torch.device:
        """The device of the buffers; inputs must be on it."""
        return self.template_vertices.device

    def extra_repr(self) -> str:
        pca = (
            f"use_pca=True, num_pca_comps={self.num_pca_comps}" if self.use_pca else "use_pca=False"
        )
        return (
            f"side={self.side!r}, {pca}, flat_hand_mean={self.flat_hand_mean}, "
            f"num_betas={self.num_betas}, dtype={self.dtype}"
        )

    def _check_input(self, value: torch.Tensor | None, name: str, width: int) -> None:
        if value is None:
            return
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        if value.dim() != 2 or value.shape[1] != width:
            raise ValueError(f"{name} must have shape [B, {width}], got {tuple(value.shape)}")
        if value.dtype != self.dtype:
            raise TypeError(
                f"{name} has dtype {value.dtype} but the layer computes in {self.dtype} "
                "(cast the input or convert the layer with .to(dtype))"
            )
        if value.device != self.device:
            raise ValueError(
                f"{name} is on {value.device} but the layer is on {self.device} (move one of them)"
            )
        if not torch.isfinite(value).all():
            raise ValueError(f"{name} contains NaN or inf values")

    def forward(
        self,
        hand_pose: torch.Tensor | None = None,
        global_orient: torch.Tensor | None = None,
        betas: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
    ) -> ManoOutput:
        """Pose the hand; a missing input is zeros (batch size from the others, else 1).

        hand_pose: [B, 45] axis-angle radians, or [B, num_pca_comps] PCA coefficients (use_pca).
        global_orient: [B, 3] axis-angle radians, rotation about the wrist joint.
        betas: [B, num_betas] shape coefficients.
        transl: [B, 3] metres, added last.
        """
        pose_width = self.hand_pose_dim
        inputs = {
            "hand_pose": (hand_pose, pose_width),
            "global_orient": (global_orient, 3),
            "betas": (betas, self.num_betas),
            "transl": (transl, 3),
        }
        batch = None
        for name, (value, width) in inputs.items():
            self._check_input(value, name, width)
            if value is None:
                continue
            if batch is None:
                batch = value.shape[0]
            elif value.shape[0] != batch:
                raise ValueError(f"{name} has batch size {value.shape[0]}, other inputs {batch}")
        batch = 1 if batch is None else batch
        device = self.device

        def zeros(width: int) -> torch.Tensor:
            return torch.zeros(batch, width, dtype=self.dtype, device=device)

        hand_pose = zeros(pose_width) if hand_pose is None else hand_pose
        global_orient = zeros(3) if global_orient is None else global_orient
        betas = zeros(self.num_betas) if betas is None else betas
        full_pose = mano_full_pose(global_orient, hand_pose, self.hand_mean, self.hand_components)
        return mano_forward(
            full_pose,
            betas,
            transl,
            template_vertices=self.template_vertices,
            shape_dirs=self.shape_dirs,
            pose_dirs=self.pose_dirs,
            joint_template=self.joint_template,
            joint_shape_dirs=self.joint_shape_dirs,
            skinning_weights=self.skinning_weights,
            fingertip_vertex_ids=self.fingertip_vertex_ids,
        )
