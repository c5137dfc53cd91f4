"""The package's layers and the direction of its imports (docs/architecture.md).

Every ``lisa_hand`` import in every module is checked against the layer table below, lazy imports
inside functions included: a layer may import only the layers listed for it. A change that makes
``render`` import ``fields`` or ``fitting`` import ``training`` fails here first.
"""

import ast
from pathlib import Path

import pytest

import lisa_hand

PACKAGE = Path(lisa_hand.__file__).parent

ALLOWED = {
    "utils": set(),
    "geometry": {"utils"},
    "skeleton": {"utils", "geometry"},
    "handmodel": {"utils", "geometry", "skeleton"},
    "data": {"utils", "geometry", "skeleton", "handmodel", "render"},  # render.raycast
    "metrics": {"utils", "geometry", "data"},
    "fields": {"utils", "geometry", "skeleton"},
    "model": {"utils", "geometry", "skeleton", "fields", "render"},
    "render": {"utils", "geometry"},  # renders any field callback, never the model
    "inference": {"utils", "geometry", "skeleton", "handmodel", "data", "fields", "model",
                  "render"},
    "training": {"utils", "geometry", "skeleton", "handmodel", "data", "fields", "model",
                 "render"},
    "fitting": {"utils", "geometry", "skeleton", "handmodel", "data", "metrics", "fields",
                "model", "render", "inference"},
    "evaluation": {"utils", "geometry", "skeleton", "handmodel", "data", "metrics", "fields",
                   "model", "render", "inference", "training", "fitting"},
    "viewer": {"utils", "geometry", "skeleton", "handmodel", "data", "metrics", "fields",
               "model", "render", "inference", "training", "fitting", "evaluation"},
    "cli": {"utils", "geometry", "skeleton", "handmodel", "data", "metrics", "fields", "model",
            "render", "inference", "training", "fitting", "evaluation", "viewer"},
}
"""Layer -> the layers it may import (besides itself and the top-level ``lisa_hand``)."""


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _imports(path: Path) -> list[tuple[int, str]]:
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    if path.name == "__init__.py":
        package = module.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
    return [(line, target) for line, target in found if target.split(".")[0] == "lisa_hand"]


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if p.parent != PACKAGE)


def test_every_module_is_in_a_layer():
    root_modules = sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py")
    assert root_modules == [], f"modules outside every layer: {root_modules}"
    layers = {p.relative_to(PACKAGE).parts[0] for p in _modules()}
    assert layers <= set(ALLOWED), f"layers missing from the table: {layers - set(ALLOWED)}"


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_flow_one_way(path):
    own = path.relative_to(PACKAGE).parts[0]
    wrong = [f"line {line}: {target}" for line, target in _imports(path)
             if _layer(target) not in (None, own) and _layer(target) not in ALLOWED[own]]
    assert not wrong, f"{own} may import only {sorted(ALLOWED[own])}; found " + "; ".join(wrong)


def test_nothing_imports_the_benchmarks():
    """``benchmarks/`` (at the repository's root) is not installed: no module of the package and
    no test may import it."""
    tests = Path(__file__).parent
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")) + sorted(tests.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            wrong += [f"{path.name}:{node.lineno}" for name in names
                      if name.split(".")[0] == "benchmarks"]
    assert not wrong, "imports of benchmarks: " + ", ".join(wrong)


MAX_FILE_LINES = 650
"""A module longer than this holds two concepts (STYLE.md: split it by stage or responsibility)."""

MAX_FUNCTION_LINES = 90
"""A function longer than this wants named steps (docstring included)."""


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_modules_and_functions_stay_small(path):
    text = path.read_text()
    assert text.count("\n") <= MAX_FILE_LINES, f"{path.name}: {text.count(chr(10))} lines"
    long = [f"{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(ast.parse(text))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, f"{path.name}: " + ", ".join(long)
