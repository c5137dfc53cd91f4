"""The open hand's fine detail: creases, palm lines, fingernails and bumps, built and evaluated.

Detail is a small displacement added to the smooth union of the parts (slopes kept below about
0.3 so that ``|grad s|`` stays within a few percent of 1):

- flexion creases across the palmar side of each finger joint and dorsal knuckle wrinkles:
  Gaussian grooves ``depth * g(along / width)`` on one face of a bone, where that bone (or its
  parent) owns the surface;
- palm lines: Gaussian grooves along circular arcs on the palmar face of the palm;
- fingernails: a raised plate on the back of each distal bone, its cuticle curved proximally;
- bumps: a sum of plane waves of the rest-pose point (wavelengths 8-30 mm, RMS height 0.06 mm).

The ``build_*`` functions lay out one subject's detail in the rest pose (float64 tensors, fields
of :class:`~lisa_hand.handmodel.parts.HandParts`), drawing from the subject's numpy generator;
the ``*_at`` functions evaluate it at points given in the detail's local frames (``[N, C]``
tensors, one column per crease or nail; see :class:`~lisa_hand.handmodel.sdf.PosedField`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES, PARENTS
from .primitives import gaussian, smoothstep
from .shape import RestSkeleton

if TYPE_CHECKING:
    from .parts import HandParts

__all__ = [
    "CREASE_SUPPORT",
    "DISTAL_BONES",
    "build_creases",
    "build_palm_lines",
    "build_nails",
    "build_bumps",
    "creases_at",
    "palm_lines_at",
    "nails_at",
    "bumps_at",
]

DISTAL_BONES = tuple(FINGER_JOINTS[name][2] for name in FINGER_NAMES)
"""The five distal bones (thumb, index, middle, ring, pinky): they carry the nails."""
CREASE_SUPPORT = 5.0
"""Crease profiles are Gaussians: beyond this many widths they are treated as zero."""
_NUM_NOISE_WAVES = 24

# Palm lines (x, z) for the average 18.5 cm hand, metres, z to be scaled by palm_width: start,
# middle and end of the distal transverse ("heart"), proximal transverse ("head") and thenar
# ("life") creases, with their depth and width (metres).
_PALM_LINES = (
    (((-0.064, -0.046), (-0.076, -0.013), (-0.083, 0.012)), 0.00055, 0.0013),
    (((-0.066, 0.030), (-0.057, 0.002), (-0.048, -0.027)), 0.00055, 0.0013),
    (((-0.064, 0.029), (-0.040, 0.013), (-0.009, 0.007)), 0.0006, 0.0014),
)


def _tensor(array, dtype=torch.float64) -> torch.Tensor:
    return torch.as_tensor(np.asarray(array), dtype=dtype)


def _skeleton_arrays(skeleton: RestSkeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(joints [16, 3], bone ends [16, 3], radii [16, 2]) as float64 arrays (views), metres."""
    return skeleton.joints.numpy(), skeleton.bone_ends.numpy(), skeleton.radii.numpy()


def _skeleton_frames(skeleton: RestSkeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bone directions, dorsal axes, lateral axes), [16, 3] float64 arrays (views)."""
    return skeleton.bone_dirs.numpy(), skeleton.dorsal.numpy(), skeleton.lateral.numpy()


def _circle_through(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the circle through three 2D points."""
    matrix = 2.0 * np.array([b - a, c - a])
    rhs = np.array([b @ b - a @ a, c @ c - a @ a])
    center = np.linalg.solve(matrix, rhs)
    return center, float(np.linalg.norm(a - center))


# ----------------------------------------------------------------------------------------------
# Building (rest pose)


def _finger_crease_rows(finger: str, length1: float, scale: float) -> tuple[list, list]:
    """(palmar rows, dorsal rows) of one finger: (bone, centre along it, width, depth) for the
    average hand (centres in metres of the average hand, except the proximal palmar one)."""
    b1, b2, b3 = FINGER_JOINTS[finger]
    if finger == "thumb":
        palmar = [(b2, -0.0008, 0.0006, 0.00045), (b2, 0.0016, 0.0006, 0.0004),
                  (b3, -0.0003, 0.0006, 0.00045)]  # fmt: skip
        dorsal_rows = [(b3, off, 0.0005, 0.00018) for off in (-0.002, 0.0004, 0.0028)]
    else:
        palmar = [(b1, 0.36 * length1 / scale, 0.0008, 0.0005), (b2, -0.0009, 0.0006, 0.00045),
                  (b2, 0.0014, 0.0006, 0.0004), (b3, -0.0006, 0.0006, 0.0004)]  # fmt: skip
        dorsal_rows = [(b2, off, 0.0005, 0.00018) for off in (-0.0024, 0.0, 0.0024)]
        dorsal_rows += [(b3, off, 0.0005, 0.00014) for off in (-0.0012, 0.0012)]
    return palmar, dorsal_rows


