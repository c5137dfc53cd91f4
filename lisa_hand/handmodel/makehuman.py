"""MakeHuman's sculpted hand (CC0): settings -> morphed hand, and a population of adult hands.

The kit (``lisa_hand/assets/makehuman/``, its README says what it holds) is the right hand of
MakeHuman's hm08 base mesh with its rig, skinning weights and morph targets, in millimetres and
MakeHuman's axes. A hand is a :class:`MakeHumanShape`: MakeHuman's macro sliders (gender, age,
muscle, weight, height, proportions, ethnic mix) and the hand's local sliders (scale, finger
length, finger diameter, finger spacing). As in MakeHuman, targets are offsets from the base
added linearly, ``v = base + sum_T w_T delta_T``: a macro target's weight is the product of its
words' weights, a local slider ``x`` in [-1, 1] weighs its decr target by ``max(0, -x)`` and its
incr target by ``max(0, x)``; joints are the means of their morphed joint vertices
(:func:`morph`).

Population (:func:`sample_makehuman_shape`): an adult of either sex (50/50) whose hand length
(wrist to the middle fingertip) and breadth (across the metacarpal heads) are drawn jointly from
the published adult anthropometry of hand model v2 (:mod:`.anthropometry`: means, SDs and
within-sex correlations by sex); age uniform over 18-80 years (:data:`ADULT_AGES`), muscle,
weight and body proportions around MakeHuman's average, an ethnic mix with one dominant
ethnicity; the hand's scale and finger-length sliders are then solved so that the morphed hand
has the drawn length and breadth (:func:`fit_hand_size`). Palm thickness and finger girth follow
from the macros (weight, muscle, age) and a finger-diameter slider.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from .anthropometry import sample_measurements

__all__ = [
    "KIT_DIR",
    "MakeHumanKit",
    "MakeHumanShape",
    "MAKEHUMAN_BOUNDS",
    "load_kit",
    "target_weights",
    "morph",
    "measure_hand",
    "fit_hand_size",
    "sample_makehuman_shape",
    "ADULT_AGES",
    "ETHNIC_SKIN_TONES",
    "skin_tone",
]

KIT_DIR = Path(__file__).resolve().parent.parent / "assets" / "makehuman"
"""The kit's folder (``right_hand.npz``, ``targets.npz``, licence and README)."""

_LOCAL_SLIDERS = {
    "hand_scale": "armslegs/r-hand-scale-decr|incr",
    "finger_length": "armslegs/r-hand-fingers-length-decr|incr",
    "finger_diameter": "armslegs/r-hand-fingers-diameter-decr|incr",
    "finger_distance": "armslegs/r-hand-fingers-distance-decr|incr",
}


@dataclass(frozen=True)
class MakeHumanShape:
    """One MakeHuman hand: macro sliders in [0, 1] (MakeHuman's defaults 0.5) and the hand's
    local sliders in [-1, 1] (default 0). Ethnic weights are normalised to sum to 1."""

    gender: float = 0.5
    """0 female, 1 male."""
    age: float = 0.5
    """0 = 1 year, 0.1875 = 10, 0.5 = 25, 1 = 90 years (MakeHuman's anchors, linear between)."""
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    """0 uncommon, 1 ideal body proportions."""
    african: float = 1.0 / 3.0
    asian: float = 1.0 / 3.0
    caucasian: float = 1.0 / 3.0
    hand_scale: float = 0.0
    finger_length: float = 0.0
    finger_diameter: float = 0.0
    finger_distance: float = 0.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TypeError(f"MakeHumanShape.{field.name} must be a float, got {value!r}")
            low, high = MAKEHUMAN_BOUNDS[field.name]
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(f"MakeHumanShape.{field.name} = {value!r} is outside "
                                 f"[{low}, {high}]")
        if self.african + self.asian + self.caucasian <= 0:
            raise ValueError("MakeHumanShape: the ethnic weights must not all be 0")

    @property
    def years(self) -> float:
        """Age in years (MakeHuman's anchors)."""
        if self.age < 0.1875:
            return 1.0 + 48.0 * self.age
        if self.age < 0.5:
            return 10.0 + 48.0 * (self.age - 0.1875)
        return 25.0 + 130.0 * (self.age - 0.5)

    @property
    def hand_length(self) -> float:
        """Wrist joint to the middle fingertip of the morphed hand, metres."""
        return _measurements(self)["hand_length"]


