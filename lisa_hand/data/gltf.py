"""An animated, skinned hand as one binary glTF 2.0 file (``.glb``), written by hand.

The file holds the hand's rest mesh (positions, smooth unit normals, vertex colours, each
vertex's four largest skinning weights renormalised to sum 1, uint32 triangles), a white
material so the vertex colours show, a skin on MANO's 16 joints and one animation, ``"clip"``,
of the pose and translation: it plays in a browser glTF viewer or in Blender.

Mapping from the package's forward kinematics (:func:`lisa_hand.skeleton.forward_kinematics`)
to glTF nodes. MANO chains ``G_0 = [R_0 | J_0]``, ``G_j = G_parent(j) [R_j | J_j - J_parent(j)]``
and adds the translation ``t`` to every ``G_j``; a vertex is skinned as
``sum_j w_j G_j [I | -J_j] v`` (:func:`lisa_hand.skeleton.linear_blend_skinning`). In glTF:

* joint node ``j`` (named :data:`lisa_hand.skeleton.JOINT_NAMES`) is a child of its MANO parent's
  node, with local translation ``J_0`` (root) or ``J_j - J_parent(j)``, rotation identity at rest;
* its inverse bind matrix is ``translate(-J_j)``, so glTF's joint matrix ``global_j ibm_j`` is
  exactly MANO's ``A_j = G_j [I | -J_j]``;
* the animation keys each joint's local rotation ``R_j`` as a unit quaternion ``(x, y, z, w)``
  (LINEAR: slerp; consecutive keys on one hemisphere), and the root's local translation as
  ``J_0 + t``: adding ``t`` to the root adds it to every ``G_j``, as MANO does;
* the scene's root node (``name``) holds the skinned mesh's node and the root joint's node.

A left hand (``side="left"``) is given as the package stores one: the mirror (``x -> -x``) of a
right hand's mesh, rest joints and translations, with the pose :func:`mirror_pose` of the
right's. The package poses it as the mirror of the right hand posed
(:class:`lisa_hand.inference.hand_field.HandField`), which is forward kinematics of the stored
left data itself (:func:`lisa_hand.inference.mesh.repose_mesh`): ``mirror_pose`` turns each
rotation ``R`` into ``M R M`` (``M = diag(-1, 1, 1)``), a proper rotation, and with mirrored
joints and vertices the skinned mesh is the mirror of the right one. So a left hand's file is
written from its stored data as it is (its faces already turned outward, see
:func:`lisa_hand.inference.mesh.mirror_mesh`); ``side`` is recorded in the root node's extras.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.meshing import Mesh
from ..skeleton.kinematics import check_side
from ..skeleton.tree import JOINT_NAMES, NUM_JOINTS, PARENTS, POSE_DIM
from ..utils.arrays import as_numpy
from ..utils.io import atomic_path

__all__ = ["animated_hand_glb", "write_animated_glb"]

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942
_INFLUENCES = 4  # joints per vertex in JOINTS_0 / WEIGHTS_0
_FIRST_JOINT = 2  # node 0: the scene's root, node 1: the skinned mesh, 2..17: the joints


class _Buffer:
    """The BIN chunk being built: one buffer view per accessor, each 4-byte aligned."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def add(self, array: np.ndarray, component: int, *, target: int | None = None,
            normalized: bool = False, bounds: bool = False) -> int:
        """Append ``array`` ([N] or [N, C], little-endian) -> its accessor's index."""
        array = np.ascontiguousarray(array)
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.data),
                                "byteLength": array.nbytes}
        if target is not None:
            view["target"] = target
        self.data += array.tobytes()
        self.data += b"\0" * (-len(self.data) % 4)
        self.views.append(view)
        flat = array.reshape(len(array), -1)
        accessor: dict[str, Any] = {"bufferView": len(self.views) - 1, "componentType": component,
                                    "count": len(array), "type": _TYPES[flat.shape[1]]}
        if normalized:
            accessor["normalized"] = True
        if bounds:
            accessor["min"], accessor["max"] = flat.min(0).tolist(), flat.max(0).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _array(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as float64 of ``shape`` (-1: any length), finite; else one-line ValueError."""
    array = as_numpy(value, name)
    if array.ndim != len(shape) or any(
            want not in (-1, got) for got, want in zip(array.shape, shape, strict=True)):
        want = ", ".join("T" if w == -1 else str(w) for w in shape)
        raise ValueError(f"{name} must have shape [{want}], got {list(array.shape)}")
    if not np.issubdtype(array.dtype, np.number) or not np.isfinite(array).all():
        raise ValueError(f"{name} must hold finite numbers")
    return array.astype(np.float64)


def _quaternions(axis_angle: np.ndarray) -> np.ndarray:
    """Axis-angle [T, J, 3] radians -> unit quaternions [T, J, 4] ``(x, y, z, w)``, each on
    the hemisphere of the previous frame's (so that slerp between keys takes the short way)."""
    angle = np.linalg.norm(axis_angle, axis=-1, keepdims=True)
    small = angle < 1e-6
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(0.5 * angle) / np.where(small, 1, angle))
    quats = np.concatenate([axis_angle * scale, np.cos(0.5 * angle)], axis=-1)
    flips = np.where(np.sum(quats[1:] * quats[:-1], axis=-1) < 0, -1.0, 1.0)
    signs = np.cumprod(np.concatenate([np.ones((1, quats.shape[1])), flips]), axis=0)
    return quats * signs[..., None]


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted smooth unit normals [V, 3] (+z where a vertex has no face)."""
    corners = vertices.astype(np.float64)[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros((len(vertices), 3))
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    unit = normals / np.maximum(length, 1e-300)
    return np.where(length > 1e-20, unit, [0.0, 0.0, 1.0]).astype(np.float32)


def _top_weights(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """skin weights [V, 16] -> (joints [V, 4] uint16, weights [V, 4] float32): each vertex's
    four largest, renormalised to sum 1; a slot of zero weight names joint 0."""
    if not np.isfinite(weights).all() or (weights < 0).any():
        raise ValueError("mesh.skin_weights must be finite and >= 0")
    order = np.argsort(-weights, axis=1, kind="stable")[:, :_INFLUENCES]
    top = np.take_along_axis(weights, order, axis=1).astype(np.float64)
    total = top.sum(axis=1, keepdims=True)
    if (total <= 0).any():
        raise ValueError(f"mesh.skin_weights: vertex {int(np.argmin(total[:, 0]))} has no weight")
    top /= total
    return np.where(top > 0, order, 0).astype("<u2"), top.astype("<f4")


def _nodes(joints: np.ndarray, name: str, side: str) -> list[dict[str, Any]]:
    """The scene's root, the skinned mesh's node and the 16 joint nodes in MANO's tree, at
    rest: local translations ``J_0`` (root) and ``J_j - J_parent(j)``, rotations identity."""
    offsets = joints - np.concatenate([np.zeros((1, 3)), joints[list(PARENTS[1:])]])
    nodes: list[dict[str, Any]] = [
        {"name": name, "children": [1, _FIRST_JOINT], "extras": {"side": side}},
        {"name": f"{name}_mesh", "mesh": 0, "skin": 0},
    ]
    for j in range(NUM_JOINTS):
        node: dict[str, Any] = {"name": JOINT_NAMES[j], "translation": offsets[j].tolist()}
        children = [_FIRST_JOINT + c for c in range(NUM_JOINTS) if PARENTS[c] == j]
        if children:
            node["children"] = children
        nodes.append(node)
    return nodes


def _animation(buffer: _Buffer, joints: np.ndarray, poses: np.ndarray,
               translations: np.ndarray, times: np.ndarray) -> dict[str, Any]:
    """The clip: every joint's local rotation and the root's local translation ``J_0 + t`` keyed
    at ``times`` (LINEAR), their data appended to ``buffer``."""
    keys = buffer.add(times, _FLOAT, bounds=True)
    quaternions = _quaternions(poses.reshape(len(poses), NUM_JOINTS, 3)).astype("<f4")
    outputs = [buffer.add(quaternions[:, j], _FLOAT) for j in range(NUM_JOINTS)]
    outputs.append(buffer.add((joints[0] + translations).astype("<f4"), _FLOAT))
    paths = ["rotation"] * NUM_JOINTS + ["translation"]
    nodes = [_FIRST_JOINT + j for j in range(NUM_JOINTS)] + [_FIRST_JOINT]
    return {"name": "clip",
            "samplers": [{"input": keys, "output": out, "interpolation": "LINEAR"}
                         for out in outputs],
            "channels": [{"sampler": i, "target": {"node": node, "path": path}}
                         for i, (node, path) in enumerate(zip(nodes, paths, strict=True))]}


def animated_hand_glb(mesh: Mesh, rest_joints: Any, poses: Any, translations: Any, times: Any,
                      *, side: str = "right", name: str = "hand") -> bytes:
    """The bytes of a ``.glb`` of ``mesh`` skinned to MANO's skeleton and animated (module doc).

    mesh: the hand at rest (pose zero, translation zero), world metres, counter-clockwise faces,
        colours [V, 3] uint8 or None, skin_weights [V, 16] (required).
    rest_joints: [16, 3] metres. poses: [T, 48] axis-angle radians (MANO order).
    translations: [T, 3] metres. times: [T] seconds, >= 0 and strictly increasing (T >= 1).
    side: "right" or "left" (a left hand as the package stores one). name: the scene's name.
    numpy arrays or torch tensors. -> the GLB file's bytes (a multiple of 4).
    """
    check_side(side)
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a lisa_hand Mesh, got {type(mesh).__name__}")
    if mesh.skin_weights is None or mesh.skin_weights.shape[1] != NUM_JOINTS:
        raise ValueError(f"mesh needs skin_weights [V, {NUM_JOINTS}] to be skinned")
    if mesh.num_vertices == 0 or mesh.num_faces == 0:
        raise ValueError("mesh has no vertices or no faces")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError("mesh.vertices must be finite")
    joints = _array(rest_joints, "rest_joints", (NUM_JOINTS, 3))
    poses = _array(poses, "poses", (-1, POSE_DIM))
    count = len(poses)
    translations = _array(translations, "translations", (count, 3))
    times = _array(times, "times", (count,)).astype("<f4")
    if count == 0:
        raise ValueError("poses must hold at least one frame")
    if times[0] < 0 or (np.diff(times) <= 0).any():
        raise ValueError("times must be >= 0 and strictly increasing (seconds, as float32)")

    buffer = _Buffer()
    attributes = {
        "POSITION": buffer.add(mesh.vertices.astype("<f4"), _FLOAT, target=_ARRAY_BUFFER,
                               bounds=True),
        "NORMAL": buffer.add(_vertex_normals(mesh.vertices, mesh.faces), _FLOAT,
                             target=_ARRAY_BUFFER),
    }
    if mesh.colors is not None:
        rgba = np.concatenate([mesh.colors, np.full((mesh.num_vertices, 1), 255, np.uint8)], 1)
        attributes["COLOR_0"] = buffer.add(rgba, _UBYTE, target=_ARRAY_BUFFER, normalized=True)
    influences, weights = _top_weights(mesh.skin_weights)
    attributes["JOINTS_0"] = buffer.add(influences, _USHORT, target=_ARRAY_BUFFER)
    attributes["WEIGHTS_0"] = buffer.add(weights, _FLOAT, target=_ARRAY_BUFFER)
    indices = buffer.add(mesh.faces.reshape(-1).astype("<u4"), _UINT,
                         target=_ELEMENT_ARRAY_BUFFER)

    bind = np.tile(np.eye(4), (NUM_JOINTS, 1, 1))
    bind[:, :3, 3] = -joints  # translate(-J_j), stored column-major below
    inverse_binds = buffer.add(bind.transpose(0, 2, 1).reshape(NUM_JOINTS, 16).astype("<f4"),
                               _FLOAT)
    animation = _animation(buffer, joints, poses, translations, times)  # the last data
    document = {
        "asset": {"version": "2.0", "generator": "lisa-hand"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": _nodes(joints, name, side),
        "meshes": [{"name": name, "primitives": [
            {"attributes": attributes, "indices": indices, "material": 0, "mode": 4}]}],
        "materials": [{"name": f"{name}_skin", "doubleSided": False, "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 0.6}}],
        "skins": [{"name": f"{name}_skeleton", "inverseBindMatrices": inverse_binds,
                   "joints": list(range(_FIRST_JOINT, _FIRST_JOINT + NUM_JOINTS)),
                   "skeleton": _FIRST_JOINT}],
        "animations": [animation],
        "buffers": [{"byteLength": len(buffer.data)}],
        "bufferViews": buffer.views,
        "accessors": buffer.accessors,
    }
    return _glb(document, bytes(buffer.data))


def _glb(document: dict[str, Any], binary: bytes) -> bytes:
    """The GLB container: 12-byte header, JSON chunk padded with spaces, BIN chunk with zeros."""
    text = json.dumps(document, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total),
                     struct.pack("<II", len(text), _JSON_CHUNK), text,
                     struct.pack("<II", len(binary), _BIN_CHUNK), binary])


def write_animated_glb(path: str | os.PathLike, mesh: Mesh, rest_joints: Any, poses: Any,
                       translations: Any, times: Any, *, side: str = "right",
                       name: str = "hand") -> Path:
    """Write :func:`animated_hand_glb`'s file to ``path`` atomically (a temporary file beside it,
    then ``os.replace``) -> ``path``."""
    data = animated_hand_glb(mesh, rest_joints, poses, translations, times, side=side, name=name)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
