"""A small random MANO model written in exactly the official ``MANO_*.pkl`` layout (for tests).

The official files are Python-2 protocol-2 pickles: byte strings are BINSTRINGs, arrays refer to
``numpy.core.multiarray._reconstruct``, ``J_regressor`` is a ``scipy.sparse.csc.csc_matrix`` and
``shapedirs`` a ``chumpy.ch.Ch``. :class:`Py2Pickler` writes the same opcodes without chumpy (and
without any fake module in ``sys.modules``): stand-in classes are written under the official
names, so the loader's chumpy/scipy stubs are what reads them back.

The model is random but valid: 778 vertices scattered around plausible hand joints, MANO's tree,
sparse joint-regressor rows summing to 1 over vertices near each joint, skinning-weight rows
summing to 1, small random blend shapes, an orthonormal pose PCA basis and a random mean pose.
"""

from __future__ import annotations

import pickle
import struct
from pathlib import Path

import numpy as np

__all__ = [
    "FakeCh",
    "FakeCscMatrix",
    "Py2Pickler",
    "mirror_arrays",
    "mirror_pose_np",
    "official_layout",
    "synthetic_mano_arrays",
    "write_pickle_py2",
    "write_synthetic_mano",
]

_ROOT_PARENT = 4294967295  # the official files store the root's parent as an unsigned -1
_PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
_MIRROR = np.array([-1.0, 1.0, 1.0])


class FakeCh:
    """Pickled as ``chumpy.ch.Ch`` with the state chumpy's ``Ch.__getstate__`` produces."""

    def __init__(self, x: np.ndarray) -> None:
        self.x = x
        self._dirty_vars = set()
        self._itr = None
        self._make_dense = False
        self._make_sparse = False
        self._depends_on_deps = {}


class FakeCscMatrix:
    """Pickled as ``scipy.sparse.csc.csc_matrix`` with an old scipy's instance dict."""

    def __init__(self, dense: np.ndarray) -> None:
        cols = [np.flatnonzero(dense[:, c]) for c in range(dense.shape[1])]
        self._shape = dense.shape
        self.maxprint = 50
        self.format = "csc"
        self.indices = np.concatenate(cols).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum([len(c) for c in cols])]).astype(np.int32)
        self.data = np.concatenate([dense[idx, c] for c, idx in enumerate(cols)])


_ALIASES = {
    id(np.empty(0).__reduce__()[0]): ("numpy.core.multiarray", "_reconstruct"),
    id(FakeCh): ("chumpy.ch", "Ch"),
    id(FakeCscMatrix): ("scipy.sparse.csc", "csc_matrix"),
}


class Py2Pickler(pickle._Pickler):
    """Protocol-2 pickler that writes byte strings and ASCII str as Python 2's ``str``
    (SHORT_BINSTRING/BINSTRING) and names globals as Python-2-era files do."""

    dispatch = pickle._Pickler.dispatch.copy()

    def __init__(self, file, protocol: int = 2, aliases: dict[type, tuple[str, str]] | None = None):
        """aliases: extra classes to write under another (module, name), e.g. more chumpy ops."""
        super().__init__(file, protocol=protocol)
        self._aliases = dict(_ALIASES)
        self._aliases.update({id(cls): name for cls, name in (aliases or {}).items()})

    def _save_py2_str(self, data: bytes, obj) -> None:
        if len(data) < 256:
            self.write(pickle.SHORT_BINSTRING + bytes([len(data)]) + data)
        else:
            self.write(pickle.BINSTRING + struct.pack("<i", len(data)) + data)
        self.memoize(obj)

    def save_bytes(self, obj: bytes) -> None:
        self._save_py2_str(obj, obj)

    def save_str(self, obj: str) -> None:
        if obj.isascii():
            self._save_py2_str(obj.encode("ascii"), obj)
        else:
            super().save_str(obj)

    def save_global(self, obj, name=None) -> None:
        alias = self._aliases.get(id(obj))
        if alias is None:
            super().save_global(obj, name)
            return
        module, qualname = alias
        self.write(pickle.GLOBAL + f"{module}\n{qualname}\n".encode("ascii"))
        self.memoize(obj)

    dispatch[bytes] = save_bytes
    dispatch[str] = save_str


def mirror_pose_np(pose: np.ndarray) -> np.ndarray:
    """Mirror axis-angles through x = 0: (x, y, z) -> (x, -y, -z). pose: [..., 3k]."""
    shape = pose.shape
    return (pose.reshape(*shape[:-1], -1, 3) * np.array([1.0, -1.0, -1.0])).reshape(shape)


def _rest_joints() -> np.ndarray:
    """Plausible right-hand rest joints in metres (fingers along +x, palm normal -y)."""
    joints = np.zeros((16, 3))
    bases = {1: 0.025, 4: 0.005, 10: -0.015, 7: -0.032}  # index, middle, ring, pinky: z offset
    for base, z in bases.items():
        for level, x in enumerate((0.09, 0.125, 0.148)):
            joints[base + level] = (x, 0.0, z)
    joints[13:16] = [(0.03, -0.01, 0.03), (0.055, -0.015, 0.05), (0.075, -0.02, 0.065)]
    return joints


