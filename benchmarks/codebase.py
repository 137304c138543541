"""How the source is shaped: the largest modules, long functions and cross-module private imports.

``python -m benchmarks codebase`` prints (and writes ``benchmarks/results/codebase.json``):

- ``largest``: the five largest modules of the packages (lines);
- ``long_functions``: every function longer than :data:`LONG` lines, with its place;
- ``private_imports``: each ``from bodymetry.x import _name`` of another module's
  private name (the tests and benchmarks are not counted: they may reach inside).

``tests/test_layers.py`` asserts that no package module imports another module's
private names; the figures here are for the closing notes of clean-ups.
"""

from __future__ import annotations

import ast
from pathlib import Path

from benchmarks.imports import FOLDERS, ROOT

#: A function longer than this many lines (def to last line) is listed.
LONG = 80


def _sources() -> list[Path]:
    return sorted(p for folder in FOLDERS.values() for p in (ROOT / folder).rglob("*.py"))


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def long_functions(limit: int = LONG) -> list[dict]:
    """Functions (and methods) whose definition spans more than ``limit`` lines."""
    out = []
    for path in _sources():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    where = f"{_rel(path)}:{node.lineno}"
                    out.append({"where": where, "name": node.name, "lines": n})
    return sorted(out, key=lambda f: -f["lines"])


def private_imports() -> list[str]:
    """``module:line name`` for each import of a private name of another bodymetry module."""
    out = []
    for path in _sources():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                if not node.module.startswith("bodymetry"):
                    continue
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        out.append(f"{_rel(path)}:{node.lineno} {node.module}.{alias.name}")
    return out


def run(**_: bool) -> dict:
    sizes = sorted(((len(p.read_text().splitlines()), _rel(p)) for p in _sources()), reverse=True)
    longs = long_functions()
    return {
        "largest": [{"module": m, "lines": n} for n, m in sizes[:5]],
        "modules": len(sizes),
        "lines": sum(n for n, _ in sizes),
        "long_functions_count": len(longs),
        "long_functions": longs,
        "private_imports": private_imports(),
    }
