"""Benchmarks: ``python -m lisa_hand.bench NAME [options]`` (scripts that print numbers).

Each benchmark is a module ``lisa_hand.bench.NAME`` with a ``main(argv)`` function; the
dispatcher finds them by name (:func:`benchmark_names`).
"""

from __future__ import annotations

import pkgutil
from pathlib import Path

__all__ = ["benchmark_names"]


def benchmark_names() -> list[str]:
    """Names of the benchmark modules in this package (e.g. 'field')."""
    here = [str(Path(__file__).parent)]
    return sorted(m.name for m in pkgutil.iter_modules(here) if not m.name.startswith("_"))