MAKEHUMAN_BOUNDS: dict[str, tuple[float, float]] = {
    **{name: (0.0, 1.0) for name in ("gender", "age", "muscle", "weight", "height",
                                      "proportions", "african", "asian", "caucasian")},
    **{name: (-1.0, 1.0) for name in _LOCAL_SLIDERS},
}
"""Valid range of every :class:`MakeHumanShape` field."""


@dataclass(frozen=True)
class MakeHumanKit:
    """The kit's arrays (millimetres, MakeHuman's axes; see the kit's README).

    vertices: [V, 3] the raw base. quads: [Q, 4] outward. weights: [V, B + 1] LBS weights.
    bone_names: [B]. parents: [B]. joint_names: [J]. joint_vertices: [H, 3].
    joint_regressor: [J, H]. targets: the open ``targets.npz``. modifiers: slider name ->
    (decr target, incr target).
    """

    vertices: np.ndarray
    quads: np.ndarray
    weights: np.ndarray
    bone_names: tuple[str, ...]
    parents: np.ndarray
    bone_head_joint: np.ndarray
    bone_tail_joint: np.ndarray
    joint_names: tuple[str, ...]
    joint_vertices: np.ndarray
    joint_regressor: np.ndarray
    targets: dict[str, np.ndarray]
    macro_targets: tuple[tuple[str, tuple[str, ...]], ...]
    modifiers: dict[str, tuple[str, str]]

    def joint(self, name: str) -> int:
        """Index of a joint, e.g. ``"wrist.R____head"``."""
        return self.joint_names.index(name)


@functools.lru_cache(maxsize=1)
def load_kit(folder: str | None = None) -> MakeHumanKit:
    """The MakeHuman kit (cached); ``folder`` defaults to :data:`KIT_DIR`."""
    root = Path(folder) if folder is not None else KIT_DIR
    try:
        with np.load(root / "right_hand.npz", allow_pickle=False) as kit:
            arrays = {key: kit[key] for key in kit.files}
        with np.load(root / "targets.npz", allow_pickle=False) as archive:
            targets = {key: archive[key] for key in archive.files}
    except (OSError, ValueError) as exc:
        raise OSError(f"{root}: the MakeHuman hand kit cannot be read ({exc})") from exc
    names, groups, factors = targets["meta/names"], targets["meta/group"], targets["meta/factors"]
    macro = tuple((str(n), tuple(str(f).split(","))) for n, g, f in zip(names, groups, factors,
                                                                          strict=True)
                  if str(g).startswith("macrodetails"))
    modifiers = {str(m): (str(d), str(i)) for m, d, i in zip(
        targets["meta/modifier_names"], targets["meta/modifier_decr"],
        targets["meta/modifier_incr"], strict=True)}
    return MakeHumanKit(
        vertices=arrays["vertices"].astype(np.float64), quads=arrays["quads"].astype(np.int64),
        weights=arrays["weights"].astype(np.float64),
        bone_names=tuple(str(b) for b in arrays["bone_names"]),
        parents=arrays["parents"].astype(np.int64),
        bone_head_joint=arrays["bone_head_joint"].astype(np.int64),
        bone_tail_joint=arrays["bone_tail_joint"].astype(np.int64),
        joint_names=tuple(str(j) for j in arrays["joint_names"]),
        joint_vertices=arrays["joint_vertices"].astype(np.float64),
        joint_regressor=arrays["joint_regressor"].astype(np.float64),
        targets=targets, macro_targets=macro, modifiers=modifiers)


def _word_weights(shape: MakeHumanShape) -> dict[str, float]:
    """Weights of the macro words (``female``, ``young``, ``maxweight``, ``asian``, ...)."""
    def low_high(x: float) -> tuple[float, float]:
        return max(0.0, 1.0 - 2.0 * x), max(0.0, 2.0 * x - 1.0)

    anchors = [0.0, 0.1875, 0.5, 1.0]
    ages = {word: float(np.interp(shape.age, anchors, row))
            for word, row in zip(("baby", "child", "young", "old"), np.eye(4), strict=True)}
    ethnic = shape.african + shape.asian + shape.caucasian
    words = {"female": 1.0 - shape.gender, "male": shape.gender, **ages,
             "african": shape.african / ethnic, "asian": shape.asian / ethnic,
             "caucasian": shape.caucasian / ethnic}
    for name in ("muscle", "weight"):
        low, high = low_high(getattr(shape, name))
        words[f"min{name}"], words[f"max{name}"] = low, high
        words[f"average{name}"] = 1.0 - low - high
    words["minheight"], words["maxheight"] = low_high(shape.height)
    words["uncommonproportions"], words["idealproportions"] = low_high(shape.proportions)
    return words


