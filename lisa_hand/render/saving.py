"""Saving rendered images: 8-bit PNG colours, normal maps as colours, depth as .npy.

The files of one :class:`~lisa_hand.render.image.ImageOutput` (:func:`save_image_outputs`) are
written atomically (:func:`~lisa_hand.utils.io.atomic_path`); imageio and numpy are imported
lazily.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from ..utils.io import atomic_path

if TYPE_CHECKING:
    from .image import ImageOutput

__all__ = ["image_to_uint8", "normals_to_rgb", "save_image_outputs"]


def image_to_uint8(image: torch.Tensor):
    """[H, W, C] floats in [0, 1] (clipped) -> numpy uint8 [H, W, C] (rounded)."""
    if not isinstance(image, torch.Tensor) or image.dim() != 3:
        raise ValueError(f"image must be a tensor [H, W, C], got {getattr(image, 'shape', image)}")
    values = (image.detach().float().clamp(0.0, 1.0) * 255.0).round()
    return values.to(torch.uint8).cpu().numpy()


def normals_to_rgb(
    normals: torch.Tensor, mask: torch.Tensor, background: tuple[float, float, float] = (0, 0, 0)
) -> torch.Tensor:
    """Encode unit normals as colours ``(n + 1) / 2`` inside the mask, ``background`` outside.

    normals: [H, W, 3] unit vectors. mask: [H, W] bool. Returns [H, W, 3] in [0, 1].
    """
    if normals.dim() != 3 or normals.shape[-1] != 3 or mask.shape != normals.shape[:2]:
        raise ValueError(
            f"normals must be [H, W, 3] and mask [H, W], got {tuple(normals.shape)} and "
            f"{tuple(mask.shape)}"
        )
    fill = torch.tensor(background, dtype=normals.dtype, device=normals.device)
    return torch.where(mask[..., None], 0.5 * (normals + 1.0), fill)


def save_image_outputs(
    out_dir: str | os.PathLike, output: ImageOutput, name: str = "view"
) -> dict[str, Path]:
    """Write ``{name}_rgb.png``, ``{name}_normals.png`` (``(n + 1) / 2``, world frame; only when
    normals were computed), ``{name}_mask.png`` and ``{name}_depth.npy`` (float32 metres along
    the ray) into ``out_dir`` atomically. Returns the paths by kind."""
    import imageio.v3 as iio
    import numpy as np

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    images = {"rgb": image_to_uint8(output.rgb[..., :3])}
    if bool((output.normals != 0).any()):
        images["normals"] = image_to_uint8(normals_to_rgb(output.normals, output.mask))
    images["mask"] = output.mask.cpu().numpy().astype(np.uint8) * 255
    paths = {}
    for kind, array in images.items():
        path = out_dir / f"{name}_{kind}.png"
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, array, extension=".png")
        paths[kind] = path
    path = out_dir / f"{name}_depth.npy"
    with atomic_path(path) as tmp:
        np.save(tmp, output.depth.detach().float().cpu().numpy())
    paths["depth"] = path
    return paths
