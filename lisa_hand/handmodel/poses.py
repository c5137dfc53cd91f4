"""Natural hand poses: anatomical joint angles, joint limits, a synergy space, named poses.

A pose is MANO's 48-D axis-angle vector (3 global + 15 joints x 3, MANO joint order, each
rotation relative to the parent's frame, rest frames aligned with the world axes). Here every
finger joint ``j`` also has an anatomical frame ``F_j`` (columns: flexion axis, abduction axis,
twist axis = the bone direction in the average rest hand of :mod:`lisa_hand.handmodel.shape`),
fixed and shape-independent so that a pose means the same motion on every subject, and its
rotation is written with three anatomical angles (radians)::

    R_j = F_j  Rx(flexion) Ry(abduction) Rz(twist)  F_j^T

- flexion > 0 curls the finger toward the palm (for the right hand a rotation about about +z);
- abduction > 0 turns the finger toward the thumb (index: spread; ring, little: close up), and
  moves the thumb out of the palm plane (palmar abduction);
- twist is the small axial rotation (the thumb's pronation in opposition).

Flexion is the first angle so that the decomposition is unique for every flexion (PIP joints
bend past 90 degrees); it is singular only at |abduction| = 90 degrees, far outside the limits.
Joint limits are boxes on these angles (:data:`JOINT_LIMITS`), taken from published active
ranges of motion (e.g. MCP flexion 0-90, PIP 0-110, DIP 0-80 degrees).

Synergies (:data:`SYNERGY_NAMES`): the curl of each of the four fingers, their spread, and the
thumb's curl, opposition and palmar abduction; :func:`synergy_to_angles` maps them to angles
(inter-joint coupling as in natural grasps, e.g. DIP ~ 2/3 PIP), :func:`sample_pose` draws
natural poses from them plus per-joint noise, within the limits.

Left hands: every function that returns or checks poses takes ``side``; a left-hand pose is the
mirror (``lisa_hand.skeleton.mirror_pose``) of the right-hand pose with the same angles.
"""

from __future__ import annotations

import math

import torch

from ..geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..skeleton.kinematics import check_pose, check_side, mirror_pose
from ..skeleton.tree import FINGER_JOINTS, NUM_JOINTS, POSE_DIM
from .shape import HandShape, rest_skeleton

__all__ = [
    "SYNERGY_NAMES",
    "SYNERGY_DIM",
    "JOINT_LIMITS",
    "POSE_NAMES",
    "joint_frames",
    "angles_to_pose",
    "pose_to_angles",
    "clamp_to_limits",
    "within_limits",
    "synergy_to_angles",
    "sample_synergies",
    "sample_pose",
    "named_pose",
    "interpolate_poses",
    "pose_sequence",
]

NUM_FINGER_JOINTS = NUM_JOINTS - 1  # 15

SYNERGY_NAMES = (
    "index_curl",
    "middle_curl",
    "ring_curl",
    "pinky_curl",
    "spread",
    "thumb_curl",
    "thumb_opposition",
    "thumb_abduction",
)
SYNERGY_DIM = len(SYNERGY_NAMES)

_DEG = math.pi / 180.0


