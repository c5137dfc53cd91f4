"""Synthetic photos of TWO hands with ground truth, for ``python -m benchmarks two_hands``.

Each scene holds a right hand and a left hand (the mirror image of its subject) of two DIFFERENT
held-out subjects of the open hand model (:func:`benchmarks._photo_scenes.held_out_subjects`).
Scene ``i`` is of kind ``KINDS[i % 5]``: ``apart`` (both raised, palms to the camera, thumbs
towards each other, a 3-8 cm gap); ``crossed`` (an X, one hand 1-2.5 cm in front of the other,
hiding part of it: the left in scenes 1, 11, ..., the right in 6, 16, ...; one in two showing
its back); ``clasped`` (palm against palm, turned 70-100 degrees from each other, the fingers of
each closed round the other); ``interlaced`` (facing, fingers spread and bent towards the other
hand, brought together at the lateral offset that lets them in deepest, the fingers of each
between the other's); ``holding_wrist`` (one raised, palm to the camera, the other's palm on its
wrist, fingers closed round it: the left hand holds in scenes 4, 14, ..., the right in 9, ...).

Per scene (a ``numpy.random.SeedSequence`` keyed by ``(seed, 11, i)``): poses of
:func:`lisa_hand.handmodel.sample_pose` (half its noise) whose finger flexions, spread and thumb
are set to the kind's synergies plus a little noise, within the joint limits. Each hand is
turned so that its palm frame (wrist to middle knuckle, palm normal) takes the kind's directions
at the kind's point, and meshed (watertight, 0.7 mm); the second hand moves along the kind's
direction until the clearance between them reaches the target (sphere tracing on signed
distances: trilinear in a 2.5 mm grid of each posed hand's field), a 0.5 mm contact (``apart``
then moves its gap further; ``crossed``'s target is its gap). Grasping hands (clasped: both,
holding: the holder) are placed open, then each digit closes (open to a fist) until it touches
the other hand (its vertices reposed by skinning), and the hand is meshed again. The penetration
left is measured exactly (:func:`lisa_hand.geometry.mesh_distance.mesh_distance`) and brought
under 1 mm (pressing digits opened, or the moving hand stepped out). The pair is turned as a
whole, put 0.35-0.5 m from a phone-like camera (60-70 degrees horizontal field of view; further
if it would leave the view), rendered as one mesh by :func:`benchmarks._photo_scenes._render`
(Embree at twice the size) over a background (plain in even scenes, textured in odd ones),
averaged down, with sensor noise, and saved as a JPEG without EXIF
(:func:`benchmarks._photo_scenes.save_photo`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._photo_scenes import _TRAINING_SEED, _render, _rotation, held_out_subjects, save_photo

__all__ = ["KINDS", "TwoHandSceneConfig", "TrueHand", "TwoHandPhoto", "make_two_hand_photo"]

KINDS = ("apart", "crossed", "clasped", "interlaced", "holding_wrist")
"""The scene kinds, in the order scenes cycle through them."""
_STREAM_TWO_HANDS = 11
_OTHER = {"right": "left", "left": "right"}
_UP = np.array([0.0, -1.0, 0.0])  # the image's up (camera frame: x right, y down, z forward)
_TOWARDS_CAMERA = np.array([0.0, 0.0, -1.0])
_ACROSS = np.array([1.0, 0.0, 0.0])
_CONTACT_M = -0.0005
"""Target clearance of the touching kinds: a 0.5 mm contact (the skin pressed in)."""
_MAX_PENETRATION_M = 0.001
_GRID_MARGIN_M = 0.03
_GRID_SPACING_M = 0.0025
_DIGITS = ("thumb", "index", "middle", "ring", "pinky")
_DIGIT_OF_SYNERGY = [1, 2, 3, 4, 0, 0, 0, 0]
"""The digit that each synergy moves (:data:`lisa_hand.handmodel.poses.SYNERGY_NAMES`; the
spread is the same open and closed)."""


@dataclass(frozen=True)
class TwoHandSceneConfig:
    """How the two-hand photos are made (see the module docstring): the seed of the scenes'
    random choices; photo size, pixels; horizontal field of view range, degrees (a phone's main
    camera is about 65); distance range from the camera to the keypoints' centre, metres;
    ``subjects``: "test" (the held-out subjects: the benchmark) or "train"; the open hand model's
    version (as :class:`benchmarks._photo_scenes.PhotoSceneConfig`'s); JPEG quality; Gaussian
    sensor noise in [0, 1] colour units; mesh resolution (hand length / voxel size: 0.7 mm)."""

    seed: int = 0
    width: int = 1024
    height: int = 768
    fov_range_deg: tuple[float, float] = (60.0, 70.0)
    distance_range_m: tuple[float, float] = (0.35, 0.5)
    subjects: str = "test"
    hand_model: str = "v1"
    jpeg_quality: int = 92
    noise_std: float = 0.01
    voxels_per_length: float = 250.0

    def __post_init__(self) -> None:
        if self.subjects not in ("test", "train"):
            raise ValueError(f"subjects must be 'test' or 'train', got {self.subjects!r}")


@dataclass(frozen=True, eq=False)
class TrueHand:
    """One hand of a two-hand photo: subject id (``s000``, ...), side ('right' or 'left'),
    ``keypoints_3d`` [21, 3] metres in the camera frame, ``keypoints_2d`` [21, 2] pixels (package
    order), ``visible`` [21] bool (in the image, not hidden by either hand: depth test)."""

    subject: str
    side: str
    keypoints_3d: np.ndarray
    keypoints_2d: np.ndarray
    visible: np.ndarray


@dataclass(frozen=True, eq=False)
class TwoHandPhoto:
    """One two-hand photo (a JPEG without EXIF) and its ground truth: its kind (one of
    :data:`KINDS`), the right and left hands, ``penetration_mm`` (how deep the true meshes
    interpenetrate, >= 0, exact distances) and ``gap_mm`` (their clearance, negative: the
    penetration), the true intrinsics ``K`` [3, 3] and field of view (never given to the fit),
    the seconds it took to make, and ``meshes`` (side -> the hand's mesh, camera frame)."""

    path: Path
    index: int
    kind: str
    right: TrueHand
    left: TrueHand
    penetration_mm: float
    gap_mm: float
    K: np.ndarray
    fov_deg: float
    textured: bool
    seconds: float
    meshes: dict


# ------------------------------------------------------------------------------------------------
# Poses, placing, signed distances


def _synergies(rng, curl: tuple[float, float], spread: tuple[float, float],
               thumb: tuple[tuple[float, float], ...]) -> np.ndarray:
    """[8]: a common curl drawn in ``curl`` (each finger +-0.05), spread and the thumb's three."""
    curls = np.clip(rng.uniform(*curl) + rng.uniform(-0.05, 0.05, 4), -0.2, 1.0)
    return np.concatenate([curls, [rng.uniform(*spread)], [rng.uniform(*r) for r in thumb]])


def _unit(vector) -> np.ndarray:
    return np.asarray(vector, np.float64) / np.linalg.norm(vector)


def _palm_frame(keypoints: np.ndarray, rest: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """keypoints [21, 3] -> (palm centre [3], frame: columns fingers (wrist to middle knuckle),
    across, palm normal). ``rest``: no global rotation (the palm faces -y: the normal's sign)."""
    wrist, knuckles = keypoints[0], keypoints[[5, 9, 13, 17]]
    fingers = _unit(keypoints[9] - wrist)
    normal = _unit(np.cross(fingers, keypoints[5] - keypoints[17]))
    if rest and normal @ _UP < 0:
        normal = -normal
    return 0.5 * (wrist + knuckles.mean(0)), _frame(fingers, normal)


def _frame(fingers, normal) -> np.ndarray:
    """Columns (fingers, across, normal), ``fingers`` made orthogonal to ``normal``."""
    normal = _unit(normal)
    fingers = _unit(np.asarray(fingers, np.float64) - (np.asarray(fingers) @ normal) * normal)
    return np.stack([fingers, np.cross(normal, fingers), normal], axis=1)


class _Hand:
    """One hand being placed: its subject, its pose between ``open`` and ``closed`` synergies
    (``digits`` [5]: thumb, index, middle, ring, pinky, 0 open, 1 closed), its global rotation
    and translation, and once meshed its keypoints and mesh (float64, moved with the hand), the
    mesh's skinning ``weights`` [V, 16] and its pose's bone ``transforms`` [16, 4, 4]."""

    def __init__(self, subject: str, hand, seed: int) -> None:
        self.subject, self.hand, self.seed = subject, hand, seed
        self.open = self.closed = np.zeros(8)
        self.digits, self.orient, self.translation = np.ones(5), np.zeros(3), np.zeros(3)
        self.keypoints = self.vertices = self.faces = self.colors = None
        self.weights = self.transforms = self.surface = None

    @property
    def side(self) -> str:
        return self.hand.side

    def posed(self, digits: np.ndarray | None = None):
        """The hand posed, ``digits`` (None: its own) of the way from open to closed: a natural
        pose (:func:`lisa_hand.handmodel.sample_pose`, half its noise) whose finger flexions,
        spread and thumb are then those synergies plus a little noise (the same for a seed),
        within the joint limits."""
        from lisa_hand.handmodel import poses
        from lisa_hand.skeleton.tree import FINGER_JOINTS

        weights = (self.digits if digits is None else digits)[_DIGIT_OF_SYNERGY]
        synergies = torch.from_numpy(self.open + weights * (self.closed - self.open))
        rng = np.random.default_rng(self.seed)
        generator = torch.Generator().manual_seed(self.seed)
        sampled = poses.sample_pose(generator, 1, noise=0.5, side=self.side)[0]
        angles = poses.pose_to_angles(sampled.double(), self.side)
        chosen = poses.synergy_to_angles(synergies)
        for finger in _DIGITS[1:]:
            chain = [j - 1 for j in FINGER_JOINTS[finger]]
            angles[chain, 0] = chosen[chain, 0] + torch.from_numpy(rng.normal(0.0, 0.05, 3))
            angles[chain[0], 1] = chosen[chain[0], 1] + float(rng.normal(0.0, 0.02))
        chain = [j - 1 for j in FINGER_JOINTS["thumb"]]
        angles[chain] = chosen[chain] + torch.from_numpy(rng.normal(0.0, 0.03, (3, 3)))
        limits = poses.JOINT_LIMITS
        angles = torch.maximum(torch.minimum(angles, limits[..., 1]), limits[..., 0])
        pose = poses.angles_to_pose(angles, side=self.side).double()
        pose[:3] = torch.from_numpy(self.orient)
        return self.hand.posed(pose, torch.from_numpy(self.translation))

    def mesh(self, voxels_per_length: float) -> None:
        posed = self.posed()
        mesh = posed.mesh(voxel_size=self.hand.shape.hand_length / voxels_per_length)
        self.keypoints = posed.keypoints.numpy()
        self.vertices = mesh.vertices.astype(np.float64)
        self.faces, self.colors, self.weights = mesh.faces, mesh.colors, mesh.skin_weights
        self.transforms = posed.transforms.numpy().copy()
        self.surface = _Surface(posed, self.vertices)

    def shift(self, vector: np.ndarray) -> None:
        """Move the hand rigidly by ``vector`` [3]."""
        self.translation = self.translation + vector
        self.keypoints = self.keypoints + vector
        self.vertices = self.vertices + vector
        self.transforms[:, :3, 3] += vector
        self.surface.shift(vector)

    def digit_of_vertices(self) -> np.ndarray:
        """[V] the digit (0 thumb ... 4 pinky) whose bones own each vertex most, -1: the palm."""
        from lisa_hand.skeleton.tree import FINGER_JOINTS

        digit_of_bone = np.full(16, -1)
        for digit, name in enumerate(_DIGITS):
            digit_of_bone[list(FINGER_JOINTS[name])] = digit
        return digit_of_bone[self.weights.argmax(1)]

    def reposed_vertices(self, digits: np.ndarray, which: np.ndarray) -> np.ndarray:
        """The mesh's vertices ``which`` (a mask) in the pose of ``digits`` (linear blend
        skinning from the mesh's pose: close for the small changes of one step)."""
        relative = self.posed(digits).transforms.numpy() @ np.linalg.inv(self.transforms)
        blended = (self.weights[which] @ relative.reshape(16, 16)).reshape(-1, 4, 4)
        points = self.vertices[which]
        return np.einsum("nij,nj->ni", blended[:, :3, :3], points) + blended[:, :3, 3]


def _place(item: _Hand, fingers, normal, centre, voxels_per_length: float) -> None:
    """Turn ``item`` so that its palm frame is (fingers, normal) with its palm centre at
    ``centre`` (its finger flexion does not move the palm frame), and mesh it."""
    from lisa_hand.geometry.rotations import matrix_to_axis_angle

    item.orient, item.translation = np.zeros(3), np.zeros(3)
    _, rest = _palm_frame(item.posed().keypoints.numpy())
    rotation = _frame(fingers, normal) @ rest.T
    item.orient = matrix_to_axis_angle(torch.from_numpy(rotation)).numpy()
    turned = item.posed().keypoints.numpy()
    item.translation = np.asarray(centre, np.float64) - _palm_frame(turned, rest=False)[0]
    item.mesh(voxels_per_length)


class _Surface:
    """Approximate signed distances to a posed hand (metres, negative inside): trilinear in a
    grid of its field, 3 cm round it (inf beyond)."""

    def __init__(self, posed, vertices: np.ndarray) -> None:
        self.low = vertices.min(0) - _GRID_MARGIN_M
        high = vertices.max(0) + _GRID_MARGIN_M
        axes = [np.arange(self.low[k], high[k] + _GRID_SPACING_M, _GRID_SPACING_M)
                for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        with torch.no_grad():
            values = torch.cat([posed.sdf(torch.from_numpy(chunk).float())
                                for chunk in np.array_split(grid, max(1, len(grid) // 200000))])
        self.values = values.double().numpy().reshape([len(axis) for axis in axes])

    def shift(self, vector: np.ndarray) -> None:
        self.low = self.low + vector

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """[N] signed distances of ``points`` [N, 3] within the grid, inf beyond it."""
        from scipy.ndimage import map_coordinates

        index = (points - self.low) / _GRID_SPACING_M
        inside = np.all((index >= 0) & (index <= np.array(self.values.shape) - 1), axis=1)
        values = np.full(len(points), np.inf)
        if inside.any():
            values[inside] = map_coordinates(self.values, index[inside].T, order=1)
        return values


def _clearance(fixed: _Hand, moving: _Hand, offset: np.ndarray) -> float:
    """Smallest signed distance of either hand's vertices to the other (metres; negative: the
    deepest penetration), ``moving`` shifted by ``offset``."""
    return float(min(fixed.surface.sdf(moving.vertices + offset).min(),
                     moving.surface.sdf(fixed.vertices - offset).min()))


def _trace(fixed: _Hand, moving: _Hand, direction: np.ndarray, target: float,
           base: np.ndarray, max_steps: int = 200, tolerance: float = 1e-4) -> float:
    """The offset d (metres) along ``direction`` nearest 0 where the clearance of ``moving``
    shifted by ``base + d * direction`` reaches ``target``: outwards from an overlap, inwards
    from a gap (sphere tracing: the clearance is 1-Lipschitz in d)."""
    offset = 0.0
    clearance = _clearance(fixed, moving, base)
    sign = 1.0 if clearance < target else -1.0
    for _ in range(max_steps):
        error = target - clearance
        if (sign > 0 and error <= 0.0) or (sign < 0 and error >= -tolerance):
            break
        offset += sign * (max(abs(error), tolerance) if math.isfinite(error) else 0.02)
        clearance = _clearance(fixed, moving, base + offset * direction)
    return offset


def _depths(item: _Hand, other: _Hand) -> tuple[np.ndarray, np.ndarray]:
    """(mask of ``item``'s vertices near ``other`` (within 2 mm by its grid; all when none
    is), their exact signed distances to its mesh:
    :func:`lisa_hand.geometry.mesh_distance.mesh_distance`)."""
    from lisa_hand.geometry.mesh_distance import mesh_distance

    near = other.surface.sdf(item.vertices) < 0.002
    near = near if near.any() else np.ones(len(near), bool)
    return near, mesh_distance(item.vertices[near], other.vertices, other.faces).sdf


def _close_digits(item: _Hand, other: _Hand, steps: int = 12, refine: int = 4) -> None:
    """Close each digit of ``item`` from open towards closed until it touches ``other``: its
    vertices (reposed by skinning) against the other's signed distances, 1 mm of skin pressed
    in allowed. Coarse steps, then bisection, all digits at once (they move independently)."""
    owner = item.digit_of_vertices()
    which = owner >= 0
    owner = owner[which]

    def blocked(digits: np.ndarray) -> np.ndarray:
        depth = other.surface.sdf(item.reposed_vertices(digits, which))
        return np.array([bool((depth[owner == digit] < -0.001).any()) for digit in range(5)])

    free, done = item.digits.copy(), np.zeros(5, bool)
    for k in range(1, steps + 1):
        trial = np.where(done, free, k / steps)
        hit = blocked(trial) & ~done
        free = np.where(done | hit, free, trial)
        done |= hit
        if done.all():
            break
    low, high = free.copy(), np.where(done, free + 1.0 / steps, free)
    for _ in range(refine):
        middle = np.where(done, 0.5 * (low + high), low)
        hit = blocked(middle)
        low = np.where(done & ~hit, middle, low)
        high = np.where(done & hit, middle, high)
    item.digits = low


# ------------------------------------------------------------------------------------------------
# The kinds


@dataclass
class _Spec:
    """A scene's layout in the pair's own frame (camera axes: x right, y down, z away), before
    the pair is turned (``turn_deg``: about the vertical, tilt, roll). Per side: synergies (open,
    closed), palm frame (fingers, normal) and palm centre (None: at the fixed hand's wrist,
    ``wrist_offset`` towards its fingers and ``back_m`` back along its own). The ``moving`` side
    goes along ``direction`` until the clearance is ``target`` (metres), from each of the
    ``lateral_m`` offsets across (the deepest wins), then ``gap_m`` further; the ``grasping``
    sides are placed open and close on the other hand."""

    kind: str
    synergies: dict[str, tuple[np.ndarray, np.ndarray]]
    frames: dict[str, tuple[np.ndarray, np.ndarray]]
    centres: dict[str, np.ndarray | None]
    moving: str
    direction: np.ndarray
    target: float
    turn_deg: tuple[float, float, float]
    grasping: tuple[str, ...] = ()
    lateral_m: tuple[float, ...] = (0.0,)
    wrist_offset: float = 0.0
    back_m: float = 0.0
    gap_m: float = 0.0


def _open_hand(rng, curl=(-0.1, 0.2), spread=(0.2, 0.9)) -> tuple[np.ndarray, np.ndarray]:
    return (_synergies(rng, curl, spread, ((0.0, 0.3), (0.0, 0.3), (0.0, 0.4))),) * 2


def _grasp(rng, thumb_open, thumb_closed) -> tuple[np.ndarray, np.ndarray]:
    """(open: straight fingers together, closed: a fist), thumbs as given."""
    spread = rng.uniform(-0.3, 0.0)
    return (np.concatenate([rng.uniform(-0.05, 0.05, 4), [spread], thumb_open]),
            np.concatenate([rng.uniform(0.95, 1.0, 4), [spread], thumb_closed]))


def _raised(roll_deg: float, turn_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(fingers, normal): fingers up, rolled ``roll_deg`` towards +x in the image; the palm to
    the camera, turned ``turn_deg`` about the vertical."""
    a, t = math.radians(roll_deg), math.radians(turn_deg)
    return (np.array([math.sin(a), -math.cos(a), 0.0]),
            np.array([math.sin(t), 0.0, -math.cos(t)]))


def _facing(rng, lean_deg: tuple[float, float], other_deg: float) -> dict:
    """Palms facing each other along x (right hand's to +x), fingers up leaning to the camera;
    the left hand's fingers turned ``other_deg`` about x from the right's."""
    lean = math.radians(rng.uniform(*lean_deg))
    fingers = np.array([0.0, -math.cos(lean), -math.sin(lean)])
    other = _rotation([1.0, 0.0, 0.0], math.radians(other_deg)) @ fingers
    return {"right": (fingers, _ACROSS.copy()), "left": (other, -_ACROSS)}


def _small_turn(rng, yaw=(-20.0, 20.0)) -> tuple[float, float, float]:
    return rng.uniform(*yaw), rng.uniform(-15, 15), rng.uniform(-15, 15)


def _spec_apart(rng, occurrence: int) -> _Spec:
    return _Spec("apart", {"right": _open_hand(rng), "left": _open_hand(rng)},
                 {"right": _raised(-rng.uniform(3, 15), rng.uniform(-15, 15)),
                  "left": _raised(rng.uniform(3, 15), rng.uniform(-15, 15))},
                 {"right": np.array([-0.05, rng.uniform(-0.02, 0.02), 0.0]),
                  "left": np.array([0.05, rng.uniform(-0.02, 0.02), 0.0])},
                 moving="left", direction=_ACROSS.copy(), target=0.0,
                 turn_deg=_small_turn(rng), gap_m=rng.uniform(0.03, 0.08))


def _spec_crossed(rng, occurrence: int) -> _Spec:
    front = "left" if occurrence % 2 == 0 else "right"
    roll = rng.uniform(20, 40)
    frames = {"right": _raised(roll, rng.uniform(-10, 10)),
              "left": _raised(-roll + rng.uniform(-5, 5), rng.uniform(-10, 10))}
    if rng.random() < 0.5:  # the front hand shows its back
        frames[front] = (frames[front][0], -frames[front][1])
    shift = rng.uniform(-0.015, 0.005)
    return _Spec("crossed", {side: _open_hand(rng, (0.0, 0.35), (0.0, 0.6))
                             for side in ("right", "left")}, frames,
                 {"right": np.array([shift, 0.0, 0.0]), "left": np.array([-shift, 0.0, 0.0])},
                 moving=front, direction=_TOWARDS_CAMERA.copy(), target=rng.uniform(0.01, 0.025),
                 turn_deg=_small_turn(rng))


def _spec_clasped(rng, occurrence: int) -> _Spec:
    thumb_open, thumb_closed = np.array([0.0, 0.0, -0.3]), np.array([0.6, 0.5, 0.3])
    return _Spec("clasped", {side: _grasp(rng, thumb_open, thumb_closed)
                             for side in ("right", "left")},
                 _facing(rng, (0, 25), rng.choice([-1.0, 1.0]) * rng.uniform(70, 100)),
                 {"right": np.zeros(3), "left": np.zeros(3)},
                 moving="left", direction=_ACROSS.copy(), target=_CONTACT_M,
                 turn_deg=_small_turn(rng, (55, 80)) if rng.random() < 0.5
                 else _small_turn(rng, (-80, -55)), grasping=("right", "left"))


def _spec_interlaced(rng, occurrence: int) -> _Spec:
    synergies = {side: (_synergies(rng, (0.3, 0.45), (1.2, 1.5),
                                   ((0.0, 0.2), (0.0, 0.1), (-0.2, 0.1))),) * 2
                 for side in ("right", "left")}
    return _Spec("interlaced", synergies, _facing(rng, (0, 20), rng.uniform(-10, 10)),
                 {"right": np.zeros(3), "left": np.array([0.15, 0.0, 0.0])},
                 moving="left", direction=_ACROSS.copy(), target=_CONTACT_M,
                 turn_deg=_small_turn(rng, (60, 80)) if rng.random() < 0.5
                 else _small_turn(rng, (-80, -60)),
                 lateral_m=tuple(np.linspace(-0.012, 0.012, 13)))


def _spec_holding_wrist(rng, occurrence: int) -> _Spec:
    holder = "left" if occurrence % 2 == 0 else "right"
    held = _OTHER[holder]
    towards = -1.0 if holder == "left" else 1.0  # the holder comes from its own side
    return _Spec("holding_wrist",
                 {held: _open_hand(rng, (0.0, 0.3), (0.0, 0.7)),
                  holder: _grasp(rng, np.array([0.0, 0.0, 0.0]), np.array([0.6, 0.8, 1.0]))},
                 {held: _raised(rng.uniform(-10, 10), rng.uniform(-15, 15)),
                  holder: (np.array([towards, 0.0, 0.0]), -_TOWARDS_CAMERA)},
                 {held: np.array([0.03 * towards, -0.03, 0.0]), holder: None},
                 moving=holder, direction=_TOWARDS_CAMERA.copy(), target=_CONTACT_M,
                 turn_deg=_small_turn(rng, (-25, 25)), grasping=(holder,),
                 wrist_offset=rng.uniform(0.0, 0.015), back_m=rng.uniform(0.01, 0.02))


_SPECS = {"apart": _spec_apart, "crossed": _spec_crossed, "clasped": _spec_clasped,
          "interlaced": _spec_interlaced, "holding_wrist": _spec_holding_wrist}


def _arrange(spec: _Spec, hands: dict[str, _Hand], voxels_per_length: float) -> None:
    """Place, move and close the hands (see the module docstring)."""
    fixed, moving = hands[_OTHER[spec.moving]], hands[spec.moving]
    for item in (fixed, moving):
        item.open, item.closed = spec.synergies[item.side]
        item.digits = np.zeros(5) if item.side in spec.grasping else np.ones(5)
        centre = spec.centres[item.side]
        if centre is None:  # at the fixed hand's wrist
            wrist = fixed.keypoints[0]
            centre = (wrist + spec.wrist_offset * _unit(fixed.keypoints[9] - wrist)
                      - spec.back_m * _unit(spec.frames[item.side][0]))
        _place(item, *spec.frames[item.side], centre, voxels_per_length)
    direction = _unit(spec.direction)
    best = None
    for lateral in spec.lateral_m:
        base = lateral * np.cross(direction, _frame(*spec.frames[fixed.side])[:, 0])
        offset = _trace(fixed, moving, direction, spec.target, base)
        if best is None or offset < best[0] - 1e-4:
            best = (offset, base)
    moving.shift(best[1] + (best[0] + spec.gap_m) * direction)
    for side in spec.grasping:  # each closes on the other as it is now
        _close_digits(hands[side], hands[_OTHER[side]])
        hands[side].mesh(voxels_per_length)


def _resolve_exactly(spec: _Spec, hands: dict[str, _Hand],
                     voxels_per_length: float) -> tuple[float, float]:
    """Exact penetration and clearance (metres: the smallest signed distance of either hand's
    vertices to the other; a gap of 2 mm to 3 cm: the grids'). While the penetration exceeds
    1 mm (the placing distances are approximate): the grasping digits pressing in open by a
    tenth, or, none pressing, the moving hand steps out along the direction."""
    fixed, moving = hands[_OTHER[spec.moving]], hands[spec.moving]
    for _ in range(8):
        if 0.002 < (clearance := _clearance(fixed, moving, np.zeros(3))) < math.inf:
            break
        depths = {item.side: _depths(item, hands[_OTHER[item.side]]) for item in (fixed, moving)}
        clearance = float(min(depth.min() for _, depth in depths.values()))
        if clearance >= -_MAX_PENETRATION_M:
            break
        opened = False
        for side in spec.grasping:
            item = hands[side]
            near, depth = depths[side]
            owners = item.digit_of_vertices()[near][depth < -_MAX_PENETRATION_M]
            pressing = np.isin(np.arange(5), owners) & (item.digits > 0.0)
            if pressing.any():
                item.digits = np.where(pressing, np.maximum(item.digits - 0.1, 0), item.digits)
                item.mesh(voxels_per_length)
                opened = True
        if not opened:
            moving.shift((-clearance - 0.0005) * _unit(spec.direction))
    return max(0.0, -clearance), clearance


def _turn_pair(hands: dict[str, _Hand], turn_deg: tuple[float, float, float]) -> None:
    """Turn both hands about their keypoints' centre: (about the vertical, tilt, roll)."""
    yaw, tilt, roll = (math.radians(angle) for angle in turn_deg)
    rotation = (_rotation([0.0, 0.0, 1.0], roll) @ _rotation([1.0, 0.0, 0.0], tilt)
                @ _rotation([0.0, 1.0, 0.0], yaw))
    keypoints = np.concatenate([item.keypoints for item in hands.values()])
    pivot = 0.5 * (keypoints.min(0) + keypoints.max(0))
    for item in hands.values():
        item.keypoints = (item.keypoints - pivot) @ rotation.T
        item.vertices = (item.vertices - pivot) @ rotation.T


def _camera_placement(rng, hands: dict[str, _Hand], fov_deg: float,
                      config: TwoHandSceneConfig) -> np.ndarray:
    """[3] translation putting the keypoints' centre at the chosen distance (off-axis a little),
    further where the hands would leave the view (a 5 % margin)."""
    keypoints = np.concatenate([item.keypoints for item in hands.values()])
    points = np.concatenate([item.vertices[::20] for item in hands.values()])
    middle = 0.5 * (keypoints.min(0) + keypoints.max(0))
    distance = rng.uniform(*config.distance_range_m)
    aspect = config.width / config.height
    offset = rng.uniform(-1.0, 1.0, 2) * 0.05
    tan_half = math.tan(math.radians(fov_deg) / 2.0)
    for _ in range(50):
        half_width = distance * tan_half
        centre = np.array([offset[0] * half_width, offset[1] * half_width / aspect, distance])
        moved = points - middle + centre
        x = moved[:, 0] / moved[:, 2] / tan_half
        y = moved[:, 1] / moved[:, 2] / tan_half * aspect
        if np.abs(x).max() < 0.95 and np.abs(y).max() < 0.95 and moved[:, 2].min() > 0.1:
            break
        distance *= 1.05
    return centre - middle


# ------------------------------------------------------------------------------------------------
# The photo


def _meshed(meshes: dict):
    """Stands for a posed hand in :func:`benchmarks._photo_scenes._render`: its ``mesh()`` is
    both hands' ``meshes`` (side -> mesh) joined."""
    from types import SimpleNamespace

    from lisa_hand.geometry.meshing import Mesh

    right, left = meshes["right"], meshes["left"]
    mesh = Mesh(np.concatenate([right.vertices, left.vertices]),
                np.concatenate([right.faces, left.faces + len(right.vertices)]),
                np.concatenate([right.colors, left.colors]))
    return SimpleNamespace(mesh=lambda voxel_size=None: mesh)


def _subjects(config: TwoHandSceneConfig, index: int, rng) -> dict[str, _Hand]:
    """The right hand of held-out subject ``index % 6`` and the left hand (mirror image) of
    another one."""
    from lisa_hand.data.synth import SynthConfig, make_subject

    subjects = held_out_subjects(config.subjects)
    right_at = index % len(subjects)
    left_at = (right_at + 1 + (index // len(subjects)) % (len(subjects) - 1)) % len(subjects)
    synth = SynthConfig(seed=_TRAINING_SEED, hand_model=config.hand_model)
    hands = {}
    for side, at in (("right", right_at), ("left", left_at)):
        record = make_subject(synth, subjects[at], fit_template=False)
        hands[side] = _Hand(record.id, dataclasses.replace(record.hand, side=side),
                            int(rng.integers(0, 2**62)))
    return hands


def _true_hand(item: _Hand, camera, camera_2x, depth) -> TrueHand:
    from lisa_hand.data.images import project_keypoints

    visible = project_keypoints(item.keypoints, camera_2x, depth=depth).visible
    projection = project_keypoints(item.keypoints, camera)
    return TrueHand(subject=item.subject, side=item.side, keypoints_3d=item.keypoints.copy(),
                    keypoints_2d=projection.pixels.astype(np.float64),
                    visible=visible & projection.in_image)


def make_two_hand_photo(config: TwoHandSceneConfig, index: int, out_dir: Path) -> TwoHandPhoto:
    """Scene ``index`` (see the module docstring), written to ``out_dir/two_hands_INDEX.jpg``."""

    from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov
    from lisa_hand.geometry.meshing import Mesh

    start = time.perf_counter()
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, _STREAM_TWO_HANDS, index]))
    kind = KINDS[index % len(KINDS)]
    hands = _subjects(config, index, rng)
    spec = _SPECS[kind](rng, index // len(KINDS))
    _arrange(spec, hands, config.voxels_per_length)
    penetration, clearance = _resolve_exactly(spec, hands, config.voxels_per_length)
    _turn_pair(hands, spec.turn_deg)
    fov_deg = float(rng.uniform(*config.fov_range_deg))
    translation = _camera_placement(rng, hands, fov_deg, config)
    for item in hands.values():
        item.shift(translation)
    meshes = {side: Mesh(item.vertices, item.faces, item.colors) for side, item in hands.items()}
    K = intrinsics_from_fov(fov_deg, config.width, config.height, dtype=torch.float64)
    camera = Camera(K=K, R=np.eye(3), t=np.zeros(3), width=config.width, height=config.height)
    camera_2x = Camera(K=torch.cat([2.0 * K[:2], K[2:]]), R=np.eye(3), t=np.zeros(3),
                       width=2 * config.width, height=2 * config.height)
    length = max(item.hand.shape.hand_length for item in hands.values())
    rgb, mask, depth = _render(_meshed(meshes), length, camera_2x, rng, config)
    textured = index % 2 == 1
    path = save_photo(rgb, mask, textured, rng, config,
                      Path(out_dir) / f"two_hands_{index:03d}.jpg")
    truth = {side: _true_hand(item, camera, camera_2x, depth) for side, item in hands.items()}
    return TwoHandPhoto(path=path, index=index, kind=kind, right=truth["right"],
                        left=truth["left"], penetration_mm=penetration * 1000.0,
                        gap_mm=clearance * 1000.0, K=camera.K.numpy(), fov_deg=fov_deg,
                        textured=textured, seconds=time.perf_counter() - start, meshes=meshes)
