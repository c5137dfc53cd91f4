"""A fit's output folder, all or nothing: checked before the work, claimed while the fit runs,
and replaced as a whole by the files of the fit (:func:`write_folder`).

* :func:`check_output_folder` fails before a long fit when ``--out`` cannot be written, or
  holds files that a fit does not write (:data:`Allowed`: by default :data:`FIT_FILES`);
* :func:`claim_output_folder` checks it and claims it for this process
  (:func:`lock_output_folder`);
* :func:`write_folder` writes the files into a hidden folder beside ``out_dir`` and swaps it in
  as a whole once all exist (what :func:`lisa_hand.fitting.outputs.write_fit` writes through).

A reused ``--out`` is replaced as a whole: after a fit it holds exactly that fit's files (a
``metrics.json`` of an earlier fit with ``--gt`` does not survive a fit without it). Like
``lisa synth``, a fit never deletes what it did not write: a folder holding anything but
:data:`FIT_FILES` is refused before the work. A ``kill -9`` while the files are written leaves a
hidden ``.OUT.staging-PID-*`` (or ``.OUT.old-PID-*``) folder beside ``OUT``; the next fit into
``OUT`` removes it (:func:`remove_stale_staging`).

One fit at a time into an ``OUT``: a fit claims it right after checking it
(:func:`claim_output_folder`, :func:`lock_output_folder`: the file ``.OUT.lock`` beside it,
created exclusively, holding the process id) and frees it when it ends
(:func:`releases_output_locks` on the fit functions); a second fit into the same ``OUT``
meanwhile is refused in one line before its work, instead of replacing the first one's files
unsaid. A lock whose process is gone (``kill -9``) is taken over.
"""

from __future__ import annotations

import atexit
import functools
import os
import secrets
import shutil
import socket
import stat
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ...utils.io import check_output_dir, is_no_space, no_space_error

__all__ = [
    "FIT_FILES",
    "Allowed",
    "fit_file",
    "hands_entry",
    "check_output_folder",
    "claim_output_folder",
    "lock_output_folder",
    "unlock_output_folder",
    "output_lock",
    "releases_output_locks",
    "remove_stale_staging",
    "write_folder",
]

FIT_FILES = ("params.json", "mesh.ply", "keypoints.json", "metrics.json", "model.pt",
             "preview.png")
"""The files a fit writes into its output folder (``metrics.json`` only with metrics,
``model.pt`` only with a refined model: ``lisa fit-points --refine``; ``preview.png``: the
picture of a point-cloud fit, :mod:`lisa_hand.fitting.points.preview`)."""

Allowed = Callable[[Path], bool]
"""Which entries a fit's output folder may hold: called with each entry's path (a file or a
folder) -> whether the fit writes it (and may replace it)."""


def hands_entry(path: Path) -> bool:
    """The :data:`Allowed` rule of a fit of several hands (``fit-points --hands``,
    ``fit-images`` of several folders): ``hands.json``, ``hands.ply`` and ``handN/`` folders
    of :data:`FIT_FILES`."""
    if path.is_symlink():
        return False
    if path.is_file():
        return path.name in ("hands.json", "hands.ply")
    return (path.is_dir() and path.name.startswith("hand") and path.name[4:].isdigit()
            and all(entry.is_file() and entry.name in FIT_FILES for entry in path.iterdir()))


def fit_file(names: Sequence[str] = FIT_FILES) -> Allowed:
    """The :data:`Allowed` rule of a fit that writes the files ``names`` (no folders)."""
    names = frozenset(names)
    return lambda path: path.name in names and path.is_file() and not path.is_symlink()


def check_output_folder(out: str | os.PathLike, allowed: Allowed | None = None,
                        described: str | None = None) -> Path:
    """Fail before a (long) fit when ``out`` cannot become the fit's folder. Creates nothing.

    allowed: which entries a previous fit of this kind leaves (default: the files
    :data:`FIT_FILES`); described: how the error message names them (default: that list).
    Raises NotADirectoryError when ``out`` (or an ancestor) is a file, PermissionError when the
    folder, its nearest existing ancestor or the folder holding it (where the files are staged
    and swapped in) is not writable, and FileExistsError when ``out`` holds anything else (a
    fit replaces the folder as a whole and never deletes what it did not write).
    """
    allowed = fit_file() if allowed is None else allowed
    described = ", ".join(FIT_FILES) if described is None else described
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: --out must be a folder, and this is a file")
    check_output_dir(out)
    _check_beside_writable(out)
    if out.is_dir():
        foreign = sorted(p.name for p in out.iterdir() if not allowed(p))
        if foreign:
            shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
            raise FileExistsError(
                f"{out}: output folder holds files a fit does not write ({shown}); a fit "
                f"replaces the folder as a whole, so choose a new or empty folder (or one "
                f"holding only a previous fit's {described})")
    return out