def _limits_table() -> torch.Tensor:
    """[15, 3, 2] (low, high) per joint (MANO order 1..15) and angle (flexion, abduction, twist)."""
    table = torch.zeros(NUM_FINGER_JOINTS, 3, 2, dtype=torch.float64)
    mcp = ((-25, 95), (-22, 22), (-12, 12))
    pip = ((-8, 115), (-6, 6), (-8, 8))
    dip = ((-15, 85), (-6, 6), (-8, 8))
    for finger in ("index", "middle", "ring", "pinky"):
        for joint, limits in zip(FINGER_JOINTS[finger], (mcp, pip, dip), strict=True):
            table[joint - 1] = torch.tensor(limits, dtype=torch.float64) * _DEG
    # Index and little fingers abduct further than the middle ones.
    table[FINGER_JOINTS["index"][0] - 1, 1] = torch.tensor([-20.0, 30.0]) * _DEG
    table[FINGER_JOINTS["pinky"][0] - 1, 1] = torch.tensor([-35.0, 15.0]) * _DEG
    thumb_cmc = ((-30, 55), (-25, 65), (-20, 45))
    thumb_mcp = ((-15, 65), (-12, 12), (-15, 15))
    thumb_ip = ((-25, 85), (-6, 6), (-8, 8))
    for joint, limits in zip(FINGER_JOINTS["thumb"], (thumb_cmc, thumb_mcp, thumb_ip), strict=True):
        table[joint - 1] = torch.tensor(limits, dtype=torch.float64) * _DEG
    return table


JOINT_LIMITS = _limits_table()
"""[15, 3, 2] float64: (low, high) radians of (flexion, abduction, twist), MANO joints 1..15."""


def _frames() -> torch.Tensor:
    """[15, 3, 3] anatomical frames (columns: flexion, abduction, twist axes) of the mean hand."""
    skel = rest_skeleton(HandShape())
    # Columns: lateral (flexion axis), dorsal (abduction axis), bone direction (twist axis).
    frames = torch.stack([skel.lateral, skel.dorsal, skel.bone_dirs], dim=-1)
    return frames[1:]


_FRAMES = _frames()


