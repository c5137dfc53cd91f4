"""Hand model v2's rest-pose parts: a rounded, padded palm, a forearm stub, D-shaped fingers.

Version 1 (:mod:`.parts`) is a mannequin: one flat rounded slab for the palm (an edge along the
back), the wrist cut flat a few millimetres past the joint, and fingers of circular round cones.
Version 2 keeps v1's skeleton (:func:`~lisa_hand.handmodel.shape.rest_skeleton`), its primitives
(round cones and rounded convex slabs on bones, :class:`~lisa_hand.handmodel.parts.HandParts`),
its field (:class:`~lisa_hand.handmodel.sdf.PosedField`, unchanged: same smooth union, culling,
skinning weights) and its detail (:mod:`.detail`: creases, palm lines, nails, bumps), and lays
the parts out anew (right hand, rest pose, average 18.5 cm hand; offsets scale with the hand):

* **palm** (bone 0, blended with the wide palm radius ``blend_palm``): a thin core slab (half
  thickness 8 mm), four metacarpal cones along the back from the carpus to the metacarpal heads
  (a back rounded across, highest over the middle metacarpal, falling toward index and little
  finger: the transverse arch), a carpal cone across the back of the wrist;
* **palmar pads**: the thenar eminence (two cones on the thumb metacarpal, bone 13, so it follows
  the thumb, and a base cone on the palm), the hypothenar eminence along the ulnar border, the
  distal palmar pad under the metacarpal heads; between them the palm is hollow (the thenar
  stands 10-11 mm, the hypothenar 4.5-6 mm out of it; v1's pads 6-8 and 2.7-3.3 mm);
* **wrist and forearm stub**: a second rounded slab in the palm plane (a stadium section 51 x
  33 mm at 2 cm proximal of the wrist joint, 52 x 33 mm at 4.5 cm; its rounded end 6.2 cm
  from the joint; an exact distance, unlike blended cones); in the palm group, so the wrist
  flows into the palm without a seam. It is rigid with the palm (bone 0): MANO has no wrist;
* **fingers**: every phalanx is three round cones, one central (the round back of the finger)
  and a lateral pair a little palmar of it (a wider, flatter palmar face): a D-shaped section,
  for the average hand 21.5 x 19.7 mm on the middle finger's proximal phalanx (9-10 % wider
  than deep), 7 % on the middle phalanges, 4-5 % on the distal ones (v1: circles); condyle
  capsules at the PIP/DIP/IP joints and v1's metacarpal heads give the knuckles;
* **webs**: between neighbouring fingers (palmar, reaching a third of the proximal phalanx) and
  the first web space between thumb and index (on the thumb metacarpal);
* **nails, creases, palm lines, bumps**: v1's detail (:func:`~.detail.build_nails`, ...) on the
  v2 surface.

Properties (``tests/handmodel/test_parts_v2.py`` checks them): near the surface ``|grad s|``
stays within a few percent of 1 on most points, as on v1, dipping most in the palm's blends; at
the generator's resolution (255 voxels per hand length) meshes in flat, fist and sampled poses
are one watertight piece; a fist keeps about 97-98 % of the flat hand's volume, as v1 does, so
touching parts do not sink into each other more than in v1. A v2 mesh takes about 1.5 times as
long as a v1 mesh (more parts, and about 9 % more vertices: the forearm).
"""

from __future__ import annotations

import numpy as np
import torch

from ..skeleton.tree import FINGER_JOINTS, FINGER_NAMES
from .detail import build_bumps, build_creases, build_nails, build_palm_lines
from .parts import (
    HandParts,
    _Cone,
    _cone_fields,
    _convex_hull_ccw,
    _finger_webs,
    _metacarpal_heads,
    _Proportions,
    _tensor,
)
from .shape import HandShape, rest_skeleton

__all__ = ["build_hand_parts_v2", "FOREARM_LENGTH"]

_PALM_FINGERS = ("index", "middle", "ring", "pinky")
FOREARM_LENGTH = 0.045
"""How far the forearm stub's slab outline runs proximal of the wrist joint (+x) for the average
18.5 cm hand, metres (its rounded end reaches 1.65 cm further)."""
# Palm core slab: mid plane height and half thickness (average hand, metres, times thickness).
_CORE_Y, _CORE_HALF = -0.0035, 0.0080
# Forearm stub slab: mid plane height, half thickness, and (x, half width) of its outline's
# ends, before the rounding (average hand, metres).
_FOREARM_Y, _FOREARM_HALF = -0.0015, 0.0165
_FOREARM_OUTLINE = ((-0.002, 0.0085), (FOREARM_LENGTH, 0.0095))
# Blend radius of the palm group, metres (v1: 3.5 mm; less here, since more parts overlap:
# a smooth union under-estimates the distance where parts blend).
_BLEND_PALM = 0.0028
# Finger section: (offset toward the back, lateral offset, radius) of the central cone and of
# the lateral pair, in units of the bone's flesh radius.
_CENTRAL_CONE = (0.02, 0.0, 0.88)
_LATERAL_PAIR = (-0.10, 0.22, 0.78)


