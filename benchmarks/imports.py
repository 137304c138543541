"""The import graph between bodymetry's packages, and the layer order it must follow.

``python -m benchmarks imports`` prints which package imports which (every
``import`` statement in the source, module level or inside a function), the
layer violations and cycles (none, when the layering holds) and the count of
function-local imports. ``tests/test_layers.py`` asserts the same rules.

Layers, lowest first (a package may import only its own layer and lower ones):

0. ``foundation``: ``bodymetry`` itself (``__version__``), ``bodymetry.errors``,
   ``bodymetry.fileio``, ``bodymetry.log``, ``bodymetry.schema``,
   ``bodymetry.settings`` (shared by every stage; they import no stage);
1. ``calibration``; 2. ``capture``; 3. ``estimation``;
4. ``studio`` (beside capture: renders sessions with estimation's body model) and
   ``review`` (reads a run); neither imports the other;
5. ``app``: the rest of ``bodymetry`` (CLI, ``process``, config, cameras).
"""

from __future__ import annotations

import ast
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Source folder of each package (as pyproject.toml's package-dir maps them).
FOLDERS = {
    "calibration": "calibration",
    "capture": "capture",
    "estimation": "estimation",
    "studio": "studio",
    "review": "review",
    "bodymetry": "bodymetry",
}
FOUNDATION = ("__init__", "errors", "fileio", "jit", "log", "schema", "settings", "threads")
#: Layer of each package: imports may only go to the same or a lower number.
LAYERS = {
    "foundation": 0,
    "calibration": 1,
    "capture": 2,
    "estimation": 3,
    "studio": 4,
    "review": 4,
    "app": 5,
}


@dataclass(frozen=True)
class Edge:
    """One import of a package by another: where it is and whether it is function-local."""

    source: str
    target: str
    file: str
    line: int
    local: bool


def package_of_module(module: str) -> str | None:
    """The layer package of a dotted module name inside ``bodymetry``, or None outside."""
    parts = module.split(".")
    if parts[0] != "bodymetry":
        return None
    if len(parts) == 1:  # the package itself: its __init__ holds only __version__
        return "foundation"
    if parts[1] in FOUNDATION:
        return "foundation"
    if parts[1] in LAYERS and parts[1] not in ("foundation", "app"):
        return parts[1]
    return "app"


def _file_package(folder: str, path: Path) -> str:
    if folder != "bodymetry":
        return folder
    rel = path.relative_to(ROOT / "bodymetry")
    return "foundation" if rel.parts[0].removesuffix(".py") in FOUNDATION else "app"


def _local_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            for sub in ast.walk(node):
                if isinstance(sub, ast.Import | ast.ImportFrom):
                    lines.add(sub.lineno)
    return lines


def source_files() -> list[tuple[str, Path]]:
    """(layer package, file) of every source file of the installed packages."""
    out = []
    for folder in FOLDERS.values():
        for path in sorted((ROOT / folder).rglob("*.py")):
            out.append((_file_package(folder, path), path))
    return out


def edges() -> list[Edge]:
    """Every import between different layer packages."""
    found = []
    for package, path in source_files():
        tree = ast.parse(path.read_text(), str(path))
        local = _local_lines(tree)
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for name in names:
                target = package_of_module(name)
                if target is not None and target != package:
                    found.append(
                        Edge(
                            package,
                            target,
                            str(path.relative_to(ROOT)),
                            node.lineno,
                            node.lineno in local,
                        )
                    )
    return found


def function_local_imports() -> list[tuple[str, int]]:
    """(file, line) of every import inside a function, in the installed packages."""
    out = []
    for _, path in source_files():
        tree = ast.parse(path.read_text(), str(path))
        out.extend((str(path.relative_to(ROOT)), line) for line in sorted(_local_lines(tree)))
    return out


def violations(found: list[Edge]) -> list[Edge]:
    """Imports that point up, or sideways between studio and review."""
    return [
        e
        for e in found
        if LAYERS[e.target] > LAYERS[e.source]
        or (LAYERS[e.target] == LAYERS[e.source] and e.target != e.source)
    ]


def cycles(found: list[Edge]) -> list[list[str]]:
    """Cycles in the package graph (each as a list of packages)."""
    graph: dict[str, set[str]] = {}
    for e in found:
        graph.setdefault(e.source, set()).add(e.target)
    out: list[list[str]] = []

    def visit(node: str, path: list[str]) -> None:
        for nxt in sorted(graph.get(node, ())):
            if nxt in path:
                cycle = path[path.index(nxt) :]
                if min(cycle) == cycle[0] and [*cycle, nxt] not in out:
                    out.append([*cycle, nxt])
            else:
                visit(nxt, [*path, nxt])

    for start in sorted(graph):
        visit(start, [start])
    return out


def declared_packages() -> set[str]:
    """The packages pyproject.toml lists."""
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return set(data["tool"]["setuptools"]["packages"])


def package_folders() -> set[str]:
    """The import name of every folder with an ``__init__.py`` under the mapped folders."""
    out = set()
    for folder in FOLDERS.values():
        prefix = "bodymetry" if folder == "bodymetry" else f"bodymetry.{folder}"
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            out.add(".".join([prefix, *rel.parts]))
    return out


def run() -> dict:
    found = edges()
    graph: dict[str, dict[str, int]] = {}
    for e in found:
        graph.setdefault(e.source, {}).setdefault(e.target, 0)
        graph[e.source][e.target] += 1
    local = function_local_imports()
    return {
        "layers": LAYERS,
        "graph": {s: dict(sorted(t.items())) for s, t in sorted(graph.items())},
        "violations": [f"{e.source} -> {e.target} ({e.file}:{e.line})" for e in violations(found)],
        "cycles": cycles(found),
        "function_local_imports": len(local),
        "function_local_import_sites": [f"{f}:{n}" for f, n in local],
    }
