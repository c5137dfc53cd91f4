"""``lisa metrics``: V2V and V2S distances between a reconstruction and a ground-truth scan, or
PSNR, SSIM and LPIPS between a rendered image and a ground-truth image."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from .options import Units

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

_LABELS = {
    "v2v_recon_to_scan_mm": "V2V recon -> scan",
    "v2s_recon_to_scan_mm": "V2S recon -> scan",
    "v2v_scan_to_recon_mm": "V2V scan -> recon",
    "v2s_scan_to_recon_mm": "V2S scan -> recon",
}


_IMAGE_LABELS = {
    "psnr_db": "PSNR (dB)",
    "ssim": "SSIM",
    "psnr_mask_db": "PSNR in mask (dB)",
    "ssim_mask": "SSIM in mask",
    "lpips": "LPIPS",
}


def _image_metrics(recon: Path, gt: Path, mask: Path | None, json_path: Path | None) -> None:
    """PSNR, SSIM (whole image and inside the mask) and LPIPS of two images."""
    from ..data.layout import read_image, read_mask
    from ..metrics import image_metrics
    from ..utils.io import write_json

    pred, target = read_image(recon), read_image(gt)
    if pred.shape != target.shape:
        raise ValueError(f"{recon} is {pred.shape[1]}x{pred.shape[0]} pixels but {gt} is "
                         f"{target.shape[1]}x{target.shape[0]}: images must be the same size")
    mask_array = None if mask is None else read_mask(mask)
    if mask_array is not None and mask_array.shape != pred.shape[:2]:
        raise ValueError(f"--mask {mask} is {mask_array.shape[1]}x{mask_array.shape[0]} pixels, "
                         f"the images {pred.shape[1]}x{pred.shape[0]}")
    result = image_metrics(pred, target, mask_array)
    values = result.to_dict()
    width = max(len(label) for label in _IMAGE_LABELS.values())
    typer.echo(f"{'metric':<{width}}  {'value':>9}")
    for key, label in _IMAGE_LABELS.items():
        value = values[key]
        if value is None and key != "lpips":
            continue  # the masked metrics without --mask
        shown = "n/a" if value is None else f"{value:.4f}"
        typer.echo(f"{label:<{width}}  {shown:>9}")
    if result.lpips_message:
        typer.echo(result.lpips_message)
    if json_path is not None:
        # JSON has no infinity: the PSNR of identical images is written as null too.
        write_json(json_path, {key: (None if value == math.inf else value)
                               for key, value in values.items()})
        typer.echo(f"wrote {json_path}")


def metrics(
    recon: Annotated[Path, typer.Argument(
        metavar="RECON",
        help="Reconstructed mesh (PLY/OBJ/GLB/STL) or points; or a rendered image (PNG/JPEG).")],
    gt: Annotated[Path, typer.Argument(
        metavar="GT",
        help="Ground-truth scan: a mesh, or points (.npy/.npz/.xyz, PLY without faces); or the "
             "ground-truth image when RECON is an image.")],
    json_path: Annotated[Path | None, typer.Option(
        "--json", help="Also write the metrics (distances in mm) to this JSON file.")] = None,
    units: Annotated[Units, typer.Option(
        "--units",
        help="Units of both mesh files: m, cm, mm, or auto (each file's own, from the size of a "
             "hand: 0.1-0.3 m, 10-30 cm or 100-300 mm across its bounding box).",
    )] = Units.auto,
    mask: Annotated[Path | None, typer.Option(
        "--mask", metavar="PNG",
        help="Images only: foreground mask (nonzero = hand) for PSNR and SSIM inside it.")] = None,
) -> None:
    """Print the V2V and V2S distances (mm) between RECON and GT, both directions (LISA Table 1);
    for two images, PSNR and SSIM (whole image, and inside --mask) and LPIPS.

    Undefined distances (V2S towards a point set) print as n/a and are null in the JSON. LPIPS
    needs the 'lpips' package and its weights on disk; without them it prints one line saying
    what is missing (nothing is ever downloaded).
    """
    from ..metrics import compare_mesh_files
    from ..utils.io import check_output_file, write_json

    if json_path is not None:
        check_output_file(json_path)  # before the work, naming the user's path
    is_image = [path.suffix.lower() in _IMAGE_SUFFIXES for path in (recon, gt)]
    if any(is_image) and not all(is_image):
        raise ValueError(f"{recon} and {gt}: compare two meshes/point sets or two images, "
                         f"not one of each")
    if all(is_image):
        _image_metrics(recon, gt, mask, json_path)
        return
    if mask is not None:
        raise ValueError(f"--mask {mask} applies to images only; {recon} and {gt} are meshes")

    result = compare_mesh_files(recon, gt, units=units.value)
    for path, note in ((recon, result.recon_note), (gt, result.scan_note)):
        if note is not None:
            typer.echo(f"{path}: {note}")
    values = result.distances.to_dict()
    width = max(len(label) for label in _LABELS.values())
    typer.echo(f"{'metric':<{width}}  {'mm':>9}")
    for key, label in _LABELS.items():
        value = values[key]
        shown = "n/a" if math.isnan(value) else f"{value:.4f}"
        typer.echo(f"{label:<{width}}  {shown:>9}")
    for key, which in (("v2s_recon_to_scan_mm", gt), ("v2s_scan_to_recon_mm", recon)):
        if math.isnan(values[key]):
            typer.echo(f"{_LABELS[key]}: n/a, {which} has no faces (points only, no surface)")
    if json_path is not None:
        write_json(json_path, {key: (None if math.isnan(value) else value)
                               for key, value in values.items()})
        typer.echo(f"wrote {json_path}")


def register(app: typer.Typer) -> None:
    app.command("metrics")(metrics)
