"""Image metrics: PSNR, SSIM (Wang et al. 2004) and LPIPS (Zhang et al. 2018).

``lisa metrics PRED.png GT.png`` prints :func:`image_metrics` for two images. Pure functions:
numpy arrays or torch tensors in, Python numbers out, computed in float64 on the CPU (evaluation,
not a training hot path). LPIPS is optional and never downloads anything.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..utils.arrays import as_numpy

__all__ = [
    "psnr",
    "ssim",
    "lpips_distance",
    "lpips_unavailable_reason",
    "ImageMetrics",
    "image_metrics",
]


def _check_image(image: Any, name: str) -> np.ndarray:
    array = as_numpy(image, name)
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (1, 3)):
        raise ValueError(f"{name} must have shape [H, W, 3] (or [H, W], [H, W, 1]), "
                         f"got {list(array.shape)}")
    if array.dtype == np.uint8:
        return array.astype(np.float64) / 255.0
    if not (np.issubdtype(array.dtype, np.floating) or array.dtype == np.bool_):
        raise TypeError(f"{name} must be float in [0, 1] or uint8, got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)


def _check_pair(pred: Any, target: Any, mask: Any | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    pred_array = _check_image(pred, "pred")
    target_array = _check_image(target, "target")
    if pred_array.shape != target_array.shape:
        raise ValueError(f"pred and target must have the same shape, got pred "
                         f"{list(pred_array.shape)} and target {list(target_array.shape)}")
    if mask is None:
        return pred_array, target_array, None
    mask_array = as_numpy(mask, "mask")
    if mask_array.ndim == 3 and mask_array.shape[2] == 1:
        mask_array = mask_array[..., 0]
    if mask_array.shape != pred_array.shape[:2]:
        raise ValueError(f"mask must have shape [H, W] = {list(pred_array.shape[:2])}, "
                         f"got {list(mask_array.shape)}")
    mask_array = mask_array.astype(bool)
    if not mask_array.any():
        raise ValueError("mask is empty: no pixel to evaluate")
    return pred_array, target_array, mask_array


def psnr(pred: Any, target: Any, mask: Any | None = None, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio ``10 log10(max_value^2 / MSE)`` in dB.

    pred, target: [H, W, 3] (or [H, W]) floats in [0, max_value], or uint8 (divided by 255, so
    keep ``max_value=1``); mask: [H, W] bool or None. With a mask the MSE averages only the
    pixels inside it (all channels). Identical images give ``inf``.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if not max_value > 0:
        raise ValueError(f"max_value must be positive, got {max_value}")
    squared = (pred_array - target_array) ** 2
    mse = float(squared[mask_array].mean() if mask_array is not None else squared.mean())
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(max_value**2 / mse)


# Gaussian 11x11 window with sigma 1.5 and population statistics: the SSIM of Wang et al. (2004),
# as used by NeRF-style evaluations (skimage's documented way to match the paper).
_SSIM_SIGMA = 1.5
_SSIM_WINDOW = 11


def ssim(pred: Any, target: Any, mask: Any | None = None, max_value: float = 1.0) -> float:
    """Structural similarity (Wang et al. 2004) via ``skimage.metrics.structural_similarity``.

    Gaussian window (sigma 1.5, 11x11), population covariances, ``data_range=max_value``, colour
    channels averaged. Without a mask: the mean SSIM of skimage (which crops the window's
    half-width at the borders). With a mask: the mean of the full SSIM map over the mask's pixels
    (and channels); windows near the mask's edge still see pixels outside it.

    pred, target: [H, W, 3] (or [H, W]) floats in [0, max_value] or uint8, H and W >= 11;
    mask: [H, W] bool or None.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if min(pred_array.shape[:2]) < _SSIM_WINDOW:
        raise ValueError(f"ssim needs images of at least {_SSIM_WINDOW}x{_SSIM_WINDOW} pixels, "
                         f"got pred {list(pred_array.shape)}")
    from skimage.metrics import structural_similarity

    channel_axis = -1 if pred_array.ndim == 3 else None
    mean_ssim, ssim_map = structural_similarity(
        pred_array, target_array, data_range=max_value, channel_axis=channel_axis,
        gaussian_weights=True, sigma=_SSIM_SIGMA, use_sample_covariance=False, full=True,
    )
    if mask_array is None:
        return float(mean_ssim)
    return float(ssim_map[mask_array].mean())


# ---------------------------------------------------------------------------------------------
# LPIPS (optional: needs the lpips package, torchvision and the backbone weights on disk)
# ---------------------------------------------------------------------------------------------

# Backbone checkpoints torchvision stores in <torch hub dir>/checkpoints.
_LPIPS_BACKBONES = {"alex": "alexnet-owt-", "vgg": "vgg16-", "squeeze": "squeezenet1_1-"}
_lpips_models: dict[str, Any] = {}
_lpips_failures: dict[str, str] = {}


