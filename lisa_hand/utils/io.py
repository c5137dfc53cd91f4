"""Small file helpers shared by every reader and writer: atomic writes, JSON, and the checks
that name the user's path before any work (an input that is a folder, an output that cannot be
written).

Commands check their outputs first (:func:`check_output_file`, :func:`check_output_dir`), then
work, then write through :func:`atomic_path`; a writer that fails anyway raises an error naming
the user's path, never the hidden temporary file."""

from __future__ import annotations

import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_path",
    "NoSpaceError",
    "is_no_space",
    "no_space_error",
    "write_json",
    "read_json",
    "read_numpy",
    "ensure_writable_dir",
    "require_file",
    "check_output_file",
    "check_output_dir",
]


def require_file(path: str | os.PathLike) -> Path:
    """``path`` as a Path when it is an existing file, else an error that names it.

    Raises FileNotFoundError ("no such file") or IsADirectoryError ("is a directory, expected a
    file"); both are OSError, which the command line prints as one line.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a file")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if not path.is_file():
        raise OSError(f"{path}: not a regular file")
    return path


def _nearest_existing(path: Path) -> Path:
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    return existing


def _check_can_create(target: Path, folder: Path, probe: bool) -> None:
    """Fail, naming ``target``, when ``folder`` (to be created if missing) cannot hold files.

    The nearest existing ancestor of ``folder`` must be a folder; with ``probe`` a temporary
    file is created and removed there (permissions, read-only file systems, /proc).
    """
    existing = _nearest_existing(folder)
    if not existing.is_dir():
        raise NotADirectoryError(f"{target}: cannot write here: {existing} is a file, not a "
                                 "folder")
    if not probe:
        return
    try:
        fd, name = tempfile.mkstemp(prefix=".write-test-", dir=existing)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise PermissionError(f"{target}: cannot write here: {existing} is not a writable folder "
                              f"({exc.strerror or exc})") from None


def check_output_file(path: str | os.PathLike) -> Path:
    """Fail before the work when ``path`` cannot be written as a file; creates nothing.

    Raises IsADirectoryError when ``path`` is a folder, NotADirectoryError when one of its
    ancestors is a file, PermissionError when the nearest existing folder is not writable (a
    temporary file is tried there). Messages name ``path``. -> ``path`` as a Path.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected a file name")
    _check_can_create(path, path.parent, probe=True)
    return path