def _core_slab(p: _Proportions) -> dict:
    """The palm's thin core: a rounded convex polygon from the wrist to the MCP joints (bone 0)
    -> the ``slab_*`` fields of :class:`HandParts`."""
    scale, width = p.scale, p.width
    mcp = {f: p.joints[FINGER_JOINTS[f][0]] for f in _PALM_FINGERS}
    outline = [
        p.xyz(0.004, 0.0, 0.012), p.xyz(0.004, 0.0, -0.016), p.xyz(-0.045, 0.0, 0.019),
        p.xyz(-0.035, 0.0, -0.028),
        mcp["index"] + np.array([0.004 * scale, 0.0, -0.002 * scale * width]),
        mcp["middle"] + np.array([0.004 * scale, 0.0, 0.0]),
        mcp["ring"] + np.array([0.004 * scale, 0.0, 0.0]),
        mcp["pinky"] + np.array([0.006 * scale, 0.0, 0.002 * scale * width]),
    ]  # fmt: skip
    forearm = [p.xyz(x, 0.0, -0.002 + sign * half) for x, half in _FOREARM_OUTLINE
               for sign in (1.0, -1.0)]
    heights = (_CORE_Y * p.scale * p.thick, _FOREARM_Y * p.scale * p.thick)
    radii = (_CORE_HALF * p.scale * p.thick, _FOREARM_HALF * p.scale * p.thick)
    # Plane frame rows (a, b, normal) = (x, -z, y), as in v1; vertices are absolute (a, b).
    plane_rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    vertices, centers, bounds = [], [], []
    for points, height, radius in zip((outline, forearm), heights, radii, strict=True):
        planar = _convex_hull_ccw(np.array([[q[0], -q[2]] for q in points]))
        centroid = planar.mean(0)
        vertices.append(_tensor(planar))
        centers.append([centroid[0], height, -centroid[1]])
        bounds.append(np.linalg.norm(planar - centroid, axis=1).max() + radius)
    return {
        "slab_rot": _tensor(np.stack([plane_rot, plane_rot])),
        "slab_origin": _tensor([[0.0, h, 0.0] for h in heights]),
        "slab_bone": _tensor([0, 0], torch.long),
        "slab_vertices": vertices,
        "slab_radius": _tensor(radii),
        "slab_center": _tensor(centers),
        "slab_bound": _tensor(bounds),
    }


def _dorsum_and_forearm(p: _Proportions) -> list[_Cone]:
    """Metacarpal cones along the back, the carpal cone, and the forearm stub: a central cone
    and a lateral pair, a little shorter (an oval section, a domed end; bone 0)."""
    scale, thick = p.scale, p.thick
    cones: list[_Cone] = []
    middle_z = p.joints[FINGER_JOINTS["middle"][0]][2]
    for finger in _PALM_FINGERS:
        mcp = p.joints[FINGER_JOINTS[finger][0]]
        r_mcp = p.radii[FINGER_JOINTS[finger][0], 0]
        # The transverse arch: outer metacarpals lower, 2.3 mm for the little finger's.
        arch = -0.06 * abs(mcp[2] - middle_z) * thick
        head = mcp + np.array([0.006 * scale, 0.0015 * scale * thick + arch, 0.0])
        base = np.array([-0.014 * scale, mcp[1] + 0.0005 * scale * thick + arch, 0.55 * mcp[2]])
        cones.append((base, head, 0.84 * r_mcp * thick, 0.76 * r_mcp * thick, 0, True))
    cones.append((p.xyz(-0.008, -0.001, 0.013), p.xyz(-0.008, -0.001, -0.017),
                  0.0105 * scale * thick, 0.0105 * scale * thick, 0, True))  # fmt: skip
    return cones


