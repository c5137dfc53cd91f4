"""Benchmarks: ``python -m lisa_hand.bench NAME [options]`` (scripts that print numbers).

Each benchmark is a module ``lisa_hand.bench.NAME`` with a ``main(argv)`` function; the
dispatcher finds them by name (:func:`benchmark_names`).
"""

from __future__ import annotations

import pkgutil
from pathlib import Path

__all__ = ["benchmark_names", "write_results"]


def benchmark_names() -> list[str]:
    """Names of the benchmark modules in this package (e.g. 'field')."""
    here = [str(Path(__file__).parent)]
    return sorted(m.name for m in pkgutil.iter_modules(here) if not m.name.startswith("_"))


def write_results(path, results: dict) -> None:
    """``--json FILE``: write a benchmark's ``results`` there (atomically) and say so; None: no
    file."""
    if path is None:
        return
    from ..utils.io import write_json

    write_json(path, results)
    print(f"wrote {path}")
