"""The package layering (docs/design.md): imports point down only, no cycles, one namespace."""

from __future__ import annotations

from benchmarks import imports


def test_imports_point_down_only():
    bad = imports.violations(imports.edges())
    assert not bad, "imports against the layer order:\n" + "\n".join(
        f"  {e.source} -> {e.target} at {e.file}:{e.line}" for e in bad
    )


def test_no_cycles_between_packages():
    assert imports.cycles(imports.edges()) == []


def test_the_rules_catch_an_upward_import():
    """The checker itself: an estimation -> review edge is a violation, a cycle is found."""
    up = imports.Edge("estimation", "review", "x.py", 1, False)
    down = imports.Edge("review", "estimation", "y.py", 1, False)
    assert imports.violations([up, down]) == [up]
    assert imports.cycles([up, down]) == [["estimation", "review", "estimation"]]
    assert imports.violations([imports.Edge("studio", "review", "z.py", 1, False)])


def test_module_names_map_to_layers():
    assert imports.package_of_module("bodymetry.errors") == "foundation"
    assert imports.package_of_module("bodymetry.capture.session") == "capture"
    assert imports.package_of_module("bodymetry.cli.process") == "app"
    assert imports.package_of_module("numpy") is None


def test_pyproject_lists_every_package():
    """A package folder missing from pyproject.toml would be left out of the wheel."""
    assert imports.declared_packages() == imports.package_folders()
