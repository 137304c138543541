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