def joint_frames(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """[15, 3, 3] the fixed anatomical frames of joints 1..15 (columns: flexion, abduction,
    twist axes, right hand, rest pose)."""
    return _FRAMES.to(dtype)


def _euler_xyz(angles: torch.Tensor) -> torch.Tensor:
    """``Rx(a0) Ry(a1) Rz(a2)``: angles [..., 3] -> [..., 3, 3]."""
    cx, cy, cz = angles.cos().unbind(-1)
    sx, sy, sz = angles.sin().unbind(-1)
    rows = [
        torch.stack([cy * cz, -cy * sz, sy], -1),
        torch.stack([sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy], -1),
        torch.stack([-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy], -1),
    ]
    return torch.stack(rows, -2)


def _check_angles(angles: torch.Tensor, name: str = "angles") -> torch.Tensor:
    if not isinstance(angles, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(angles).__name__}")
    if angles.shape[-2:] != (NUM_FINGER_JOINTS, 3):
        raise ValueError(
            f"{name} must have shape [..., 15, 3] (flexion, abduction, twist per finger joint), "
            f"got {tuple(angles.shape)}"
        )
    if not torch.isfinite(angles).all():
        raise ValueError(f"{name} contains NaN or inf values")
    return angles


def _check_pose48(pose: torch.Tensor, name: str = "pose") -> tuple[torch.Tensor, tuple]:
    """Accept [48] or [..., 48]; return ([B, 16, 3], batch shape)."""
    if not isinstance(pose, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(pose).__name__}")
    if pose.shape[-1:] != (POSE_DIM,):
        raise ValueError(f"{name} must have shape [..., {POSE_DIM}], got {tuple(pose.shape)}")
    batch = tuple(pose.shape[:-1])
    return check_pose(pose.reshape(-1, POSE_DIM), name), batch


def angles_to_pose(
    angles: torch.Tensor,
    global_orient: torch.Tensor | None = None,
    side: str = "right",
) -> torch.Tensor:
    """Anatomical angles -> MANO axis-angle pose.

    angles: [..., 15, 3] radians (flexion, abduction, twist) of joints 1..15 (MANO order).
    global_orient: [..., 3] axis-angle of the wrist (the hand's side convention), or None (zero).
    side: 'right' or 'left' (the left pose is the mirror of the right one).
    -> [..., 48] axis-angle, radians.
    """
    angles = _check_angles(angles)
    check_side(side)
    frames = _FRAMES.to(angles)
    local = _euler_xyz(angles)
    rotmats = frames @ local @ frames.transpose(-1, -2)
    fingers = matrix_to_axis_angle(rotmats)  # [..., 15, 3]
    if global_orient is None:
        wrist = angles.new_zeros(*angles.shape[:-2], 1, 3)
    else:
        if global_orient.shape != angles.shape[:-2] + (3,):
            raise ValueError(
                f"global_orient must have shape {tuple(angles.shape[:-2]) + (3,)}, got "
                f"{tuple(global_orient.shape)}"
            )
        wrist = global_orient.to(angles)[..., None, :]
        if side == "left":
            wrist = mirror_pose(wrist)  # undone below with the fingers
    pose = torch.cat([wrist, fingers], dim=-2).reshape(*angles.shape[:-2], POSE_DIM)
    return mirror_pose(pose) if side == "left" else pose


def pose_to_angles(pose: torch.Tensor, side: str = "right") -> torch.Tensor:
    """MANO axis-angle pose -> anatomical angles (inverse of :func:`angles_to_pose`).

    pose: [..., 48] axis-angle radians. side: 'right' or 'left'.
    -> [..., 15, 3] radians (flexion, abduction, twist); the global orientation is dropped.
    """
    pose16, batch = _check_pose48(pose)
    check_side(side)
    if side == "left":
        pose16 = mirror_pose(pose16)
    frames = _FRAMES.to(pose16)
    rotmats = axis_angle_to_matrix(pose16[:, 1:])
    local = frames.transpose(-1, -2) @ rotmats @ frames
    abduction = torch.asin(local[..., 0, 2].clamp(-1.0, 1.0))
    flexion = torch.atan2(-local[..., 1, 2], local[..., 2, 2])
    twist = torch.atan2(-local[..., 0, 1], local[..., 0, 0])
    return torch.stack([flexion, abduction, twist], -1).reshape(*batch, NUM_FINGER_JOINTS, 3)


def clamp_to_limits(pose: torch.Tensor, side: str = "right") -> torch.Tensor:
    """Clamp each finger joint's anatomical angles into :data:`JOINT_LIMITS`.

    pose: [..., 48] axis-angle radians; the global orientation (first 3) is kept as is.
    -> [..., 48]
    """
    angles = pose_to_angles(pose, side)
    limits = JOINT_LIMITS.to(angles)
    clamped = torch.maximum(torch.minimum(angles, limits[..., 1]), limits[..., 0])
    result = angles_to_pose(clamped, side=side)
    return torch.cat([pose[..., :3], result[..., 3:]], dim=-1)


def within_limits(pose: torch.Tensor, side: str = "right", tolerance: float = 1e-4) -> torch.Tensor:
    """Whether every finger joint is within :data:`JOINT_LIMITS` (+- ``tolerance`` radians).

    pose: [..., 48] axis-angle radians. -> [...] bool
    """
    angles = pose_to_angles(pose, side)
    limits = JOINT_LIMITS.to(angles)
    inside = (angles >= limits[..., 0] - tolerance) & (angles <= limits[..., 1] + tolerance)
    return inside.flatten(-2).all(-1)


# Per-joint flexion (radians) at curl 1 for MCP, PIP, DIP, and the extension at curl -1.
_CURL_FLEXION = torch.tensor([1.40, 1.75, 1.15]) * 1.0
_CURL_EXTENSION = torch.tensor([0.35, 0.10, 0.20])
# Abduction at spread 1 (radians) of index, middle, ring, pinky MCP joints.
_SPREAD = {"index": 0.30, "middle": 0.04, "ring": -0.2, "pinky": -0.42}


def synergy_to_angles(synergies: torch.Tensor) -> torch.Tensor:
    """Synergy coordinates -> anatomical joint angles.

    synergies: [..., 8] in :data:`SYNERGY_NAMES` order: finger curls (0 straight, 1 fist,
        negative = hyperextension), spread (0 rest, 1 wide, negative = fingers pressed together),
        thumb curl (MCP and IP flexion), thumb opposition (0 in the palm plane, 1 across the palm
        toward the little finger), thumb abduction (out of the palm plane).
    -> [..., 15, 3] radians (flexion, abduction, twist), not yet clamped to the limits.
    """
    if not isinstance(synergies, torch.Tensor) or synergies.shape[-1:] != (SYNERGY_DIM,):
        raise ValueError(
            f"synergies must be a tensor of shape [..., {SYNERGY_DIM}] ({', '.join(SYNERGY_NAMES)})"
        )
    dtype = synergies.dtype if synergies.is_floating_point() else torch.float32
    syn = synergies.to(dtype)
    angles = syn.new_zeros(*syn.shape[:-1], NUM_FINGER_JOINTS, 3)
    flex_pos = _CURL_FLEXION.to(syn)
    flex_neg = _CURL_EXTENSION.to(syn)
    spread = syn[..., 4]
    for k, finger in enumerate(("index", "middle", "ring", "pinky")):
        curl = syn[..., k]
        flexion = (
            curl.clamp_min(0.0)[..., None] * flex_pos + curl.clamp_max(0.0)[..., None] * flex_neg
        )
        chain = [j - 1 for j in FINGER_JOINTS[finger]]
        angles[..., chain, 0] = flexion
        # Spread fades as the finger curls (collateral ligaments tighten in flexion).
        fade = 1.0 - 0.6 * curl.clamp(0.0, 1.0)
        angles[..., chain[0], 1] = _SPREAD[finger] * spread * fade
    curl, opposition, abduction = syn[..., 5], syn[..., 6], syn[..., 7]
    cmc, mcp, ip = (j - 1 for j in FINGER_JOINTS["thumb"])
    angles[..., cmc, 0] = 0.5 * opposition + 0.1 * curl
    angles[..., cmc, 1] = 0.2 * opposition + 0.75 * abduction
    angles[..., cmc, 2] = 0.7 * opposition
    angles[..., mcp, 0] = 0.55 * curl + 0.1 * opposition
    angles[..., ip, 0] = 0.9 * curl + 0.05 * opposition
    return angles


# Ranges the sampler draws synergies from: (low, high).
_SYNERGY_RANGE = torch.tensor(
    [[-0.15, 1.0], [-0.15, 1.0], [-0.15, 1.0], [-0.15, 1.0], [-0.4, 1.0], [-0.2, 1.0],
     [-0.2, 1.0], [-0.3, 1.0]]
)  # fmt: skip
# Standard deviation of the per-joint noise on (flexion, abduction, twist), radians.
_NOISE_STD = torch.tensor([0.08, 0.035, 0.03])


def sample_synergies(generator: torch.Generator, num: int) -> torch.Tensor:
    """Draw natural synergy coordinates.

    Finger curls share a common grasp level plus per-finger deviations, correlated between
    neighbours (ring and little move together); one draw in four individuates the fingers
    (independent curls, as in pointing or counting). Spread is limited when the fingers curl.

    generator: a seeded ``torch.Generator``; num: how many.
    -> [num, 8] float32
    """
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
    if not isinstance(num, int) or num < 1:
        raise ValueError(f"num must be a positive int, got {num!r}")

    def uniform(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=generator, dtype=torch.float64)

    def normal(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=generator, dtype=torch.float64)

    low, high = _SYNERGY_RANGE[:, 0].double(), _SYNERGY_RANGE[:, 1].double()
    base = uniform(num, 1) * 1.15 - 0.15
    deviation = 0.18 * normal(num, 4)
    deviation[:, 3] = 0.6 * deviation[:, 2] + 0.8 * deviation[:, 3]  # pinky follows ring
    grouped = base + deviation
    independent = uniform(num, 4) * 1.15 - 0.15
    individuate = (uniform(num, 1) < 0.25).double()
    curls = individuate * independent + (1.0 - individuate) * grouped
    mean_curl = curls.clamp(0.0, 1.0).mean(1, keepdim=True)
    spread = (uniform(num, 1) * 1.4 - 0.4) * (1.0 - 0.7 * mean_curl)
    thumb = uniform(num, 3) * (high[5:] - low[5:]) + low[5:]
    synergies = torch.cat([curls, spread, thumb], dim=1)
    return torch.maximum(torch.minimum(synergies, high), low).float()


def sample_pose(
    generator: torch.Generator,
    num: int = 1,
    noise: float = 1.0,
    global_orient: bool = False,
    side: str = "right",
) -> torch.Tensor:
    """Draw natural hand poses within the joint limits.

    Synergies from :func:`sample_synergies`, mapped to joint angles, plus independent Gaussian
    noise per joint (std 0.08 rad flexion, 0.035 abduction, 0.03 twist, times ``noise``),
    clamped to :data:`JOINT_LIMITS`.

    generator: a seeded ``torch.Generator`` (same seed, same poses).
    num: how many poses. noise: scale of the per-joint noise (0 = pure synergies).
    global_orient: also draw a uniformly random wrist orientation (else zero).
    side: 'right' or 'left'.
    -> [num, 48] float32 axis-angle.
    """
    check_side(side)
    if not (isinstance(noise, (int, float)) and math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a finite number >= 0, got {noise!r}")
    synergies = sample_synergies(generator, num).double()
    angles = synergy_to_angles(synergies)
    jitter = torch.randn(num, NUM_FINGER_JOINTS, 3, generator=generator, dtype=torch.float64)
    angles = angles + jitter * _NOISE_STD.double() * noise
    limits = JOINT_LIMITS
    angles = torch.maximum(torch.minimum(angles, limits[..., 1]), limits[..., 0])
    orient = None
    if global_orient:
        quat = torch.randn(num, 4, generator=generator, dtype=torch.float64)
        quat = quat / quat.norm(dim=-1, keepdim=True)
        quat = quat * torch.sign(quat[:, :1] + 1e-12)
        half = torch.acos(quat[:, 0].clamp(-1.0, 1.0))
        axis = quat[:, 1:] / torch.sin(half).clamp_min(1e-12)[:, None]
        orient = axis * (2.0 * half)[:, None]
    return angles_to_pose(angles, orient, side=side).float()


# Named poses as synergies (SYNERGY_NAMES order) plus per-joint overrides: MANO joint ->
# (flexion, abduction, twist) radians, None keeps the synergy's value. The pinch and ok thumbs
# and index fingers come from a small inverse-kinematics fit on the average hand (pad to pad).
_Override = tuple[float | None, float | None, float | None]
_NAMED: dict[str, tuple[tuple[float, ...], dict[int, _Override]]] = {
    "flat": ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), {}),
    "relaxed": ((0.22, 0.3, 0.36, 0.42, 0.15, 0.25, 0.2, 0.15), {}),
    "fist": ((1.0, 1.0, 1.0, 1.0, 0.0, 0.75, 0.55, 0.0), {}),
    "point": ((-0.05, 1.0, 1.0, 1.0, 0.1, 0.7, 0.6, 0.0), {}),
    "pinch": (
        (0.42, 0.45, 0.5, 0.55, 0.1, 0.1, 0.8, 0.2),
        {1: (0.64, None, None), 2: (0.95, None, None), 3: (0.8, None, None),
         13: (0.43, 0.15, 0.57), 14: (0.0, 0.0, 0.0), 15: (0.1, 0.0, 0.0)},
    ),
    "ok": (
        (0.6, 0.12, 0.16, 0.2, 0.45, 0.1, 0.8, 0.2),
        {1: (0.5, None, None), 2: (1.03, None, None), 3: (0.9, None, None),
         13: (0.41, 0.05, 0.75), 14: (0.0, 0.0, 0.0), 15: (0.1, 0.0, 0.0)},
    ),
}  # fmt: skip
POSE_NAMES = tuple(_NAMED)


