"""Hand model v3's rest hand: a MakeHuman hand on MANO's skeleton, closed, smooth, in the
package's rest frame.

From a :class:`~.makehuman.MakeHumanShape` (:func:`build_mesh_rest`):

1. the morphed kit (:func:`~.makehuman.morph`) is moved into the rest frame of every hand model
   (metres, wrist joint at the origin, fingers along -x, palm facing -y, thumb on +z);
2. the forearm's open cut is closed by one polygon and the mesh is smoothed by two Catmull-Clark
   steps (:mod:`lisa_hand.geometry.subdivision`: MakeHuman's own display smoothing), the
   skinning weights carried along;
3. the rig's 22 bones become MANO's 16 joints (forearm, wrist and metacarpals -> the wrist
   joint; each phalanx -> its MANO joint; the thumb's metacarpal -> thumb1);
4. each finger bone is turned, by dual quaternion skinning, to the direction it has in the
   mean hand of :mod:`.shape` (straight fingers, the thumb's rest direction), so that a pose
   means the same motion as on hand models v1 and v2 (the joint limits and the pose sampler of
   :mod:`.poses` are defined on that rest hand);
5. surface features for the skin's colour (:func:`lisa_hand.handmodel.appearance.albedo`):
   palmar side, fingernails, flexion creases and knuckles, from each vertex's place on its bone.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.rotations import matrix_to_axis_angle
from ..geometry.subdivision import Subdivision, catmull_clark, quads_to_triangles
from ..skeleton.kinematics import dual_quaternion_skinning, forward_kinematics
from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS, PARENTS
from .makehuman import MakeHumanKit, MakeHumanShape, load_kit, morph
from .shape import HandShape, RestSkeleton, rest_skeleton

__all__ = ["MeshRest", "build_mesh_rest", "SUBDIVISION_LEVELS"]

SUBDIVISION_LEVELS = 2
"""Catmull-Clark steps: 1685 kit vertices -> about 27k (1-2 mm apart)."""

# MakeHuman finger number (1 thumb .. 5 little) -> MANO finger name.
_FINGERS = {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "pinky"}


def _mano_joint_of_bone(bone: str) -> int:
    """The MANO joint whose transform moves the skin of a kit bone."""
    if bone.startswith("finger"):
        finger, segment = bone[len("finger"):].split(".")[0].split("-")
        return FINGER_JOINTS[_FINGERS[int(finger)]][int(segment) - 1]
    return 0  # forearm, wrist and the four metacarpals move with the wrist joint


def _joint_names() -> list[str]:
    """Kit joint of each MANO joint (the head of its bone)."""
    names = ["wrist.R____head"] + [""] * (NUM_JOINTS - 1)
    for number, finger in _FINGERS.items():
        for segment, joint in enumerate(FINGER_JOINTS[finger], start=1):
            names[joint] = f"finger{number}-{segment}.R____head"
    return names


@dataclass(frozen=True)
class MeshRest:
    """The rest hand of one shape (right hand, metres, float64 numpy unless said).

    vertices: [V, 3] closed, outward mesh. faces: [F, 3] int64 triangles (quads split).
    weights: [V, 16] skinning weights on MANO's joints, rows summing to 1.
    features: per vertex [V] in [0, 1]: ``palmar``, ``nail``, ``nail_along``, ``crease``,
        ``knuckle`` (see :class:`lisa_hand.handmodel.sdf.HandFieldOutput`).
    skeleton: the :class:`~.shape.RestSkeleton` (torch float64), as the other hand models'.
    """

    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    features: dict[str, np.ndarray]
    skeleton: RestSkeleton


@functools.lru_cache(maxsize=1)
def _topology() -> tuple[Subdivision, np.ndarray]:
    """The kit closed at the forearm and subdivided (cached): (operator, triangles [F, 3])."""
    kit = load_kit()
    quads = kit.quads
    directed = {(int(a), int(b)) for quad in quads for a, b in zip(quad, np.roll(quad, -1),
                                                                     strict=True)}
    boundary = {a: b for a, b in directed if (b, a) not in directed}
    start = next(iter(boundary))
    loop = [start]
    while boundary[loop[-1]] != start:
        loop.append(boundary[loop[-1]])
    if len(loop) != len(boundary):
        raise ValueError("the MakeHuman kit must have exactly one open boundary (the forearm cut)")
    cap = loop[::-1]  # the cap runs each boundary edge the other way
    operator = catmull_clark([*map(list, quads), cap], len(kit.vertices), SUBDIVISION_LEVELS)
    return operator, quads_to_triangles(operator.quads)


def _rest_frame(joints_mm: np.ndarray, kit: MakeHumanKit) -> tuple[np.ndarray, np.ndarray]:
    """Rotation [3, 3] and origin [3] (mm) of the rest frame: fingers along -x, thumb side +z."""
    wrist = joints_mm[kit.joint("wrist.R____head")]
    index, middle, little = (joints_mm[kit.joint(f"finger{f}-1.R____head")] for f in (2, 3, 5))
    fingers = _unit(middle - wrist)
    thumb_side = index - little
    thumb_side = _unit(thumb_side - thumb_side @ fingers * fingers)
    x_axis, z_axis = -fingers, thumb_side
    y_axis = np.cross(z_axis, x_axis)
    return np.stack([x_axis, y_axis, z_axis]), wrist


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def _minimal_rotation(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[3, 3] the smallest rotation taking unit ``source`` to unit ``target``."""
    axis = np.cross(source, target)
    sin, cos = np.linalg.norm(axis), float(source @ target)
    if sin < 1e-12:
        return np.eye(3)
    k = axis / sin
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sin * skew + (1.0 - cos) * skew @ skew


