"""The one place that changes torch's CPU thread count.

Two CPU-bound torch processes with several threads each on a small machine slow each other down
by an order of magnitude (OpenMP barriers): fits run side by side in one-thread processes, and a
fit or a test that wants a given count sets it for a block and gives the previous one back.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

__all__ = ["cpu_threads", "single_thread_worker"]


@contextlib.contextmanager
def cpu_threads(num_threads: int | None) -> Iterator[None]:
    """Run the block with ``num_threads`` torch CPU threads (None: unchanged), then restore the
    previous count, also when the block raises."""
    if num_threads is not None and (isinstance(num_threads, bool) or not isinstance(
            num_threads, int) or num_threads < 1):
        raise ValueError(f"num_threads must be a positive integer or None, got {num_threads!r}")
    previous = torch.get_num_threads()
    if num_threads is not None:
        torch.set_num_threads(num_threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def single_thread_worker() -> None:
    """Initializer of a worker process: one torch CPU thread for the process's whole life (the
    pool's processes share the machine's cores between them)."""
    torch.set_num_threads(1)
