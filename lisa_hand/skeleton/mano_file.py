"""Reading the official MANO_RIGHT.pkl / MANO_LEFT.pkl without chumpy (:func:`load_mano_pkl`).

The official model files (MANO v1.2, Romero et al., SIGGRAPH Asia 2017) are Python-2 pickles. Most
arrays are plain NumPy arrays, ``J_regressor`` is a ``scipy.sparse`` CSC matrix and ``shapedirs`` is
a ``chumpy.ch.Ch`` object. :func:`load_mano_pkl` reads them with a restricted unpickler: chumpy and
scipy.sparse classes are replaced by inert stand-ins that only keep their pickled state (chumpy is
never imported and need not be installed), and any other global a MANO file never contains is
refused, so loading a file never runs code from it. Posing the result is :mod:`.mano`.
"""

from __future__ import annotations

import functools
import os
import pickle
import types
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .kinematics import check_side
from .tree import NUM_JOINTS, PARENTS

__all__ = ["NUM_MANO_VERTICES", "POSE_FEATURE_DIM", "ManoData", "load_mano_pkl"]

NUM_MANO_VERTICES = 778
POSE_FEATURE_DIM = 9 * (NUM_JOINTS - 1)  # 135: vec(R_j - I) over the 15 finger joints
_MAX_SPARSE_ELEMENTS = 10_000_000  # a densified sparse matrix (MANO's J_regressor: 16 x 778)

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
def _allowed_globals() -> Mapping[tuple[str, str], object]:
    """The globals a MANO pickle may name: NumPy's array reconstructors (old and new module
    names), ``copyreg._reconstructor``, ``_codecs.encode`` and a few inert builtins. Built once;
    a read-only mapping, so that no caller can widen the allow-list for the next one."""
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
    return types.MappingProxyType(table)


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


def _sparse_to_dense(obj: _SparseStub, path: Path, key: str,
                     expected: tuple | None = None) -> np.ndarray:
    """Densify a pickled scipy.sparse CSC, CSR or COO matrix from its state, with NumPy only.

    expected: the shape the key must have (None entries: any); the claimed shape is checked
    against it and against a hard cap before anything is allocated, and every index against
    the shape (a hostile file can claim any shape and any index)."""
    state = obj.stub_state
    shape = state.get("_shape", state.get("shape"))
    try:
        rows, cols = (int(size) for size in shape)
        if rows < 0 or cols < 0 or (expected is not None and any(
                want is not None and have != want
                for have, want in zip((rows, cols), expected, strict=True))):
            raise ValueError(f"claims shape {(rows, cols)}, expected "
                             f"{tuple('*' if w is None else w for w in expected or ())}")
        if rows * cols > _MAX_SPARSE_ELEMENTS:
            raise ValueError(f"claims shape {(rows, cols)}, over {_MAX_SPARSE_ELEMENTS} entries")
        data = np.asarray(state["data"], dtype=np.float64).ravel()
        fmt = str(state.get("format", obj.pickled_name.rsplit(".", 1)[-1][:3]))
        if fmt in ("csc", "csr"):
            indices = np.asarray(state["indices"], dtype=np.int64).ravel()
            indptr = np.asarray(state["indptr"], dtype=np.int64).ravel()
            if (len(indptr) != (cols if fmt == "csc" else rows) + 1 or indptr[0] != 0
                    or (np.diff(indptr) < 0).any() or indptr[-1] != len(indices)):
                raise ValueError("indptr does not match the shape and indices")
            major = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
            row_idx, col_idx = (indices, major) if fmt == "csc" else (major, indices)
        elif fmt == "coo":
            coords = state.get("coords", (state.get("row"), state.get("col")))
            row_idx, col_idx = (np.asarray(c, dtype=np.int64).ravel() for c in coords)
        else:
            raise ValueError(f"unsupported sparse format {fmt!r}")
        if not len(row_idx) == len(col_idx) == len(data):
            raise ValueError("data and indices differ in length")
        if len(data) and (row_idx.min() < 0 or row_idx.max() >= rows or col_idx.min() < 0
                          or col_idx.max() >= cols):
            raise ValueError(f"an index is outside the shape {(rows, cols)}")
        dense = np.zeros((rows, cols), dtype=np.float64)
        np.add.at(dense, (row_idx, col_idx), data)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ValueError(
            f"{path}: key {key!r} is a scipy.sparse matrix ({obj.pickled_name}) that cannot be "
            f"read ({type(exc).__name__}: {exc})"
        ) from None
    return dense


def _to_array(value, path: Path, key: str, depth: int = 0,
              expected: tuple | None = None) -> np.ndarray:
    """The array a pickled value holds; ``expected``: the shape a sparse matrix must claim."""
    if isinstance(value, _SparseStub):
        return _sparse_to_dense(value, path, key, expected)
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
    array = _to_array(raw[key], path, key, expected=shape if len(shape) == 2 else None)
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
    side = _resolve_side(path, side)
    raw = _read_model_dict(path)
    template, shape_dirs, pose_dirs, regressor, weights, components, hands_mean = (
        _model_arrays(raw, path))
    faces = _model_topology(raw, path)
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
        faces=faces,
        hands_components=components,
        hands_mean=hands_mean,
    )


def _resolve_side(path: Path, side: str | None) -> str:
    """The hand side: ``side``, or the one the file name says (they must agree)."""
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

    return side


def _read_model_dict(path: Path) -> dict:
    """The unpickled dict of a MANO file, its required keys and blend-skinning style checked."""
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

    return raw


def _model_arrays(raw: dict, path: Path) -> tuple[np.ndarray, ...]:
    """(template [V, 3], shapedirs [V, 3, S], posedirs [V, 3, 135], J_regressor [16, V],
    weights [V, 16], hands_components [45, 45], hands_mean [45]) as float64 arrays."""
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

    return template, shape_dirs, pose_dirs, regressor, weights, components, hands_mean


def _model_topology(raw: dict, path: Path) -> np.ndarray:
    """The faces [F, 3] (int64), after checking them and that the kinematic tree is MANO's."""
    num_v = NUM_MANO_VERTICES
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

    return faces.astype(np.int64)