def claim_output_folder(out_dir: str | os.PathLike, allowed: Allowed | None = None,
                        described: str | None = None) -> Path:
    """Check ``out_dir`` (:func:`check_output_folder`) and claim it for this process's fit
    (:func:`lock_output_folder`; the fit frees it, :func:`releases_output_locks`) -> the
    folder."""
    out_dir = check_output_folder(out_dir, allowed, described)
    lock_output_folder(out_dir)
    return out_dir


def _target(out: str | os.PathLike) -> Path:
    """The folder a fit into ``out`` replaces: absolute, a symbolic link resolved."""
    target = Path(os.path.abspath(out))
    return target.resolve() if target.is_symlink() else target


def _check_beside_writable(out: Path) -> None:
    """Fail, naming ``out``, when the folder holding it cannot take the staging folder and the
    lock (:func:`write_folder`, :func:`lock_output_folder`)."""
    parent = _target(out).parent
    try:
        check_output_dir(parent)
    except OSError as exc:
        raise PermissionError(f"{out}: cannot write the fit: the folder holding it, {parent}, is "
                              f"not writable (a fit writes its files beside --out, then renames "
                              f"them into place): {str(exc).split(': ', 1)[-1]}") from None


# ------------------------------------------------------------------------------------------------
# one fit at a time into a folder

_HELD_LOCKS: set[Path] = set()
"""Lock files this process holds (a fit claims its folder once; later claims are no-ops)."""


def _lock_path(out: str | os.PathLike) -> Path:
    target = _target(out)
    return target.parent / f".{target.name}.lock"


def _lock_owner(lock: Path) -> tuple[int | None, str]:
    """(process id, host) written in ``lock``; (None, "") when unreadable or empty."""
    try:
        words = lock.read_text().split()
        return int(words[0]), (words[1] if len(words) > 1 else "")
    except (OSError, ValueError, IndexError):
        return None, ""


def lock_output_folder(out_dir: str | os.PathLike) -> Path:
    """Claim ``out_dir`` for this process's fit: create ``.OUT.lock`` beside it exclusively
    (``O_EXCL``), holding this process id and host. -> the lock file.

    Raises FileExistsError naming ``out_dir`` and the other process when a running process of
    this host holds it (or another host, or a lock just being created). A lock whose process has
    ended is removed and taken. Claiming a folder this process holds does nothing. Freed by
    :func:`unlock_output_folder` (and at the exit of this process).
    """
    lock = _lock_path(out_dir)
    if lock in _HELD_LOCKS:
        return lock
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise type(exc)(f"{out_dir}: cannot create the folder holding it "
                        f"({exc.strerror or exc})") from None
    host = socket.gethostname()
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            pid, owner_host = _lock_owner(lock)
            fresh = pid is None and _age_seconds(lock) < 60.0  # being written right now
            if fresh or (pid is not None and pid != os.getpid() and
                         (owner_host != host or _pid_alive(pid))):
                who = "a process being started" if pid is None else (
                    f"process {pid}" + (f" on {owner_host}" if owner_host != host else ""))
                raise FileExistsError(
                    f"{out_dir}: another fit ({who}) is writing this folder; wait for it to "
                    f"end or choose another --out (if no fit runs, delete {lock})") from None
            lock.unlink(missing_ok=True)  # its process has ended: take it over
            continue
        except OSError as exc:
            raise type(exc)(f"{out_dir}: cannot claim the folder ({exc.strerror or exc})"
                            ) from None
        with os.fdopen(fd, "w") as handle:
            handle.write(f"{os.getpid()} {host}\n")
        if not _HELD_LOCKS:
            atexit.register(_release_all)
        _HELD_LOCKS.add(lock)
        return lock
    raise FileExistsError(f"{out_dir}: another fit keeps claiming this folder; choose another "
                          "--out")


def _age_seconds(path: Path) -> float:
    import time

    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return 0.0


def unlock_output_folder(out_dir: str | os.PathLike) -> None:
    """Free ``out_dir`` if this process holds it (:func:`lock_output_folder`)."""
    _release(_lock_path(out_dir))


def _release(lock: Path) -> None:
    if lock not in _HELD_LOCKS:
        return
    _HELD_LOCKS.discard(lock)
    if _lock_owner(lock)[0] == os.getpid():
        lock.unlink(missing_ok=True)


def _release_all() -> None:
    for lock in list(_HELD_LOCKS):
        _release(lock)


