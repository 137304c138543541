"""``bodymetry view`` (argument handling; the viewer itself is not started) and
``bodymetry report``."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

import bodymetry.cli.runs
from bodymetry.cli import main


@pytest.fixture
def launched(monkeypatch):
    calls: list[list[str]] = []

    def fake(args):
        calls.append(list(args))
        return 0

    monkeypatch.setattr(bodymetry.cli.runs, "_launch_viewer", fake)
    return calls


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_view_opens_the_recording(review_run, launched):
    rrd = review_run.folder / "recording.rrd"
    assert _run("view", review_run.folder).exit_code == 0
    assert _run("view", review_run.folder, "--web").exit_code == 0
    assert _run("view", review_run.folder, "--web", "--port", 9091).exit_code == 0
    assert _run("view", review_run.folder, "--mcap").exit_code == 0
    assert _run("view", rrd).exit_code == 0
    assert launched == [
        [str(rrd)],
        ["--web-viewer", str(rrd)],
        ["--web-viewer", "--web-viewer-port", "9091", str(rrd)],
        [str(review_run.folder / "recording.mcap")],
        [str(rrd)],
    ]


def test_view_without_a_recording_names_the_file(tmp_path, launched):
    result = _run("view", tmp_path)
    assert result.exit_code == 2
    assert "recording.rrd: not found" in result.output
    (tmp_path / "notes.txt").write_text("x")
    result = _run("view", tmp_path / "notes.txt")
    assert result.exit_code == 2 and ".rrd or .mcap" in result.output
    assert launched == []


def test_view_port_needs_web(review_run, launched):
    result = _run("view", review_run.folder, "--port", 9000)
    assert result.exit_code == 2 and "--port" in result.output
    assert launched == []


def test_report_rebuilds_without_touching_the_recordings(review_run):
    rrd = review_run.folder / "recording.rrd"
    before = rrd.stat().st_mtime_ns
    result = _run("report", review_run.folder)
    assert result.exit_code == 0, result.output
    assert "report.html" in result.output and "measurements.csv" in result.output
    assert rrd.stat().st_mtime_ns == before


def test_report_on_a_folder_without_results(tmp_path):
    result = _run("report", tmp_path)
    assert result.exit_code == 2
    assert "results.json: not found" in result.output


def test_report_on_results_of_an_older_version(review_run, tmp_path):
    results = json.loads((review_run.folder / "results.json").read_text())
    del results["format"]  # as written before the typed schema
    (tmp_path / "results.json").write_text(json.dumps(results))
    result = _run("report", tmp_path)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert str(tmp_path / "results.json") in lines[0] and "older bodymetry" in lines[0]


def test_process_refuses_pdf_without_review(tmp_path):
    result = _run("process", tmp_path, "--no-review", "--pdf")
    assert result.exit_code == 2 and "--no-review" in result.output
