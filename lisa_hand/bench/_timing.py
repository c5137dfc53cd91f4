"""Timing and FLOP counting shared by the field benchmark's parts (``field``, ``_pairs``).

The leading underscore keeps this module out of :func:`lisa_hand.bench.benchmark_names`: it is
not a benchmark.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

__all__ = ["interleaved_best", "mlp_flops"]


def interleaved_best(
    fns: dict[str, Callable[[], object]],
    rounds: int,
    slow: tuple[str, ...] = (),
    slow_rounds: int = 2,
) -> dict[str, float]:
    """Best wall time of each function over ``rounds`` rounds (``slow_rounds`` for the names in
    ``slow``), the functions interleaved in each round, so that a burst of load from other
    processes hits all of them alike. One warm-up call each first. -> {name: seconds}"""
    for fn in fns.values():
        fn()
    best = dict.fromkeys(fns, math.inf)
    for index in range(max(rounds, slow_rounds)):
        for name, fn in fns.items():
            if index >= (slow_rounds if name in slow else rounds):
                continue
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def mlp_flops(mlp, rows: int, with_cond: bool) -> float:
    """Multiply-add FLOPs (2 per MAC) of ``rows`` points through one group of ``mlp`` (a
    :class:`lisa_hand.fields.mlp.StackedMLP`; ``with_cond``: the conditioning in the input)."""
    first_in = mlp.point_dim + (mlp.cond_dim if with_cond else 0)
    macs = first_in * mlp.hidden + (mlp.depth - 1) * mlp.hidden**2 + mlp.hidden * mlp.out_dim
    return 2.0 * rows * macs
