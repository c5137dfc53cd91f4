"""Benchmarks: ``python -m benchmarks NAME [options]``, run from the repository root (scripts
that print numbers; not part of the installed package, and no test imports them).

Each benchmark is a module ``benchmarks.NAME`` with a ``main(argv)`` function; the dispatcher
finds them by name (:func:`benchmark_names`). ``--json FILE`` writes a benchmark's numbers with
the command, date and machine that produced them (:func:`write_results`); the JSON files kept in
``benchmarks/results/`` are what ``python -m benchmarks pages`` turns into ``docs/results.md``.
"""

from __future__ import annotations

import pkgutil
from pathlib import Path

__all__ = ["RESULTS_DIR", "benchmark_names", "machine", "write_results"]

RESULTS_DIR = Path(__file__).resolve().parent / "results"
"""Where the recorded benchmark JSON files live (``benchmarks/results/NAME.json``)."""

_COMMAND: list[str] | None = None
"""The command line of this run, set by ``python -m benchmarks`` (None when called otherwise)."""


def benchmark_names() -> list[str]:
    """Names of the benchmark modules in this package (e.g. 'field'); 'pages' is the page
    generator."""
    here = [str(Path(__file__).parent)]
    return sorted(m.name for m in pkgutil.iter_modules(here) if not m.name.startswith("_"))


def machine() -> dict:
    """What a measurement ran on: CPU model and logical cores, GPU (if any), torch, Python and
    the OS, and ``OMP_NUM_THREADS``."""
    import os
    import platform

    import torch

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cpu_count": os.cpu_count(),
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
            "torch": torch.__version__, "python": platform.python_version(),
            "os": platform.platform(), "omp_num_threads": os.environ.get("OMP_NUM_THREADS")}


def _commit() -> str | None:
    """The repository's commit (short hash, '+dirty' with uncommitted changes), or None."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, text=True,
                                capture_output=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, text=True, capture_output=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+dirty" if dirty.strip() else "")


def write_results(path, results: dict) -> None:
    """``--json FILE``: write a benchmark's ``results`` there (atomically) and say so; None: no
    file. Adds ``recorded``: {"command" (the ``python -m benchmarks ...`` line, None when not run
    that way), "date" (UTC, ISO 8601), "commit", "machine" (:func:`machine`)}."""
    if path is None:
        return
    import datetime
    import shlex

    from lisa_hand.utils.io import write_json

    command = None if _COMMAND is None else " ".join(shlex.quote(part) for part in _COMMAND)
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    recorded = {"command": command, "date": date, "commit": _commit(), "machine": machine()}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_json(path, {**results, "recorded": recorded})
    print(f"wrote {path}")