def build_creases(
    skeleton: RestSkeleton, scale: float, palm_radius: float, rng: np.random.Generator
) -> dict[str, torch.Tensor]:
    """Flexion creases and knuckle wrinkles of every finger, then two wrist creases.

    skeleton: the rest skeleton; scale: hand length / 0.185 m; palm_radius: the palm slab's half
    thickness, metres (the wrist creases' flesh radius). Draws a normal jitter of each centre
    and a uniform depth factor per crease from ``rng``.
    -> the ``crease_*`` fields of :class:`~lisa_hand.handmodel.parts.HandParts`.
    """
    joints, ends, radii = _skeleton_arrays(skeleton)
    dirs, dorsal, lateral = _skeleton_frames(skeleton)
    # Creases: (bone, parent, centre along bone, width, depth, radius, side).
    creases: list[tuple] = []
    for finger in FINGER_NAMES:
        b1 = FINGER_JOINTS[finger][0]
        length1 = np.linalg.norm(ends[b1] - joints[b1])
        palmar, dorsal_rows = _finger_crease_rows(finger, length1, scale)
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
    crease_bound = np.hypot(CREASE_SUPPORT * crease_width, crease_radius + 0.006)
    return {
        "crease_rot": _tensor(crease_rot),
        "crease_origin": _tensor(crease_origin),
        "crease_bone": _tensor(crease_bone, torch.long),
        "crease_parent": _tensor([c[1] for c in creases], torch.long),
        "crease_width": _tensor(crease_width),
        "crease_depth": _tensor([c[4] for c in creases]),
        "crease_radius": _tensor(crease_radius),
        "crease_side": _tensor([c[6] for c in creases]),
        "crease_bound": _tensor(crease_bound),
    }


def build_palm_lines(
    scale: float, width: float, palm_y: float, palm_radius: float, rng: np.random.Generator
) -> dict[str, torch.Tensor]:
    """Palm lines: circular arcs through three jittered points of the average hand's lines.

    scale: hand length / 0.185 m; width: the shape's ``palm_width``; palm_y, palm_radius: the
    palm slab's mid plane and half thickness, metres. Draws the points' jitter and a depth
    factor per line from ``rng``. -> the ``line_*`` fields of ``HandParts``.
    """
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
    return {
        "line_center": _tensor(lines["center"]),
        "line_radius": _tensor(lines["radius"]),
        "line_mid": _tensor(lines["mid"]),
        "line_cos_half": _tensor(lines["cos"]),
        "line_width": _tensor(lines["width"]),
        "line_depth": _tensor(lines["depth"]),
        "line_bound_center": _tensor(line_bound_center),
        "line_bound": _tensor(line_bound),
    }


def build_nails(skeleton: RestSkeleton, scale: float) -> dict[str, torch.Tensor | float]:
    """Fingernails on the distal bones (no randomness). -> the ``nail_*`` fields of
    ``HandParts`` (``nail_height``, the plate's raise, a float in metres)."""
    joints, ends, radii = _skeleton_arrays(skeleton)
    dirs, dorsal, lateral = _skeleton_frames(skeleton)
    nail_bone = np.array(DISTAL_BONES)
    nail_length = np.linalg.norm(ends[nail_bone] - joints[nail_bone], axis=1)
    nail_tip_radius = radii[nail_bone, 1]
    nail_start = np.where(nail_bone == 15, 0.36, 0.42) * nail_length
    nail_end = nail_length - 0.5 * nail_tip_radius
    nail_radius = 0.5 * (radii[nail_bone, 0] + nail_tip_radius)
    nail_rot = np.stack([dirs[nail_bone], dorsal[nail_bone], lateral[nail_bone]], axis=1)
    nail_center = joints[nail_bone] + dirs[nail_bone] * (0.5 * (nail_start + nail_end))[:, None]
    nail_bound = 0.5 * (nail_end - nail_start) + nail_radius + 0.006
    return {
        "nail_rot": _tensor(nail_rot),
        "nail_origin": _tensor(joints[nail_bone]),
        "nail_bone": _tensor(nail_bone, torch.long),
        "nail_start": _tensor(nail_start),
        "nail_end": _tensor(nail_end),
        "nail_radius": _tensor(nail_radius),
        "nail_height": 0.00035 * scale,
        "nail_center": _tensor(nail_center),
        "nail_bound": _tensor(nail_bound),
    }


