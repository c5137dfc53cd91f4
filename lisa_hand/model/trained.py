"""A trained LISA model ready for inference: the field, its latent codes and its calibration.

What fitting, meshing, rendering and animation load. It comes from one of

* a model shipped with the package, by name (:data:`SHIPPED_MODELS`): ``"default"``
  (``lisa_hand/assets/lisa_pretrained.pt``, LISA-full: geometry and colour from images of hand
  model v1, what ``load_trained(None)`` gives), ``"geometry"``
  (``lisa_hand/assets/lisa_geometry.pt``, the geometric prior LISA-full was trained from: no
  colour) or ``"geometry_v3"`` (``lisa_hand/assets/lisa_geometry_v3.pt``, a geometric prior on
  644 subjects of hand models v1, v2 and v3, the MakeHuman hands: the default of ``lisa
  fit-points``);
* a file written by :func:`export_trained` (``python -m lisa_hand.model.trained RUN --out FILE``);
* a training run: a ``lisa train`` run (geometry and colour) or a ``lisa train-prior`` run
  (geometry only), as its folder or its checkpoint file.

An exported file holds only what inference needs (no optimizer state, no per-frame pose
offsets), is read with ``torch.load(weights_only=True)`` (it cannot run code) and may store the
weights in float16 to halve its size (:func:`export_trained` reports the largest change).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from ..fields.config import FieldConfig
from ..render.density import laplace_beta
from ..render.shading import HeadlightShading
from ..utils.config import config_from_dict
from ..utils.io import atomic_path
from .checkpoint import (
    IMAGE_KIND,
    LAST_CHECKPOINT,
    PRIOR_KIND,
    Checkpoint,
    load_checkpoint,
    read_torch_file,
)
from .lisa import LisaModel

__all__ = [
    "TRAINED_FORMAT",
    "DEFAULT_BETA",
    "TrainedModel",
    "SHIPPED_MODELS",
    "default_model_path",
    "shipped_model_path",
    "shipped_name",
    "model_label",
    "load_trained",
    "trained_from_checkpoint",
    "export_trained",
    "main",
]

TRAINED_FORMAT = "lisa_hand.trained"
_VERSION = 1
DEFAULT_BETA = 0.002
"""VolSDF's beta (metres) for rendering a geometry-only model (a prior has no learned beta)."""


@dataclass
class TrainedModel:
    """A trained field and what inference needs beside it.

    field: :class:`LisaModel` in eval mode.
    shape_codes: [S, shape_dim] the training subjects' shape codes (fitting starts from their
        mean); color_codes: [S, color_dim] or None (geometry-only model).
    subject_ids: [S] names of the rows.
    beta: VolSDF's Laplace scale, metres (learned by image training, else :data:`DEFAULT_BETA`).
    gain, bias: [3] the per-camera colour calibration averaged over the training cameras (LISA's
        inference-time calibration); identity for a geometry-only model.
    source: where it was loaded from (for messages and reports).
    shading: the learned shading of a model trained with ``shading="headlight"`` or
        ``"camera_light"`` (:class:`~lisa_hand.render.shading.HeadlightShading`), else None (the
        field's colour as it is).
    """

    field: LisaModel
    shape_codes: torch.Tensor
    color_codes: torch.Tensor | None
    subject_ids: list[str]
    beta: float
    gain: torch.Tensor
    bias: torch.Tensor
    source: str
    shading: HeadlightShading | None = None

    @property
    def config(self) -> FieldConfig:
        return self.field.config

    @property
    def has_color(self) -> bool:
        return self.color_codes is not None and self.field.color_mlp is not None

    @property
    def device(self) -> torch.device:
        return self.shape_codes.device

    def mean_shape_code(self) -> torch.Tensor:
        """[shape_dim] mean of the training subjects' shape codes (where fitting starts)."""
        return self.shape_codes.mean(dim=0)

    def mean_color_code(self) -> torch.Tensor | None:
        """[color_dim] mean colour code, or None for a geometry-only model."""
        return None if self.color_codes is None else self.color_codes.mean(dim=0)

    def to(self, device: torch.device | str) -> TrainedModel:
        """This model on ``device`` (a new object; the field module is moved in place)."""
        return TrainedModel(
            field=self.field.to(device),
            shape_codes=self.shape_codes.to(device),
            color_codes=None if self.color_codes is None else self.color_codes.to(device),
            subject_ids=list(self.subject_ids),
            beta=self.beta,
            gain=self.gain.to(device),
            bias=self.bias.to(device),
            source=self.source,
            shading=None if self.shading is None else self.shading.to(device),
        )