def synthetic_mano_arrays(seed: int = 0) -> dict[str, np.ndarray]:
    """A random right-hand MANO model as dense float64 arrays (keys as in the official file)."""
    rng = np.random.default_rng(seed)
    num_v = 778
    joints = _rest_joints()
    owner = np.arange(num_v) % 16
    template = joints[owner] + 0.01 * rng.standard_normal((num_v, 3))

    regressor = np.zeros((16, num_v))
    for j in range(16):
        chosen = rng.choice(np.flatnonzero(owner == j), size=8, replace=False)
        values = rng.uniform(0.2, 1.0, size=8)
        regressor[j, chosen] = values / values.sum()

    weights = 0.05 * rng.uniform(size=(num_v, 16))
    weights[np.arange(num_v), owner] += 1.0
    parent = np.array(_PARENTS)[owner]
    has_parent = parent >= 0
    weights[np.flatnonzero(has_parent), parent[has_parent]] += 0.4
    weights /= weights.sum(axis=1, keepdims=True)

    components, _ = np.linalg.qr(rng.standard_normal((45, 45)))
    return {
        "v_template": template,
        "weights": weights,
        "J_regressor": regressor,
        "shapedirs": 2e-3 * rng.standard_normal((num_v, 3, 10)),
        "posedirs": 2e-3 * rng.standard_normal((num_v, 3, 135)),
        "f": rng.integers(0, num_v, size=(1538, 3)).astype(np.uint32),
        "kintree_table": np.array([[_ROOT_PARENT, *_PARENTS[1:]], list(range(16))], dtype=np.int64),
        "hands_components": components.T.copy(),
        "hands_mean": 0.3 * rng.standard_normal(45),
        "hands_coeffs": rng.standard_normal((20, 45)),
    }


def mirror_arrays(arrays: dict[str, np.ndarray], shapedirs_quirk: bool) -> dict[str, np.ndarray]:
    """The left hand mirroring a right model through x = 0.

    Pose blend shapes follow from ``M (R - I) M`` with ``M = diag(-1, 1, 1)``: entry (r, c) of a
    joint's feature changes sign by ``s_r s_c``, and each vertex offset's x by ``s_x``.
    ``shapedirs_quirk`` keeps the right hand's x sign in ``shapedirs`` as MANO_LEFT.pkl does.
    """
    left = dict(arrays)
    left["v_template"] = arrays["v_template"] * _MIRROR
    left["f"] = arrays["f"][:, [0, 2, 1]]
    left["shapedirs"] = arrays["shapedirs"] * (1.0 if shapedirs_quirk else _MIRROR[:, None])
    feature_sign = np.tile(np.outer(_MIRROR, _MIRROR).ravel(), 15)  # [135]
    left["posedirs"] = arrays["posedirs"] * _MIRROR[:, None] * feature_sign
    left["hands_components"] = mirror_pose_np(arrays["hands_components"])
    left["hands_mean"] = mirror_pose_np(arrays["hands_mean"])
    left["hands_coeffs"] = arrays["hands_coeffs"]
    return left


def official_layout(arrays: dict[str, np.ndarray]) -> dict[str, object]:
    """The dict the official file pickles: chumpy ``shapedirs``, sparse ``J_regressor``, extras."""
    content: dict[str, object] = dict(arrays)
    content["shapedirs"] = FakeCh(arrays["shapedirs"])
    content["J_regressor"] = FakeCscMatrix(arrays["J_regressor"])
    content["J"] = arrays["J_regressor"] @ arrays["v_template"]
    content["weights_prior"] = arrays["weights"].copy()
    content["bs_type"] = "lrotmin"
    content["bs_style"] = "lbs"
    return content


def write_pickle_py2(
    path: Path, content: object, aliases: dict[type, tuple[str, str]] | None = None
) -> Path:
    """Pickle ``content`` with :class:`Py2Pickler` (protocol 2)."""
    with Path(path).open("wb") as handle:
        Py2Pickler(handle, protocol=2, aliases=aliases).dump(content)
    return Path(path)


def write_synthetic_mano(
    path: str | Path, side: str = "right", seed: int = 0, shapedirs_quirk: bool = True
) -> dict[str, np.ndarray]:
    """Write a synthetic MANO file at ``path`` and return its dense arrays (for references).

    side 'left' writes the mirror of the right model of the same seed (with MANO_LEFT.pkl's
    shapedirs quirk unless ``shapedirs_quirk`` is False).
    """
    arrays = synthetic_mano_arrays(seed)
    if side == "left":
        arrays = mirror_arrays(arrays, shapedirs_quirk)
    write_pickle_py2(Path(path), official_layout(arrays))
    return arrays