def build_bumps(scale: float, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Bumps: random plane waves, wavelengths 8-30 mm, amplitude proportional to wavelength
    (constant slope), RMS height 0.06 mm (peaks about 0.2 mm). Being a 3D field, its gradient
    also has a component along the surface normal, so the slope is kept at about 0.02.
    -> ``noise_freqs`` [K, 3] rad/m, ``noise_phases`` [K], ``noise_amps`` [K] metres."""
    directions = rng.normal(size=(_NUM_NOISE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wavelengths = np.exp(rng.uniform(math.log(0.008), math.log(0.030), _NUM_NOISE_WAVES))
    freqs = directions * (2.0 * math.pi / (wavelengths * scale))[:, None]
    phases = rng.uniform(0.0, 2.0 * math.pi, _NUM_NOISE_WAVES)
    amps = wavelengths / np.sqrt(np.sum(wavelengths**2) / 2.0) * 0.00006 * scale
    return {"noise_freqs": _tensor(freqs), "noise_phases": _tensor(phases),
            "noise_amps": _tensor(amps)}  # fmt: skip


# ----------------------------------------------------------------------------------------------
# Evaluation (posed: coordinates in each item's local frame)


def creases_at(
    along: torch.Tensor,
    up: torch.Tensor,
    side: torch.Tensor,
    table: torch.Tensor,
    owner: torch.Tensor,
    weights: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint creases and knuckle wrinkles (Gaussian grooves across a bone).

    along, up, side: [N, C] coordinates in the creases' frames, metres. table: [C, 7] rows
    (1 / width, depth, -side / radius, face low, face high, near far, near in). owner: [16, C]
    bone -> crease ownership. weights: [N, 16] skinning weights.
    -> (shape [N, C] in [0, 1], displacement [N] metres).
    """
    profile = gaussian(along * table[:, 0])
    face_mask = smoothstep(table[:, 3], table[:, 4], up * table[:, 2])
    crease_radial = (up * up + side * side + 1e-20).sqrt()
    near = smoothstep(table[:, 5], table[:, 6], crease_radial)
    ownership = (weights @ owner).clamp(max=1.0)
    crease_shape = profile * face_mask * near * ownership
    return crease_shape, crease_shape @ table[:, 1]


def palm_lines_at(
    x_palm: torch.Tensor, weights: torch.Tensor, parts: HandParts
) -> tuple[torch.Tensor, torch.Tensor]:
    """Palm lines: arcs on the palmar side of the palm, where the palm owns the surface.

    x_palm: [N, 3] points in the palm bone's rest frame, metres. weights: [N, 16].
    -> (shape [N, L] in [0, 1], displacement [N] metres).
    """
    planar = x_palm[:, None, 0::2] - parts.line_center  # [N, L, 2]
    dist_center = ((planar * planar).sum(-1) + 1e-14).sqrt()
    cos_mid = (planar * parts.line_mid).sum(-1) / dist_center
    arc_mask = smoothstep(parts.line_cos_half - 0.06, parts.line_cos_half + 0.06, cos_mid)
    palm_y, half = parts.palm_center_y, parts.palm_half_thickness
    height = x_palm[:, 1]
    palm_face = smoothstep(palm_y - 0.3 * half, palm_y - 0.75 * half, height)
    palm_face = palm_face * smoothstep(palm_y - half - 0.009, palm_y - half - 0.005, height)
    across = (dist_center - parts.line_radius) / parts.line_width
    line_shape = (
        gaussian(across)
        * arc_mask
        * (palm_face * (weights[:, 0] + weights[:, 13]))[:, None]
    )
    return line_shape, line_shape @ parts.line_depth


def nails_at(
    along: torch.Tensor,
    up: torch.Tensor,
    side: torch.Tensor,
    nails: torch.Tensor,
    ownership: torch.Tensor,
    parts: HandParts,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fingernails: a raised plate on the back of each distal bone, cuticle curved proximally.

    along, up, side: [N, M] coordinates in the frames of the nails ``nails`` [M] (indices into
    the five), metres. ownership: [N, M] the nail bones' skinning weights.
    -> (mask [N, M] in [0, 1], displacement [N] metres, negative: the surface rises).
    """
    radius = parts.nail_radius[nails]
    start, end = parts.nail_start[nails], parts.nail_end[nails]
    cuticle = along - 0.45 * side * side / radius
    nail_mask = (
        smoothstep(start, start + 0.0018, cuticle)
        * smoothstep(end + 0.001, end - 0.001, along)
        * smoothstep(0.3, 0.6, up / radius)
        * smoothstep(
            radius + 0.004, radius + 0.0015, (up * up + side * side + 1e-20).sqrt()
        )
        * ownership
    )
    return nail_mask, nail_mask.sum(-1) * -parts.nail_height


def bumps_at(rest_points: torch.Tensor, parts: HandParts) -> torch.Tensor:
    """Bumps: plane waves at the rest-pose point. rest_points: [N, 3] metres -> [N] metres."""
    waves = torch.sin(torch.addmm(parts.noise_phases, rest_points, parts.noise_freqs.T))
    return waves @ parts.noise_amps
