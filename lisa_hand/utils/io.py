"""Small file helpers shared by every reader and writer: atomic writes, JSON, and the checks
that name the user's path before any work (an input that is a folder, an output that cannot be
written).

Commands check their outputs first (:func:`check_output_file`, :func:`check_output_dir`), then
work, then write through :func:`atomic_path`; a writer that fails anyway raises an error naming
the user's path, never the hidden temporary file."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_path",
    "write_json",
    "read_json",
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
        yield tmp_path
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