def _bone_ends(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """[16, 3] where each bone ends: its child joint, its fingertip (distal bones), the middle
    MCP joint (the wrist bone)."""
    ends = joints.copy()
    for name, chain in FINGER_JOINTS.items():
        ends[chain[0]], ends[chain[1]] = joints[chain[1]], joints[chain[2]]
        ends[chain[2]] = tips[FINGER_NAMES.index(name)]
    ends[0] = joints[FINGER_JOINTS["middle"][0]]
    return ends


def _bone_directions(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """[16, 3] unit directions of each bone (:func:`_bone_ends`)."""
    return _unit(_bone_ends(joints, tips) - joints)


def _straightening_pose(joints: np.ndarray, tips: np.ndarray) -> torch.Tensor:
    """[48] the pose that turns every finger bone to the mean hand's direction (v1's rest)."""
    target = rest_skeleton(HandShape()).bone_dirs.numpy()
    current = _bone_directions(joints, tips)
    world = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    local = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    for joint in range(1, NUM_JOINTS):
        world[joint] = _minimal_rotation(current[joint], target[joint])
        local[joint] = world[PARENTS[joint]].T @ world[joint]
    return matrix_to_axis_angle(torch.from_numpy(local)).reshape(-1)


def _features(vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray,
              skeleton: RestSkeleton) -> dict[str, np.ndarray]:
    """Per-vertex surface features of the rest hand (see :class:`MeshRest`)."""
    import trimesh

    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals
    joints = skeleton.joints.numpy()
    dirs, dorsal = skeleton.bone_dirs.numpy(), skeleton.dorsal.numpy()
    ends = skeleton.bone_ends.numpy()
    owner = weights.argmax(axis=1)
    palmar = _smoothstep(0.05, 0.5, -(normals * dorsal[owner]).sum(1))
    nail = np.zeros(len(vertices))
    nail_along = np.zeros(len(vertices))
    crease = np.zeros(len(vertices))
    knuckle = np.zeros(len(vertices))
    for name in FINGER_NAMES:
        chain = FINGER_JOINTS[name]
        distal = chain[2]
        length = np.linalg.norm(ends[distal] - joints[distal])
        relative = vertices - joints[distal]
        along = relative @ dirs[distal] / length
        lateral = np.cross(dorsal[distal], dirs[distal])
        side = np.abs(relative @ lateral)
        width = np.quantile(side[(owner == distal) & (np.abs(along - 0.5) < 0.2)], 0.9)
        facing = (normals @ dorsal[distal])
        plate = (_smoothstep(0.35, 0.45, along) * _smoothstep(0.45, 0.65, facing)
                 * _smoothstep(0.75, 0.6, side / max(width, 1e-6)) * (owner == distal))
        nail = np.maximum(nail, plate)
        nail_along = np.where(plate > 0, np.clip((along - 0.4) / 0.6, 0.0, 1.0), nail_along)
        for joint in chain[1:]:
            distance = np.abs((vertices - joints[joint]) @ dirs[joint])
            crease = np.maximum(crease, np.exp(-0.5 * (distance / 0.0012) ** 2) * palmar)
            knuckle = np.maximum(knuckle, np.exp(-0.5 * (distance / 0.005) ** 2) * (1 - palmar))
        mcp = chain[0]
        distance = np.linalg.norm(vertices - joints[mcp], axis=1)
        knuckle = np.maximum(knuckle, np.exp(-0.5 * (distance / 0.008) ** 2) * (1 - palmar)
                             * (name != "thumb"))
    return {"palmar": palmar, "nail": nail, "nail_along": nail_along, "crease": crease,
            "knuckle": knuckle}


def _smoothstep(edge0: float, edge1: float, values: np.ndarray) -> np.ndarray:
    t = np.clip((values - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _skeleton(vertices: np.ndarray, weights: np.ndarray, joints: np.ndarray,
              tips: np.ndarray) -> RestSkeleton:
    """The rest skeleton: joints, fingertips on the skin, bone ends, flesh radii, bone axes."""
    from ..geometry.mesh_distance import mesh_distance

    tips = mesh_distance(tips, vertices, _topology()[1]).closest
    ends = _bone_ends(joints, tips)
    dirs = _unit(ends - joints)
    up = np.array([0.0, 1.0, 0.0])
    dorsal = _unit(up - (dirs @ up)[:, None] * dirs)
    lateral = np.cross(dorsal, dirs)
    owner = weights.argmax(axis=1)
    radii = np.zeros((NUM_JOINTS, 2))
    for joint in range(NUM_JOINTS):
        for end, point in enumerate((joints[joint], ends[joint])):
            relative = vertices[owner == joint] - point
            along = relative @ dirs[joint]
            radial = np.linalg.norm(relative - along[:, None] * dirs[joint], axis=1)
            near = np.abs(along) < 0.004
            radii[joint, end] = np.median(radial[near]) if near.sum() >= 8 else np.median(radial)
    as_torch = functools.partial(torch.as_tensor, dtype=torch.float64)
    return RestSkeleton(joints=as_torch(joints), fingertips=as_torch(tips),
                        bone_ends=as_torch(ends), radii=as_torch(radii),
                        bone_dirs=as_torch(dirs), dorsal=as_torch(dorsal),
                        lateral=as_torch(lateral))


@functools.lru_cache(maxsize=64)
def build_mesh_rest(shape: MakeHumanShape) -> MeshRest:
    """The rest hand of a shape (cached: a subject's frames share it). See the module
    docstring for the steps."""
    if not isinstance(shape, MakeHumanShape):
        raise TypeError(f"shape must be a MakeHumanShape, got {type(shape).__name__}")
    kit = load_kit()
    operator, faces = _topology()
    vertices_mm, joints_mm = morph(shape, kit)
    rotation, origin = _rest_frame(joints_mm, kit)
    coarse = (vertices_mm - origin) @ rotation.T / 1000.0
    kit_joints = (joints_mm - origin) @ rotation.T / 1000.0
    to_mano = np.zeros((len(kit.bone_names) + 1, NUM_JOINTS))
    for bone, name in enumerate(kit.bone_names):
        to_mano[bone, _mano_joint_of_bone(name)] = 1.0
    to_mano[-1, 0] = 1.0  # the rest of the body (weight 0 on the kit) stays with the wrist
    weights = operator.apply(kit.weights @ to_mano)
    weights /= weights.sum(axis=1, keepdims=True)
    vertices = operator.apply(coarse)
    joints = kit_joints[[kit.joint(name) for name in _joint_names()]]
    tips = kit_joints[[kit.joint(f"finger{n}-3.R____tail") for n in range(1, 6)]]
    # FINGER_NAMES order is thumb, index, middle, ring, pinky: MakeHuman's fingers 1..5.
    pose = _straightening_pose(joints, tips)
    kinematics = forward_kinematics(pose[None], torch.from_numpy(joints))
    transforms = kinematics.transforms[0]
    vertices = dual_quaternion_skinning(torch.from_numpy(vertices), torch.from_numpy(weights),
                                        transforms).numpy()
    joints = kinematics.joints[0].numpy()
    distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
    tips_h = np.concatenate([tips, np.ones((5, 1))], axis=1)
    tips = np.einsum("fij,fj->fi", transforms[distal].numpy(), tips_h)[:, :3]
    skeleton = _skeleton(vertices, weights, joints, tips)
    features = _features(vertices, faces, weights, skeleton)
    return MeshRest(vertices=vertices, faces=faces, weights=weights, features=features,
                    skeleton=skeleton)
