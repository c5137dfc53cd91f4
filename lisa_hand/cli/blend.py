"""``lisa blend``: swap or interpolate the shape and colour of two fitted hands."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

_WEIGHT_HELP = ("A, B, or a number T in [0, 1] for (1 - T) A + T B.")


def _weight(text: str, option: str) -> float:
    value = text.strip().upper()
    if value in ("A", "B"):
        return 0.0 if value == "A" else 1.0
    try:
        weight = float(value)
    except ValueError:
        raise ValueError(f"{option} must be A, B or a number in [0, 1], got {text!r}") from None
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"{option} must be A, B or a number in [0, 1], got {text!r}")
    return weight


def blend(
    a: Annotated[Path, typer.Argument(metavar="A", help="First hand (params.json): its pose.")],
    b: Annotated[Path, typer.Argument(metavar="B", help="Second hand (params.json).")],
    out: Annotated[Path, typer.Option("--out", help="The new params.json.")],
    shape: Annotated[str, typer.Option(
        "--shape", help="Shape (shape code and skeleton) from: " + _WEIGHT_HELP)] = "A",
    color: Annotated[str, typer.Option(
        "--color", help="Colour code from: " + _WEIGHT_HELP)] = "A",
) -> None:
    """Hand A in its pose with the shape and/or colour of hand B, or in between: e.g. '--shape A
    --color B' gives A's hand with B's skin, '--shape 0.5 --color 0.5' the hand halfway. Both
    hands must be fitted with the same model; 'lisa mesh', 'lisa render' and 'lisa animate' take
    the result."""
    from ..inference import blend_params
    from ..skeleton.params import read_params, write_params
    from ..utils.io import check_output_file

    shape_weight = _weight(shape, "--shape")
    color_weight = _weight(color, "--color")
    check_output_file(out)  # a folder or an unwritable place fails before reading the hands
    hand_a, hand_b = read_params(a), read_params(b)
    try:
        mixed = blend_params(hand_a, hand_b, shape=shape_weight, color=color_weight)
    except ValueError as exc:
        raise ValueError(f"{a} and {b}: {exc}") from None
    mixed.extra["blend"].update({"a": str(a), "b": str(b)})
    write_params(out, mixed)
    typer.echo(f"wrote {out}: pose of {a}, shape {1 - shape_weight:g} A + {shape_weight:g} B, "
               f"colour {1 - color_weight:g} A + {color_weight:g} B")


def register(app: typer.Typer) -> None:
    app.command("blend")(blend)
