"""A trained LISA model ready for inference: the field, its latent codes and its calibration.

What fitting, meshing, rendering and animation load. It comes from one of

* the model shipped with the package (``lisa_hand/assets/lisa_pretrained.pt``, the default);
* a file written by :func:`export_trained` (``python -m lisa_hand.trained RUN --out FILE``);
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
from ..utils.io import atomic_path
from .lisa import LisaModel

__all__ = [
    "TRAINED_FORMAT",
    "DEFAULT_BETA",
    "TrainedModel",
    "default_model_path",
    "load_trained",
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
    """

    field: LisaModel
    shape_codes: torch.Tensor
    color_codes: torch.Tensor | None
    subject_ids: list[str]
    beta: float
    gain: torch.Tensor
    bias: torch.Tensor
    source: str

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
        )


def default_model_path() -> Path:
    """Path of the model shipped with the package (it may be missing in a source checkout)."""
    return Path(str(resources.files("lisa_hand") / "assets" / "lisa_pretrained.pt"))


def _from_run(path: Path) -> TrainedModel:
    from ..training.checkpoint import LAST_CHECKPOINT, load_checkpoint
    from ..training.images import IMAGE_KIND, load_image_model
    from ..training.prior import PRIOR_KIND, load_prior

    ckpt_path = path / LAST_CHECKPOINT if path.is_dir() else path
    if not ckpt_path.is_file():
        raise FileNotFoundError(f"{ckpt_path}: no checkpoint here (expected a run folder with "
                                f"{LAST_CHECKPOINT}, a checkpoint or an exported model file)")
    kind = load_checkpoint(ckpt_path).extra.get("kind")
    if kind == IMAGE_KIND:
        model = load_image_model(ckpt_path)
        gain, bias = model.mean_calibration()
        return TrainedModel(
            field=model.field.eval(),
            shape_codes=model.shape_codes.weight.detach().clone(),
            color_codes=model.color_codes.weight.detach().clone(),
            subject_ids=list(model.subject_ids),
            beta=float(model.density.beta.detach()),
            gain=gain.detach().clone(),
            bias=bias.detach().clone(),
            source=str(ckpt_path),
        )
    if kind == PRIOR_KIND:
        model = load_prior(ckpt_path)
        return TrainedModel(
            field=model.field.eval(),
            shape_codes=model.shape_codes.weight.detach().clone(),
            color_codes=None,
            subject_ids=list(model.subject_ids),
            beta=DEFAULT_BETA,
            gain=torch.ones(3),
            bias=torch.zeros(3),
            source=str(ckpt_path),
        )
    raise ValueError(f"{ckpt_path}: a checkpoint of kind {kind!r}, not a LISA model "
                     f"({IMAGE_KIND!r} or {PRIOR_KIND!r})")


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
    return TrainedModel(
        field=field.eval(),
        shape_codes=shape_codes,
        color_codes=color_codes,
        subject_ids=[str(s) for s in subject_ids],
        beta=beta,
        gain=_tensor(data, "gain", path, (3,)),
        bias=_tensor(data, "bias", path, (3,)),
        source=str(path),
    )


def load_trained(
    path: str | os.PathLike | None = None, device: torch.device | str = "cpu"
) -> TrainedModel:
    """Load a model for inference.

    path: an exported model file, a training run folder or checkpoint (``lisa train`` or ``lisa
        train-prior``), or None for the model shipped with the package.
    device: where to put it.
    """
    if path is None:
        path = default_model_path()
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: the shipped pretrained model is missing from this installation; pass "
                "--model with a trained run or an exported model (see README, 'Pretrained model')"
            )
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such model file or run folder")
    if path.is_dir():
        return _from_run(path).to(device)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt or foreign files
        raise ValueError(f"{path}: cannot read this model file ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})") from None
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
    }
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(data, tmp)
    return path, worst


def main(argv: list[str] | None = None) -> None:
    """``python -m lisa_hand.trained RUN --out FILE [--half]``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.trained",
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