def check_output_dir(path: str | os.PathLike) -> Path:
    """Fail before the work when ``path`` cannot be (or become) a writable folder; creates
    nothing.

    Raises NotADirectoryError when ``path`` or an ancestor is a file, PermissionError when the
    folder (or its nearest existing ancestor) is not writable. -> ``path`` as a Path.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise NotADirectoryError(f"{path}: is a file, expected a folder")
    _check_can_create(path, path, probe=True)
    return path


_NO_SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


class NoSpaceError(OSError):
    """A write failed for want of disk space (``errno`` ENOSPC): ``str()`` is the one-line
    message, which names the path written (:func:`no_space_error`)."""

    def __init__(self, message: str) -> None:
        super().__init__(errno.ENOSPC, message)

    def __str__(self) -> str:
        return str(self.strerror)

    def __reduce__(self) -> tuple:  # survives the trip back from a worker process
        return (type(self), (self.strerror,))


def is_no_space(exc: BaseException | None) -> bool:
    """Whether ``exc``, or an exception it was raised from (``torch.save`` wraps the OSError of
    a full disk in a RuntimeError), is a full disk or quota (ENOSPC, EDQUOT)."""
    for _ in range(16):  # the chain of causes, bounded
        if exc is None:
            return False
        if isinstance(exc, OSError) and exc.errno in _NO_SPACE_ERRNOS:
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def no_space_error(path: str | os.PathLike, needed_bytes: int | None = None,
                   then: str | None = None) -> NoSpaceError:
    """The one-line error of a full disk while writing ``path``: the free space of its disk,
    ``needed_bytes`` (about what the write needed) when known, and ``then`` (what is left, what
    to do) appended."""
    path = Path(path)
    try:
        free = f"{shutil.disk_usage(_nearest_existing(path.parent)).free / 1e6:.0f} MB free there"
    except OSError:
        free = "free space unknown"
    needed = f", about {needed_bytes / 1e6:.1f} MB needed" if needed_bytes else ""
    tail = f"; {then}" if then else ""
    return NoSpaceError(f"{path}: no space left on device ({free}{needed}){tail}")


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    A crash or an exception leaves the previous file (or nothing) in place, never a half-written
    one. ``suffix`` defaults to the target's own suffix, so writers that pick a format by file
    extension (trimesh, imageio) still see the right one. The temporary file is
    ``.<name>.<random><suffix>``; only a ``kill -9`` during the write leaves it behind
    (:func:`lisa_hand.training.checkpoint.remove_stale_temporaries` clears those). Errors of
    the file system (``path`` is a folder, a parent is a file, no permission) name ``path``.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected a file name")
    _check_can_create(path, path.parent, probe=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.",
            suffix=suffix if suffix is not None else path.suffix,
            dir=path.parent,
        )
    except OSError as exc:  # name the user's path, not the temporary one
        raise type(exc)(f"{path}: cannot write here ({exc.strerror or exc})") from None
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp creates the file 0600; give the final file the usual permissions (0666 - umask).
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        try:
            yield tmp_path
        except Exception as exc:  # a full disk names the user's path, not the temporary file
            if is_no_space(exc) and not isinstance(exc, NoSpaceError):
                raise no_space_error(path) from None
            raise
        try:
            os.replace(tmp_path, path)
        except OSError as exc:
            raise type(exc)(f"{path}: cannot write ({exc.strerror or exc})") from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_json(path: str | os.PathLike, data: Any, indent: int = 2) -> Path:
    """Write ``data`` as JSON atomically and return the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=indent) + "\n")
    return path


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing or malformed file raises an error that names it."""
    path = require_file(path)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise ValueError(f"{path}: not valid JSON (nested too deeply)") from None


def read_numpy(path: str | os.PathLike) -> Any:
    """A ``.npy`` file's array, or a ``.npz`` file's arrays as a dict (all read now), never
    unpickling anything.

    -> numpy.ndarray (``.npy``) or dict[str, numpy.ndarray] (``.npz``; any other suffix is read
    as what its content is). Raises ValueError naming the file for a truncated or corrupted file
    and for one that holds Python objects (a pickle: refused, never loaded).
    """
    import numpy as np

    path = require_file(path)
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.ndarray):  # an NpzFile: read every array, close the file
            with loaded:
                return {key: loaded[key] for key in loaded.files}
        return loaded
    except Exception as exc:  # numpy, zipfile, zlib and tokenize raise many types for a bad file
        raise _numpy_error(path, exc) from None


def _numpy_error(path: Path, exc: Exception) -> ValueError:
    """The one-line error of a ``.npy``/``.npz`` file numpy cannot read; numpy's advice to
    allow pickles is not passed on (a pickle runs code: LISA never loads one)."""
    with open(path, "rb") as handle:
        magic = handle.read(6)
    if "pickle" in str(exc).lower():
        if magic.startswith((b"\x93NUMPY", b"PK")) or magic[:1] == b"\x80":
            return ValueError(f"{path}: cannot read: it holds Python objects (pickled data), "
                              "which LISA never loads; save plain numeric arrays (numpy.save, "
                              "numpy.savez)")
        return ValueError(f"{path}: cannot read: not a .npy or .npz file")
    return ValueError(f"{path}: cannot read: not a .npy/.npz file, or a truncated or corrupted "
                      f"one ({type(exc).__name__}: {exc})")


def ensure_writable_dir(path: str | os.PathLike) -> Path:
    """Create ``path`` (and parents) and check that files can be written in it."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise NotADirectoryError(f"{path}: is a file, expected a folder")
    _check_can_create(path, path, probe=False)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-", delete=True)
        probe.close()
    except OSError as exc:
        raise OSError(f"{path}: output folder is not writable ({exc.strerror or exc})") from None
    return path
