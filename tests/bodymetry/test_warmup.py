"""``bodymetry compile`` (:mod:`bodymetry.warmup`): the install-time kernel warm-up."""

from __future__ import annotations

import dataclasses
import sys

from click.testing import CliRunner

import bodymetry.warmup as warmup
from bodymetry.cli import main
from bodymetry.warmup import compile_kernels


def test_compile_kernels_runs_the_pipeline_and_leaves_nothing_behind(tmp_path, monkeypatch):
    # Two kept frames instead of three: the same stages and kernels, one fit less.
    monkeypatch.setattr(warmup, "TINY_SESSION", dataclasses.replace(warmup.TINY_SESSION, frames=3))
    seconds = compile_kernels(tmp_path)
    assert seconds > 0
    # The tiny session, its run and its models lived in a temporary folder inside.
    assert list(tmp_path.iterdir()) == []


def test_compile_command_reports_its_time(monkeypatch):
    monkeypatch.setattr("bodymetry.cli.compile.compile_kernels", lambda: 12.3)
    result = CliRunner().invoke(main, ["compile"])
    assert result.exit_code == 0, result.output
    assert "kernels compiled and cached (12 s)" in result.output


def test_compile_kernels_without_numba_compiles_nothing(monkeypatch, tmp_path, caplog):
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba raises ImportError
    assert compile_kernels(tmp_path) == 0.0
    assert "no kernels to compile" in caplog.text
    assert list(tmp_path.iterdir()) == []
