"""Evaluation metrics: mesh distances (LISA, Table 1; :mod:`.mesh`), image metrics (PSNR,
SSIM, LPIPS; :mod:`.image`) and a fitted mesh's colour errors (:mod:`.colours`).

``lisa metrics RECON GT`` prints :func:`compare_mesh_files` for two meshes (or point sets) and
:func:`image_metrics` for two images. The length unit of a file is decided by
:mod:`lisa_hand.data.units`, beside the readers it serves.
"""

from .colours import colour_errors
from .image import (
    ImageMetrics,
    image_metrics,
    lpips_distance,
    lpips_unavailable_reason,
    psnr,
    ssim,
)
from .keypoints import mpjpe, pa_mpjpe, procrustes_align
from .mesh import (
    MeshComparison,
    MeshData,
    MeshDistances,
    compare_mesh_files,
    load_mesh,
    mesh_distances,
)

__all__ = [
    "MeshData",
    "MeshDistances",
    "MeshComparison",
    "mesh_distances",
    "load_mesh",
    "compare_mesh_files",
    "psnr",
    "ssim",
    "lpips_distance",
    "lpips_unavailable_reason",
    "ImageMetrics",
    "image_metrics",
    "mpjpe",
    "pa_mpjpe",
    "procrustes_align",
    "colour_errors",
]