SHIPPED_MODELS = {"default": "lisa_pretrained.pt", "geometry": "lisa_geometry.pt",
                  "geometry_v3": "lisa_geometry_v3.pt"}
"""The models in ``lisa_hand/assets`` by the name ``--model`` and ``params.json`` give them:
"default" is LISA-full (images: geometry and colour) trained on the open hand model v1 from the
"geometry" prior (``lisa train-prior`` on 203 subjects of hand model v1: the SDF and skinning
networks only, no colour); "geometry_v3" is the geometric prior of the point fit, 644 subjects
of hand models v1, v2 and v3 (105, 203 and 336: ``python -m lisa_hand.data.merge``), the one
closest on hands no generator made. A name always means the same weights (a ``params.json``
holds a shape code of that model's space), so a retrained model ships under a new name."""

_RETIRED_MODELS = ("geometry_v2", "geometry_mix", "full_v2", "full_8k", "full_14k")
"""Names that were shipped once: a ``params.json`` may still name them."""


def shipped_model_path(name: str = "default") -> Path:
    """Path of the shipped model ``name`` (a key of :data:`SHIPPED_MODELS`; the file may be
    missing in a source checkout)."""
    if name not in SHIPPED_MODELS:
        raise ValueError(f"no shipped model named {name!r} (shipped: "
                         f"{', '.join(SHIPPED_MODELS)})")
    return Path(str(resources.files("lisa_hand") / "assets" / SHIPPED_MODELS[name]))


def shipped_name(path: str | os.PathLike) -> str | None:
    """``path`` as the name of a shipped model (a key of :data:`SHIPPED_MODELS` with no file or
    folder of that name here), else None."""
    return str(path) if str(path) in SHIPPED_MODELS and not Path(path).exists() else None


def model_label(path: str | os.PathLike | None) -> str:
    """What ``params.json`` records as the model of a fit made with ``path``: a shipped model's
    name ("default" for None), else the absolute path."""
    if path is None:
        return "default"
    return shipped_name(path) or str(Path(path).resolve())


def default_model_path() -> Path:
    """Path of the model shipped with the package (it may be missing in a source checkout)."""
    return shipped_model_path("default")


def _from_run(path: Path) -> TrainedModel:
    ckpt_path = path / LAST_CHECKPOINT if path.is_dir() else path
    if not ckpt_path.is_file():
        raise FileNotFoundError(f"{ckpt_path}: no checkpoint here (expected a run folder with "
                                f"{LAST_CHECKPOINT}, a checkpoint or an exported model file)")
    return trained_from_checkpoint(load_checkpoint(ckpt_path))


def _run_field(ckpt: Checkpoint, source: Path) -> tuple[LisaModel, dict[str, Any]]:
    """The trained field of a prior or image run (``model.field``, the ``field.*`` weights),
    its config checked; -> (field in eval mode, the run's config)."""
    if ckpt.config is None:
        raise ValueError(f"{source}: the checkpoint holds no run config")
    field_config = config_from_dict(FieldConfig, ckpt.config.get("field", {}),
                                    source=f"{source} (field)")
    field = LisaModel(field_config)
    prefix = "field."
    state = {k[len(prefix):]: v for k, v in ckpt.model.items() if k.startswith(prefix)}
    try:
        field.load_state_dict(state)
    except RuntimeError as exc:
        first = " ".join(line.strip() for line in str(exc).strip().splitlines()[:3])
        raise ValueError(f"{source}: the weights do not fit the saved config ({first})") \
            from None
    return field.eval(), ckpt.config


def _run_names(ckpt: Checkpoint, source: Path, keys: tuple[str, ...]) -> dict[str, list]:
    names = {}
    for key in keys:
        value = ckpt.extra.get(key)
        if not isinstance(value, list) or not value:
            raise ValueError(f"{source}: the checkpoint lists no {key}")
        names[key] = value
    return names


