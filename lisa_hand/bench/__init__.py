"""Benchmarks: ``python -m lisa_hand.bench NAME [options]`` (scripts that print numbers).

Each benchmark is a module of this package with a ``main(argv)`` function, listed in
:data:`BENCHMARKS`.
"""

from __future__ import annotations

__all__ = ["BENCHMARKS"]

BENCHMARKS = {
    "field": "lisa_hand.bench.field",
}
"""Benchmark name -> module with ``main(argv: list[str] | None)``."""
