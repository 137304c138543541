"""The step graph: one wiring of the steps, shared by both executors (bodymetry/pipeline.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import bodymetry
from bodymetry import pipeline
from bodymetry.executors import DaskExecutor, Executor, LocalExecutor

APP = Path(bodymetry.__file__).parent


def _step_references() -> dict[str, list[str]]:
    """Where each step is named in the application's code, outside its own definition:
    in pipeline.py, and in any module that imports steps from it."""
    names = {step.__name__ for step in pipeline.STEPS}
    found: dict[str, list[str]] = {n: [] for n in names}
    for path in sorted(APP.rglob("*.py")):
        tree = ast.parse(path.read_text())
        visible = set(names) if path.name == "pipeline.py" else set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module == "bodymetry.pipeline":
                visible |= {a.asname or a.name for a in node.names} & names
        for func in ast.walk(tree):
            if not isinstance(func, ast.FunctionDef):
                continue
            for node in ast.walk(func):
                if isinstance(node, ast.Name) and node.id in visible and func.name != node.id:
                    found[node.id].append(f"{path.name}:{func.name}:{node.lineno}")
    # Each reference once: ast.walk visits a nested function's nodes from its parent too.
    return {n: sorted(set(p)) for n, p in found.items()}


def test_each_step_has_one_call_site_in_run_session():
    """process and batch cannot wire a step differently: each step is named in one place."""
    for step, places in _step_references().items():
        assert len(places) == 1, f"{step} is wired in {places}"
        assert places[0].startswith("pipeline.py:run_session:"), places


def test_process_and_batch_run_the_session_graph_only():
    sources = {name: (APP / f"{name}.py").read_text() for name in ("process", "batch")}
    for name, text in sources.items():
        assert "run_session(" in text, name
        for step in pipeline.STEPS:
            assert f" {step.__name__}(" not in text, f"{name}.py calls {step.__name__}"


def test_both_executors_offer_what_the_graph_needs():
    wanted = {
        n for n in dir(Executor) if not n.startswith("_") and n not in ("read_method", "remote")
    }
    for cls in (LocalExecutor, DaskExecutor):
        assert wanted <= set(dir(cls)), cls
        assert cls.read_method in ("sequential", "seek")


def test_the_local_executor_holds_a_step_error_until_its_result_is_read():
    def boom() -> None:
        raise ValueError("bad input")

    with LocalExecutor(1) as ex:
        future = ex.submit(boom)
        assert isinstance(future.exception(), ValueError)
        chained = ex.submit(lambda x: x + 1, ex.submit(lambda: 1))
        assert chained.result() == 2
        assert ex.item(ex.submit(lambda: [3, 4]), 1).result() == 4
        assert ex.frame_chunks([0, 25, 50]) == [(0, 25, 50)]
        first = ex.shared("rig", lambda: object())
        assert ex.shared("rig", lambda: object()) is first
