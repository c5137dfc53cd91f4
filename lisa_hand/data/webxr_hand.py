"""The artist-made WebXR hand (``tests/assets/webxr_hand``, MIT, Amazon): a skinned hand the
project did not make, read from its rig file and posed with its own skeleton, so that fits and
metrics can be checked on a mesh no generator of this package made.

The rig file (``right_hand.npz`` / ``left_hand.npz``, converted from the WebXR Input Profiles'
skinned glTF ``generic-hand``) holds ``vertices [V, 3]`` mm, ``faces [F, 3]``, ``weights [V,
25]`` (linear blend skinning weights), ``joint_names [25]`` (the 25 OpenXR joints: wrist, then
per finger metacarpal, phalanges and tip; parents before children), ``joints [25, 3]`` mm (bind
pose) and ``parents [25]``. Everything here returns metres.

* :func:`load_webxr_rig`: the rig in metres, optionally in other proportions
  (:func:`reshape_webxr_rig`); :func:`webxr_side`: which hand it is; :func:`webxr_wrist`: its
  wrist joint and forearm direction.
* :func:`pose_webxr_hand`: the mesh posed by linear blend skinning in one of
  :data:`WEBXR_POSES` (rest, a bent index, a fist).
* :func:`outer_surface`: the part of a posed mesh a scanner can see (skinning pushes a fist's
  fingertips into its palm); :func:`extend_forearm` and :func:`webxr_wrist_variant`: what a scan
  does beyond the wrist (:data:`WEBXR_WRISTS`).

Scenes with more than the hand in them (a table, a wall, a person) are in
:mod:`lisa_hand.data.webxr_scenes`; ``python -m benchmarks fit --webxr`` (from the repository
root) measures the point fit on all of them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["WEBXR_POSES", "WEBXR_WRISTS", "FOREARM_START_M", "FOREARM_LENGTH_M",
           "load_webxr_rig", "reshape_webxr_rig", "pose_webxr_hand", "outer_surface",
           "webxr_side", "palm_normal", "webxr_wrist", "extend_forearm", "webxr_wrist_variant"]

WEBXR_WRISTS = ("as-is", "forearm", "cut")
"""What a scan of the hand does beyond the wrist (:func:`webxr_wrist_variant`): ``as-is`` (the
artist's 2.2 cm stub beyond the wrist joint), ``forearm`` (the stub cut
:data:`FOREARM_START_M` beyond the wrist joint and its rim extruded :data:`FOREARM_LENGTH_M` along
the forearm, the far end closed), ``cut`` (the mesh cut at the wrist joint)."""
FOREARM_START_M = 0.015
FOREARM_LENGTH_M = 0.12

WEBXR_POSES = {
    "rest": {},
    "bent_index": {"index-finger": (0.9, 1.2, 0.7)},
    "fist": {**{finger: (1.3, 1.5, 0.9) for finger in ("index-finger", "middle-finger",
                                                        "ring-finger", "pinky-finger")},
             "thumb": (0.3, 0.5, 0.5)},
}
"""Flexion (radians) of each finger's three joints (MCP, PIP, DIP; thumb CMC, MCP, IP)."""


