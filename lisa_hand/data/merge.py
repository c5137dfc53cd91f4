"""One dataset from several: ``python -m lisa_hand.data.merge OUT DATA[=PREFIX] ...``.

For training a model on the subjects of several ``lisa synth`` (or ``lisa import``) datasets at
once, e.g. the open hand models v1, v2 and v3 (the ``geometry_v3`` prior, docs/training.md).
``OUT`` gets a ``split.json`` that keeps every source's own split (a
held-out subject stays held out), a ``dataset.json`` naming the sources, and one symbolic link per
subject to its folder in its source (nothing is copied). A source's subject ids get its ``PREFIX``
(``runs/v1=v1``: ``s000`` -> ``v1s000``); ids must be unique across the sources.

Merging into a folder that holds anything but an earlier merge's links and files fails (nothing
is written then); the links and ``split.json`` of an earlier merge are replaced.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Sequence
from pathlib import Path

from ..utils.io import read_json, write_json
from .layout import read_split

__all__ = ["merge_datasets", "main"]

_SPLITS = ("train", "val", "test")
_PREFIX = re.compile(r"^[A-Za-z0-9_-]*$")


def _plan(sources: Sequence[tuple[Path, str]]
          ) -> tuple[dict[str, list[str]], dict[str, Path], list[dict]]:
    """-> (the merged split, {merged id: subject folder}, ``merged_from``: each source's path,
    prefix and split sizes); ValueError on a clash."""
    split: dict[str, list[str]] = {name: [] for name in _SPLITS}
    folders: dict[str, Path] = {}
    merged_from = []
    for root, prefix in sources:
        if not _PREFIX.match(prefix):
            raise ValueError(f"prefix {prefix!r} of {root}: letters, digits, '-' and '_' only")
        own = read_split(root)
        merged_from.append({"path": str(root), "prefix": prefix,
                            **{name: len(own[name]) for name in _SPLITS}})
        for name, subjects in own.items():
            for subject in subjects:
                merged = prefix + subject
                if merged in folders:
                    raise ValueError(f"{root}: subject id {merged!r} is also in "
                                     f"{folders[merged].parent}; give one source a prefix "
                                     "(DATA=PREFIX)")
                folder = (root / subject).resolve()
                if not folder.is_dir():
                    raise FileNotFoundError(f"{folder}: subject folder listed in "
                                            f"{root / 'split.json'} is missing")
                folders[merged] = folder
                split[name].append(merged)
    return split, folders, merged_from


def _check_out(out: Path) -> None:
    """``out`` must be absent, empty or an earlier merge (links and its two files only)."""
    if not out.exists():
        return
    if not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder")
    own = {"split.json", "dataset.json"}
    foreign = [p.name for p in out.iterdir() if not p.is_symlink() and p.name not in own]
    if foreign:
        raise ValueError(f"{out}: holds {', '.join(sorted(foreign)[:3])}, not a merged dataset; "
                         "choose an empty or new folder")
    if (out / "dataset.json").is_file() and "merged_from" not in read_json(out / "dataset.json"):
        raise ValueError(f"{out}: its dataset.json is not a merge's; choose another folder")


def merge_datasets(out: str | os.PathLike, sources: Sequence[tuple[str | os.PathLike, str]]
                   ) -> dict[str, list[str]]:
    """Merge ``sources`` ((dataset folder, subject id prefix), at least one) into ``out``
    (see the module docstring) -> the merged split {train, val, test: [subject ids]}."""
    if not sources:
        raise ValueError("give at least one dataset to merge")
    resolved = [(Path(root).resolve(), str(prefix)) for root, prefix in sources]
    out = Path(out).resolve()
    if any(out == root for root, _ in resolved):
        raise ValueError(f"{out}: the output folder cannot be one of the sources")
    split, folders, merged_from = _plan(resolved)
    _check_out(out)
    first = read_json(resolved[0][0] / "dataset.json")
    out.mkdir(parents=True, exist_ok=True)
    for link in out.iterdir():
        if link.is_symlink():
            link.unlink()
    for merged, folder in folders.items():
        os.symlink(folder, out / merged, target_is_directory=True)
    dataset = dict(first) if isinstance(first, dict) else {}
    dataset["merged_from"] = merged_from
    write_json(out / "dataset.json", dataset)
    write_json(out / "split.json", split)
    return split


def _source(text: str) -> tuple[str, str]:
    path, _, prefix = text.partition("=")
    return path, prefix


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.data.merge",
        description="Merge datasets (lisa synth or lisa import folders) into one for training: "
                    "each source's train/val/test split kept, one link per subject, nothing "
                    "copied. Example: python -m lisa_hand.data.merge runs/mix runs/v2 runs/v1=v1")
    parser.add_argument("out", type=Path, help="merged dataset folder (new or empty)")
    parser.add_argument("sources", nargs="+", type=_source, metavar="DATA[=PREFIX]",
                        help="a dataset folder, optionally with a prefix for its subject ids")
    args = parser.parse_args(argv)
    try:
        split = merge_datasets(args.out, args.sources)
    except (ValueError, OSError) as exc:
        parser.exit(2, f"error: {exc}\n")
    counts = ", ".join(f"{len(split[name])} {name}" for name in _SPLITS)
    print(f"wrote {args.out}: {sum(map(len, split.values()))} subjects ({counts}), linked")


if __name__ == "__main__":
    main()
