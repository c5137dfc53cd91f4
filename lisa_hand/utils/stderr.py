"""Lines that native libraries write straight to file descriptor 2 (MediaPipe's TensorFlow
Lite start-up, FFmpeg's complaints about a file OpenCV cannot read), held back:
:func:`native_stderr_captured`. Python's own ``sys.stderr`` is not enough: C code writes to the
descriptor underneath it."""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["native_stderr_captured"]


@contextmanager
def native_stderr_captured() -> Iterator[None]:
    """Hold back what native code writes to file descriptor 2 inside the block (MediaPipe's
    TensorFlow Lite and absl start-up lines: "Created TensorFlow Lite XNNPACK delegate", "All log
    messages before absl::InitializeLog()", "Feedback manager requires ..."; FFmpeg's "moov atom
    not found"), and give it back on stderr only when the block raises."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no file descriptor 2 (a daemon): nothing to hold back
        yield
        return
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield
        except BaseException:
            _flush_c_stdio()
            os.dup2(saved, 2)
            captured.seek(0)
            os.write(2, captured.read())
            raise
        finally:
            _flush_c_stdio()  # what C code left in stdio's buffer belongs to the block
            os.dup2(saved, 2)
            os.close(saved)


def _flush_c_stdio() -> None:
    """``fflush(NULL)`` of the C library: TensorFlow Lite writes "INFO: " and the rest of its
    line in two calls, the first left in stdio's buffer (it would reach the terminal later)."""
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask (not a POSIX system)
        pass