def reshape_webxr_rig(vertices: np.ndarray, joints: np.ndarray, names: list[str],
                      proportions: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The WebXR hand in other proportions, in its bind pose: a hand unlike the artist's for
    checks beyond one mesh, made by a map that keeps the wrist joint where it is.

    vertices: [V, 3] metres; joints: [25, 3] metres, in the rig's order ``names``.
    proportions: (breadth, thickness, fingers): the palm's breadth across the knuckles and its
    thickness along the knuckle plane's normal scaled about the wrist joint, and everything
    beyond the knuckle line (the mean of the four fingers' proximal joints along the wrist ->
    middle knuckle axis) stretched along that axis, the fingers that many times longer (the
    thumb's tip, which reaches past the line, a little longer too).
    -> (vertices [V, 3], joints [25, 3]) metres, the same map applied to both.
    """
    breadth, thickness, fingers = (float(f) for f in proportions)
    wrist = joints[names.index("wrist")]
    along = joints[names.index("middle-finger-phalanx-proximal")] - wrist
    along /= np.linalg.norm(along)
    normal = palm_normal(joints, names)
    normal = normal - along * (normal @ along)
    normal /= np.linalg.norm(normal)
    frame = np.stack([along, np.cross(normal, along), normal])  # rows: fingers, breadth, normal
    knuckles = np.mean([(joints[names.index(f"{finger}-phalanx-proximal")] - wrist) @ along
                        for finger in ("index-finger", "middle-finger", "ring-finger",
                                       "pinky-finger")])

    def reshape(points):
        local = (points - wrist) @ frame.T
        local[:, 0] += (fingers - 1.0) * np.maximum(local[:, 0] - knuckles, 0.0)
        local[:, 1] *= breadth
        local[:, 2] *= thickness
        return wrist + local @ frame

    return reshape(vertices), reshape(joints)


def load_webxr_rig(path: str | Path, proportions=None) -> dict:
    """The WebXR rig file ``path`` (module docstring) in metres: {"vertices": [V, 3] metres,
    "faces": [F, 3], "weights": [V, 25], "joints": [25, 3] metres (bind pose), "parents": [25]
    (-1 for the wrist), "names": the 25 OpenXR joint names}, reshaped by
    :func:`reshape_webxr_rig` when ``proportions`` (breadth, thickness, fingers) is given."""
    with np.load(path, allow_pickle=False) as data:
        rig = {"vertices": data["vertices"] * 1e-3, "faces": data["faces"],
               "weights": data["weights"], "joints": data["joints"].astype(np.float64) * 1e-3,
               "parents": data["parents"], "names": [str(n) for n in data["joint_names"]]}
    if proportions is not None and tuple(proportions) != (1.0, 1.0, 1.0):
        rig["vertices"], rig["joints"] = reshape_webxr_rig(rig["vertices"], rig["joints"],
                                                           rig["names"], proportions)
    return rig


def pose_webxr_hand(path: str | Path, pose: str = "rest",
                    proportions: tuple[float, float, float] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The WebXR hand (``right_hand.npz``: millimetres, 25 OpenXR joints, its own skinning
    weights) posed by linear blend skinning, in metres.

    Each joint of :data:`WEBXR_POSES` turns about the axis ``bone x palm normal``, so positive
    angles curl the finger towards the palm, of a right hand (``right_hand.npz``) or a left one
    (``left_hand.npz``): for the four fingers the palm normal is the normal of the knuckle plane
    (wrist, index and little-finger proximal joints) on the thumb's side, so that they curl as
    hinges in their own plane; for the thumb it is the normal of the plane of the thumb's
    proximal joint and the middle finger, on the same side. (The plane of the thumb and the
    fingers would not do for the four fingers: the thumb's proximal joint lies well in front of
    the palm, so that axis is about 45 degrees off the knuckle plane's normal and would curl them
    diagonally across the palm, sideways at their PIP and DIP hinges, which a hand cannot do.)
    proportions: the hand reshaped first
    (:func:`reshape_webxr_rig`; None: as the artist made it).
    -> (vertices [V, 3] metres, faces [F, 3]).
    """
    from ..geometry import axis_angle_to_matrix

    if pose not in WEBXR_POSES:
        raise ValueError(f"unknown WebXR pose {pose!r}: one of {', '.join(WEBXR_POSES)}")
    rig = load_webxr_rig(path, proportions)
    vertices, faces, weights = rig["vertices"], rig["faces"], rig["weights"]
    joints, parents, names = rig["joints"], rig["parents"], rig["names"]
    index = {name: number for number, name in enumerate(names)}
    fingers = joints[index["middle-finger-phalanx-proximal"]] - joints[0]
    fingers /= np.linalg.norm(fingers)
    thumb = joints[index["thumb-phalanx-proximal"]] - joints[0]
    thumb -= fingers * (thumb @ fingers)
    palm = palm_normal(joints, names)
    thumb_normal = np.cross(thumb / np.linalg.norm(thumb), fingers)
    thumb_normal = thumb_normal if thumb_normal @ palm > 0 else -thumb_normal
    local = np.tile(np.eye(4), (len(names), 1, 1))
    for finger, angles in WEBXR_POSES[pose].items():
        chain = (["thumb-metacarpal", "thumb-phalanx-proximal", "thumb-phalanx-distal"]
                 if finger == "thumb" else
                 [f"{finger}-phalanx-{part}" for part in ("proximal", "intermediate", "distal")])
        ends = chain[1:] + [f"{finger}-tip"]
        for joint_name, end_name, angle in zip(chain, ends, angles, strict=True):
            joint, end = index[joint_name], index[end_name]
            normal = thumb_normal if finger == "thumb" else palm
            axis = np.cross(joints[end] - joints[joint], normal)
            axis_angle = torch.from_numpy(angle * axis / np.linalg.norm(axis))
            rotation = axis_angle_to_matrix(axis_angle).numpy()
            local[joint, :3, :3] = rotation
            local[joint, :3, 3] = joints[joint] - rotation @ joints[joint]
    world = np.empty_like(local)
    for joint in range(len(names)):  # parents come first in the OpenXR order
        world[joint] = local[joint] if parents[joint] < 0 else world[parents[joint]] @ local[joint]
    blended = np.einsum("vj,jab->vab", weights, world)
    posed = np.einsum("vab,vb->va", blended[:, :3, :3], vertices) + blended[:, :3, 3]
    return posed, faces


def outer_surface(vertices: np.ndarray, faces: np.ndarray, offset: float = 2e-4
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The outside of a posed mesh: (vertices [V', 3], faces [F', 3]), without the faces (and
    the vertices only they use) that linear blend skinning pushed inside the hand (a fist's
    fingertips sink into the palm: 2.6% of the WebXR fist's area), which no scanner sees and
    no surface can reach.

    A face is inside when the point ``offset`` metres out along its normal from its centroid
    has a winding number above one half (point-cloud-utils' fast winding numbers; an open cut
    at the wrist leaves faces far from it unaffected). vertices: [V, 3] metres; faces: [F, 3]
    outward.
    """
    import point_cloud_utils as pcu
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    probes = mesh.triangles_center + offset * mesh.face_normals
    winding = pcu.triangle_soup_fast_winding_number(
        np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64),
        np.ascontiguousarray(probes, np.float64))
    kept = faces[winding <= 0.5]
    used, compact = np.unique(kept, return_inverse=True)
    return vertices[used], compact.reshape(kept.shape).astype(np.int64)


def webxr_side(path: str | Path) -> str:
    """'right' or 'left': the hand of a WebXR rig file. Looking from the palm's side (the thumb's
    proximal joint's side of the knuckle plane) with the fingers up, a right hand's thumb points
    one way and a left hand's the other: the sign of ``(thumb x fingers) . palm normal``
    (MANO's right-hand convention makes it positive)."""
    with np.load(path, allow_pickle=False) as data:
        joints = data["joints"].astype(np.float64)
        names = [str(n) for n in data["joint_names"]]
    wrist = joints[names.index("wrist")]
    fingers = joints[names.index("middle-finger-phalanx-proximal")] - wrist
    thumb = joints[names.index("thumb-phalanx-proximal")] - wrist
    return "right" if np.cross(thumb, fingers) @ palm_normal(joints, names) > 0 else "left"


def palm_normal(joints: np.ndarray, names: list[str]) -> np.ndarray:
    """[3] unit normal of the knuckle plane (wrist, index and little-finger proximal joints;
    joints [25, 3] in the rig's order ``names``) on the palm's side, which is the thumb's: its
    proximal joint lies in front of the palm, in a right hand and a left one alike."""
    wrist = joints[names.index("wrist")]
    knuckles = np.cross(joints[names.index("index-finger-phalanx-proximal")] - wrist,
                        joints[names.index("pinky-finger-phalanx-proximal")] - wrist)
    knuckles /= np.linalg.norm(knuckles)
    thumb = joints[names.index("thumb-phalanx-proximal")] - wrist
    return knuckles if knuckles @ thumb > 0 else -knuckles


def webxr_wrist(path: str | Path, proportions=None) -> tuple[np.ndarray, np.ndarray]:
    """(the wrist joint [3] metres, the unit forearm direction [3]: middle knuckle -> wrist) of
    the WebXR hand (in ``proportions``, :func:`reshape_webxr_rig`); its poses move only the
    fingers, so these hold in every pose."""
    rig = load_webxr_rig(path, proportions)
    joints, names = rig["joints"], rig["names"]
    wrist = joints[names.index("wrist")]
    forearm = wrist - joints[names.index("middle-finger-phalanx-proximal")]
    return wrist, forearm / np.linalg.norm(forearm)


def extend_forearm(vertices: np.ndarray, faces: np.ndarray, wrist: np.ndarray,
                   forearm: np.ndarray, start: float = FOREARM_START_M,
                   length: float = FOREARM_LENGTH_M, rings: int = 12
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A closed hand mesh cut ``start`` metres beyond the wrist joint and its cut rim extruded
    ``length`` metres along ``forearm`` (in ``rings`` rings; the far end closed by a fan).

    vertices: [V, 3] metres; faces: [F, 3] outward; wrist: [3] metres; forearm: [3] unit.
    -> (vertices [V', 3] metres, faces [F', 3]), outward, closed.
    """
    from ..geometry.planes import Plane, clip_mesh

    cut = Plane(wrist + start * forearm, -forearm)
    kept, kept_faces = clip_mesh(vertices, faces, cut)
    edges = np.concatenate([kept_faces[:, [0, 1]], kept_faces[:, [1, 2]], kept_faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    rim = edges[counts[inverse.reshape(-1)] == 1]  # directed as in their faces
    rim_vertices = np.unique(rim)
    count = len(kept)
    new_vertices = [kept]
    ring_index = {}
    for ring in range(1, rings + 1):
        offset = forearm * (length * ring / rings)
        ring_index[ring] = {v: count + k for k, v in enumerate(rim_vertices)}
        new_vertices.append(kept[rim_vertices] + offset)
        count += len(rim_vertices)
    ring_index[0] = {v: v for v in rim_vertices}
    new_faces = [kept_faces]
    for ring in range(rings):
        low, high = ring_index[ring], ring_index[ring + 1]
        for a, b in rim:  # the face holding a -> b lies on the hand's side
            new_faces.append(np.array([[low[b], low[a], high[a]], [low[b], high[a], high[b]]]))
    centre = kept[rim_vertices].mean(0) + forearm * length
    new_vertices.append(centre[None])
    last = ring_index[rings]
    new_faces.append(np.array([[last[b], last[a], count] for a, b in rim]))
    return np.concatenate(new_vertices), np.concatenate(new_faces).astype(np.int64)


def webxr_wrist_variant(vertices: np.ndarray, faces: np.ndarray, wrist: np.ndarray,
                   forearm: np.ndarray, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """The mesh to scan and to compare against for a wrist variant (module docstring)."""
    from ..geometry.planes import Plane, clip_mesh

    if variant == "forearm":
        return extend_forearm(vertices, faces, wrist, forearm)
    if variant == "cut":
        return clip_mesh(vertices, faces, Plane(wrist, -forearm))
    return vertices, faces
