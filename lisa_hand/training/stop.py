"""A graceful stop on Ctrl-C / SIGTERM: the first signal asks the run to finish its step,
checkpoint and return; a second Ctrl-C aborts at once (``KeyboardInterrupt``, no checkpoint)."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["StopRequest"]


class StopRequest:
    """Signal handlers for the duration of a run (``with StopRequest(note) as stop: ...``).

    ``stop.signal`` is None until SIGINT or SIGTERM arrives, then the signal's number. Handlers
    are installed only in the main thread (elsewhere Python refuses them; the run then stops only
    when killed) and the previous ones are restored on exit.
    """

    def __init__(self, note: Callable[[str], None]) -> None:
        """note: prints a message to the user (rank 0) when a stop is requested."""
        self.signal: int | None = None
        self._note = note
        self._previous: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        if self.signal is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt  # second Ctrl-C: abort now, no checkpoint
        self.signal = signum
        self._note(f"received {signal.Signals(signum).name}: stopping at the end of the "
                   "current step and writing a checkpoint (Ctrl-C again to abort without one)")

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is not threading.main_thread():
            return self
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self._previous[signum] = signal.signal(signum, self._handler)
            except (ValueError, OSError):
                pass
        return self

    def __exit__(self, *exc_info: Any) -> None:
        for signum, old in self._previous.items():
            signal.signal(signum, old)
        self._previous = {}
