"""``params.json``: one hand as LISA sees it (what fitting writes and meshing, rendering and
animation read).

Keys (JSON object):

* ``format`` ``"lisa-hand-params"``, ``version`` 1;
* ``side``: ``"right"`` or ``"left"``;
* ``pose`` [48]: axis-angle, radians (MANO order: global rotation then 15 finger joints);
* ``translation`` [3]: metres;
* ``rest_joints`` [16, 3]: the rest-pose skeleton, metres;
* ``betas`` [K] or null: the mesh template's shape coefficients that gave ``rest_joints``;
* ``shape_code`` [D]: LISA's shape latent; ``color_code`` [D'] or null (geometry only);
* ``model``: the model the codes belong to: a shipped model's name (``"default"``, ...), an
  absolute path (what a fit records for a model given with ``--model``), or a path relative to
  the params file's folder that stays inside it (``"model.pt"``; ``"../m.pt"`` is refused: a
  model elsewhere is given with ``--model``;
  :func:`lisa_hand.inference.hand_field.resolve_model_path`);
* ``extra``: free-form information (fit losses, timings), optional.

:func:`read_params` refuses what no hand is: another ``version``, arrays of anything but
numbers (``true``, strings), a translation over :data:`MAX_TRANSLATION_M` from the origin (float32
would flatten the hand), and a skeleton with a bone shorter than :data:`MIN_BONE_M`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from ..utils.io import read_json, write_json
from .kinematics import check_side
from .tree import NUM_JOINTS, PARENTS, POSE_DIM

__all__ = ["PARAMS_FORMAT", "MAX_TRANSLATION_M", "MIN_BONE_M", "HandParams", "read_params",
           "write_params"]

PARAMS_FORMAT = "lisa-hand-params"
_VERSION = 1
MAX_TRANSLATION_M = 100.0
"""The farthest a hand of ``params.json`` may be from the origin, metres."""
MIN_BONE_M = 0.001
"""The shortest bone of a ``params.json`` skeleton, metres (a real hand's are over 1 cm)."""


@dataclass
class HandParams:
    """One hand: pose, skeleton and latent codes (float32 CPU tensors).

    pose: [48] radians. translation: [3] metres. rest_joints: [16, 3] metres.
    shape_code: [D]. color_code: [D'] or None. betas: [K] or None.
    """

    pose: torch.Tensor
    translation: torch.Tensor
    rest_joints: torch.Tensor
    shape_code: torch.Tensor
    color_code: torch.Tensor | None = None
    betas: torch.Tensor | None = None
    side: str = "right"
    model: str = "default"
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_side(self.side)
        self.pose = _vector(self.pose, "pose", (POSE_DIM,))
        self.translation = _vector(self.translation, "translation", (3,))
        self.rest_joints = _vector(self.rest_joints, "rest_joints", (NUM_JOINTS, 3))
        self.shape_code = _vector(self.shape_code, "shape_code", (None,))
        if self.color_code is not None:
            self.color_code = _vector(self.color_code, "color_code", (None,))
        if self.betas is not None:
            self.betas = _vector(self.betas, "betas", (None,))

    def with_pose(self, pose: torch.Tensor, translation: torch.Tensor | None = None) -> HandParams:
        """The same hand in another pose (and translation, when given)."""
        return replace(self, pose=pose,
                       translation=self.translation if translation is None else translation)

    def batch(self, device: torch.device | str = "cpu") -> dict[str, torch.Tensor | None]:
        """The arguments of :meth:`LisaModel.prepare` for this hand, batch of one."""
        def one(value: torch.Tensor | None) -> torch.Tensor | None:
            return None if value is None else value[None].to(device)

        return {
            "pose": one(self.pose),
            "translation": one(self.translation),
            "rest_joints": one(self.rest_joints),
            "shape_code": one(self.shape_code),
            "color_code": one(self.color_code),
        }

    def to_dict(self) -> dict[str, Any]:
        def listed(value: torch.Tensor | None):
            return None if value is None else value.tolist()

        return {
            "format": PARAMS_FORMAT,
            "version": _VERSION,
            "side": self.side,
            "pose": listed(self.pose),
            "translation": listed(self.translation),
            "rest_joints": listed(self.rest_joints),
            "betas": listed(self.betas),
            "shape_code": listed(self.shape_code),
            "color_code": listed(self.color_code),
            "model": self.model,
            "extra": self.extra,
        }


def _vector(value: Any, name: str, shape: tuple[int | None, ...]) -> torch.Tensor:
    try:
        tensor = torch.as_tensor(value, dtype=torch.float32).detach().cpu().clone()
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{name} must be numbers of shape {list(shape)}") from None
    if tensor.dim() != len(shape) or any(
        want is not None and got != want for got, want in zip(tensor.shape, shape, strict=False)
    ):
        raise ValueError(f"{name} must have shape {list(shape)}, got {list(tensor.shape)}")
    if not torch.isfinite(tensor).all():
        raise ValueError(f"{name} holds NaN or inf")
    return tensor


def read_params(path: str | os.PathLike) -> HandParams:
    """Read a ``params.json`` (see the module docstring); errors name the file and the key."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object")
    if data.get("format", PARAMS_FORMAT) != PARAMS_FORMAT:
        raise ValueError(f"{path}: format {data.get('format')!r} is not {PARAMS_FORMAT!r}")
    version = data.get("version", _VERSION)
    if isinstance(version, bool) or version != _VERSION:
        raise ValueError(f"{path}: version {version!r} is not one this code reads ({_VERSION})")
    missing = [k for k in ("pose", "translation", "rest_joints", "shape_code") if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {', '.join(missing)}")
    model = data.get("model", "default")
    if not isinstance(model, str):
        raise ValueError(f"{path}: model must be a shipped model's name or a path, got "
                         f"{type(model).__name__}")
    extra = data.get("extra") or {}
    try:
        for key in ("pose", "translation", "rest_joints", "shape_code", "color_code", "betas"):
            _check_numbers(data.get(key), key)
        params = HandParams(
            pose=data["pose"],
            translation=data["translation"],
            rest_joints=data["rest_joints"],
            shape_code=data["shape_code"],
            color_code=data.get("color_code"),
            betas=data.get("betas"),
            side=data.get("side", "right"),
            model=model,
            extra=extra if isinstance(extra, dict) else {},
        )
        _check_plausible(params)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return params


def _check_numbers(value: Any, name: str) -> None:
    """ValueError naming ``name`` when the JSON value ``value`` (nested lists) holds anything
    but numbers: booleans, strings, null, objects."""
    stack = [value] if value is not None else []
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ValueError(f"{name} must hold numbers only, found {item!r}")


def _check_plausible(params: HandParams) -> None:
    """ValueError when ``params`` is no hand: far beyond any camera's reach (float32 flattens
    it), or with a bone of (about) zero length."""
    distance = float(params.translation.double().norm())
    if distance > MAX_TRANSLATION_M:
        raise ValueError(f"translation is {distance:.3g} m from the origin (at most "
                         f"{MAX_TRANSLATION_M:g} m: a hand's position in metres)")
    joints = params.rest_joints.double()
    children = list(range(1, NUM_JOINTS))
    lengths = (joints[children] - joints[[PARENTS[child] for child in children]]).norm(dim=1)
    shortest = int(lengths.argmin())
    if float(lengths[shortest]) < MIN_BONE_M:
        raise ValueError(f"rest_joints is degenerate: the bone to joint {children[shortest]} is "
                         f"{1000 * float(lengths[shortest]):.3g} mm long (at least "
                         f"{1000 * MIN_BONE_M:g} mm)")


def write_params(path: str | os.PathLike, params: HandParams) -> Path:
    """Write ``params`` as JSON (atomic)."""
    data = params.to_dict()
    for key, value in data["extra"].items():
        if isinstance(value, float) and not math.isfinite(value):
            data["extra"][key] = None
    return write_json(path, data)