def target_weights(shape: MakeHumanShape, kit: MakeHumanKit | None = None) -> dict[str, float]:
    """{target name: weight} of a shape (zero weights left out)."""
    kit = load_kit() if kit is None else kit
    words = _word_weights(shape)
    weights = {}
    for name, factors in kit.macro_targets:
        value = float(np.prod([words[word] for word in factors]))
        if value:
            weights[name] = value
    for field, modifier in _LOCAL_SLIDERS.items():
        value = getattr(shape, field)
        decr, incr = kit.modifiers[modifier]
        target = incr if value > 0 else decr
        if value and target:
            weights[target] = weights.get(target, 0.0) + abs(value)
    return weights


def morph(shape: MakeHumanShape, kit: MakeHumanKit | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The morphed hand -> (vertices [V, 3], joints [J, 3]) float64 millimetres, MakeHuman axes."""
    kit = load_kit() if kit is None else kit
    vertices, joint_vertices = kit.vertices.copy(), kit.joint_vertices.copy()
    targets = kit.targets
    for name, weight in target_weights(shape, kit).items():
        np.add.at(vertices, targets[f"{name}/idx"], weight * targets[f"{name}/delta"])
        np.add.at(joint_vertices, targets[f"{name}/jidx"], weight * targets[f"{name}/jdelta"])
    return vertices, kit.joint_regressor @ joint_vertices


def measure_hand(vertices: np.ndarray, joints: np.ndarray,
                 kit: MakeHumanKit | None = None) -> dict[str, float]:
    """Caliper measurements of a morphed hand (inputs in millimetres) -> metres:

    ``hand_length``: wrist joint to the middle fingertip; ``hand_breadth``: across the
    metacarpal heads, the skin's extent along the index-to-little MCP line within 5 mm of the
    plane through that line and the palm normal; ``palm_thickness``: dorsal to palmar, the skin's
    extent along the palm normal within 5 mm of the middle of that line.
    """
    kit = load_kit() if kit is None else kit
    wrist = joints[kit.joint("wrist.R____head")]
    tip = joints[kit.joint("finger3-3.R____tail")]
    index, middle, little = (joints[kit.joint(f"finger{f}-1.R____head")] for f in (2, 3, 5))
    along = _unit(middle - wrist)
    line = _unit(index - little)
    normal = _unit(np.cross(along, line))
    across_palm = np.cross(line, normal)
    relative = vertices - 0.5 * (index + little)
    in_plane = np.abs(relative @ across_palm) < 5.0
    breadth = relative[in_plane & (np.abs(relative @ normal) < 20.0)] @ line
    thickness = relative[in_plane & (np.abs(relative @ line) < 5.0)] @ normal
    return {
        "hand_length": float(np.linalg.norm(tip - wrist)) / 1000.0,
        "hand_breadth": float(breadth.max() - breadth.min()) / 1000.0,
        "palm_thickness": float(thickness.max() - thickness.min()) / 1000.0,
    }


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


@functools.lru_cache(maxsize=256)
def _measurements(shape: MakeHumanShape) -> dict[str, float]:
    vertices, joints = morph(shape)
    return measure_hand(vertices, joints)


def fit_hand_size(shape: MakeHumanShape, hand_length: float, hand_breadth: float,
                  iterations: int = 6) -> MakeHumanShape:
    """``shape`` with its ``hand_scale`` and ``finger_length`` sliders solved (Newton steps on
    finite differences, the sliders kept in [-1, 1]) so that its measured length and breadth
    (:func:`measure_hand`, metres) are the given ones; the nearest reachable hand when they are
    out of the sliders' range."""
    def measured(scale: float, fingers: float) -> np.ndarray:
        trial = dataclasses.replace(shape, hand_scale=scale, finger_length=fingers)
        values = _measurements(trial)
        return np.array([values["hand_length"], values["hand_breadth"]])

    goal = np.array([hand_length, hand_breadth])
    sliders = np.array([shape.hand_scale, shape.finger_length])
    step = 0.02
    for _ in range(iterations):
        current = measured(*sliders)
        if np.abs(current - goal).max() < 5e-5:
            break
        jacobian = np.stack([(measured(*(sliders + step * e)) - current) / step
                             for e in np.eye(2)], axis=1)
        sliders = np.clip(sliders + np.linalg.solve(jacobian, goal - current), -0.98, 0.98)
    return dataclasses.replace(shape, hand_scale=float(sliders[0]), finger_length=float(sliders[1]))


def _clipped(generator: torch.Generator, mean: float, std: float, low: float,
             high: float) -> float:
    value = mean + std * float(torch.randn((), generator=generator, dtype=torch.float64))
    return float(min(max(value, low), high))


ADULT_AGES = (18.0, 80.0)
"""Ages (years) of the population :func:`sample_makehuman_shape` draws from by default."""


def sample_makehuman_shape(generator: torch.Generator,
                           ages: tuple[float, float] = ADULT_AGES) -> MakeHumanShape:
    """Draw an adult hand (see the module docstring): the anthropometric measurements first
    (:func:`~.anthropometry.sample_measurements`), then the macros, then the size sliders
    solved to the drawn length and breadth.

    generator: a seeded ``torch.Generator`` (CPU); the same seed gives the same hand.
    ages: (youngest, oldest) years, uniform between (a narrower range holds the rest of the
        population out of a dataset, e.g. ``(18, 65)`` to test on older hands).
    """
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
    youngest, oldest = (float(age) for age in ages)
    if not 1.0 <= youngest <= oldest <= 90.0:
        raise ValueError(f"ages must be (youngest, oldest) years within 1-90, got {ages!r}")
    measured = sample_measurements(generator)
    uniform = torch.rand(2, generator=generator, dtype=torch.float64).tolist()
    gender_offset = 0.15 * uniform[0]
    gender = gender_offset if measured.female else 1.0 - gender_offset
    years = youngest + (oldest - youngest) * uniform[1]
    age = 0.1875 + (years - 10.0) / 48.0 if years < 25.0 else 0.5 + (years - 25.0) / 130.0
    # One ethnicity dominant (3/4), the rest a uniform mix (a Dirichlet(1, 1, 1) quarter).
    gammas = -torch.log(torch.rand(3, generator=generator, dtype=torch.float64)) + 1e-3
    dominant = int(torch.randint(0, 3, (), generator=generator))
    ethnic = (0.25 * gammas / gammas.sum() + 0.75 * torch.eye(3, dtype=torch.float64)[dominant])
    ethnic = ethnic.tolist()
    shape = MakeHumanShape(
        gender=gender, age=min(age, 1.0),
        muscle=_clipped(generator, 0.5, 0.15, 0.1, 0.9),
        weight=_clipped(generator, 0.5, 0.15, 0.1, 0.9),
        height=0.5,
        proportions=_clipped(generator, 0.5, 0.15, 0.1, 0.9),
        african=ethnic[0], asian=ethnic[1], caucasian=ethnic[2],
        finger_diameter=_clipped(generator, 0.0, 0.25, -0.6, 0.6),
        finger_distance=_clipped(generator, 0.0, 0.2, -0.5, 0.5),
    )
    return fit_hand_size(shape, measured["hand_length"], measured["hand_breadth"])


ETHNIC_SKIN_TONES = {"african": 0.8, "asian": 0.35, "caucasian": 0.25}
"""Where the kit's three skin references sit on :class:`~.appearance.Appearance`'s
``skin_tone`` scale (0 very light, 1 very dark). The references are the mean sRGB of MakeHuman's
lit skin spheres, african (114, 80, 65), asian (153, 99, 78), caucasian (162, 100, 79): their
order and the asian/caucasian closeness are kept; the spheres' baked lighting compresses the
range, so the african anchor is placed by the palette's dark end rather than by luminance."""


def skin_tone(shape: MakeHumanShape, generator: torch.Generator) -> float:
    """A skin tone for a shape: its ethnic mix of :data:`ETHNIC_SKIN_TONES`, plus an individual
    spread (SD 0.1), clipped to [0, 1]."""
    total = shape.african + shape.asian + shape.caucasian
    mixed = sum(getattr(shape, name) * tone for name, tone in ETHNIC_SKIN_TONES.items()) / total
    return _clipped(generator, mixed, 0.1, 0.0, 1.0)
