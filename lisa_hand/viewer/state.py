"""What the viewer shows, as values: :class:`ViewState`, and :func:`view_params`, the pure
function that turns them into the one hand state (:class:`~lisa_hand.skeleton.params.HandParams`).

The viewer holds a list of hands (:class:`NamedHand`: the loaded ``params.json`` files, the
model's mean hand, its training subjects) and a :class:`ViewState`; every GUI control changes
one value of the state, and the hand on screen is ``view_params(state, hands, spaces)``:

1. **A and B** (``hand_a``, ``hand_b``): hand A with ``shape_t`` of B's shape (code and
   skeleton) and ``color_t`` of B's colour code (:func:`lisa_hand.inference.blend_params`: 0 and
   1 swap exactly), and ``pose_t`` of the way from A's pose to B's (finger joints linear in
   anatomical angles, the global rotation by slerp, the translation linearly:
   :func:`lisa_hand.handmodel.poses.interpolate_poses`).
2. **Principal directions** (``shape_pcs``, ``color_pcs``): the codes move by ``c_i std_i u_i``
   along the principal directions ``u_i`` of the model's training codes
   (:class:`lisa_hand.fitting.images.shape_prior.ShapeSpace`, the space the image fit keeps its
   shape in), ``c_i`` in standard deviations.
3. **Pose** (:class:`PoseEdit`): the finger joints' anatomical angles (flexion, abduction,
   twist: :mod:`lisa_hand.handmodel.poses`) are those of the hand (or of a named pose), plus the
   synergies (per-finger curl, spread, thumb: :func:`~lisa_hand.handmodel.poses.synergy_to_angles`),
   plus per-joint offsets (the 45 finger values), clamped to the joint limits (widened to hold
   the starting pose, so a fitted hand outside them is shown as it is); then an extra global
   rotation about the wrist.
4. **Side**: the mirror image (:func:`lisa_hand.fitting.sides.mirror_hand`) when asked.

With every edit at its neutral value the result is hand A itself (exactly: no round trip
through angles).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import torch

from ..fitting.images.shape_prior import ShapeSpace
from ..fitting.sides import mirror_hand
from ..geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..handmodel.poses import (
    JOINT_LIMITS,
    POSE_NAMES,
    SYNERGY_DIM,
    SYNERGY_NAMES,
    angles_to_pose,
    interpolate_poses,
    named_pose,
    pose_to_angles,
    synergy_to_angles,
)
from ..inference.blend import blend_params
from ..model.trained import TrainedModel
from ..skeleton import NUM_JOINTS, POSE_DIM
from ..skeleton.params import HandParams

__all__ = [
    "NUM_FINGER_VALUES",
    "NamedHand",
    "CodeSpaces",
    "PoseEdit",
    "ViewState",
    "mean_hand",
    "model_hands",
    "interpolated_pose",
    "finger_angles",
    "view_params",
]

NUM_FINGER_VALUES = 3 * (NUM_JOINTS - 1)
"""45: (flexion, abduction, twist) of the 15 finger joints."""
_POSE_STEPS = 100
"""``pose_t`` is taken on this many steps between A and B (the slider's step is 1 / 100)."""


@dataclass(frozen=True)
class NamedHand:
    """A hand the viewer can show: name (what the dropdowns list), params, and where it came
    from (a file, "model", "photo")."""

    name: str
    params: HandParams
    source: str = "model"


@dataclass(frozen=True)
class CodeSpaces:
    """The principal directions of a model's training codes: shape (always) and colour (None
    for a geometry-only model or fewer than two subjects)."""

    shape: ShapeSpace | None
    color: ShapeSpace | None

    @classmethod
    def from_model(cls, model: TrainedModel, max_dims: int = 4) -> CodeSpaces:
        """At most ``max_dims`` directions of each (those with a non-negligible spread)."""
        def space(codes: torch.Tensor | None) -> ShapeSpace | None:
            if codes is None or codes.shape[0] < 2:
                return None
            found = ShapeSpace.from_codes(codes.detach().cpu().float(), max_dims)
            return found if found.num_dims else None

        return cls(shape=space(model.shape_codes), color=space(model.color_codes))


@dataclass(frozen=True)
class PoseEdit:
    """The pose controls (all neutral by default: the hand's own pose)."""

    named: str | None = None
    """A named pose (:data:`lisa_hand.handmodel.poses.POSE_NAMES`) whose finger angles replace
    the hand's, or None (the hand's own)."""
    synergies: tuple[float, ...] = (0.0,) * SYNERGY_DIM
    """Added synergies, :data:`lisa_hand.handmodel.poses.SYNERGY_NAMES` order (curls: 1 is a
    fist; spread; thumb curl, opposition, abduction)."""
    offsets_deg: tuple[float, ...] = (0.0,) * NUM_FINGER_VALUES
    """[45] per-joint offsets, degrees: (flexion, abduction, twist) of MANO joints 1..15."""
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Extra global rotation, degrees about the world x, y, z axes (applied in that order,
    about the wrist, before the hand's own rotation is kept)."""
    limits: bool = True
    """Clamp the finger angles to the joint limits (widened to hold the starting pose)."""

    def __post_init__(self) -> None:
        if self.named is not None and self.named not in POSE_NAMES:
            raise ValueError(f"unknown pose name {self.named!r}: known are {', '.join(POSE_NAMES)}")
        for name, values, size in (("synergies", self.synergies, SYNERGY_DIM),
                                   ("offsets_deg", self.offsets_deg, NUM_FINGER_VALUES),
                                   ("rotation_deg", self.rotation_deg, 3)):
            if len(values) != size or not all(math.isfinite(float(v)) for v in values):
                raise ValueError(f"{name} must be {size} finite numbers, got {values!r}")

    @property
    def fingers_neutral(self) -> bool:
        return (self.named is None and not any(self.synergies) and not any(self.offsets_deg))

    def with_synergy(self, name: str, value: float) -> PoseEdit:
        """This edit with synergy ``name`` (one of :data:`SYNERGY_NAMES`) set to ``value``."""
        values = list(self.synergies)
        values[SYNERGY_NAMES.index(name)] = float(value)
        return replace(self, synergies=tuple(values))

    def with_offset(self, index: int, value_deg: float) -> PoseEdit:
        """This edit with finger value ``index`` (0..44: joint ``index // 3 + 1``, angle
        ``index % 3``) offset by ``value_deg`` degrees."""
        values = list(self.offsets_deg)
        values[index] = float(value_deg)
        return replace(self, offsets_deg=tuple(values))


@dataclass(frozen=True)
class ViewState:
    """Everything the viewer's controls set (see the module docstring)."""

    hand_a: int = 0
    """Index of hand A in the viewer's hands (its pose, shape and colour at 0)."""
    hand_b: int = 0
    """Index of hand B."""
    shape_t: float = 0.0
    """Weight of B's shape (code and skeleton), in [0, 1]."""
    color_t: float = 0.0
    """Weight of B's colour code, in [0, 1]."""
    pose_t: float = 0.0
    """Weight of B's pose (and translation), in [0, 1]."""
    shape_pcs: tuple[float, ...] = ()
    """Coefficients (standard deviations) along the shape code's principal directions."""
    color_pcs: tuple[float, ...] = ()
    """Coefficients (standard deviations) along the colour code's principal directions."""
    pose: PoseEdit = field(default_factory=PoseEdit)
    """The pose controls."""
    side: str | None = None
    """"right" / "left": show that side (the mirror image when A is the other), None: A's."""

    def __post_init__(self) -> None:
        for name in ("shape_t", "color_t", "pose_t"):
            value = getattr(self, name)
            if not 0.0 <= float(value) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1] (0: A's, 1: B's), got {value!r}")
        if self.side not in (None, "right", "left"):
            raise ValueError(f"side must be 'right', 'left' or None, got {self.side!r}")


def mean_hand(model: TrainedModel, model_label: str = "default") -> HandParams:
    """The model's mean hand: the mean shape and colour codes on the mesh template's mean
    skeleton (betas 0), flat, at the origin (what ``lisa view`` shows without PARAMS)."""
    from ..handmodel.template import load_template

    template = load_template()
    betas = torch.zeros(1, template.num_betas, dtype=template.dtype)
    rest = template.rest_joints(betas)[0].float()
    color = model.mean_color_code()
    return HandParams(pose=torch.zeros(POSE_DIM), translation=torch.zeros(3), rest_joints=rest,
                      shape_code=model.mean_shape_code().cpu().float(),
                      color_code=None if color is None else color.cpu().float(),
                      betas=betas[0].float(), model=model_label)


def model_hands(model: TrainedModel, model_label: str = "default") -> list[NamedHand]:
    """The mean hand, then each training subject's codes on the mean hand's skeleton."""
    mean = mean_hand(model, model_label)
    hands = [NamedHand("mean hand", mean, "model")]
    for row, subject in enumerate(model.subject_ids):
        color = None if model.color_codes is None else model.color_codes[row].cpu().float()
        hands.append(NamedHand(f"subject {subject}", replace(
            mean, shape_code=model.shape_codes[row].cpu().float(), color_code=color), "model"))
    return hands


def interpolated_pose(a: HandParams, b: HandParams, weight: float
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """(pose [48] radians, translation [3] metres) ``weight`` of the way from A's to B's (B
    mirrored to A's side first), A's and B's exactly at 0 and 1."""
    if weight == 0.0:
        return a.pose.clone(), a.translation.clone()
    if b.side != a.side:
        b = mirror_hand(b)
    if weight == 1.0:
        return b.pose.clone(), b.translation.clone()
    step = round(weight * _POSE_STEPS)
    poses = interpolate_poses(a.pose, b.pose, _POSE_STEPS + 1, a.side)
    return poses[step].float(), torch.lerp(a.translation, b.translation, weight)


def _moved_code(code: torch.Tensor | None, space: ShapeSpace | None,
                coefficients: Sequence[float]) -> torch.Tensor | None:
    """code + sum_i c_i std_i u_i (unchanged when every c_i is 0 or there is no space)."""
    if code is None or space is None or not any(coefficients):
        return code
    values = torch.zeros(space.num_dims)
    used = min(len(coefficients), space.num_dims)
    values[:used] = torch.tensor([float(c) for c in coefficients[:used]])
    return code + (values * space.std) @ space.directions


def finger_angles(edit: PoseEdit, pose: torch.Tensor, side: str
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """The finger joints' anatomical angles of ``pose`` [48] edited by ``edit``.

    -> (before [15, 3]: the hand's or the named pose's angles plus the synergies, radians,
    float64; after [15, 3]: with the offsets, clamped when ``edit.limits``). The 45 sliders
    of the viewer show ``after``; a slider set to ``v`` makes its offset ``v - before``.
    """
    own = pose_to_angles(pose.double(), side)
    base = own if edit.named is None else pose_to_angles(named_pose(edit.named, "right",
                                                                    torch.float64), "right")
    before = base + synergy_to_angles(torch.tensor(edit.synergies, dtype=torch.float64))
    after = before + torch.tensor(edit.offsets_deg, dtype=torch.float64).reshape(-1, 3) * (
        math.pi / 180.0)
    if edit.limits:
        low = torch.minimum(JOINT_LIMITS[..., 0], base)
        high = torch.maximum(JOINT_LIMITS[..., 1], base)
        after = torch.maximum(torch.minimum(after, high), low)
    return before, after


def _rotated(pose: torch.Tensor, rotation_deg: Sequence[float]) -> torch.Tensor:
    """``pose`` with its global rotation turned by ``R_z R_y R_x`` (degrees) in the world."""
    if not any(rotation_deg):
        return pose
    turn = torch.eye(3, dtype=torch.float64)
    for axis, degrees in enumerate(rotation_deg):
        vector = torch.zeros(3, dtype=torch.float64)
        vector[axis] = math.radians(float(degrees))
        turn = axis_angle_to_matrix(vector) @ turn
    glob = matrix_to_axis_angle(turn @ axis_angle_to_matrix(pose[:3].double()))
    return torch.cat([glob.float(), pose[3:]])


def view_params(state: ViewState, hands: Sequence[NamedHand], spaces: CodeSpaces
                ) -> HandParams:
    """The hand the viewer shows for ``state`` (see the module docstring).

    hands: the viewer's hands (``state.hand_a`` and ``hand_b`` index them; all of one model).
    spaces: the model's code spaces (:meth:`CodeSpaces.from_model`).
    -> :class:`HandParams` (its ``extra['view']`` records the state).
    """
    for name in ("hand_a", "hand_b"):
        index = getattr(state, name)
        if not 0 <= index < len(hands):
            raise ValueError(f"{name} = {index} is not one of the {len(hands)} hands")
    a, b = hands[state.hand_a].params, hands[state.hand_b].params
    mixed = blend_params(a, replace(b, model=a.model), shape=state.shape_t, color=state.color_t)
    pose, translation = interpolated_pose(a, b, state.pose_t)
    edit = state.pose
    if not edit.fingers_neutral:
        _, angles = finger_angles(edit, pose, a.side)
        pose = torch.cat([pose[:3], angles_to_pose(angles, side=a.side)[3:].float()])
    pose = _rotated(pose, edit.rotation_deg)
    hand = replace(
        mixed, pose=pose, translation=translation,
        shape_code=_moved_code(mixed.shape_code, spaces.shape, state.shape_pcs),
        color_code=_moved_code(mixed.color_code, spaces.color, state.color_pcs),
        extra={"view": {"a": hands[state.hand_a].name, "b": hands[state.hand_b].name,
                        "shape_t": state.shape_t, "color_t": state.color_t,
                        "pose_t": state.pose_t}})
    if state.side is not None and state.side != hand.side:
        hand = replace(mirror_hand(hand), extra=hand.extra)
    return hand