@contextmanager
def output_lock(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Hold ``out_dir`` (:func:`lock_output_folder`) inside the block; freed after it unless
    this process already held it before."""
    held = _lock_path(out_dir) in _HELD_LOCKS
    lock = lock_output_folder(out_dir)
    try:
        yield lock
    finally:
        if not held:
            _release(lock)


def releases_output_locks(function: Callable) -> Callable:
    """Decorator of a fit function: the folders it claims (:func:`claim_output_folder`,
    :func:`lock_output_folder`) are freed when it returns or raises."""

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        before = set(_HELD_LOCKS)
        try:
            return function(*args, **kwargs)
        finally:
            for lock in _HELD_LOCKS - before:
                _release(lock)

    return wrapper


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process, or no permission to ask: assume it runs
        return True
    return True


def remove_stale_staging(out_dir: str | os.PathLike) -> list[Path]:
    """Remove the hidden folders a killed fit left beside ``out_dir``; return them.

    :func:`write_folder` stages into ``.OUT.staging-PID-*`` and moves the previous fit to
    ``.OUT.old-PID-*`` for the swap; only a ``kill -9`` leaves them. Folders whose process
    still runs (a fit writing into ``out_dir`` right now) are kept.
    """
    target = Path(os.path.abspath(out_dir))
    removed = []
    if not target.parent.is_dir():
        return removed
    prefixes = [f".{target.name}.{kind}-" for kind in ("staging", "old")]
    for stale in sorted(target.parent.iterdir()):
        prefix = next((p for p in prefixes if stale.name.startswith(p)), None)
        if prefix is None or not stale.is_dir():
            continue
        pid_text = stale.name[len(prefix):].split("-", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            shutil.rmtree(stale, ignore_errors=True)
            removed.append(stale)
    return removed


def _can_swap(target: Path) -> bool:
    """Whether ``target`` may be renamed away: not the working folder (or above it), not a
    mount point."""
    cwd = Path.cwd()
    return not (target == cwd or target in cwd.parents or os.path.ismount(target))


def _swap_in(staging: Path, target: Path, allowed: Allowed) -> None:
    """Make ``staging`` the folder ``target``: two renames, the previous folder removed after.

    At every moment ``target`` is the previous folder or the new one, except between the two
    renames (microseconds; a kill there leaves both hidden folders, which the next fit
    removes). Where ``target`` cannot be renamed away, the entries are moved in one by one and
    the previous fit's other entries (those ``allowed`` accepts) removed.
    """
    if not target.exists():
        os.rename(staging, target)
        return
    if _can_swap(target):
        old = target.parent / f".{target.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            os.rename(target, old)
        except OSError:
            pass  # busy or not ours to rename: fall back to moving the files
        else:
            os.rename(staging, target)
            shutil.rmtree(old, ignore_errors=True)
            return
    names = [entry.name for entry in staging.iterdir()]
    for name in names:
        if (target / name).is_dir() and not (target / name).is_symlink():
            shutil.rmtree(target / name)  # a previous fit's folder (allowed: checked before)
        os.replace(staging / name, target / name)
    for entry in list(target.iterdir()):
        if entry.name not in names and allowed(entry):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()


def write_folder(out_dir: str | os.PathLike, write: Callable[[Path], list[Path]],
                 allowed: Allowed | None = None, described: str | None = None) -> list[Path]:
    """Make the folder ``out_dir`` (created) hold what ``write`` writes, all or nothing.

    write: called with a hidden staging folder beside ``out_dir``; writes the files (and
    folders) there -> their paths. The staging folder then replaces ``out_dir`` as a whole (two
    renames): the folder holds these files and nothing else. An exception in ``write`` leaves
    ``out_dir`` as it was. allowed, described: what a previous fit of this kind leaves
    (:func:`check_output_folder`; default :data:`FIT_FILES`): ``out_dir`` must be new, empty or
    hold only that, and no other process may hold it (:func:`lock_output_folder`: claimed while
    writing). Stale staging folders of killed fits into ``out_dir`` are removed first
    (:func:`remove_stale_staging`).
    -> the written paths as they are after the move (under ``out_dir``), in ``write``'s order.
    """
    allowed = fit_file() if allowed is None else allowed
    out_dir = check_output_folder(out_dir, allowed, described)
    with output_lock(out_dir):
        return _write_folder(out_dir, write, allowed)


def _write_folder(out_dir: Path, write: Callable[[Path], list[Path]],
                  allowed: Allowed) -> list[Path]:
    """:func:`write_folder` once ``out_dir`` is checked and claimed."""
    target = _target(out_dir)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(target)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.staging-{os.getpid()}-",
                                    dir=target.parent))
    try:
        # mkdtemp makes the folder 0700: give it the previous folder's mode, or the usual one.
        umask = os.umask(0)
        os.umask(umask)
        mode = stat.S_IMODE(target.stat().st_mode) if target.is_dir() else 0o777 & ~umask
        os.chmod(staging, mode)
        files = write(staging)
        _swap_in(staging, target, allowed)
    except Exception as exc:  # a full disk names --out, not the hidden staging folder
        if is_no_space(exc):
            raise no_space_error(out_dir, then="nothing was written; the folder is as it was"
                                 ) from None
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out_dir / Path(file).relative_to(staging) for file in files]