def _palmar_pads(p: _Proportions) -> list[_Cone]:
    """Thenar (on the thumb metacarpal and at its base), hypothenar and distal palmar pads, the
    first web space and the thumb metacarpal itself (all in the palm group)."""
    scale, thick, width = p.scale, p.thick, p.width
    cones: list[_Cone] = []
    cmc, thumb_mcp = p.joints[13], p.ends[13]
    cones.append((cmc, thumb_mcp, p.radii[13, 0], p.radii[13, 1], 13, True))
    thumb_len = np.linalg.norm(thumb_mcp - cmc)
    palmward = -p.dorsal[13] * 0.009 * scale * thick
    cones.append((cmc + p.dirs[13] * 0.05 * thumb_len + palmward,
                  cmc + p.dirs[13] * 0.72 * thumb_len + 0.5 * palmward,
                  0.0145 * scale * thick, 0.0100 * scale * thick, 13, True))  # fmt: skip
    cones.append((p.xyz(-0.010, -0.0080, 0.009), p.xyz(-0.036, -0.0085, 0.016),
                  0.0105 * scale * thick, 0.0095 * scale * thick, 0, True))  # fmt: skip
    # Hypothenar eminence along the ulnar border.
    cones.append((p.xyz(-0.012, -0.0065, -0.020), p.xyz(-0.062, -0.0070, -0.033),
                  0.0105 * scale * thick, 0.0098 * scale * thick, 0, True))  # fmt: skip
    # Distal palmar pad under the metacarpal heads, from index to little finger.
    index_mcp = p.joints[FINGER_JOINTS["index"][0]]
    pinky_mcp = p.joints[FINGER_JOINTS["pinky"][0]]
    cones.append((index_mcp + np.array([0.010 * scale, -0.0075 * scale * thick,
                                        -0.003 * scale * width]),
                  pinky_mcp + np.array([0.008 * scale, -0.0055 * scale * thick,
                                        0.004 * scale * width]),
                  0.0085 * scale * thick, 0.0075 * scale * thick, 0, True))  # fmt: skip
    # First web space: a fan of two cones from the thumb metacarpal toward the index MCP joint.
    web_target = index_mcp + np.array([0.013 * scale, -0.004 * scale * thick,
                                       0.002 * scale * width])
    for along, radius in ((0.85, 0.0060), (0.5, 0.0068)):
        start = cmc + along * (thumb_mcp - cmc)
        cones.append((start, web_target, radius * scale * thick, 0.0052 * scale * thick, 13,
                      True))
    # Webs between the fingers, palmar, reaching about a third of the proximal phalanx.
    cones += _finger_webs(p, (0.003 * scale, -0.0035 * scale * thick),
                          (-0.017 * scale, -0.0005 * scale), (0.0078 * scale, 0.0055 * scale))
    return cones


def _finger_cones(p: _Proportions) -> list[_Cone]:
    """Three cones per phalanx (a D-shaped section) and the condyles of every finger."""
    cones: list[_Cone] = []
    for finger in FINGER_NAMES:
        chain = FINGER_JOINTS[finger]
        for k, bone in enumerate(chain):
            if finger == "thumb" and k == 0:
                continue  # the metacarpal is in the palm group
            start, end = p.joints[bone], p.ends[bone]
            r0, r1 = p.radii[bone]
            up, side = p.dorsal[bone], p.lateral[bone]
            for dorsal, lateral, radius in (_CENTRAL_CONE, _LATERAL_PAIR):
                for sign in ((1.0,) if lateral == 0.0 else (1.0, -1.0)):
                    shift0 = up * dorsal * r0 + side * sign * lateral * r0
                    shift1 = up * dorsal * r1 + side * sign * lateral * r1
                    tip = end - p.dirs[bone] * (radius * r1 if lateral == 0.0 else r1)
                    cone_end = tip if k == 2 else end
                    cones.append((start + shift0, cone_end + shift1, radius * r0, radius * r1,
                                  bone, False))
        for bone in chain[:2]:
            r_joint = p.radii[bone, 1]
            half = r_joint * (0.2 + 0.1 * p.knuckle)
            radius = r_joint * (0.64 + 0.1 * p.knuckle)
            center = p.ends[bone] + p.dorsal[bone] * 0.08 * r_joint - p.dirs[bone] * 0.1 * r_joint
            cones.append((center - p.lateral[bone] * half, center + p.lateral[bone] * half,
                          radius, radius, bone, False))  # fmt: skip
    return cones


def build_hand_parts_v2(shape: HandShape, detail_seed: int) -> HandParts:
    """All parts and the per-subject detail of a v2 hand (rest pose, right hand).

    shape: the subject's :class:`HandShape` (the same parameters as v1; v2's own sampling is
        :func:`lisa_hand.handmodel.anthropometry.sample_anthropometric_shape`).
    detail_seed: seeds the subject's random detail (creases, palm lines, bumps), drawn in v1's
        order; the same seed gives the same hand.
    """
    if not isinstance(shape, HandShape):
        raise TypeError(f"shape must be a HandShape, got {type(shape).__name__}")
    if not isinstance(detail_seed, (int, np.integer)) or isinstance(detail_seed, bool):
        raise TypeError(f"detail_seed must be an int, got {type(detail_seed).__name__}")
    rng = np.random.default_rng(int(detail_seed))
    skel = rest_skeleton(shape)
    p = _Proportions.of(shape, skel)
    scale = p.scale
    cones = _palmar_pads(p) + _dorsum_and_forearm(p) + _finger_cones(p) + _metacarpal_heads(p)
    palm_y = _CORE_Y * scale * p.thick
    palm_half = (_CORE_HALF + 0.0015) * scale * p.thick  # the palmar face, pads averaged in
    wrist_half = 0.015 * scale * p.thick
    creases = build_creases(skel, scale, wrist_half, rng)
    lines = build_palm_lines(scale, p.width, palm_y, palm_half, rng)
    nails = build_nails(skel, scale)
    bumps = build_bumps(scale, rng)
    return HandParts(
        skeleton=skel,
        **_cone_fields(cones),
        **_core_slab(p),
        blend=0.0012 * shape.flesh * scale,
        blend_palm=_BLEND_PALM * shape.flesh * scale,
        **creases,
        **lines,
        **nails,
        **bumps,
        palm_center_y=palm_y,
        palm_half_thickness=palm_half,
    )

