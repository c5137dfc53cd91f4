"""The open hand's signed distance field: rigid parts per bone, a smooth union, and fine detail.

Every part is defined in the rest pose and attached to one bone ``j``; a query point ``x`` is
taken into the bone's rest frame with ``x_j = A_j^-1 x`` (``A_j`` = rest-to-posed transform of
:func:`lisa_hand.skeleton.forward_kinematics`), so parts move rigidly with their bones:

- round cones (hulls of two spheres) along each phalanx, their axes a little palmar of the bone
  so that the back of a flexed joint shows a knuckle, plus lateral capsules for the condyles at
  the PIP/DIP/IP joints and the metacarpal heads (the knuckles of a fist);
- a palm body (a rounded convex slab spanning a short forearm stub, the wrist and the four MCP
  joints), the hypothenar pad, the finger webs, the first web space and the thumb's metacarpal
  with the thenar eminence, blended with a wide radius (``blend_palm``, about 3.5 mm) into one
  soft body;
- everything joined by a smooth minimum ``s = -k log sum_i exp(-d_i / k)`` (``k = blend``, about
  1.2 mm). Because the parts of two bones move rigidly and blend, a flexed joint bulges on the
  outside and creases on the inside: pose-dependent deformation that linear blend skinning of a
  template cannot represent.

Fine detail is added as small displacements (slopes kept below about 0.3 so that ``|grad s|``
stays within a few percent of 1): flexion creases across the palmar side of each finger joint,
dorsal knuckle wrinkles, palm lines, raised fingernails, and per-subject smooth bumps of about
0.1-0.2 mm. Near the surface ``|grad s|`` is 1 (to 5 %) on about 80 % of an open hand; it dips
below 1 inside the blends (part junctions, contacts between fingers) where the smooth union
slightly under-estimates the distance. Skinning weights are the union's blend factors
``softmax(-d / k)`` summed per bone (the derivatives of ``s`` with respect to each part's
distance), so they sum to 1 and say which bones own a point.

Speed: each part, crease and nail has a rest-pose local frame; posing composes it with
``A_j^-1`` into one affine map, so local coordinates of all parts come from one small matrix
product, and :class:`PosedField` groups query points into cells of a few centimetres and drops the
parts, creases and nails that cannot reach a cell (their blend weight there is below
``exp(-10)``).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.transforms import invert_rigid
from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS, PARENTS
from .primitives import gaussian, round_cone_sdf, rounded_polygon_sdf, smooth_union, smoothstep
from .shape import HandShape, RestSkeleton, rest_skeleton

__all__ = ["HandTemplate", "HandFieldOutput", "PosedField", "build_template", "single_threaded"]

_DISTAL_BONES = tuple(FINGER_JOINTS[name][2] for name in FINGER_NAMES)
_NUM_NOISE_WAVES = 24
# A part whose distance exceeds the nearest part's by this many blend radii is dropped (its
# weight exp(-10) ~ 5e-5 changes the distance by < 1e-7 m).
_CULL_BLENDS = 10.0
# Points evaluated together at most (keeps temporaries in cache), fewest points worth culling,
# and the number of points per culling cell aimed at.
_MAX_GROUP = 8192
_MIN_CULL = 2048
_TARGET_GROUP = 1500
# Crease profiles are Gaussians: beyond this many widths they are treated as zero.
_CREASE_SUPPORT = 5.0


@dataclass
class HandTemplate:
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

    def to(self, device: torch.device | str, dtype: torch.dtype) -> HandTemplate:
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

        return HandTemplate(**{name: convert(value) for name, value in self.__dict__.items()})


@dataclass
class HandFieldOutput:
    """The hand's field at N query points (world frame).

    sdf: [N] signed distance, metres (negative inside).
    weights: [N, 16] skinning weights (bone ownership), rows summing to 1.
    rest_points: [N, 3] the points carried back to the rest pose by their owning bones
        (``sum_j w_j A_j^-1 x``), metres: what texture and appearance are functions of.
    nail: [N] in [0, 1], 1 on a fingernail. nail_along: [N] in [0, 1], cuticle to free edge.
    crease: [N] in [0, 1], 1 in the middle of a crease, palm line or knuckle wrinkle.
    palmar: [N] in [0, 1], 1 on the palmar side.
    knuckle: [N] in [0, 1], 1 on the back of a knuckle.
    Feature fields (``rest_points`` onward) are None unless requested.
    """

    sdf: torch.Tensor
    weights: torch.Tensor
    rest_points: torch.Tensor | None = None
    nail: torch.Tensor | None = None
    nail_along: torch.Tensor | None = None
    crease: torch.Tensor | None = None
    palmar: torch.Tensor | None = None
    knuckle: torch.Tensor | None = None


# ----------------------------------------------------------------------------------------------
# Building the rest-pose template


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


def _circle_through(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the circle through three 2D points."""
    matrix = 2.0 * np.array([b - a, c - a])
    rhs = np.array([b @ b - a @ a, c @ c - a @ a])
    center = np.linalg.solve(matrix, rhs)
    return center, float(np.linalg.norm(a - center))


