"""``python -m benchmarks NAME [options]`` (from the repository root): run one benchmark (see
:func:`benchmark_names`), or ``pages`` to write ``docs/results.md`` from the recorded JSON."""

from __future__ import annotations

import importlib
import sys

import benchmarks

from . import benchmark_names


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    names = benchmark_names()
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in names:
        print(f"usage: python -m benchmarks NAME [options]   (NAME: {', '.join(names)})")
        if argv and argv[0] not in ("-h", "--help"):
            print(f"unknown benchmark {argv[0]!r}", file=sys.stderr)
            return 2
        return 0 if argv else 2
    benchmarks._COMMAND = ["python", "-m", "benchmarks", *argv]
    module = importlib.import_module(f"{__package__}.{argv[0]}")
    try:
        module.main(argv[1:])
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
