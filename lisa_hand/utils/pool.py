"""The one worker-pool helper: spawned one-thread processes, or the caller's own process.

``spawn`` gives every worker a fresh interpreter (forking a process whose torch thread pools are
running can deadlock). With one worker, or one task, everything runs in this process with one torch
thread, so results are the same bits as in a pool (each worker also has one thread).

A spawned worker ends itself within a second of its parent's end, however the parent ended
(SIGTERM, SIGKILL, a crash): killing ``lisa eval --workers 2`` or ``lisa synth --workers N`` used
to leave its workers fitting on for many minutes, slowing everything else on the machine.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from .threads import cpu_threads, single_thread_worker

__all__ = ["InProcessExecutor", "worker_pool", "run_tasks"]

T = TypeVar("T")


class InProcessExecutor(Executor):
    """The :class:`~concurrent.futures.Executor` interface, run in this process with one torch
    thread (restored at :meth:`shutdown`)."""

    def __init__(self) -> None:
        self._threads = cpu_threads(1)
        self._threads.__enter__()
        self._open = True

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Future[T]:
        future: Future[T] = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the caller by future.result()
            future.set_exception(exc)
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if self._open:
            self._open = False
            self._threads.__exit__(None, None, None)


def worker_pool(num_workers: int, initializer: Callable[[], None] | None = None) -> Executor:
    """An executor of ``num_workers`` spawned one-thread processes, or (``num_workers <= 1``) an
    :class:`InProcessExecutor`. ``initializer`` runs in each worker after the thread setting."""
    if num_workers <= 1:
        if initializer is not None:
            initializer()
        return InProcessExecutor()
    return ProcessPoolExecutor(max_workers=num_workers, mp_context=multiprocessing.get_context(
        "spawn"), initializer=_Initializer(initializer))


_PARENT_POLL_S = 0.5


class _Initializer:
    """Picklable worker initializer: the parent watch (:func:`_exit_with_parent`), one torch
    thread, then the caller's initializer."""

    def __init__(self, then: Callable[[], None] | None) -> None:
        self.then = then
        self.parent = os.getpid()

    def __call__(self) -> None:
        threading.Thread(target=_exit_with_parent, args=(self.parent,), daemon=True,
                         name="lisa-parent-watch").start()
        single_thread_worker()
        if self.then is not None:
            self.then()


def _exit_with_parent(parent: int) -> None:
    """Ends this worker process at once when its parent process ``parent`` is gone (the worker
    is handed to another parent then), checked every :data:`_PARENT_POLL_S` seconds."""
    while os.getppid() == parent:
        time.sleep(_PARENT_POLL_S)
    os._exit(1)


def run_tasks(fn: Callable[..., T], tasks: Iterable[tuple], num_workers: int
              ) -> Iterator[tuple[tuple, T]]:
    """Run ``fn(*task)`` for every task in a :func:`worker_pool`; yields ``(task, result)`` as
    each finishes (in order of completion). A task's exception is raised here."""
    tasks = list(tasks)
    pool = worker_pool(1 if len(tasks) <= 1 else num_workers)
    try:
        futures = {pool.submit(fn, *task): task for task in tasks}
        for future in as_completed(futures):
            yield futures[future], future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