def lpips_unavailable_reason(net: str = "alex") -> str:
    """Why :func:`lpips_distance` returns None, in one line; "" when LPIPS can run.

    Checks only files and importability, never downloads: the ``lpips`` package, ``torchvision``,
    the package's linear-layer weights ``lpips/weights/v0.1/<net>.pth`` and the backbone
    checkpoint in ``<torch hub dir>/checkpoints``.
    """
    if net in _lpips_failures:
        return _lpips_failures[net]
    if net not in _LPIPS_BACKBONES:
        return f"unknown LPIPS network {net!r} (expected one of {sorted(_LPIPS_BACKBONES)})"
    spec = importlib.util.find_spec("lpips")
    if spec is None or spec.origin is None:
        return "LPIPS unavailable: the 'lpips' package is not installed"
    if importlib.util.find_spec("torchvision") is None:
        return "LPIPS unavailable: 'lpips' needs torchvision, which is not installed"
    linear = Path(spec.origin).parent / "weights" / "v0.1" / f"{net}.pth"
    if not linear.is_file():
        return f"LPIPS unavailable: missing the lpips linear weights {linear}"
    import torch

    checkpoints = Path(torch.hub.get_dir()) / "checkpoints"
    prefix = _LPIPS_BACKBONES[net]
    if not any(checkpoints.glob(f"{prefix}*.pth")):
        return (f"LPIPS unavailable: no '{prefix}*.pth' backbone weights in {checkpoints} "
                f"(they are never downloaded at run time)")
    return ""


@contextmanager
def _downloads_forbidden() -> Iterator[None]:
    """Make any torch.hub download raise instead of reaching the network."""
    import torch.hub

    original = torch.hub.download_url_to_file

    def refuse(url: str, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError(f"LPIPS tried to download {url}; downloads are disabled")

    torch.hub.download_url_to_file = refuse
    try:
        yield
    finally:
        torch.hub.download_url_to_file = original


def lpips_distance(pred: Any, target: Any, net: str = "alex") -> float | None:
    """LPIPS perceptual distance (Zhang et al. 2018; lower is more similar), or None.

    Returns None when the package or its weights are not available locally (see
    :func:`lpips_unavailable_reason`); never downloads anything.

    pred, target: [H, W, 3] floats in [0, 1] or uint8.
    """
    pred_array, target_array, _ = _check_pair(pred, target, None)
    if pred_array.ndim != 3 or pred_array.shape[2] != 3:
        raise ValueError(f"lpips_distance needs [H, W, 3] images, got {list(pred_array.shape)}")
    if lpips_unavailable_reason(net):
        return None
    import torch

    model = _lpips_models.get(net)
    if model is None:
        import lpips

        try:
            with _downloads_forbidden():
                model = lpips.LPIPS(net=net, pretrained=True, verbose=False).eval()
        except (RuntimeError, OSError) as exc:  # refused download, unreadable weights
            _lpips_failures[net] = f"LPIPS unavailable: loading the model failed ({exc})"
            return None
        _lpips_models[net] = model

    def to_tensor(image: np.ndarray) -> torch.Tensor:
        # LPIPS expects [1, 3, H, W] in [-1, 1].
        return torch.from_numpy(image).float().permute(2, 0, 1)[None] * 2.0 - 1.0

    with torch.no_grad():
        return float(model(to_tensor(pred_array), to_tensor(target_array)).item())


# ---------------------------------------------------------------------------------------------
# All image metrics at once
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageMetrics:
    """PSNR, SSIM and LPIPS of one rendered image against its ground truth (:func:`image_metrics`).

    A field is NaN where it is undefined: the masked metrics without a mask, LPIPS when its
    weights are not installed (``lpips_message`` then says why, in one line).
    """

    psnr_db: float
    """PSNR over the whole image, dB (``inf`` for identical images)."""
    ssim: float
    """Mean SSIM over the whole image (unitless, at most 1)."""
    psnr_mask_db: float
    """PSNR inside the mask, dB (NaN without a mask)."""
    ssim_mask: float
    """Mean SSIM map inside the mask (NaN without a mask)."""
    lpips: float
    """LPIPS over the whole image (lower is more similar; NaN when unavailable)."""
    lpips_message: str
    """Why LPIPS is NaN, one line (:func:`lpips_unavailable_reason`); "" when it was computed."""

    def to_dict(self) -> dict[str, float | None]:
        """The five metrics by field name, NaN as None (JSON's null); no message."""
        return {key: (None if isinstance(value, float) and math.isnan(value) else value)
                for key, value in asdict(self).items() if key != "lpips_message"}


def image_metrics(pred: Any, target: Any, mask: Any | None = None,
                  lpips_net: str = "alex") -> ImageMetrics:
    """:func:`psnr` and :func:`ssim` of the whole image and inside ``mask``, and
    :func:`lpips_distance` of the whole image (never downloads anything).

    pred, target: [H, W, 3] floats in [0, 1] or uint8, H and W >= 11; mask: [H, W] bool or None.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if mask_array is None:
        psnr_mask_db = ssim_mask = math.nan
    else:
        psnr_mask_db = psnr(pred_array, target_array, mask_array)
        ssim_mask = ssim(pred_array, target_array, mask_array)
    value = lpips_distance(pred_array, target_array, net=lpips_net)
    message = "" if value is not None else (lpips_unavailable_reason(lpips_net)
                                            or "LPIPS unavailable")
    return ImageMetrics(
        psnr_db=psnr(pred_array, target_array),
        ssim=ssim(pred_array, target_array),
        psnr_mask_db=psnr_mask_db,
        ssim_mask=ssim_mask,
        lpips=math.nan if value is None else value,
        lpips_message=message,
    )
