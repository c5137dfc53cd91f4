"""The methods of the paper's tables and how a trained model is checked against its method.

Every implicit method is a configuration of the same code (:class:`lisa_hand.fields.FieldConfig`
``composition``), trained by ``lisa train`` (images) and ``lisa train-prior`` (scans):

========== ============ ======================================================= ===============
method      composition  what it is                                              trained on
========== ============ ======================================================= ===============
mano        (mesh)       the MANO-like template, pose and shape fitted            (built in)
volsdf      single       one SDF and one colour MLP on pose, shape and colour     images
nasa        nasa         per-bone SDF, the bone with the smallest SDF selected    images
narf        narf         skinning weights from the unposed points only            images
lisa_im     lisa         LISA from images only                                    images
lisa_geom   lisa         LISA's geometric prior only (no colour)                  scans
lisa_full   lisa         the prior, then images                                   scans, images
========== ============ ======================================================= ===============
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Method", "METHODS", "method_names", "check_model_method"]


@dataclass(frozen=True)
class Method:
    """One row of the tables: ``name`` (CLI and JSON key), ``label`` (in the tables), the
    field ``composition`` its model must have (None: the mesh template), and whether the model
    must have colour (True), must not (False) or either (None)."""

    name: str
    label: str
    composition: str | None
    color: bool | None
    description: str


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("mano", "MANO-like", None, None,
           "the mesh template (MANO's layout), pose and shape fitted, subdivided to ~100k "
           "vertices"),
    Method("volsdf", "VolSDF", "single", True,
           "one MLP conditioned on pose, shape and colour codes, no per-bone reasoning"),
    Method("nasa", "NASA", "nasa", True,
           "per-bone SDF and colour MLPs, the bone with the smallest SDF selected"),
    Method("narf", "NARF", "narf", True,
           "per-bone MLPs blended by weights predicted from the unposed points only"),
    Method("lisa_im", "LISA-im", "lisa", True, "LISA trained on images only"),
    Method("lisa_geom", "LISA-geom", "lisa", False, "LISA's geometric prior (scans) only"),
    Method("lisa_full", "LISA-full", "lisa", True, "LISA: the geometric prior, then images"),
)}


def method_names() -> list[str]:
    """The method names in table order."""
    return list(METHODS)


def check_model_method(method: str, model, source: str) -> None:
    """Raise ValueError when a loaded model (:class:`lisa_hand.trained.TrainedModel`) cannot be
    the method ``method`` (its composition, or colour, does not match)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    spec = METHODS[method]
    if spec.composition is None:
        raise ValueError(f"{method}: the MANO-like baseline takes no model (it is the mesh "
                         "template)")
    composition = model.config.composition
    if composition != spec.composition:
        raise ValueError(f"{source}: a {composition!r} model cannot be {spec.label} (it needs "
                         f"field.composition={spec.composition!r})")
    if spec.color is True and not model.has_color:
        raise ValueError(f"{source}: {spec.label} is trained on images and has colour; this "
                         "model has none (a geometry prior?)")
    if spec.color is False and model.has_color:
        raise ValueError(f"{source}: {spec.label} is the geometric prior alone (no colour); "
                         "this model has colour (pass the 'lisa train-prior' run)")