def _axis_frame(axis: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """Rows (axis, e2, e3): an orthonormal frame whose first row is ``axis``."""
    axis = axis / np.linalg.norm(axis)
    second = hint - axis * (hint @ axis)
    if np.linalg.norm(second) < 1e-6:
        second = np.array([0.0, 0.0, 1.0]) - axis * axis[2]
    second /= np.linalg.norm(second)
    return np.stack([axis, second, np.cross(axis, second)])


# Palm lines (x, z) for the average 18.5 cm hand, metres, z to be scaled by palm_width: start,
# middle and end of the distal transverse ("heart"), proximal transverse ("head") and thenar
# ("life") creases, with their depth and width (metres).
_PALM_LINES = (
    (((-0.064, -0.046), (-0.076, -0.013), (-0.083, 0.012)), 0.00055, 0.0013),
    (((-0.066, 0.030), (-0.057, 0.002), (-0.048, -0.027)), 0.00055, 0.0013),
    (((-0.064, 0.029), (-0.040, 0.013), (-0.009, 0.007)), 0.0006, 0.0014),
)


def build_template(shape: HandShape, detail_seed: int) -> HandTemplate:
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
    joints = skel.joints.numpy()
    ends = skel.bone_ends.numpy()
    radii = skel.radii.numpy()
    dirs = skel.bone_dirs.numpy()
    dorsal = skel.dorsal.numpy()
    lateral = skel.lateral.numpy()
    scale = shape.hand_length / 0.185
    width = shape.palm_width
    thick = shape.palm_thickness
    knuckle = shape.knuckle_size

    def xyz(x: float, y: float, z: float) -> np.ndarray:
        """A palm-frame point of the average hand, scaled to this hand."""
        return np.array([x * scale, y * scale * thick, z * scale * width])

    # Cones: (start, end, start radius, end radius, bone, palm group?)
    cones: list[tuple] = []
    # Hypothenar pad along the ulnar border of the palm.
    cones.append(
        (xyz(-0.014, -0.0055, -0.018), xyz(-0.060, -0.0055, -0.031), 0.0108 * scale * thick,
         0.0098 * scale * thick, 0, True)
    )  # fmt: skip
    # Thumb metacarpal and thenar eminence (bone 13, the thumb's CMC joint).
    cmc, thumb_mcp = joints[13], ends[13]
    cones.append((cmc, thumb_mcp, radii[13, 0], radii[13, 1], 13, True))
    thumb_len = np.linalg.norm(thumb_mcp - cmc)
    toward_palm = -dorsal[13] * 0.0075 * scale * thick
    cones.append(
        (cmc + dirs[13] * 0.1 * thumb_len + toward_palm + np.array([0, 0.002, 0]) * scale,
         cmc + dirs[13] * 0.7 * thumb_len + toward_palm * 0.5,
         0.0125 * scale * thick, 0.0095 * scale * thick, 13, True)
    )  # fmt: skip
    # First web space: a fan of two cones from the thumb metacarpal (its distal part and its
    # middle) to a point in the radial border of the palm near the index MCP joint. On the thumb
    # bone, so the web follows the thumb (it stretches out in palmar abduction).
    index_mcp = joints[FINGER_JOINTS["index"][0]]
    web_target = index_mcp + np.array(
        [0.014 * scale, -0.003 * scale * thick, 0.002 * scale * width]
    )
    for along, radius in ((0.85, 0.0068), (0.5, 0.0075)):
        web_start = cmc + along * (thumb_mcp - cmc)
        cones.append(
            (web_start, web_target, radius * scale * thick, 0.0058 * scale * thick, 13, True)
        )
    # Finger webs between the bases of neighbouring fingers.
    bases = [joints[FINGER_JOINTS[f][0]] for f in ("index", "middle", "ring", "pinky")]
    for left, right in zip(bases[:-1], bases[1:], strict=True):
        start = 0.5 * (left + right) + np.array([0.0, -0.002 * scale * thick, 0.0])
        end = start + np.array([-0.014 * scale, -0.0015 * scale, 0.0])
        cones.append((start, end, 0.0085 * scale, 0.007 * scale, 0, True))
    # Fingers: phalanx cones (axes a little palmar of the bones) and joint condyles.
    for finger in FINGER_NAMES:
        chain = FINGER_JOINTS[finger]
        for k, bone in enumerate(chain):
            if finger == "thumb" and k == 0:
                continue  # the metacarpal is in the palm group
            start, end = joints[bone], ends[bone]
            r0, r1 = radii[bone]
            offset0, offset1 = -dorsal[bone] * 0.12 * r0, -dorsal[bone] * 0.12 * r1
            if k == 2:
                end = end - dirs[bone] * r1  # the tip sphere's surface reaches the fingertip
            cones.append((start + offset0, end + offset1, r0, r1, bone, False))
        # Condyles at the distal end of the first two bones of each chain (PIP, DIP; the
        # thumb's MCP and IP), attached to the proximal bone.
        for bone in chain[:2]:
            r_joint = radii[bone, 1]
            half = r_joint * (0.16 + 0.1 * knuckle)
            radius = r_joint * (0.66 + 0.1 * knuckle)
            center = ends[bone] + dorsal[bone] * 0.04 * r_joint - dirs[bone] * 0.1 * r_joint
            cones.append(
                (center - lateral[bone] * half, center + lateral[bone] * half, radius, radius,
                 bone, False)
            )  # fmt: skip
    # Metacarpal heads of the four fingers (the knuckles of a fist), on the palm bone.
    for finger in ("index", "middle", "ring", "pinky"):
        mcp_bone = FINGER_JOINTS[finger][0]
        r_mcp = radii[mcp_bone, 0]
        half = r_mcp * (0.15 + 0.15 * knuckle)
        radius = r_mcp * (0.66 + 0.14 * knuckle)
        center = joints[mcp_bone] + np.array([0.0015 * scale, 0.0024 * scale * thick, 0.0])
        side = np.array([0.0, 0.0, 1.0])
        cones.append((center - side * half, center + side * half, radius, radius, 0, False))

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

    # Palm slab and forearm stub: rounded convex polygons in horizontal planes on bone 0.
    mcp = {f: joints[FINGER_JOINTS[f][0]] for f in ("index", "middle", "ring", "pinky")}
    palm_y = -0.002 * scale * thick
    palm_radius = 0.0122 * scale * thick
    outline = [
        xyz(-0.004, 0.0, 0.011), xyz(-0.004, 0.0, -0.015), xyz(-0.050, 0.0, 0.018),
        xyz(-0.034, 0.0, -0.030),
        mcp["index"] + np.array([0.003 * scale, 0.0, -0.002 * scale * width]),
        mcp["middle"] + np.array([0.002 * scale, 0.0, 0.0]),
        mcp["ring"] + np.array([0.003 * scale, 0.0, 0.0]),
        mcp["pinky"] + np.array([0.004 * scale, 0.0, 0.0]),
    ]  # fmt: skip
    # The wrist and a short forearm stub belong to the same slab (one exact rounded polygon, no
    # blend at the wrist).
    outline += [xyz(0.026, 0, -0.0115), xyz(0.026, 0, 0.0075)]
    # Plane frame rows (a, b, normal) = (x, -z, y): right-handed, normal = back of the hand.
    plane_rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    slab_origin = np.array([[0.0, palm_y, 0.0]])
    slab_radius = np.array([palm_radius])
    slab_vertices, slab_center, slab_bound = [], [], []
    for points, origin, radius in zip((outline,), slab_origin, slab_radius, strict=True):
        planar = _convex_hull_ccw(np.array([[p[0], -p[2]] for p in points]))
        slab_vertices.append(planar)
        centroid = planar.mean(0)
        slab_center.append(origin + np.array([centroid[0], 0.0, -centroid[1]]))
        slab_bound.append(np.linalg.norm(planar - centroid, axis=1).max() + radius)

    # Creases: (bone, parent, centre along bone, width, depth, radius, side).
    creases: list[tuple] = []
    for finger in FINGER_NAMES:
        b1, b2, b3 = FINGER_JOINTS[finger]
        length1 = np.linalg.norm(ends[b1] - joints[b1])
        if finger == "thumb":
            palmar = [(b2, -0.0008, 0.0006, 0.00045), (b2, 0.0016, 0.0006, 0.0004),
                      (b3, -0.0003, 0.0006, 0.00045)]  # fmt: skip
            dorsal_rows = [(b3, off, 0.0005, 0.00018) for off in (-0.002, 0.0004, 0.0028)]
        else:
            palmar = [(b1, 0.36 * length1 / scale, 0.0008, 0.0005), (b2, -0.0009, 0.0006, 0.00045),
                      (b2, 0.0014, 0.0006, 0.0004), (b3, -0.0006, 0.0006, 0.0004)]  # fmt: skip
            dorsal_rows = [(b2, off, 0.0005, 0.00018) for off in (-0.0024, 0.0, 0.0024)]
            dorsal_rows += [(b3, off, 0.0005, 0.00014) for off in (-0.0012, 0.0012)]
        for rows, side in ((palmar, 1.0), (dorsal_rows, -1.0)):
            for bone, center, crease_width, depth in rows:
                center = center * scale + float(rng.normal(0.0, 0.0003))
                bone_len = np.linalg.norm(ends[bone] - joints[bone])
                along = np.clip(center / bone_len, 0.0, 1.0)
                radius = radii[bone, 0] + (radii[bone, 1] - radii[bone, 0]) * along
                creases.append(
                    (bone, PARENTS[bone], center, crease_width * scale,
                     depth * scale * float(rng.uniform(0.7, 1.3)), radius, side)
                )  # fmt: skip
    # Two wrist creases on the palmar side of the forearm stub (bone 0 runs toward -x, so a
    # negative centre is proximal of the wrist joint).
    for center in (-0.006, -0.013):
        creases.append(
            (0, 0, center * scale + float(rng.normal(0.0, 0.0003)), 0.0007 * scale,
             0.00035 * scale * float(rng.uniform(0.7, 1.3)), palm_radius, 1.0)
        )  # fmt: skip
    crease_bone = np.array([c[0] for c in creases])
    crease_center_along = np.array([c[2] for c in creases])
    crease_rot = np.stack([dirs[crease_bone], dorsal[crease_bone], lateral[crease_bone]], axis=1)
    crease_origin = joints[crease_bone] + dirs[crease_bone] * crease_center_along[:, None]
    crease_width = np.array([c[3] for c in creases])
    crease_radius = np.array([c[5] for c in creases])
    crease_bound = np.hypot(_CREASE_SUPPORT * crease_width, crease_radius + 0.006)

    # Palm lines: circular arcs through three jittered points.
    lines: dict[str, list] = {k: [] for k in ("center", "radius", "mid", "cos", "width", "depth")}
    line_bound_center, line_bound = [], []
    for (start, middle, end), depth, line_width in _PALM_LINES:
        pts = [
            np.array([p[0] * scale, p[1] * scale * width]) + rng.normal(0.0, 0.0015, 2) * scale
            for p in (start, middle, end)
        ]
        center, radius = _circle_through(*pts)
        mid_dir = (pts[1] - center) / np.linalg.norm(pts[1] - center)
        cos_half = min(
            float(((p - center) / np.linalg.norm(p - center)) @ mid_dir) for p in (pts[0], pts[2])
        )
        lines["center"].append(center)
        lines["radius"].append(radius)
        lines["mid"].append(mid_dir)
        lines["cos"].append(cos_half)
        lines["width"].append(line_width * scale)
        lines["depth"].append(depth * scale * float(rng.uniform(0.7, 1.3)))
        mean = np.mean(pts, axis=0)
        line_bound_center.append(np.array([mean[0], palm_y - palm_radius, mean[1]]))
        line_bound.append(max(np.linalg.norm(p - mean) for p in pts) + 0.012 * scale)

    # Fingernails on the distal bones.
    nail_bone = np.array(_DISTAL_BONES)
    nail_length = np.linalg.norm(ends[nail_bone] - joints[nail_bone], axis=1)
    nail_tip_radius = radii[nail_bone, 1]
    nail_start = np.where(nail_bone == 15, 0.36, 0.42) * nail_length
    nail_end = nail_length - 0.5 * nail_tip_radius
    nail_radius = 0.5 * (radii[nail_bone, 0] + nail_tip_radius)
    nail_rot = np.stack([dirs[nail_bone], dorsal[nail_bone], lateral[nail_bone]], axis=1)
    nail_center = joints[nail_bone] + dirs[nail_bone] * (0.5 * (nail_start + nail_end))[:, None]
    nail_bound = 0.5 * (nail_end - nail_start) + nail_radius + 0.006

    # Bumps: random plane waves, wavelengths 8-30 mm, amplitude proportional to wavelength
    # (constant slope), RMS height 0.06 mm (peaks about 0.2 mm). Being a 3D field, its gradient
    # also has a component along the surface normal, so the slope is kept at about 0.02.
    directions = rng.normal(size=(_NUM_NOISE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wavelengths = np.exp(rng.uniform(math.log(0.008), math.log(0.030), _NUM_NOISE_WAVES))
    freqs = directions * (2.0 * math.pi / (wavelengths * scale))[:, None]
    phases = rng.uniform(0.0, 2.0 * math.pi, _NUM_NOISE_WAVES)
    amps = wavelengths / np.sqrt(np.sum(wavelengths**2) / 2.0) * 0.00006 * scale

    def t(array, dtype=torch.float64) -> torch.Tensor:
        return torch.as_tensor(np.asarray(array), dtype=dtype)

    return HandTemplate(
        skeleton=skel,
        cone_rot=t(cone_rot),
        cone_origin=t(cone_start),
        cone_bone=t([c[4] for c in cones], torch.long),
        cone_length=t(cone_length),
        cone_radii=t(cone_radii),
        cone_palm=t([c[5] for c in cones], torch.bool),
        cone_center=t(cone_center),
        cone_bound=t(cone_bound),
        slab_rot=t(plane_rot[None]),
        slab_origin=t(slab_origin),
        slab_bone=t([0], torch.long),
        slab_vertices=[t(v) for v in slab_vertices],
        slab_radius=t(slab_radius),
        slab_center=t(slab_center),
        slab_bound=t(slab_bound),
        blend=0.0012 * shape.flesh * scale,
        blend_palm=0.0035 * shape.flesh * scale,
        crease_rot=t(crease_rot),
        crease_origin=t(crease_origin),
        crease_bone=t(crease_bone, torch.long),
        crease_parent=t([c[1] for c in creases], torch.long),
        crease_width=t(crease_width),
        crease_depth=t([c[4] for c in creases]),
        crease_radius=t(crease_radius),
        crease_side=t([c[6] for c in creases]),
        crease_bound=t(crease_bound),
        line_center=t(lines["center"]),
        line_radius=t(lines["radius"]),
        line_mid=t(lines["mid"]),
        line_cos_half=t(lines["cos"]),
        line_width=t(lines["width"]),
        line_depth=t(lines["depth"]),
        line_bound_center=t(line_bound_center),
        line_bound=t(line_bound),
        nail_rot=t(nail_rot),
        nail_origin=t(joints[nail_bone]),
        nail_bone=t(nail_bone, torch.long),
        nail_start=t(nail_start),
        nail_end=t(nail_end),
        nail_radius=t(nail_radius),
        nail_height=0.00035 * scale,
        nail_center=t(nail_center),
        nail_bound=t(nail_bound),
        noise_freqs=t(freqs),
        noise_phases=t(phases),
        noise_amps=t(amps),
        palm_center_y=palm_y,
        palm_half_thickness=palm_radius,
    )


# ----------------------------------------------------------------------------------------------
# The posed field


def _posed_maps(
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


def _apply(
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


@contextlib.contextmanager
def single_threaded(device: torch.device):
    """Run CPU tensor work on one thread (restored afterwards); no-op on other devices.

    The field is many small tensor operations: intra-op threads do not pay for their start-up,
    and when other processes share the cores OpenMP's spinning makes them ten times slower.
    """
    if torch.device(device).type != "cpu":
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@dataclass
class _Selection:
    """Indices of the parts, creases, nails and palm lines evaluated for a group of points."""

    cones: torch.Tensor
    slabs: list[int]
    creases: torch.Tensor
    nails: torch.Tensor
    lines: bool


@dataclass
class _Prepared:
    """A selection's gathered frames (one matrix product gives all local coordinates) and
    parameter rows; local frame order: cones (palm group first), creases, nails, plane, bone 0."""

    weight: torch.Tensor
    bias: torch.Tensor
    count: int
    num_cones: int
    num_palm: int
    palm_on: bool
    cone_table: torch.Tensor
    palm_onehot: torch.Tensor | None
    top_onehot: torch.Tensor
    num_creases: int
    crease_table: torch.Tensor
    crease_owner: torch.Tensor
    num_nails: int
    nail_index: torch.Tensor
    nail_owner: torch.Tensor
    lines: bool


class PosedField:
    """The signed distance field (and features) of one subject in one pose.

    template: the subject's :class:`HandTemplate` (any device/dtype: converted to ``dtype`` on
        the transforms' device).
    transforms: [16, 4, 4] rest-to-posed bone transforms ``A_j`` (world frame, metres).
    cell_size: edge of the cells that group query points for culling, metres.
    """

    def __init__(
        self, template: HandTemplate, transforms: torch.Tensor, cell_size: float = 0.02
    ) -> None:
        if transforms.shape != (NUM_JOINTS, 4, 4):
            raise ValueError(f"transforms must be [16, 4, 4], got {tuple(transforms.shape)}")
        self.dtype = transforms.dtype
        self.device = transforms.device
        tpl = template.to(self.device, self.dtype)
        self.template = tpl
        self.cell_size = cell_size
        self.transforms = transforms
        inv = invert_rigid(transforms)
        self.inv_transforms = inv
        skel = tpl.skeleton
        identity = torch.eye(3, dtype=self.dtype, device=self.device)
        bones = torch.arange(NUM_JOINTS, device=self.device)
        # world -> each bone's rest frame (for rest points), and bone-anatomical frames.
        self.rest_matrix, self.rest_offset = inv[:, :3, :3], inv[:, :3, 3]
        bone_rot = torch.stack([skel.bone_dirs, skel.dorsal, skel.lateral], dim=1)
        self.bone_matrix, self.bone_offset = _posed_maps(bone_rot, skel.joints, bones, inv)
        self.cone_matrix, self.cone_offset = _posed_maps(
            tpl.cone_rot, tpl.cone_origin, tpl.cone_bone, inv
        )
        self.slab_matrix, self.slab_offset = _posed_maps(
            tpl.slab_rot, tpl.slab_origin, tpl.slab_bone, inv
        )
        self.crease_matrix, self.crease_offset = _posed_maps(
            tpl.crease_rot, tpl.crease_origin, tpl.crease_bone, inv
        )
        self.nail_matrix, self.nail_offset = _posed_maps(
            tpl.nail_rot, tpl.nail_origin, tpl.nail_bone, inv
        )
        self.palm_matrix, self.palm_offset = _posed_maps(
            identity[None], torch.zeros_like(identity[:1]), bones[:1], inv
        )

        # One-hot part -> bone maps for ownership, and bone -> detail ownership selectors.
        def onehot(index: torch.Tensor) -> torch.Tensor:
            return torch.nn.functional.one_hot(index, NUM_JOINTS).to(self.dtype)

        self.cone_onehot = onehot(tpl.cone_bone)
        self.slab_onehot = onehot(tpl.slab_bone)
        same = (tpl.crease_parent == tpl.crease_bone)[:, None]
        self.crease_owner = (
            onehot(tpl.crease_bone) + onehot(tpl.crease_parent).masked_fill(same, 0.0)
        ).T.contiguous()  # [16, C]
        self.nail_owner = onehot(tpl.nail_bone).T.contiguous()  # [16, 5]
        palmar = tpl.crease_side > 0
        self.crease_face_low = torch.where(palmar, -0.05, 0.35).to(self.dtype)
        self.crease_face_high = torch.where(palmar, 0.5, 0.8).to(self.dtype)
        self.rest_flat = inv[:, :3, :3].reshape(NUM_JOINTS, 9)

        # Posed bounding spheres.
        def posed(center: torch.Tensor, bone: torch.Tensor) -> torch.Tensor:
            a = transforms[bone]
            return (a[:, :3, :3] @ center[..., None])[..., 0] + a[:, :3, 3]

        self.cone_center = posed(tpl.cone_center, tpl.cone_bone)
        self.slab_center = posed(tpl.slab_center, tpl.slab_bone)
        self.crease_center = posed(tpl.crease_origin, tpl.crease_bone)
        self.nail_center = posed(tpl.nail_center, tpl.nail_bone)
        self.line_center = posed(tpl.line_bound_center, bones[:1].expand(len(tpl.line_bound)))
        self.all_cones = torch.arange(tpl.cone_bone.shape[0], device=self.device)
        self.all_creases = torch.arange(tpl.crease_bone.shape[0], device=self.device)
        self.all_nails = torch.arange(5, device=self.device)
        self._everything = _Selection(
            self.all_cones, list(range(len(tpl.slab_vertices))), self.all_creases,
            self.all_nails, True,
        )  # fmt: skip
        self._init_tables()
        self._prepared: dict[tuple, _Prepared] = {}

    def _init_tables(self) -> None:
        """Stacked frames and per-part parameter rows for the hot path (:meth:`_evaluate`)."""
        tpl = self.template
        # All local frames in one table: cones, creases, nails, the slabs' plane, bone 0.
        plane_matrix, plane_offset = _posed_maps(
            tpl.slab_rot[:1], torch.zeros_like(tpl.slab_origin[:1]), tpl.slab_bone[:1],
            self.inv_transforms,
        )  # fmt: skip
        matrices = [self.cone_matrix, self.crease_matrix, self.nail_matrix, plane_matrix,
                    self.palm_matrix]  # fmt: skip
        offsets = [self.cone_offset, self.crease_offset, self.nail_offset, plane_offset,
                   self.palm_offset]  # fmt: skip
        self.frame_matrix = torch.cat(matrices)  # [K, 3, 3]
        self.frame_offset = torch.cat(offsets)  # [K, 3]
        num_cones, num_creases = tpl.cone_bone.shape[0], tpl.crease_bone.shape[0]
        self.crease_start = num_cones
        self.nail_start = num_cones + num_creases
        self.plane_index = self.nail_start + 5
        # Cone rows: length, start radius, sin a, tan a.
        sin_a = (tpl.cone_radii[:, 0] - tpl.cone_radii[:, 1]) / tpl.cone_length
        tan_a = sin_a / (1.0 - sin_a * sin_a).sqrt()
        self.cone_table = torch.stack([tpl.cone_length, tpl.cone_radii[:, 0], sin_a, tan_a], 1)
        # Crease rows: 1 / width, depth, -side / radius, face low, face high, near far, near in.
        self.crease_table = torch.stack(
            [1.0 / tpl.crease_width, tpl.crease_depth, -tpl.crease_side / tpl.crease_radius,
             self.crease_face_low, self.crease_face_high, tpl.crease_radius + 0.006,
             tpl.crease_radius + 0.0025], 1,
        )  # fmt: skip
        # Slabs: both planes share their axes; edges padded to the same count.
        num_vertices = max(v.shape[0] for v in tpl.slab_vertices)
        padded = [
            torch.cat([v, v[-1:].expand(num_vertices - v.shape[0], 2)]) for v in tpl.slab_vertices
        ]
        vertices = torch.stack(padded)  # [Q, V, 2]
        edges = torch.roll(vertices, -1, dims=1) - vertices
        self.slab_vx, self.slab_vy = vertices[..., 0].reshape(-1), vertices[..., 1].reshape(-1)
        self.slab_ex, self.slab_ey = edges[..., 0].reshape(-1), edges[..., 1].reshape(-1)
        self.slab_inv_len = 1.0 / (edges * edges).sum(-1).clamp_min(1e-20).reshape(-1)
        self.slab_height = tpl.slab_origin @ tpl.slab_rot[0, 2]  # plane heights along normal
        self.slab_shape = (vertices.shape[0], num_vertices)

    def _prepare(self, sel: _Selection) -> _Prepared:
        """Gather the frames and parameters of a selection once (cached by its indices)."""
        key = (tuple(sel.cones.tolist()), tuple(sel.slabs), tuple(sel.creases.tolist()),
               tuple(sel.nails.tolist()), sel.lines)  # fmt: skip
        prepared = self._prepared.get(key)
        if prepared is not None:
            return prepared
        tpl = self.template
        palm_flags = tpl.cone_palm[sel.cones]
        cones = torch.cat([sel.cones[palm_flags], sel.cones[~palm_flags]])
        num_palm = int(palm_flags.sum())
        palm_on = bool(sel.slabs) or num_palm > 0
        frames = torch.cat(
            [cones, self.crease_start + sel.creases, self.nail_start + sel.nails,
             torch.tensor([self.plane_index, self.plane_index + 1], device=self.device)]
        )  # fmt: skip
        matrix = self.frame_matrix[frames]
        count = frames.shape[0]
        weight = matrix.transpose(0, 1).reshape(3 * count, 3).T.contiguous()
        bias = self.frame_offset[frames].T.reshape(3 * count).contiguous()
        onehot = self.cone_onehot[cones]
        palm_onehot = torch.cat([onehot[:num_palm], self.slab_onehot]) if palm_on else None
        prepared = _Prepared(
            weight=weight,
            bias=bias,
            count=count,
            num_cones=cones.shape[0],
            num_palm=num_palm,
            palm_on=palm_on,
            cone_table=self.cone_table[cones],
            palm_onehot=palm_onehot,
            top_onehot=onehot[num_palm:],
            num_creases=sel.creases.shape[0],
            crease_table=self.crease_table[sel.creases],
            crease_owner=self.crease_owner[:, sel.creases],
            num_nails=sel.nails.shape[0],
            nail_index=sel.nails,
            nail_owner=self.nail_owner[:, sel.nails],
            lines=sel.lines and palm_on,
        )
        self._prepared[key] = prepared
        return prepared

    # ------------------------------------------------------------------------------------------
    def evaluate(
        self, points: torch.Tensor, with_features: bool = False, cull: bool = True
    ) -> HandFieldOutput:
        """The field at world points.

        points: [N, 3] world points, metres, on this field's device (any float dtype; computed
            in the field's dtype).
        with_features: also compute rest points and appearance features.
        cull: group points in cells and skip the parts that cannot reach a cell (same values to
            about 1e-7 m); False evaluates every part at every point (the reference).
        """
        points = points.to(self.dtype)
        with single_threaded(points.device):
            return self._evaluate_grouped(points, with_features, cull)

    def _evaluate_grouped(
        self, points: torch.Tensor, with_features: bool, cull: bool
    ) -> HandFieldOutput:
        num = points.shape[0]
        if not cull or num <= _MIN_CULL:
            return self._evaluate(points, self._everything, with_features)
        detached = points.detach()
        low = detached.amin(0)
        extent = (detached.amax(0) - low).clamp_min(self.cell_size)
        # Cells of at least cell_size, larger where points are sparse (few points per cell cost
        # more in per-call overhead than culling saves).
        cell = max(self.cell_size, float((extent.prod() * _TARGET_GROUP / num) ** (1.0 / 3.0)))
        cells = torch.floor((detached - low) / cell).long()
        dims = cells.amax(0) + 1
        keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        keys, order = torch.sort(keys)
        unique, counts = torch.unique_consecutive(keys, return_counts=True)
        cell_index = torch.stack(
            [unique // (dims[1] * dims[2]), (unique // dims[2]) % dims[1], unique % dims[2]], -1
        )
        centers = low + (cell_index.to(self.dtype) + 0.5) * cell
        masks = self._select(centers, 0.5 * math.sqrt(3.0) * cell)
        pieces: list[HandFieldOutput] = []
        for m, index in enumerate(torch.split(order, counts.tolist())):
            selection = _Selection(
                torch.nonzero(masks[0][m])[:, 0],
                [q for q in range(masks[1].shape[1]) if masks[1][m, q]],
                torch.nonzero(masks[2][m])[:, 0],
                torch.nonzero(masks[3][m])[:, 0],
                bool(masks[4][m]),
            )
            group = points[index]
            for begin in range(0, group.shape[0], _MAX_GROUP):
                pieces.append(
                    self._evaluate(group[begin : begin + _MAX_GROUP], selection, with_features)
                )
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(num, device=order.device)
        merged = {}
        for name in HandFieldOutput.__dataclass_fields__:
            values = [getattr(piece, name) for piece in pieces]
            merged[name] = None if values[0] is None else torch.cat(values)[inverse]
        return HandFieldOutput(**merged)

    def _select(self, centers: torch.Tensor, half_diagonal: float) -> tuple[torch.Tensor, ...]:
        """Which parts and details can matter within ``half_diagonal`` of each centre.

        centers: [M, 3] world points. Uses the exact part distances at the centres: within a
        cell a part's distance lies in ``d(c) +- half_diagonal`` (distances are 1-Lipschitz), so a
        part whose lowest possible distance exceeds the highest possible nearest distance by
        ``_CULL_BLENDS`` blend radii weighs less than ``exp(-10)`` everywhere in the cell.
        -> masks [M, P] cones, [M, Q] slabs, [M, C] creases, [M, 5] nails, [M] palm lines.
        """
        tpl = self.template
        along, up, side = _apply(centers, self.cone_matrix, self.cone_offset)
        cone_d = round_cone_sdf(
            along, up * up + side * side, tpl.cone_length, tpl.cone_radii[:, 0],
            tpl.cone_radii[:, 1],
        )  # fmt: skip
        slab_d = torch.stack(
            [
                rounded_polygon_sdf(
                    torch.stack(_apply(centers, self.slab_matrix[q : q + 1],
                                       self.slab_offset[q : q + 1]), -1)[:, 0],
                    tpl.slab_vertices[q], tpl.slab_radius[q],
                )
                for q in range(len(tpl.slab_vertices))
            ], dim=1,
        )  # fmt: skip
        spread = 2.0 * half_diagonal
        palm_min = torch.minimum(cone_d[:, tpl.cone_palm].amin(1), slab_d.amin(1))
        top_min = torch.minimum(cone_d[:, ~tpl.cone_palm].amin(1), palm_min)
        top_limit = (top_min + spread + _CULL_BLENDS * tpl.blend)[:, None]
        palm_limit = (palm_min + spread + _CULL_BLENDS * tpl.blend_palm)[:, None]
        palm_on = palm_min[:, None] <= top_limit
        cone_mask = torch.where(
            tpl.cone_palm, (cone_d <= palm_limit) & palm_on, cone_d <= top_limit
        )
        slab_mask = (slab_d <= palm_limit) & palm_on
        c_along, c_up, c_side = _apply(centers, self.crease_matrix, self.crease_offset)
        crease_mask = (c_along.abs() <= _CREASE_SUPPORT * tpl.crease_width + half_diagonal) & (
            (c_up * c_up + c_side * c_side).sqrt() <= tpl.crease_radius + 0.006 + half_diagonal
        )
        n_along, n_up, n_side = _apply(centers, self.nail_matrix, self.nail_offset)
        nail_mask = (
            (n_along >= tpl.nail_start - 0.004 - half_diagonal)
            & (n_along <= tpl.nail_end + 0.002 + half_diagonal)
            & ((n_up * n_up + n_side * n_side).sqrt() <= tpl.nail_radius + 0.004 + half_diagonal)
        )
        line_dist = (centers[:, None] - self.line_center).norm(dim=-1)
        line_mask = palm_on[:, 0] & (line_dist <= tpl.line_bound + half_diagonal).any(1)
        return cone_mask, slab_mask, crease_mask, nail_mask, line_mask

    def _evaluate(
        self, points: torch.Tensor, sel: _Selection, with_features: bool
    ) -> HandFieldOutput:
        tpl = self.template
        prep = self._prepare(sel)
        num = points.shape[0]
        count = prep.count
        local = torch.addmm(prep.bias, points, prep.weight)  # [N, 3K]: all along | up | side
        along, up, side = local[:, :count], local[:, count : 2 * count], local[:, 2 * count :]

        # Round cones (branch-free form of primitives.round_cone_sdf with cached rows).
        k = prep.num_cones
        table = prep.cone_table
        c_along, c_up, c_side = along[:, :k], up[:, :k], side[:, :k]
        radial_sq = c_up * c_up + c_side * c_side
        radial = (radial_sq + 1e-20).sqrt()
        center = torch.minimum((c_along - radial * table[:, 3]).clamp_min(0.0), table[:, 0])
        offset = c_along - center
        cone_d = (offset * offset + radial_sq + 1e-20).sqrt() - (table[:, 1] - center * table[:, 2])

        # Palm group: palm cones and the two rounded slabs (shared plane axes).
        if prep.palm_on:
            plane_a, plane_b = along[:, count - 2 : count - 1], up[:, count - 2 : count - 1]
            height = side[:, count - 2 : count - 1]
            rel_x, rel_y = plane_a - self.slab_vx, plane_b - self.slab_vy  # [N, Q V]
            t = ((rel_x * self.slab_ex + rel_y * self.slab_ey) * self.slab_inv_len).clamp(0, 1)
            dx, dy = rel_x - t * self.slab_ex, rel_y - t * self.slab_ey
            shape = (num,) + self.slab_shape
            seg_sq = (dx * dx + dy * dy).view(shape).amin(-1)  # [N, Q]
            cross = (self.slab_ex * rel_y - self.slab_ey * rel_x).view(shape).amin(-1)
            outside = (cross < 0.0).to(points.dtype)
            heights = height - self.slab_height
            slab_d = (seg_sq * outside + heights * heights + 1e-20).sqrt() - tpl.slab_radius
            palm_d = torch.cat([cone_d[:, : prep.num_palm], slab_d], dim=1)
            palm_s, palm_w = smooth_union(palm_d, tpl.blend_palm)
            top_d = torch.cat([palm_s[:, None], cone_d[:, prep.num_palm :]], dim=1)
            sdf, top_w = smooth_union(top_d, tpl.blend)
            weights = (top_w[:, :1] * palm_w) @ prep.palm_onehot + top_w[:, 1:] @ prep.top_onehot
        else:
            sdf, top_w = smooth_union(cone_d, tpl.blend)
            weights = top_w @ prep.top_onehot

        # Joint creases and knuckle wrinkles (Gaussian grooves across a bone).
        displacement = None
        crease_shape = None
        if prep.num_creases:
            lo, hi = k, k + prep.num_creases
            ctab = prep.crease_table
            r_along, r_up, r_side = along[:, lo:hi], up[:, lo:hi], side[:, lo:hi]
            profile = gaussian(r_along * ctab[:, 0])
            face_mask = smoothstep(ctab[:, 3], ctab[:, 4], r_up * ctab[:, 2])
            crease_radial = (r_up * r_up + r_side * r_side + 1e-20).sqrt()
            near = smoothstep(ctab[:, 5], ctab[:, 6], crease_radial)
            owner = (weights @ prep.crease_owner).clamp(max=1.0)
            crease_shape = profile * face_mask * near * owner
            displacement = crease_shape @ ctab[:, 1]

        # Palm lines: arcs on the palmar side of the palm, where the palm owns the surface.
        x_palm = torch.stack([along[:, -1], up[:, -1], side[:, -1]], dim=1)
        line_shape = None
        if prep.lines:
            planar = x_palm[:, None, 0::2] - tpl.line_center  # [N, L, 2]
            dist_center = ((planar * planar).sum(-1) + 1e-14).sqrt()
            cos_mid = (planar * tpl.line_mid).sum(-1) / dist_center
            arc_mask = smoothstep(tpl.line_cos_half - 0.06, tpl.line_cos_half + 0.06, cos_mid)
            palm_y, half = tpl.palm_center_y, tpl.palm_half_thickness
            height = x_palm[:, 1]
            palm_face = smoothstep(palm_y - 0.3 * half, palm_y - 0.75 * half, height)
            palm_face = palm_face * smoothstep(palm_y - half - 0.009, palm_y - half - 0.005, height)
            across = (dist_center - tpl.line_radius) / tpl.line_width
            line_shape = (
                gaussian(across)
                * arc_mask
                * (palm_face * (weights[:, 0] + weights[:, 13]))[:, None]
            )
            lines = line_shape @ tpl.line_depth
            displacement = lines if displacement is None else displacement + lines

        # Fingernails: a raised plate on the back of each distal bone, cuticle curved proximally.
        nail_mask = None
        nail_along = None
        if prep.num_nails:
            lo = k + prep.num_creases
            hi = lo + prep.num_nails
            n = prep.nail_index
            nail_along, n_up, n_side = along[:, lo:hi], up[:, lo:hi], side[:, lo:hi]
            radius = tpl.nail_radius[n]
            start, end = tpl.nail_start[n], tpl.nail_end[n]
            cuticle = nail_along - 0.45 * n_side * n_side / radius
            nail_mask = (
                smoothstep(start, start + 0.0018, cuticle)
                * smoothstep(end + 0.001, end - 0.001, nail_along)
                * smoothstep(0.3, 0.6, n_up / radius)
                * smoothstep(
                    radius + 0.004, radius + 0.0015, (n_up * n_up + n_side * n_side + 1e-20).sqrt()
                )
                * (weights @ prep.nail_owner)
            )
            nails = nail_mask.sum(-1) * -tpl.nail_height
            displacement = nails if displacement is None else displacement + nails

        # Bumps: plane waves at the rest-pose point, carried by the owning bones:
        # sum_j w_j (R_j x + t_j) = (sum_j w_j R_j) x + sum_j w_j t_j.
        blended = (weights @ self.rest_flat).view(num, 3, 3)
        rest_points = (blended @ points[:, :, None])[..., 0] + weights @ self.rest_offset
        waves = torch.sin(torch.addmm(tpl.noise_phases, rest_points, tpl.noise_freqs.T))
        bumps = waves @ tpl.noise_amps
        displacement = bumps if displacement is None else displacement + bumps

        sdf = sdf + displacement
        if not with_features:
            return HandFieldOutput(sdf=sdf, weights=weights)
        return self._features(points, sdf, weights, rest_points, x_palm, crease_shape,
                              line_shape, nail_mask, nail_along, prep)  # fmt: skip

    def _features(
        self,
        points,
        sdf,
        weights,
        rest_points,
        x_palm,
        crease_shape,
        line_shape,
        nail_mask,
        nail_along,
        prep,
    ) -> HandFieldOutput:
        tpl = self.template
        skel = tpl.skeleton
        zeros = sdf.new_zeros(sdf.shape)
        if nail_mask is not None:
            n = prep.nail_index
            span = (tpl.nail_end[n] - tpl.nail_start[n]).clamp_min(1e-6)
            along = ((nail_along - tpl.nail_start[n]) / span).clamp(0.0, 1.0)
            total = nail_mask.sum(-1)
            nail = total.clamp(max=1.0)
            nail_along = (along * nail_mask).sum(-1) / total.clamp_min(1e-6)
        else:
            nail, nail_along = zeros, zeros
        crease = zeros
        if crease_shape is not None:
            crease = torch.maximum(crease, crease_shape.amax(-1))
        if line_shape is not None:
            crease = torch.maximum(crease, line_shape.amax(-1))
        crease = crease.clamp(max=1.0)
        # Palmar side: for fingers from the bone-local dorsal coordinate, for the palm from height.
        along, up, _ = _apply(points, self.bone_matrix, self.bone_offset)  # [N, 16] each
        bone_radius = skel.radii.mean(-1)
        finger_palmar = smoothstep(0.15 * bone_radius, -0.45 * bone_radius, up)
        palm_y, half = tpl.palm_center_y, tpl.palm_half_thickness
        palm_palmar = smoothstep(palm_y + 0.1 * half, palm_y - 0.6 * half, x_palm[:, 1])
        finger_palmar = torch.cat([palm_palmar[:, None], finger_palmar[:, 1:]], dim=1)
        palmar = (weights * finger_palmar).sum(-1)
        # Knuckles: the back of each joint, where the joint's two bones own the surface.
        joint_near = gaussian(along / (0.6 * bone_radius))
        back = smoothstep(0.2 * bone_radius, 0.8 * bone_radius, up)
        parents = torch.as_tensor(PARENTS[1:], device=points.device)
        joint_owner = (weights[:, 1:] + weights[:, parents]).clamp(max=1.0)
        knuckle = (joint_near[:, 1:] * back[:, 1:] * joint_owner).amax(-1)
        return HandFieldOutput(
            sdf=sdf,
            weights=weights,
            rest_points=rest_points,
            nail=nail,
            nail_along=nail_along,
            crease=crease,
            palmar=palmar,
            knuckle=knuckle,
        )
