"""The open hand's signed distance field: rigid parts per bone, a smooth union, and fine detail.

Every part is defined in the rest pose and attached to one bone ``j``; a query point ``x`` is
taken into each bone's rest frame with ``x_j = A_j^-1 x`` (``A_j`` = rest-to-posed transform of
:func:`lisa_hand.skeleton.forward_kinematics`), so parts move rigidly with their bones:

- round cones (hulls of two spheres) along each phalanx, their axes a little palmar of the bone
  so that the back of a flexed joint shows a knuckle, plus lateral capsules for the condyles at
  the PIP/DIP/IP joints and the metacarpal heads (the knuckles of a fist);
- a palm body (a rounded convex slab spanning the wrist and the four MCP joints), a short forearm
  stub, the hypothenar pad and the thumb's metacarpal with the thenar eminence, blended with a wide
  radius (``blend_palm``) into one soft body;
- everything joined by a smooth minimum ``s = -k log sum_i exp(-d_i / k)`` (``k = blend``, about
  1.5 mm). Because the parts of two bones move rigidly and blend, a flexed joint bulges on the
  outside and creases on the inside: pose-dependent deformation that linear blend skinning of a
  template cannot represent.

Fine detail is added as small displacements (slopes kept below about 0.3 so that ``|grad s|``
stays within a few percent of 1): flexion creases across the palmar side of each finger joint,
dorsal knuckle wrinkles, palm lines, raised fingernails, and per-subject smooth bumps of about
0.1-0.3 mm. Skinning weights are the union's blend factors ``softmax(-d / k)`` summed per bone
(the derivative of ``s`` with respect to each part), so they sum to 1 and say which bones own a
point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, NUM_JOINTS, PARENTS
from .primitives import round_cone_sdf, rounded_polygon_sdf, smooth_union, smoothstep
from .shape import HandShape, RestSkeleton, rest_skeleton

__all__ = ["HandTemplate", "HandFieldOutput", "build_template", "evaluate_hand_field"]

_DISTAL_BONES = tuple(FINGER_JOINTS[name][2] for name in FINGER_NAMES)
_NUM_NOISE_WAVES = 24


@dataclass
class HandTemplate:
    """Rest-pose parts and detail of one subject (float64 CPU tensors; :meth:`to` converts).

    skeleton: the :class:`RestSkeleton` the parts hang on.
    cone_start, cone_end: [P, 3] round cone sphere centres in the rest pose, metres.
    cone_radii: [P, 2] their radii, metres. cone_bone: [P] owning bone.
    num_palm_cones: how many leading cones belong to the palm group (blended with ``blend_palm``).
    slab_origin: [Q, 3], slab_axes: [Q, 3, 3] rows (a, b, normal) of each slab's plane frame,
    slab_vertices: [Q, V, 2] counter-clockwise outline, slab_radius: [Q], slab_bone: [Q]; slabs
        always belong to the palm group.
    blend, blend_palm: smooth-union radii k (metres) of the whole hand and of the palm group.
    crease_*: [C] line grooves across bones: bone, centre along the bone (metres from the bone's
        start joint), Gaussian width, depth (metres), flesh radius there, side (+1 palmar, -1
        dorsal), and the parent bone whose ownership also counts.
    line_*: palm lines (circular arcs on the palm, bone 0): centre [L, 2] (x, z), radius [L],
        mid-arc direction [L, 2], cosine of the half extent [L], width [L], depth [L].
    nail_*: [5] fingernails on the distal bones: start and end along the bone (metres), radius at
        the nail, raise (metres).
    noise_freqs: [K, 3] rad/m, noise_phases: [K], noise_amps: [K] metres: surface bumps.
    palm_center_y, palm_half_thickness: the palm slab's mid plane and half thickness (metres).
    """

    skeleton: RestSkeleton
    cone_start: torch.Tensor
    cone_end: torch.Tensor
    cone_radii: torch.Tensor
    cone_bone: torch.Tensor
    num_palm_cones: int
    slab_origin: torch.Tensor
    slab_axes: torch.Tensor
    slab_vertices: torch.Tensor
    slab_radius: torch.Tensor
    slab_bone: torch.Tensor
    blend: float
    blend_palm: float
    crease_bone: torch.Tensor
    crease_parent: torch.Tensor
    crease_center: torch.Tensor
    crease_width: torch.Tensor
    crease_depth: torch.Tensor
    crease_radius: torch.Tensor
    crease_side: torch.Tensor
    line_center: torch.Tensor
    line_radius: torch.Tensor
    line_mid: torch.Tensor
    line_cos_half: torch.Tensor
    line_width: torch.Tensor
    line_depth: torch.Tensor
    nail_start: torch.Tensor
    nail_end: torch.Tensor
    nail_radius: torch.Tensor
    nail_height: float
    noise_freqs: torch.Tensor
    noise_phases: torch.Tensor
    noise_amps: torch.Tensor
    palm_center_y: float
    palm_half_thickness: float

    def to(self, device: torch.device | str, dtype: torch.dtype) -> HandTemplate:
        """A copy with every floating tensor on ``device`` in ``dtype`` (indices stay long)."""
        values = {}
        for name, value in self.__dict__.items():
            if isinstance(value, torch.Tensor):
                if value.is_floating_point():
                    value = value.to(device=device, dtype=dtype)
                else:
                    value = value.to(device=device)
            elif isinstance(value, RestSkeleton):
                value = RestSkeleton(
                    **{k: v.to(device=device, dtype=dtype) for k, v in value.__dict__.items()}
                )
            values[name] = value
        return HandTemplate(**values)

    @property
    def num_parts(self) -> int:
        return self.cone_start.shape[0] + self.slab_origin.shape[0]


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


# Palm lines (x, z) for the average 18.5 cm hand, metres, z to be scaled by palm_width: start,
# middle and end of the distal transverse ("heart"), proximal transverse ("head") and thenar
# ("life") creases, with their depth (m) and width (m).
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

    palm_cones: list[tuple] = []  # (start, end, r0, r1, bone)
    cones: list[tuple] = []
    # Hypothenar pad along the ulnar border of the palm.
    palm_cones.append(
        (xyz(-0.014, -0.0055, -0.018), xyz(-0.060, -0.0055, -0.031), 0.0108 * scale * thick,
         0.0098 * scale * thick, 0)
    )  # fmt: skip
    # Thumb metacarpal and thenar eminence (bone 13, the thumb's CMC joint).
    cmc, thumb_mcp = joints[13], ends[13]
    palm_cones.append((cmc, thumb_mcp, radii[13, 0], radii[13, 1], 13))
    thumb_len = np.linalg.norm(thumb_mcp - cmc)
    toward_palm = -dorsal[13] * 0.0065 * scale * thick
    palm_cones.append(
        (cmc + dirs[13] * 0.05 * thumb_len + toward_palm,
         cmc + dirs[13] * 0.72 * thumb_len + toward_palm * 0.6,
         0.0135 * scale * thick, 0.0098 * scale * thick, 13)
    )  # fmt: skip

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
            cones.append((start + offset0, end + offset1, r0, r1, bone))
        # Condyles: at the distal end of the first two bones of each chain (PIP, DIP; the
        # thumb's MCP and IP), attached to the proximal bone.
        for bone in chain[:2]:
            r_joint = radii[bone, 1]
            half = r_joint * (0.2 + 0.14 * knuckle)
            radius = r_joint * (0.7 + 0.12 * knuckle)
            center = ends[bone] + dorsal[bone] * 0.04 * r_joint - dirs[bone] * 0.1 * r_joint
            cones.append(
                (center - lateral[bone] * half, center + lateral[bone] * half, radius, radius, bone)
            )
    # Metacarpal heads of the four fingers (the knuckles of a fist), on the palm bone.
    for finger in ("index", "middle", "ring", "pinky"):
        mcp_bone = FINGER_JOINTS[finger][0]
        r_mcp = radii[mcp_bone, 0]
        half = r_mcp * (0.15 + 0.15 * knuckle)
        radius = r_mcp * (0.66 + 0.14 * knuckle)
        center = joints[mcp_bone] + np.array([0.0015 * scale, 0.0024 * scale * thick, 0.0])
        side = np.array([0.0, 0.0, 1.0])
        cones.append((center - side * half, center + side * half, radius, radius, 0))

    all_cones = palm_cones + cones
    cone_start = np.array([c[0] for c in all_cones])
    cone_end = np.array([c[1] for c in all_cones])
    cone_radii = np.array([[c[2], c[3]] for c in all_cones])
    cone_bone = np.array([c[4] for c in all_cones])
    lengths = np.linalg.norm(cone_end - cone_start, axis=1)
    assert np.all(np.abs(cone_radii[:, 0] - cone_radii[:, 1]) < 0.95 * lengths)

    # Palm slab and forearm stub: rounded convex polygons in horizontal planes on bone 0.
    mcp = {f: joints[FINGER_JOINTS[f][0]] for f in ("index", "middle", "ring", "pinky")}
    palm_y = -0.002 * scale * thick
    palm_radius = 0.0115 * scale * thick
    outline = [
        xyz(-0.004, 0.0, 0.011), xyz(-0.004, 0.0, -0.015), xyz(-0.050, 0.0, 0.018),
        xyz(-0.034, 0.0, -0.030),
        mcp["index"] + np.array([0.003 * scale, 0.0, -0.002 * scale * width]),
        mcp["middle"] + np.array([0.002 * scale, 0.0, 0.0]),
        mcp["ring"] + np.array([0.003 * scale, 0.0, 0.0]),
        mcp["pinky"] + np.array([0.004 * scale, 0.0, 0.0]),
    ]  # fmt: skip
    forearm = [xyz(0.004, 0, -0.013), xyz(0.050, 0, -0.013), xyz(0.050, 0, 0.009),
               xyz(0.004, 0, 0.009)]  # fmt: skip
    # Plane frame rows (a, b, normal) = (x, -z, y): right-handed, normal = back of the hand.
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    polygons = []
    for points in (outline, forearm):
        planar = np.array([[p[0], -p[2]] for p in points])
        polygons.append(_convex_hull_ccw(planar))
    num_vertices = max(len(p) for p in polygons)
    slab_vertices = np.stack(
        [np.concatenate([p, np.repeat(p[-1:], num_vertices - len(p), 0)]) for p in polygons]
    )
    slab_origin = np.array([[0.0, palm_y, 0.0], [0.0, -0.001 * scale * thick, 0.0]])
    slab_radius = np.array([palm_radius, 0.0165 * scale * thick])

    # Creases: (bone, parent, centre along bone, width, depth, radius, side).
    creases: list[tuple] = []

    def jitter_depth() -> float:
        return float(rng.uniform(0.7, 1.3))

    def jitter_pos() -> float:
        return float(rng.normal(0.0, 0.0003))

    for finger in FINGER_NAMES:
        b1, b2, b3 = FINGER_JOINTS[finger]
        length1 = np.linalg.norm(ends[b1] - joints[b1])
        if finger == "thumb":
            palmar = [(b2, -0.0008, 0.0006, 0.00045), (b2, 0.0016, 0.0006, 0.0004),
                      (b3, -0.0003, 0.0006, 0.00045)]  # fmt: skip
            dorsal_rows = [(b3, off, 0.0005, 0.00018) for off in (-0.002, 0.0004, 0.0028)]
        else:
            palmar = [(b1, 0.36 * length1, 0.0008, 0.0005), (b2, -0.0009, 0.0006, 0.00045),
                      (b2, 0.0014, 0.0006, 0.0004), (b3, -0.0006, 0.0006, 0.0004)]  # fmt: skip
            dorsal_rows = [(b2, off, 0.0005, 0.00018) for off in (-0.0024, 0.0, 0.0024)]
            dorsal_rows += [(b3, off, 0.0005, 0.00014) for off in (-0.0012, 0.0012)]
        for rows, side in ((palmar, 1.0), (dorsal_rows, -1.0)):
            for bone, center, crease_width, depth in rows:
                center = center * scale + jitter_pos()
                along = np.clip(center / max(np.linalg.norm(ends[bone] - joints[bone]), 1e-9), 0, 1)
                radius = radii[bone, 0] + (radii[bone, 1] - radii[bone, 0]) * along
                creases.append(
                    (bone, PARENTS[bone], center, crease_width * scale, depth * jitter_depth(),
                     radius, side)
                )  # fmt: skip
    # Two wrist creases on the palmar side of the forearm stub (bone 0 runs toward -x, so a
    # negative centre is proximal of the wrist joint).
    for center in (-0.006, -0.013):
        creases.append((0, 0, center * scale + jitter_pos(), 0.0007 * scale,
                        0.00035 * jitter_depth(), 0.0165 * scale * thick, 1.0))  # fmt: skip

    # Palm lines: circular arcs through three jittered points.
    line_center, line_radius, line_mid, line_cos_half, line_width, line_depth = ([] for _ in range(6))
    for (start, middle, end), depth, line_w in _PALM_LINES:
        pts = [
            np.array([p[0] * scale, p[1] * scale * width]) + rng.normal(0.0, 0.0015, 2) * scale
            for p in (start, middle, end)
        ]
        center, radius = _circle_through(*pts)
        mid_dir = pts[1] - center
        mid_dir /= np.linalg.norm(mid_dir)
        cos_half = min(
            float(((p - center) / np.linalg.norm(p - center)) @ mid_dir) for p in (pts[0], pts[2])
        )
        line_center.append(center)
        line_radius.append(radius)
        line_mid.append(mid_dir)
        line_cos_half.append(cos_half)
        line_width.append(line_w * scale)
        line_depth.append(depth * jitter_depth())

    # Fingernails on the distal bones.
    nail_start, nail_end, nail_radius = [], [], []
    for finger in FINGER_NAMES:
        bone = FINGER_JOINTS[finger][2]
        length3 = np.linalg.norm(ends[bone] - joints[bone])
        r_tip = radii[bone, 1]
        nail_start.append((0.36 if finger == "thumb" else 0.42) * length3)
        nail_end.append(length3 - 0.5 * r_tip)
        nail_radius.append(0.5 * (radii[bone, 0] + r_tip))

    # Bumps: a sum of random plane waves, wavelengths 4-16 mm, RMS about 0.08 mm.
    directions = rng.normal(size=(_NUM_NOISE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wavelengths = np.exp(rng.uniform(math.log(0.004), math.log(0.016), _NUM_NOISE_WAVES))
    freqs = directions * (2.0 * math.pi / wavelengths)[:, None]
    phases = rng.uniform(0.0, 2.0 * math.pi, _NUM_NOISE_WAVES)
    # Amplitude proportional to wavelength (constant slope), total RMS ~ 0.08 mm.
    amps = wavelengths / np.sqrt(np.sum(wavelengths**2) / 2.0) * 0.00008

    def t(array, dtype=torch.float64) -> torch.Tensor:
        return torch.as_tensor(np.asarray(array), dtype=dtype)

    crease_cols = list(zip(*creases, strict=True))
    return HandTemplate(
        skeleton=skel,
        cone_start=t(cone_start),
        cone_end=t(cone_end),
        cone_radii=t(cone_radii),
        cone_bone=t(cone_bone, torch.long),
        num_palm_cones=len(palm_cones),
        slab_origin=t(slab_origin),
        slab_axes=t(np.stack([axes, axes])),
        slab_vertices=t(slab_vertices),
        slab_radius=t(slab_radius),
        slab_bone=t([0, 0], torch.long),
        blend=0.0015 * shape.flesh * scale,
        blend_palm=0.004 * shape.flesh * scale,
        crease_bone=t(crease_cols[0], torch.long),
        crease_parent=t(crease_cols[1], torch.long),
        crease_center=t(crease_cols[2]),
        crease_width=t(crease_cols[3]),
        crease_depth=t(np.array(crease_cols[4]) * scale),
        crease_radius=t(crease_cols[5]),
        crease_side=t(crease_cols[6]),
        line_center=t(line_center),
        line_radius=t(line_radius),
        line_mid=t(line_mid),
        line_cos_half=t(line_cos_half),
        line_width=t(line_width),
        line_depth=t(np.array(line_depth) * scale),
        nail_start=t(nail_start),
        nail_end=t(nail_end),
        nail_radius=t(nail_radius),
        nail_height=0.00035 * scale,
        noise_freqs=t(freqs),
        noise_phases=t(phases),
        noise_amps=t(amps),
        palm_center_y=palm_y,
        palm_half_thickness=palm_radius,
    )


def _bone_local(points: torch.Tensor, inv_transforms: torch.Tensor) -> torch.Tensor:
    """Points in every bone's rest frame: ``x_j = A_j^-1 x``.

    points: [N, 3]; inv_transforms: [16, 4, 4] -> [N, 16, 3]
    """
    rot = inv_transforms[:, :3, :3]  # [J, 3, 3]
    return torch.einsum("jab,nb->nja", rot, points) + inv_transforms[:, :3, 3]


def evaluate_hand_field(
    template: HandTemplate,
    inv_transforms: torch.Tensor,
    points: torch.Tensor,
    with_features: bool = False,
) -> HandFieldOutput:
    """Evaluate the posed hand at world points.

    template: the subject's :class:`HandTemplate` on the points' device and dtype.
    inv_transforms: [16, 4, 4] ``A_j^-1``, posed-to-rest transforms of the bones.
    points: [N, 3] world points, metres.
    with_features: also compute rest points and appearance features (nails, creases, ...).
    """
    skel = template.skeleton
    x_bone = _bone_local(points, inv_transforms)  # [N, J, 3]

    # Part distances: palm group first (cones, then slabs), then the other cones.
    cone_points = x_bone[:, template.cone_bone]  # [N, P, 3]
    cone_d = round_cone_sdf(
        cone_points,
        template.cone_start,
        template.cone_end,
        template.cone_radii[:, 0],
        template.cone_radii[:, 1],
    )
    slab_points = x_bone[:, template.slab_bone] - template.slab_origin
    slab_points = torch.einsum("qab,nqb->nqa", template.slab_axes, slab_points)
    slab_d = rounded_polygon_sdf(slab_points, template.slab_vertices, template.slab_radius)
    num_palm = template.num_palm_cones
    palm_d = torch.cat([cone_d[:, :num_palm], slab_d], dim=1)
    palm_s, palm_w = smooth_union(palm_d, template.blend_palm)
    top_d = torch.cat([palm_s[:, None], cone_d[:, num_palm:]], dim=1)
    sdf, top_w = smooth_union(top_d, template.blend)

    # Ownership: blend factors summed per bone.
    part_weights = torch.cat([top_w[:, :1] * palm_w, top_w[:, 1:]], dim=1)
    part_bones = torch.cat(
        [template.cone_bone[:num_palm], template.slab_bone, template.cone_bone[num_palm:]]
    )
    weights = points.new_zeros(points.shape[0], NUM_JOINTS)
    weights = weights.index_add(1, part_bones, part_weights)

    # Bone-local anatomical coordinates: along, dorsal and lateral (relative to the bone start).
    rel = x_bone - skel.joints
    along = (rel * skel.bone_dirs).sum(-1)  # [N, J]
    up = (rel * skel.dorsal).sum(-1)
    side = (rel * skel.lateral).sum(-1)
    radial = torch.sqrt(up * up + side * side + 1e-14)

    # Joint creases and knuckle wrinkles.
    cb = template.crease_bone
    c_along = along[:, cb] - template.crease_center
    profile = torch.exp(-0.5 * (c_along / template.crease_width) ** 2)
    facing = -template.crease_side * up[:, cb] / template.crease_radius
    palmar_side = template.crease_side > 0
    face_mask = torch.where(
        palmar_side, smoothstep(-0.05, 0.5, facing), smoothstep(0.35, 0.8, facing)
    )
    near = smoothstep(
        template.crease_radius + 0.006, template.crease_radius + 0.0025, radial[:, cb]
    )
    owner = weights[:, cb] + torch.where(
        template.crease_parent == cb, torch.zeros_like(profile), weights[:, template.crease_parent]
    )
    crease_shape = profile * face_mask * near * owner.clamp(max=1.0)
    displacement = (crease_shape * template.crease_depth).sum(-1)

    # Palm lines: arcs on the palmar side of the palm, where the palm owns the surface.
    x_palm = x_bone[:, 0]
    planar = torch.stack([x_palm[:, 0], x_palm[:, 2]], dim=-1)[:, None] - template.line_center
    dist_center = torch.sqrt((planar * planar).sum(-1) + 1e-14)  # [N, L]
    off_arc = dist_center - template.line_radius
    cos_mid = (planar * template.line_mid).sum(-1) / dist_center
    arc_mask = smoothstep(template.line_cos_half - 0.06, template.line_cos_half + 0.06, cos_mid)
    palm_y = template.palm_center_y
    half = template.palm_half_thickness
    palm_face = smoothstep(palm_y - 0.3 * half, palm_y - 0.75 * half, x_palm[:, 1])
    palm_owner = weights[:, 0] + weights[:, 13]
    line_shape = (
        torch.exp(-0.5 * (off_arc / template.line_width) ** 2)
        * arc_mask
        * (palm_face * palm_owner)[:, None]
    )
    displacement = displacement + (line_shape * template.line_depth).sum(-1)

    # Fingernails: a raised plate on the back of each distal bone, cuticle curved proximally.
    distal = torch.as_tensor(_DISTAL_BONES, device=points.device)
    n_along, n_up, n_side = along[:, distal], up[:, distal], side[:, distal]
    n_radius = template.nail_radius
    cuticle = n_along - 0.45 * n_side * n_side / n_radius
    nail_mask = (
        smoothstep(template.nail_start, template.nail_start + 0.0012, cuticle)
        * smoothstep(template.nail_end + 0.0008, template.nail_end - 0.0004, n_along)
        * smoothstep(0.3, 0.6, n_up / n_radius)
        * smoothstep(n_radius + 0.004, n_radius + 0.0015, radial[:, distal])
        * weights[:, distal]
    )
    displacement = displacement - template.nail_height * nail_mask.sum(-1)

    # Bumps: plane waves in the rest pose, carried by the owning bones.
    rest_points = torch.einsum("nj,nja->na", weights, x_bone)
    waves = torch.sin(rest_points @ template.noise_freqs.T + template.noise_phases)
    displacement = displacement + (waves * template.noise_amps).sum(-1)

    sdf = sdf + displacement
    if not with_features:
        return HandFieldOutput(sdf=sdf, weights=weights)

    nail = nail_mask.sum(-1).clamp(max=1.0)
    span = (template.nail_end - template.nail_start).clamp_min(1e-6)
    nail_along = ((n_along - template.nail_start) / span).clamp(0.0, 1.0)
    nail_along = (nail_along * nail_mask).sum(-1) / nail_mask.sum(-1).clamp_min(1e-6)
    crease = (crease_shape.amax(-1) if crease_shape.shape[1] else sdf * 0).clamp(max=1.0)
    crease = torch.maximum(crease, line_shape.amax(-1))
    # Palmar side: for fingers from the bone-local dorsal coordinate, for the palm from height.
    bone_radius = skel.radii.mean(-1)
    finger_palmar = smoothstep(0.15 * bone_radius, -0.45 * bone_radius, up)  # [N, J]
    palm_palmar = smoothstep(palm_y + 0.1 * half, palm_y - 0.6 * half, x_palm[:, 1])
    finger_palmar = torch.cat([palm_palmar[:, None], finger_palmar[:, 1:]], dim=1)
    palmar = (weights * finger_palmar).sum(-1)
    # Knuckles: the back of each joint (start of bones 1-15, in the parent-or-child region).
    joint_near = torch.exp(-0.5 * (along / (0.6 * bone_radius)) ** 2)
    back = smoothstep(0.2 * bone_radius, 0.8 * bone_radius, up)
    parents = torch.as_tensor(PARENTS[1:], device=points.device)
    joint_owner = weights[:, 1:] + weights[:, parents]
    knuckle = (joint_near[:, 1:] * back[:, 1:] * joint_owner.clamp(max=1.0)).amax(-1)
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