def named_pose(name: str, side: str = "right", dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """A named pose: one of :data:`POSE_NAMES` (flat, relaxed, fist, point, pinch, ok).

    -> [48] axis-angle radians (zero global orientation), within the joint limits.
    """
    if name not in _NAMED:
        raise ValueError(f"unknown pose name {name!r}: known names are {', '.join(POSE_NAMES)}")
    check_side(side)
    synergies, overrides = _NAMED[name]
    angles = synergy_to_angles(torch.tensor(synergies, dtype=torch.float64))
    for joint, values in overrides.items():
        for k, value in enumerate(values):
            if value is not None:
                angles[joint - 1, k] = value
    angles = torch.maximum(torch.minimum(angles, JOINT_LIMITS[..., 1]), JOINT_LIMITS[..., 0])
    return angles_to_pose(angles, side=side).to(dtype)


def interpolate_poses(
    start: torch.Tensor, end: torch.Tensor, num: int, side: str = "right"
) -> torch.Tensor:
    """Poses moving from ``start`` to ``end``, both included.

    Finger joints move linearly in anatomical angles (so every intermediate pose stays within the
    joint limits when both ends are), the global orientation by spherical interpolation (slerp).

    start, end: [48] axis-angle radians. num: number of poses (>= 2). side: 'right' or 'left'.
    -> [num, 48]
    """
    for name, pose in (("start", start), ("end", end)):
        if not isinstance(pose, torch.Tensor) or pose.shape != (POSE_DIM,):
            shape = tuple(pose.shape) if isinstance(pose, torch.Tensor) else type(pose).__name__
            raise ValueError(f"{name} must be a tensor of shape [{POSE_DIM}], got {shape}")
    if not isinstance(num, int) or num < 2:
        raise ValueError(f"num must be an int >= 2, got {num!r}")
    dtype = torch.promote_types(start.dtype, torch.float32)
    start64, end64 = start.double(), end.to(start.device).double()
    weights = torch.linspace(0.0, 1.0, num, dtype=torch.float64, device=start.device)
    angles_a, angles_b = pose_to_angles(start64, side), pose_to_angles(end64, side)
    angles = angles_a + weights[:, None, None] * (angles_b - angles_a)
    rot_a = axis_angle_to_matrix(start64[:3])
    rot_b = axis_angle_to_matrix(end64[:3])
    relative = matrix_to_axis_angle(rot_a.T @ rot_b)
    orient = matrix_to_axis_angle(rot_a @ axis_angle_to_matrix(weights[:, None] * relative))
    if side == "left":
        orient = mirror_pose(orient)  # angles_to_pose mirrors it back with the fingers
    poses = angles_to_pose(angles, orient, side=side)
    return poses.to(dtype)


def pose_sequence(
    poses: list[torch.Tensor], frames_per_segment: int, side: str = "right"
) -> torch.Tensor:
    """Chain :func:`interpolate_poses` through several key poses (no repeated key frames).

    poses: K >= 2 tensors [48]. frames_per_segment: poses per segment including its start (>= 1).
    -> [(K - 1) * frames_per_segment + 1, 48]
    """
    if len(poses) < 2:
        raise ValueError(f"poses must hold at least 2 key poses, got {len(poses)}")
    if not isinstance(frames_per_segment, int) or frames_per_segment < 1:
        raise ValueError(f"frames_per_segment must be an int >= 1, got {frames_per_segment!r}")
    segments = []
    for a, b in zip(poses[:-1], poses[1:], strict=True):
        segments.append(interpolate_poses(a, b, frames_per_segment + 1, side)[:-1])
    segments.append(poses[-1].to(segments[0])[None])
    return torch.cat(segments)
