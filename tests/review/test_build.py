"""The review stage keeps going when one output fails, and leaves no partial file."""

from __future__ import annotations

import json
import shutil

import pytest
import rerun.chunk as rc

import bodymetry.review.mcap_recording as mcap_recording
from bodymetry.review.build import build_review


@pytest.fixture
def run_copy(review_run, tmp_path):
    """The run's records (results.json, calibration.yaml, frames/) without review outputs."""
    folder = tmp_path / "run"
    folder.mkdir()
    for name in ("results.json", "calibration.yaml"):
        shutil.copy(review_run.folder / name, folder / name)
    shutil.copytree(review_run.folder / "frames", folder / "frames")
    return folder


def test_a_failing_writer_is_dropped_and_the_rest_is_written(run_copy, monkeypatch, caplog):
    def broken(self, view):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(mcap_recording.McapWriter, "add", broken)
    summary = build_review(run_copy)
    assert set(summary.errors) == {"mcap"} and "disk on fire" in summary.errors["mcap"]
    assert not (run_copy / "recording.mcap").exists()
    for name in ("recording.rrd", "report.html", "measurements.csv"):
        assert (run_copy / name).is_file()
    assert not list(run_copy.glob(".*.tmp"))
    assert "disk on fire" in caplog.text


def test_a_failing_writer_keeps_the_previous_file(run_copy, monkeypatch):
    (run_copy / "recording.mcap").write_bytes(b"previous")

    def broken(self, view):
        raise RuntimeError("no")

    monkeypatch.setattr(mcap_recording.McapWriter, "add", broken)
    build_review(run_copy, report=False)
    assert (run_copy / "recording.mcap").read_bytes() == b"previous"


def test_frames_left_out_by_a_quality_gate_are_still_shown(run_copy):
    path = run_copy / "results.json"
    results = json.loads(path.read_text())
    gated = results["persons"][0]["frames"][1]
    gated["status"] = "poor fit: mean IoU 0.50 < 0.85"
    path.write_text(json.dumps(results))
    summary = build_review(run_copy)
    assert not summary.errors, summary.errors
    html = (run_copy / "report.html").read_text()
    assert "poor fit: mean IoU 0.50" in html
    chunks = rc.RrdReader(run_copy / "recording.rrd").store().stream().to_chunks()
    meshes = [
        c
        for c in chunks
        if c.entity_path == "/world/body/mesh"
        and "Mesh3D:vertex_positions" in c.to_record_batch().schema.names
    ]
    frames = set()
    for c in meshes:
        frames.update(c.to_record_batch().column("frame").to_pylist())
    assert gated["frame"] in frames


@pytest.mark.parametrize(
    ("gate", "says", "not_said"),
    [
        # A child's studio session: the widened min_iou alone set the gate.
        (
            {"threshold": 0.8682, "min_iou": 0.9, "reference": 0.94, "width_scale": 1.318},
            ["at least 0.87", "loses 1.32 times the IoU of a mid-population adult"],
            ["so the gate follows them"],
        ),
        # A child in clothes on real footage: the frames set it, widened too.
        (
            {"threshold": 0.8105, "min_iou": 0.9, "reference": 0.85, "width_scale": 1.318},
            ["this session's good frames score 0.85, so the gate follows them, and a body"],
            [],
        ),
        # An adult on real footage: the frames alone.
        (
            {"threshold": 0.82, "min_iou": 0.9, "reference": 0.85, "width_scale": 1.0},
            ["so the gate follows them;"],
            ["times the IoU"],
        ),
    ],
)
def test_the_report_says_what_set_the_quality_gate(run_copy, gate, says, not_said):
    path = run_copy / "results.json"
    results = json.loads(path.read_text())
    results["persons"][0]["quality_gate"] = gate
    path.write_text(json.dumps(results))
    summary = build_review(run_copy, recordings=False)
    assert not summary.errors, summary.errors
    html = " ".join((run_copy / "report.html").read_text().split())
    for text in says:
        assert text in html
    for text in not_said:
        assert text not in html
