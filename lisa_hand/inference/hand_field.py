"""One hand of a trained model, prepared for evaluation: :class:`HandField`.

The one hand state of the package is :class:`lisa_hand.skeleton.params.HandParams` (what a fit
returns and ``params.json`` holds). A :class:`HandField` is not a second one: it is that hand
*bound to a trained model*, with the field's per-frame state computed once, so that meshing and
rendering can call it. Its callbacks follow the one field protocol
(:class:`lisa_hand.geometry.fields.SdfFn`, :class:`~lisa_hand.geometry.fields.FieldFn`).

A left hand is the mirror image of a right one (x -> -x, as MANO's left model): the field, a
right hand, is evaluated at mirrored points with the mirrored pose and skeleton.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch

from ..geometry.fields import FieldFn, SdfFn
from ..model import FrameState
from ..model.trained import SHIPPED_MODELS, TrainedModel, load_trained, shipped_model_path
from ..render.renderer import apply_gain_bias
from ..skeleton import mirror_points, mirror_pose
from ..skeleton.params import HandParams, read_params

__all__ = [
    "GEOMETRY_ONLY_GREY",
    "HandField",
    "HandOutput",
    "check_params",
    "field_inputs",
    "hand_field",
    "resolve_model_path",
    "load_hand",
]

GEOMETRY_ONLY_GREY = 0.7
"""Albedo given to a geometry-only model (a shape prior) when it is rendered or meshed."""


@dataclass
class HandOutput:
    """The field of one hand at world points (:meth:`HandField.evaluate`).

    sdf: [N] metres, negative inside the hand.
    rgb: [N, 3] in [0, 1], calibrated with the model's mean gain and bias
        (:data:`GEOMETRY_ONLY_GREY` for a geometry-only model), or None when not asked.
    weights: [N, 16] skinning weights (>= 0, rows sum to 1; bone order of
        :data:`lisa_hand.skeleton.PARENTS`), or None for the 'single' composition (no bones).
    """

    sdf: torch.Tensor
    rgb: torch.Tensor | None
    weights: torch.Tensor | None


@dataclass
class HandField:
    """The field of one hand, ready to evaluate in the world frame (:func:`hand_field`).

    Not a hand state: the hand is ``params``, a :class:`lisa_hand.skeleton.params.HandParams`
    (the one hand state, read and written as ``params.json``); this binds it to ``model`` and
    holds the field's per-frame state, computed once for every call of its callbacks.

    model: the trained model. params: the hand (its side, pose and codes).
    frame: the field's per-frame state, of the right hand (mirrored inputs for a left hand).
    mirrored: True for a left hand: world points are mirrored (x -> -x) before evaluation.
    """

    model: TrainedModel
    params: HandParams
    frame: FrameState
    mirrored: bool

    @property
    def has_color(self) -> bool:
        return self.model.has_color

    def _field_points(self, points: torch.Tensor) -> torch.Tensor:
        return mirror_points(points) if self.mirrored else points

    def sdf_fn(self) -> SdfFn:
        """``points [N, 3] world metres -> sdf [N] metres`` (negative inside)."""
        base = self.model.field.sdf_fn(self.frame)

        def sdf(points: torch.Tensor) -> torch.Tensor:
            return base(self._field_points(points))

        return sdf

    def field_fn(self) -> FieldFn:
        """``(points [N, 3] metres, directions [N, 3]) -> (sdf [N] metres, rgb [N, 3])``.

        Colours are calibrated with the model's mean gain and bias
        (:func:`lisa_hand.render.renderer.apply_gain_bias`, LISA's inference-time calibration;
        per sample, which composites to the same image as calibrating the rendered colour). A
        geometry-only model is :data:`GEOMETRY_ONLY_GREY` everywhere.
        """
        if not self.has_color:
            sdf_fn = self.sdf_fn()

            def grey(points: torch.Tensor, directions: torch.Tensor):
                sdf = sdf_fn(points)
                return sdf, sdf.new_full((points.shape[0], 3), GEOMETRY_ONLY_GREY)

            return grey
        base = self.model.field.field_fn(self.frame)
        gain, bias = self.model.gain, self.model.bias

        def calibrated(points: torch.Tensor, directions: torch.Tensor):
            sdf, rgb = base(self._field_points(points), self._field_points(directions))
            return sdf, apply_gain_bias(rgb, gain.to(rgb.dtype), bias.to(rgb.dtype))

        return calibrated

    def evaluate(self, points: torch.Tensor, colors: bool = True,
                 chunk_size: int = 65536) -> HandOutput:
        """The SDF, calibrated colour and skinning weights at world points, in one pass of the
        field per ``chunk_size`` points (what ``model(pose, codes, points)`` is in smplx's
        terms). Not differentiable (``torch.no_grad``): for gradients call
        :meth:`lisa_hand.model.lisa.LisaModel.field` on ``self.frame``.

        points: [N, 3] metres (the model's dtype and device). colors: also the colours.
        -> :class:`HandOutput` on the model's device.
        """
        parts = [self._evaluate(chunk, colors) for chunk in points.split(max(1, chunk_size))]

        def joined(name: str) -> torch.Tensor | None:
            values = [getattr(part, name) for part in parts]
            return None if values[0] is None else torch.cat(values)

        return HandOutput(sdf=joined("sdf"), rgb=joined("rgb"), weights=joined("weights"))

    def _evaluate(self, points: torch.Tensor, colors: bool) -> HandOutput:
        """:meth:`evaluate` of one chunk."""
        with torch.no_grad():
            out = self.model.field.field(self.frame, self._field_points(points)[None],
                                         with_color=colors and self.has_color)
        rgb = None
        if colors and self.has_color:
            rgb = apply_gain_bias(out.rgb[0], self.model.gain, self.model.bias).clamp(0.0, 1.0)
        elif colors:
            rgb = points.new_full((points.shape[0], 3), GEOMETRY_ONLY_GREY)
        return HandOutput(sdf=out.sdf[0], rgb=rgb,
                          weights=None if out.weights is None else out.weights[0])

    def attributes(
        self, points: torch.Tensor, colors: bool = True, skin_weights: bool = True
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """Calibrated colours and skinning weights at world points.

        points: [N, 3] metres (the model's dtype and device).
        -> (rgb [N, 3] in [0, 1] or None, weights [N, 16] or None). Colours are None when not
        asked; a geometry-only model gives :data:`GEOMETRY_ONLY_GREY`. Weights are None when
        not asked or for the 'single' composition (no bones).
        """
        field = self.model.field
        with torch.no_grad():
            out = field.field(
                self.frame, self._field_points(points)[None], with_color=colors and self.has_color
            )
        rgb = weights = None
        if colors:
            if self.has_color:
                rgb = apply_gain_bias(out.rgb[0], self.model.gain, self.model.bias).clamp(0.0, 1.0)
            else:
                rgb = points.new_full((points.shape[0], 3), GEOMETRY_ONLY_GREY)
        if skin_weights and out.weights is not None:
            weights = out.weights[0]
        return rgb, weights


def check_params(model: TrainedModel, params: HandParams, source: str | None = None) -> None:
    """Check that the codes of ``params`` fit ``model`` (ValueError naming ``source`` if not)."""
    prefix = f"{source}: " if source else ""
    config = model.config
    if not isinstance(params, HandParams):
        raise TypeError(f"{prefix}params must be a HandParams, got {type(params).__name__}")
    if params.shape_code.shape != (config.shape_dim,):
        raise ValueError(
            f"{prefix}shape_code has {params.shape_code.shape[0]} entries but the model "
            f"({model.source}) has shape codes of {config.shape_dim}"
        )
    if (
        params.color_code is not None
        and model.has_color
        and params.color_code.shape != (config.color_dim,)
    ):
        raise ValueError(
            f"{prefix}color_code has {params.color_code.shape[0]} entries but the model "
            f"({model.source}) has colour codes of {config.color_dim}"
        )


def hand_field(model: TrainedModel, params: HandParams) -> HandField:
    """Prepare the field of ``model`` for the hand ``params`` (one frame).

    A hand without a colour code takes the model's mean colour code. The field lives on the
    model's device and dtype.
    """
    if not isinstance(model, TrainedModel):
        raise TypeError(f"model must be a TrainedModel, got {type(model).__name__}")
    check_params(model, params)
    with torch.no_grad():
        frame = model.field.prepare(*field_inputs(model, params))
    return HandField(model=model, params=params, frame=frame, mirrored=params.side == "left")


def field_inputs(model: TrainedModel, params: HandParams) -> list[torch.Tensor | None]:
    """What :meth:`lisa_hand.model.lisa.LisaModel.prepare` takes for the hand ``params``, batched
    (B = 1) on the model's device and dtype: [pose [1, 48], translation [1, 3], rest joints
    [1, 16, 3], shape code, colour code (the hand's, else the training codes' mean; None for a
    field without colour)], a left hand's mirrored into the right hand the field is."""
    field = model.field
    pose, translation, rest_joints = params.pose, params.translation, params.rest_joints
    if params.side == "left":
        pose, translation = mirror_pose(pose), mirror_points(translation)
        rest_joints = mirror_points(rest_joints)
    color_code = None
    if field.color_mlp is not None:
        color_code = params.color_code if model.has_color else None
        if color_code is None:
            mean = model.mean_color_code()
            color_code = mean if mean is not None else torch.zeros(model.config.color_dim)
    return [None if value is None else value[None].to(device=field.device, dtype=field.dtype)
            for value in (pose, translation, rest_joints, params.shape_code, color_code)]


def resolve_model_path(
    params: HandParams, params_path: str | os.PathLike | None, model: str | os.PathLike | None
) -> Path | None:
    """The model to load for a hand: ``model`` (the command line's ``--model``) when given; else
    the one ``params`` names: ``"default"`` (the shipped model, returned as None), another
    shipped model's name, an absolute path (what the fits and ``lisa blend`` record for a model
    given with ``--model``), or a relative path, taken relative to the params file's folder
    (never the working folder) and refused with a ValueError naming the file when it leaves
    that folder (``../m.pt``): a model elsewhere is given with ``--model``. Without
    ``params_path`` (a hand in memory) a relative path is taken as it is."""
    if model is not None:
        return Path(model)
    if params.model in ("", "default"):
        return None
    if params.model in SHIPPED_MODELS:
        shipped = shipped_model_path(params.model)
        return shipped if shipped.is_file() else Path(params.model)  # missing: load_trained says
    named = Path(params.model)
    if named.is_absolute() or params_path is None:
        return named
    folder = Path(params_path).resolve().parent
    target = (folder / named).resolve()
    if not target.is_relative_to(folder):
        raise ValueError(f"{params_path}: its model {params.model!r} leaves the file's folder, "
                         f"which a relative path in params.json may not; give the model on the "
                         f"command line: --model {target}")
    return target


def load_hand(
    params_path: str | os.PathLike,
    model: str | os.PathLike | None = None,
    device: torch.device | str = "cpu",
) -> tuple[TrainedModel, HandParams]:
    """Read ``params.json`` and load the model its codes belong to (``model`` overrides the one
    it names); errors name the file. -> (model, params)"""
    params = read_params(params_path)
    model_path = resolve_model_path(params, params_path, model)
    trained = load_trained(model_path, device)
    check_params(trained, params, source=str(params_path))
    return trained, params
