"""The open hand's rest-pose parts: the layout of primitives and detail that its SDF evaluates.

:func:`build_hand_parts` turns a :class:`~lisa_hand.handmodel.shape.HandShape` and a detail seed
into a :class:`HandParts` table (right hand, rest pose, metres), in these steps:

1. rigid parts (:func:`_palm_group_cones`, :func:`_finger_cones`, :func:`_metacarpal_heads`):
   round cones along each phalanx, a little palmar of the bone, lateral capsules for the condyles
   and the metacarpal heads; the hypothenar pad, the thumb's metacarpal with the thenar eminence,
   the first web space and the finger webs form the palm group;
2. the palm slab (:func:`_palm_slab`): one rounded convex polygon spanning a short forearm stub,
   the wrist and the four MCP joints;
3. per-subject detail (:mod:`.detail`, drawn from ``numpy.random.default_rng(detail_seed)`` in
   this order): flexion creases and knuckle wrinkles, palm lines, fingernails, surface bumps.

Every part and detail item has a rest-pose frame on one bone (see :class:`HandParts`);
:class:`~lisa_hand.handmodel.sdf.PosedField` composes it with the bone's inverse transform and
evaluates the field. (Not to be confused with the MANO-like *mesh* template of
:mod:`.template`.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES
from .detail import build_bumps, build_creases, build_nails, build_palm_lines
from .shape import HandShape, RestSkeleton, rest_skeleton

__all__ = ["HandParts", "build_hand_parts", "posed_frame_maps", "local_coordinates"]

_PALM_FINGERS = ("index", "middle", "ring", "pinky")


@dataclass
class HandParts:
    """Rest-pose parts and detail of one subject (float64 CPU tensors; :meth:`to` converts).

    A *frame* is a rest-pose rotation ``rot`` [3, 3] (rows: the local axes) and origin [3] on a
    bone: local coordinates are ``rot (A_j^-1 x - origin)``.

    skeleton: the :class:`RestSkeleton` the parts hang on.
    cone_rot, cone_origin, cone_bone: [P, 3, 3], [P, 3], [P] round cone frames (first row = axis
        from the start sphere's centre). cone_length: [P], cone_radii: [P, 2] metres.
    cone_palm: [P] bool, True for the palm group (blended with ``blend_palm``).
    slab_rot, slab_origin, slab_bone: [Q, 3, 3], [Q, 3], [Q] plane frames of the rounded slabs
        (rows a, b, normal; all slabs share the axes and differ in height); slab_vertices: Q
        tensors [V, 2] (counter-clockwise outlines); slab_radius: [Q] half thicknesses. Slabs
        belong to the palm group (Q = 1 here: palm, wrist and forearm stub in one outline).
    blend, blend_palm: smooth-union radii k of the whole hand and of the palm group, metres.
    crease_rot, crease_origin, crease_bone: [C, ...] frames (rows: along, dorsal, lateral;
        origin at the crease's centre on the bone axis). crease_parent: [C] the other bone whose
        ownership counts; crease_width, crease_depth, crease_radius: [C] Gaussian width, depth,
        flesh radius (metres); crease_side: [C] +1 palmar, -1 dorsal.
    line_*: palm lines, circular arcs on the palm (bone 0): centre [L, 2] (x, z), radius [L],
        mid-arc direction [L, 2], cosine of the half extent [L], width [L], depth [L] (metres).
    nail_rot, nail_origin, nail_bone: [5, ...] distal bone frames (origin at the DIP/IP joint);
        nail_start, nail_end, nail_radius: [5] metres; nail_height: the nail's raise, metres.
    noise_freqs: [K, 3] rad/m, noise_phases: [K], noise_amps: [K] metres: surface bumps.
    *_center, *_bound: rest-pose bounding spheres (centre [.., 3], radius [..]) used to cull.
    palm_center_y, palm_half_thickness: the palm slab's mid plane and half thickness, metres.
    """

    skeleton: RestSkeleton
    cone_rot: torch.Tensor
    cone_origin: torch.Tensor
    cone_bone: torch.Tensor
    cone_length: torch.Tensor
    cone_radii: torch.Tensor
    cone_palm: torch.Tensor
    cone_center: torch.Tensor
    cone_bound: torch.Tensor
    slab_rot: torch.Tensor
    slab_origin: torch.Tensor
    slab_bone: torch.Tensor
    slab_vertices: list[torch.Tensor]
    slab_radius: torch.Tensor
    slab_center: torch.Tensor
    slab_bound: torch.Tensor
    blend: float
    blend_palm: float
    crease_rot: torch.Tensor
    crease_origin: torch.Tensor
    crease_bone: torch.Tensor
    crease_parent: torch.Tensor
    crease_width: torch.Tensor
    crease_depth: torch.Tensor
    crease_radius: torch.Tensor
    crease_side: torch.Tensor
    crease_bound: torch.Tensor
    line_center: torch.Tensor
    line_radius: torch.Tensor
    line_mid: torch.Tensor
    line_cos_half: torch.Tensor
    line_width: torch.Tensor
    line_depth: torch.Tensor
    line_bound_center: torch.Tensor
    line_bound: torch.Tensor
    nail_rot: torch.Tensor
    nail_origin: torch.Tensor
    nail_bone: torch.Tensor
    nail_start: torch.Tensor
    nail_end: torch.Tensor
    nail_radius: torch.Tensor
    nail_height: float
    nail_center: torch.Tensor
    nail_bound: torch.Tensor
    noise_freqs: torch.Tensor
    noise_phases: torch.Tensor
    noise_amps: torch.Tensor
    palm_center_y: float
    palm_half_thickness: float

    def to(self, device: torch.device | str, dtype: torch.dtype) -> HandParts:
        """A copy with every floating tensor on ``device`` in ``dtype`` (indices stay long)."""

        def convert(value):
            if isinstance(value, torch.Tensor):
                if value.is_floating_point():
                    return value.to(device=device, dtype=dtype)
                return value.to(device=device)
            if isinstance(value, list):
                return [convert(v) for v in value]
            if isinstance(value, RestSkeleton):
                return RestSkeleton(**{k: convert(v) for k, v in value.__dict__.items()})
            return value

        return HandParts(**{name: convert(value) for name, value in self.__dict__.items()})


# ----------------------------------------------------------------------------------------------
# Frames on bones, posed


def posed_frame_maps(
    rot: torch.Tensor, origin: torch.Tensor, bone: torch.Tensor, inv_transforms: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine maps world -> local for frames on bones: ``local = rot (A_b^-1 x - origin)``.

    rot: [K, 3, 3], origin: [K, 3], bone: [K], inv_transforms: [16, 4, 4]
    -> (matrix [K, 3, 3], offset [K, 3]) with ``local = matrix x + offset``.
    """
    inv = inv_transforms[bone]  # [K, 4, 4]
    matrix = rot @ inv[:, :3, :3]
    offset = (rot @ (inv[:, :3, 3] - origin)[..., None])[..., 0]
    return matrix, offset


def local_coordinates(
    points: torch.Tensor, matrix: torch.Tensor, offset: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Local coordinates of points in K frames, one [N, K] tensor per local axis.

    points [N, 3], matrix [K, 3, 3], offset [K, 3] -> three [N, K] (rows contiguous in K, so
    that the element-wise math that follows runs vectorised).
    """
    num = matrix.shape[0]
    weight = matrix.transpose(0, 1).reshape(3 * num, 3)
    flat = torch.addmm(offset.T.reshape(3 * num), points, weight.T)
    return flat[:, :num], flat[:, num : 2 * num], flat[:, 2 * num :]


# ----------------------------------------------------------------------------------------------
# Small geometry helpers


def _convex_hull_ccw(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull of 2D points (Andrew's monotone chain)."""
    order = sorted(map(tuple, points))

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in order:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(order):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def _axis_frame(axis: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """Rows (axis, e2, e3): an orthonormal frame whose first row is ``axis``."""
    axis = axis / np.linalg.norm(axis)
    second = hint - axis * (hint @ axis)
    if np.linalg.norm(second) < 1e-6:
        second = np.array([0.0, 0.0, 1.0]) - axis * axis[2]
    second /= np.linalg.norm(second)
    return np.stack([axis, second, np.cross(axis, second)])


def _tensor(array, dtype=torch.float64) -> torch.Tensor:
    return torch.as_tensor(np.asarray(array), dtype=dtype)


@dataclass(frozen=True)
class _Proportions:
    """The rest skeleton as float64 arrays (views of its tensors) and the shape's scales."""

    joints: np.ndarray
    ends: np.ndarray
    radii: np.ndarray
    dirs: np.ndarray
    dorsal: np.ndarray
    lateral: np.ndarray
    scale: float
    """hand length / 0.185 m (the average hand's length)."""
    width: float
    thick: float
    knuckle: float

    @classmethod
    def of(cls, shape: HandShape, skel: RestSkeleton) -> _Proportions:
        return cls(joints=skel.joints.numpy(), ends=skel.bone_ends.numpy(),
                   radii=skel.radii.numpy(), dirs=skel.bone_dirs.numpy(),
                   dorsal=skel.dorsal.numpy(), lateral=skel.lateral.numpy(),
                   scale=shape.hand_length / 0.185, width=shape.palm_width,
                   thick=shape.palm_thickness, knuckle=shape.knuckle_size)  # fmt: skip

    def xyz(self, x: float, y: float, z: float) -> np.ndarray:
        """A palm-frame point of the average hand, scaled to this hand."""
        return np.array([x * self.scale, y * self.scale * self.thick, z * self.scale * self.width])


# A cone: (start [3], end [3], start radius, end radius, bone, palm group?).
_Cone = tuple


# ----------------------------------------------------------------------------------------------
# Rigid parts


def _palm_group_cones(p: _Proportions) -> list[_Cone]:
    """Hypothenar pad, thumb metacarpal and thenar eminence, first web space, finger webs."""
    scale, thick, width = p.scale, p.thick, p.width
    cones: list[_Cone] = []
    # Hypothenar pad along the ulnar border of the palm.
    cones.append(
        (p.xyz(-0.014, -0.0055, -0.018), p.xyz(-0.060, -0.0055, -0.031), 0.0108 * scale * thick,
         0.0098 * scale * thick, 0, True)
    )  # fmt: skip
    # Thumb metacarpal and thenar eminence (bone 13, the thumb's CMC joint).
    cmc, thumb_mcp = p.joints[13], p.ends[13]
    cones.append((cmc, thumb_mcp, p.radii[13, 0], p.radii[13, 1], 13, True))
    thumb_len = np.linalg.norm(thumb_mcp - cmc)
    toward_palm = -p.dorsal[13] * 0.0075 * scale * thick
    cones.append(
        (cmc + p.dirs[13] * 0.1 * thumb_len + toward_palm + np.array([0, 0.002, 0]) * scale,
         cmc + p.dirs[13] * 0.7 * thumb_len + toward_palm * 0.5,
         0.0125 * scale * thick, 0.0095 * scale * thick, 13, True)
    )  # fmt: skip
    # First web space: a fan of two cones from the thumb metacarpal (its distal part and its
    # middle) to a point in the radial border of the palm near the index MCP joint. On the thumb
    # bone, so the web follows the thumb (it stretches out in palmar abduction).
    index_mcp = p.joints[FINGER_JOINTS["index"][0]]
    web_target = index_mcp + np.array(
        [0.014 * scale, -0.003 * scale * thick, 0.002 * scale * width]
    )
    for along, radius in ((0.85, 0.0068), (0.5, 0.0075)):
        web_start = cmc + along * (thumb_mcp - cmc)
        cones.append(
            (web_start, web_target, radius * scale * thick, 0.0058 * scale * thick, 13, True)
        )
    # Finger webs between the bases of neighbouring fingers.
    cones += _finger_webs(p, (0.0, -0.002 * scale * thick), (-0.014 * scale, -0.0015 * scale),
                          (0.0085 * scale, 0.007 * scale))
    return cones


def _finger_webs(p: _Proportions, lift: tuple[float, float], reach: tuple[float, float],
                 radii: tuple[float, float]) -> list[_Cone]:
    """A web cone between the bases of each pair of neighbouring fingers: from their midpoint
    moved by ``lift`` (x, y metres), along ``reach`` (x, y metres), radii ``radii`` metres."""
    bases = [p.joints[FINGER_JOINTS[f][0]] for f in _PALM_FINGERS]
    cones: list[_Cone] = []
    for left, right in zip(bases[:-1], bases[1:], strict=True):
        start = 0.5 * (left + right) + np.array([lift[0], lift[1], 0.0])
        end = start + np.array([reach[0], reach[1], 0.0])
        cones.append((start, end, radii[0], radii[1], 0, True))
    return cones


def _finger_cones(p: _Proportions) -> list[_Cone]:
    """Phalanx cones (axes a little palmar of the bones) and joint condyles of every finger."""
    cones: list[_Cone] = []
    for finger in FINGER_NAMES:
        chain = FINGER_JOINTS[finger]
        for k, bone in enumerate(chain):
            if finger == "thumb" and k == 0:
                continue  # the metacarpal is in the palm group
            start, end = p.joints[bone], p.ends[bone]
            r0, r1 = p.radii[bone]
            offset0, offset1 = -p.dorsal[bone] * 0.12 * r0, -p.dorsal[bone] * 0.12 * r1
            if k == 2:
                end = end - p.dirs[bone] * r1  # the tip sphere's surface reaches the fingertip
            cones.append((start + offset0, end + offset1, r0, r1, bone, False))
        # Condyles at the distal end of the first two bones of each chain (PIP, DIP; the
        # thumb's MCP and IP), attached to the proximal bone.
        for bone in chain[:2]:
            r_joint = p.radii[bone, 1]
            half = r_joint * (0.16 + 0.1 * p.knuckle)
            radius = r_joint * (0.66 + 0.1 * p.knuckle)
            center = p.ends[bone] + p.dorsal[bone] * 0.04 * r_joint - p.dirs[bone] * 0.1 * r_joint
            cones.append(
                (center - p.lateral[bone] * half, center + p.lateral[bone] * half, radius, radius,
                 bone, False)
            )  # fmt: skip
    return cones


def _metacarpal_heads(p: _Proportions) -> list[_Cone]:
    """Metacarpal heads of the four fingers (the knuckles of a fist), on the palm bone."""
    cones: list[_Cone] = []
    for finger in _PALM_FINGERS:
        mcp_bone = FINGER_JOINTS[finger][0]
        r_mcp = p.radii[mcp_bone, 0]
        half = r_mcp * (0.15 + 0.15 * p.knuckle)
        radius = r_mcp * (0.66 + 0.14 * p.knuckle)
        center = p.joints[mcp_bone] + np.array([0.0015 * p.scale, 0.0024 * p.scale * p.thick, 0.0])
        side = np.array([0.0, 0.0, 1.0])
        cones.append((center - side * half, center + side * half, radius, radius, 0, False))
    return cones


def _cone_fields(cones: list[_Cone]) -> dict[str, torch.Tensor]:
    """The ``cone_*`` fields of :class:`HandParts` from the cone list."""
    cone_start = np.array([c[0] for c in cones])
    cone_end = np.array([c[1] for c in cones])
    cone_radii = np.array([[c[2], c[3]] for c in cones])
    cone_length = np.linalg.norm(cone_end - cone_start, axis=1)
    assert np.all(np.abs(cone_radii[:, 0] - cone_radii[:, 1]) < 0.95 * cone_length)
    cone_rot = np.stack(
        [
            _axis_frame(e - s, np.array([0.0, 1.0, 0.0]))
            for s, e in zip(cone_start, cone_end, strict=True)
        ]
    )
    cone_center = 0.5 * (cone_start + cone_end)
    cone_bound = 0.5 * cone_length + cone_radii.max(1)
    return {
        "cone_rot": _tensor(cone_rot),
        "cone_origin": _tensor(cone_start),
        "cone_bone": _tensor([c[4] for c in cones], torch.long),
        "cone_length": _tensor(cone_length),
        "cone_radii": _tensor(cone_radii),
        "cone_palm": _tensor([c[5] for c in cones], torch.bool),
        "cone_center": _tensor(cone_center),
        "cone_bound": _tensor(cone_bound),
    }


def _palm_plane(p: _Proportions) -> tuple[float, float]:
    """(height of the palm slab's mid plane, its half thickness), metres."""
    return -0.002 * p.scale * p.thick, 0.0122 * p.scale * p.thick


def _palm_slab(p: _Proportions) -> dict[str, torch.Tensor]:
    """Palm slab and forearm stub: rounded convex polygons in horizontal planes on bone 0
    -> the ``slab_*`` fields of :class:`HandParts`."""
    scale, width = p.scale, p.width
    mcp = {f: p.joints[FINGER_JOINTS[f][0]] for f in _PALM_FINGERS}
    palm_y, palm_radius = _palm_plane(p)
    outline = [
        p.xyz(-0.004, 0.0, 0.011), p.xyz(-0.004, 0.0, -0.015), p.xyz(-0.050, 0.0, 0.018),
        p.xyz(-0.034, 0.0, -0.030),
        mcp["index"] + np.array([0.003 * scale, 0.0, -0.002 * scale * width]),
        mcp["middle"] + np.array([0.002 * scale, 0.0, 0.0]),
        mcp["ring"] + np.array([0.003 * scale, 0.0, 0.0]),
        mcp["pinky"] + np.array([0.004 * scale, 0.0, 0.0]),
    ]  # fmt: skip
    # The wrist and a short forearm stub belong to the same slab (one exact rounded polygon, no
    # blend at the wrist).
    outline += [p.xyz(0.026, 0, -0.0115), p.xyz(0.026, 0, 0.0075)]
    # Plane frame rows (a, b, normal) = (x, -z, y): right-handed, normal = back of the hand.
    plane_rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    slab_origin = np.array([[0.0, palm_y, 0.0]])
    slab_radius = np.array([palm_radius])
    slab_vertices, slab_center, slab_bound = [], [], []
    for points, origin, radius in zip((outline,), slab_origin, slab_radius, strict=True):
        planar = _convex_hull_ccw(np.array([[q[0], -q[2]] for q in points]))
        slab_vertices.append(planar)
        centroid = planar.mean(0)
        slab_center.append(origin + np.array([centroid[0], 0.0, -centroid[1]]))
        slab_bound.append(np.linalg.norm(planar - centroid, axis=1).max() + radius)
    return {
        "slab_rot": _tensor(plane_rot[None]),
        "slab_origin": _tensor(slab_origin),
        "slab_bone": _tensor([0], torch.long),
        "slab_vertices": [_tensor(v) for v in slab_vertices],
        "slab_radius": _tensor(slab_radius),
        "slab_center": _tensor(slab_center),
        "slab_bound": _tensor(slab_bound),
    }


# ----------------------------------------------------------------------------------------------
# The whole layout


def build_hand_parts(shape: HandShape, detail_seed: int) -> HandParts:
    """All parts and the per-subject detail of a hand (rest pose, right hand).

    shape: the subject's :class:`HandShape`.
    detail_seed: seeds the subject's random detail (crease depths and positions, palm lines,
        bumps); the same seed gives the same hand.
    """
    if not isinstance(shape, HandShape):
        raise TypeError(f"shape must be a HandShape, got {type(shape).__name__}")
    if not isinstance(detail_seed, (int, np.integer)) or isinstance(detail_seed, bool):
        raise TypeError(f"detail_seed must be an int, got {type(detail_seed).__name__}")
    rng = np.random.default_rng(int(detail_seed))
    skel = rest_skeleton(shape)
    proportions = _Proportions.of(shape, skel)
    scale = proportions.scale
    cones = _palm_group_cones(proportions) + _finger_cones(proportions)
    cones += _metacarpal_heads(proportions)
    palm_y, palm_radius = _palm_plane(proportions)
    # The detail draws from one generator, in this order: creases, palm lines, (nails: none),
    # bumps.
    creases = build_creases(skel, scale, palm_radius, rng)
    lines = build_palm_lines(scale, proportions.width, palm_y, palm_radius, rng)
    nails = build_nails(skel, scale)
    bumps = build_bumps(scale, rng)
    return HandParts(
        skeleton=skel,
        **_cone_fields(cones),
        **_palm_slab(proportions),
        blend=0.0012 * shape.flesh * scale,
        blend_palm=0.0035 * shape.flesh * scale,
        **creases,
        **lines,
        **nails,
        **bumps,
        palm_center_y=palm_y,
        palm_half_thickness=palm_radius,
    )
