"""Option types and declarations shared by several ``lisa`` verbs."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer


class Units(str, Enum):
    """Length unit of input files: metres, millimetres, or guessed from their size."""

    auto = "auto"
    m = "m"
    mm = "mm"


FitModelOpt = Annotated[Path | None, typer.Option(
    "--model", help="Trained model: exported file, run folder or checkpoint "
                    "(default: the shipped model).")]