def trained_from_checkpoint(ckpt: Checkpoint) -> TrainedModel:
    """What inference needs of a training run's checkpoint (a ``lisa train`` or ``lisa
    train-prior`` run, :data:`IMAGE_KIND` or :data:`PRIOR_KIND`): the field, the codes, beta
    and the mean colour calibration (identity and :data:`DEFAULT_BETA` for a prior)."""
    source = ckpt.path if ckpt.path is not None else Path("<checkpoint>")
    kind = ckpt.extra.get("kind")
    if kind not in (IMAGE_KIND, PRIOR_KIND):
        raise ValueError(f"{source}: a checkpoint of kind {kind!r}, not a LISA model "
                         f"({IMAGE_KIND!r} or {PRIOR_KIND!r})")
    field, config = _run_field(ckpt, source)
    dims = field.config.shape_dim, field.config.color_dim
    if kind == PRIOR_KIND:
        names = _run_names(ckpt, source, ("subject_ids",))
        num = len(names["subject_ids"])
        return TrainedModel(
            field=field,
            shape_codes=_tensor(ckpt.model, "shape_codes.weight", source, (num, dims[0])).clone(),
            color_codes=None,
            subject_ids=list(names["subject_ids"]),
            beta=DEFAULT_BETA,
            gain=torch.ones(3),
            bias=torch.zeros(3),
            source=str(source),
        )
    names = _run_names(ckpt, source, ("subject_ids", "camera_names", "frame_keys"))
    num, cameras = len(names["subject_ids"]), len(names["camera_names"])
    beta_min = config.get("beta_min")
    if isinstance(beta_min, bool) or not isinstance(beta_min, (int, float)):
        raise ValueError(f"{source}: the run config has no beta_min")
    beta_raw = _tensor(ckpt.model, "density.beta_raw", source, ())
    shading = None
    if "shading.diffuse_raw" in ckpt.model:
        learned = "shading.light_raw" in ckpt.model
        shading = HeadlightShading(learn_light=learned).eval()
        state = {"diffuse_raw": _tensor(ckpt.model, "shading.diffuse_raw", source, ())}
        if learned:
            state["light_raw"] = _tensor(ckpt.model, "shading.light_raw", source, (3,))
        shading.load_state_dict(state)
    return TrainedModel(
        field=field,
        shape_codes=_tensor(ckpt.model, "shape_codes.weight", source, (num, dims[0])).clone(),
        color_codes=_tensor(ckpt.model, "color_codes.weight", source, (num, dims[1])).clone(),
        subject_ids=list(names["subject_ids"]),
        beta=float(laplace_beta(beta_raw, float(beta_min))),
        gain=_tensor(ckpt.model, "gain", source, (cameras, 3)).mean(dim=0),
        bias=_tensor(ckpt.model, "bias", source, (cameras, 3)).mean(dim=0),
        source=str(source),
        shading=shading,
    )


def _tensor(data: dict, key: str, path: Path, shape: tuple[int | None, ...]) -> torch.Tensor:
    value = data.get(key)
    if not isinstance(value, torch.Tensor) or value.dim() != len(shape) or any(
        want is not None and got != want for got, want in zip(value.shape, shape, strict=False)
    ):
        raise ValueError(f"{path}: {key!r} is missing or has the wrong shape (expected "
                         f"{list(shape)})")
    if not torch.isfinite(value).all():
        raise ValueError(f"{path}: {key!r} holds NaN or inf")
    return value.float()


