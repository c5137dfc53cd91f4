"""``lisa metrics``: V2V and V2S distances between a reconstruction and a ground-truth scan."""

from __future__ import annotations

import math
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer


class Units(str, Enum):
    """Length unit of the input files."""

    m = "m"
    mm = "mm"
    auto = "auto"


_LABELS = {
    "v2v_recon_to_scan_mm": "V2V recon -> scan",
    "v2s_recon_to_scan_mm": "V2S recon -> scan",
    "v2v_scan_to_recon_mm": "V2V scan -> recon",
    "v2s_scan_to_recon_mm": "V2S scan -> recon",
}


def metrics(
    recon: Annotated[Path, typer.Argument(
        metavar="RECON", help="Reconstructed mesh (PLY/OBJ/GLB/STL) or points.")],
    gt: Annotated[Path, typer.Argument(
        metavar="GT",
        help="Ground-truth scan: a mesh, or points (.npy/.npz/.xyz, PLY without faces).")],
    json_path: Annotated[Path | None, typer.Option(
        "--json", help="Also write the four distances (mm) to this JSON file.")] = None,
    units: Annotated[Units, typer.Option(
        "--units",
        help="Units of both files: m, mm, or auto (a bounding-box diagonal over 2 means mm).",
    )] = Units.auto,
) -> None:
    """Print the V2V and V2S distances (mm) between RECON and GT, both directions (LISA Table 1).

    Undefined distances (V2S towards a point set) print as n/a and are null in the JSON.
    """
    from ..io_utils import write_json
    from ..metrics import compare_mesh_files

    result = compare_mesh_files(recon, gt, units=units.value)
    for path, unit, detected in ((recon, result.recon_unit, result.recon_unit_detected),
                                 (gt, result.scan_unit, result.scan_unit_detected)):
        if detected and unit == "mm":
            typer.echo(f"{path}: bounding box over 2 units across, read as millimetres")
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
