"""``lisa view``: the hand in the browser, with pose, shape and colour controls (viser)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from .options import DeviceOpt


def _hand_name(path: Path) -> str:
    """``fits/anna/params.json`` -> ``anna``; ``anna.json`` -> ``anna``."""
    return path.parent.name if path.stem == "params" and path.parent.name else path.stem


def view(
    params: Annotated[list[Path] | None, typer.Argument(
        metavar="[PARAMS]...",
        help="Hands to show (params.json of 'lisa fit-points', 'fit-images', 'fit-photo', "
             "'blend'); none: the model's mean hand. The A / B lists also hold the mean hand "
             "and the model's training subjects.")] = None,
    model: Annotated[Path | None, typer.Option(
        "--model", help="Trained model (exported file, or a 'lisa train' / 'lisa train-prior' "
                        "run); default: the one the first PARAMS names (the shipped model for "
                        "'default').")] = None,
    port: Annotated[int, typer.Option(
        "--port", min=0, max=65535, help="Port of the web server (the next free one when it "
                                         "is taken).")] = 8080,
    host: Annotated[str, typer.Option(
        "--host", help="Address to listen on (0.0.0.0 to reach it from other machines, "
                       "by IP address: pages of other names are refused).")
    ] = "127.0.0.1",
    coarse_res: Annotated[int, typer.Option(
        "--coarse-res", min=8, max=512, help="Grid samples per side of the fast mesh shown "
                                             "first after every change.")] = 40,
    fine_res: Annotated[int, typer.Option(
        "--fine-res", min=0, max=1024, help="Grid samples per side of the mesh that replaces "
                                            "it (0: none).")] = 128,
    export_dir: Annotated[Path, typer.Option(
        "--export-dir", help="Folder the Export panel writes into (params.json, mesh.ply, "
                             "view.json, screenshot.png); the panel's Folder box names one "
                             "folder inside it, never a path elsewhere.")] = Path("lisa_view"),
    export_res: Annotated[int, typer.Option(
        "--export-res", min=8, max=1024, help="Grid samples per side of the exported mesh.")
    ] = 160,
    threads: Annotated[int, typer.Option(
        "--threads", min=1, help="Torch CPU threads for meshing.")] = 2,
    device: DeviceOpt = "auto",
) -> None:
    """Serve an interactive 3D viewer of LISA hands at http://HOST:PORT (the web client ships
    with viser: no internet needed). Controls: global rotation, per-finger curl and spread,
    thumb, named poses and motions, the 45 finger joint angles; interpolate and swap shape and
    colour between two hands, move along the principal directions of the training codes;
    show skinning weights as colours (dense correspondences), normals, the skeleton and 21
    keypoints, left or right; export params.json and mesh.ply, take a screenshot; with the
    photo extra, fit an uploaded photo. Only the viewer's own page (and local programs) may
    connect; exports stay inside --export-dir. Needs the view extra: pip install -e '.[view]'."""
    from ..viewer.config import ViewerConfig, viser_missing

    missing = viser_missing()
    if missing is not None:
        typer.echo(f"lisa: error: {missing}", err=True)
        raise typer.Exit(2)
    from ..inference.hand_field import check_params, resolve_model_path
    from ..model.trained import load_trained, model_label
    from ..skeleton.params import read_params
    from ..utils.device import resolve_device
    from ..viewer.meshing import RemeshConfig
    from ..viewer.server import serve
    from ..viewer.state import NamedHand, model_hands

    config = ViewerConfig(host=host, port=port, threads=threads, export_dir=export_dir,
                          export_resolution=export_res,
                          remesh=RemeshConfig(coarse_resolution=coarse_res,
                                              fine_resolution=fine_res))
    files = list(params or [])
    loaded = [read_params(path) for path in files]
    model_path = resolve_model_path(loaded[0], files[0], model) if loaded else model
    trained = load_trained(model_path, resolve_device(device))
    label = model_label(model_path)
    hands = []
    for path, hand in zip(files, loaded, strict=True):
        check_params(trained, hand, source=str(path))
        hands.append(NamedHand(_hand_name(path), replace(hand, model=label), str(path)))
    serve(trained, hands + model_hands(trained, label), config, model_path=model_path,
          log=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("view")(view)