def _from_export(path: Path, data: dict) -> TrainedModel:
    try:
        config = FieldConfig.from_dict(data["field_config"])
        state = {k: v.float() for k, v in data["field_state"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a valid exported LISA model ({exc})") from None
    field = LisaModel(config)
    try:
        field.load_state_dict(state)
    except RuntimeError as exc:
        first = " ".join(str(exc).strip().splitlines()[:2])
        raise ValueError(f"{path}: the weights do not fit the saved config ({first})") from None
    shape_codes = _tensor(data, "shape_codes", path, (None, config.shape_dim))
    color_codes = None
    if data.get("color_codes") is not None:
        color_codes = _tensor(data, "color_codes", path, (shape_codes.shape[0], config.color_dim))
    subject_ids = data.get("subject_ids")
    if not isinstance(subject_ids, list) or len(subject_ids) != shape_codes.shape[0]:
        raise ValueError(f"{path}: 'subject_ids' must list one id per shape code")
    beta = data.get("beta")
    if not isinstance(beta, float) or not beta > 0:
        raise ValueError(f"{path}: 'beta' must be a positive float, got {beta!r}")
    shading = None
    if data.get("shading") is not None:
        try:
            shading = HeadlightShading.from_values(**data["shading"]).eval()
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: 'shading' must hold a diffuse fraction in (0, 1) and "
                             f"optionally a light direction [3] ({exc})") from None
    return TrainedModel(
        field=field.eval(),
        shape_codes=shape_codes,
        color_codes=color_codes,
        subject_ids=[str(s) for s in subject_ids],
        beta=beta,
        gain=_tensor(data, "gain", path, (3,)),
        bias=_tensor(data, "bias", path, (3,)),
        source=str(path),
        shading=shading,
    )


def load_trained(
    path: str | os.PathLike | None = None, device: torch.device | str = "cpu"
) -> TrainedModel:
    """Load a model for inference.

    path: an exported model file, a training run folder or checkpoint (``lisa train`` or ``lisa
        train-prior``), the name of a shipped model (:data:`SHIPPED_MODELS`, when no file or
        folder of that name exists), or None for the model shipped with the package.
    device: where to put it.
    """
    name = "default" if path is None else shipped_name(path)
    if name is not None:
        path = shipped_model_path(name)
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: the shipped model {name!r} is missing from this installation; pass "
                "--model with a trained run or an exported model (see README, 'Models')"
            )
    path = Path(path)
    if not path.exists() and str(path) in _RETIRED_MODELS:
        raise FileNotFoundError(
            f"{path}: this model is no longer shipped (shipped: {', '.join(SHIPPED_MODELS)}); "
            f"the git history keeps its file, lisa_hand/assets/lisa_{path}.pt: pass that file")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such model file or run folder")
    if path.is_dir():
        return _from_run(path).to(device)
    data = read_torch_file(path)
    if isinstance(data, dict) and data.get("format") == TRAINED_FORMAT:
        return _from_export(path, data).to(device)
    if isinstance(data, dict) and data.get("format") == "lisa_hand.checkpoint":
        return _from_run(path).to(device)
    raise ValueError(f"{path}: not a LISA model (neither an exported model nor a training "
                     "checkpoint)")


def export_trained(
    model: TrainedModel, path: str | os.PathLike, half: bool = False
) -> tuple[Path, float]:
    """Write ``model`` for inference (atomic).

    half: store the field's weights in float16 (half the size).
    -> (path, the largest absolute weight change that storing caused: 0 unless ``half``).
    """
    state = model.field.state_dict()
    stored: dict[str, torch.Tensor] = {}
    worst = 0.0
    for key, value in state.items():
        value = value.detach().cpu()
        kept = value.half() if half and value.is_floating_point() else value.clone()
        worst = max(worst, float((kept.float() - value.float()).abs().max()) if value.numel()
                    else 0.0)
        stored[key] = kept
    data: dict[str, Any] = {
        "format": TRAINED_FORMAT,
        "version": _VERSION,
        "field_config": model.config.to_dict(),
        "field_state": stored,
        "shape_codes": model.shape_codes.detach().cpu().float(),
        "color_codes": None if model.color_codes is None
        else model.color_codes.detach().cpu().float(),
        "subject_ids": list(model.subject_ids),
        "beta": float(model.beta),
        "gain": model.gain.detach().cpu().float(),
        "bias": model.bias.detach().cpu().float(),
        "shading": None if model.shading is None else model.shading.values(),
    }
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(data, tmp)
    return path, worst


def main(argv: list[str] | None = None) -> None:
    """``python -m lisa_hand.model.trained RUN --out FILE [--half]``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.model.trained",
        description="Export a trained run (lisa train or lisa train-prior) for inference.")
    parser.add_argument("run", help="run folder or checkpoint (or an exported model)")
    parser.add_argument("--out", required=True, help="output file (.pt)")
    parser.add_argument("--half", action="store_true", help="store weights in float16")
    args = parser.parse_args(argv)
    model = load_trained(args.run)
    path, worst = export_trained(model, args.out, half=args.half)
    size = path.stat().st_size / 2**20
    print(f"wrote {path} ({size:.1f} MiB, colour: {model.has_color}, "
          f"{len(model.subject_ids)} subjects, largest weight change {worst:.2e})")


if __name__ == "__main__":
    main()
