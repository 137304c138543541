"""The cohort of a study (cohort.csv, cohort.parquet, cohort.html) and ``bodymetry report
STUDY``, on a study folder assembled from the processed tiny run (no pipeline run here)."""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import json
import re
import shutil

import pytest
from click.testing import CliRunner

from bodymetry.cli import main
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS
from bodymetry.estimation.records import CORE_MEASUREMENTS, STAGES, summarize
from bodymetry.estimation.run_files import RigEntry, RunResults, StudyResults, StudySession
from bodymetry.fileio import write_json_atomic
from bodymetry.review import cohort
from bodymetry.review.cohort import cohort_columns, cohort_rows, measurement_keys, write_cohort

NAMES = ("alice", "bob")
FAILED_REASON = "calibration: no ChArUco board found in cam_01"
IMG_SRC = re.compile(r'<img[^>]*\bsrc="([^"]*)"')
HAS_PYARROW = importlib.util.find_spec("pyarrow") is not None


def _write_study(folder, sessions, **extra):
    write_json_atomic(folder / "study.json", StudyResults(tuple(sessions), **extra).to_json())


def _pass_quality_gate(path, n_ok):
    """Mark the first ``n_ok`` fitted frames of a run ``ok``, the other fitted ones
    ``poor fit``, and summarize them again: each copy gets its own used frames
    (whatever the tiny run's own quality gate decided)."""
    results = RunResults.read(path)
    fitted = [r.frame for r in results.fitted_frames][:n_ok]
    assert len(fitted) == n_ok, "the tiny run has fewer fitted frames than the test needs"
    frames = tuple(
        dataclasses.replace(r, status="ok" if r.frame in fitted else "poor fit: test")
        if r.fitted
        else r
        for r in results.frames
    )
    results = dataclasses.replace(
        results.with_person(frames=frames, summary=summarize(frames, results.session_shape)),
        warnings=("a warning",),
    )
    write_json_atomic(path, results.to_json())


@pytest.fixture
def study(review_run, tmp_path, monkeypatch):
    """Two copies of the tiny run (``alice``, ``bob``) and one failed session."""
    folder = tmp_path / "study"
    folder.mkdir()
    for name, n_ok in zip(NAMES, (3, 2), strict=True):
        # The recordings are not read by the cohort: leave them out of the copies.
        shutil.copytree(
            review_run.folder, folder / name, ignore=shutil.ignore_patterns("recording.*")
        )
        _pass_quality_gate(folder / name / "results.json", n_ok)
    sessions = [StudySession(n, f"/data/{n}", "done", rig="abc123") for n in NAMES]
    sessions.append(StudySession("carol", "/data/carol", "failed", FAILED_REASON, "abc123"))
    _write_study(
        folder,
        sessions,
        rigs={"abc123": RigEntry((*NAMES, "carol"), True, 12.5)},
        timing_seconds={"total": 99.0},
    )
    # Parquet is tested on its own; here the CSV and HTML only.
    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: False)
    return folder


def _read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _digits(key):
    return 1 if MEASUREMENTS.get(key) == "mm" else 2


def test_csv_has_a_row_per_session_with_the_runs_summaries(study, review_run):
    files = write_cohort(study)
    assert files.csv == study / "cohort.csv" and files.parquet is None
    rows = _read_csv(files.csv)
    assert [r["session"] for r in rows] == [*NAMES, "carol"]
    n_kept = len(review_run.results.frames)
    for row, n_used in zip(rows[:2], (3, 2), strict=True):
        summary = json.loads((study / row["session"] / "results.json").read_text())["persons"][0][
            "summary"
        ]
        assert row["status"] == "done" and row["reason"] == ""
        assert row["warnings"] == "a warning"
        assert row["subject"] == review_run.results.session.name
        assert int(row["frames_kept"]) == n_kept and int(row["frames_used"]) == n_used
        assert float(row["fraction_used"]) == pytest.approx(n_used / n_kept, abs=1e-3)
        assert row["report"] == f"{row['session']}/report.html"
        for stage in STAGES:
            for key, stat in summary[stage].items():
                for what in ("mean", "std"):
                    cell = row[f"{stage}_{key}_{what}"]
                    if stat[what] is None:
                        assert cell == ""
                    else:
                        assert float(cell) == round(stat[what], _digits(key))
        assert summary["generative"]["height_mm"]["n"] == n_used
        # The session value's 95 % interval, where the run states one.
        intervals = RunResults.read(study / row["session"] / "results.json").stated_intervals
        for key in CORE_MEASUREMENTS:
            for end in ("low", "high"):
                cell = row[f"session_{key}_{end}"]
                if key in intervals:
                    assert float(cell) == round(getattr(intervals[key], end), _digits(key))
                else:
                    assert cell == ""
    # Each copy its own numbers: the CSV is not one run repeated (any one column
    # may agree by chance to its rounding: the tiny run's frames are close).
    columns = [f"generative_{k}_{w}" for k in CORE_MEASUREMENTS for w in ("mean", "std")]
    assert all(rows[0][c] and rows[1][c] for c in columns)
    assert [rows[0][c] for c in columns] != [rows[1][c] for c in columns]
    failed = rows[2]
    assert failed["status"] == "failed" and failed["reason"] == FAILED_REASON
    assert failed["subject"] == "carol" and failed["report"] == ""
    assert all(failed[f"generative_{k}_mean"] == "" for k in CORE_MEASUREMENTS)
    assert failed["frames_kept"] == "" and failed["iou_mean"] == ""
    # The columns: the documented order, core measurements first.
    header = list(rows[0])
    assert header == cohort_columns(measurement_keys(cohort_rows(study, _read(study))))
    assert header[:3] == ["session", "person", "subject"]
    assert [r["person"] for r in rows] == ["0", "0", ""]  # a failed session: no person
    assert header[9:15] == [
        f"discriminative_{k}_{w}" for k in CORE_MEASUREMENTS for w in ("mean", "std")
    ]
    assert not list(study.glob(".*.tmp"))


def _read(study):
    return StudyResults.read(study / "study.json")


def test_rows_carry_iou_warnings_and_the_link(study, review_run):
    (study / "bob" / "report.html").unlink()
    rows = cohort_rows(study, _read(study))
    alice, bob, carol = rows
    for row in (alice, bob):
        ok = RunResults.read(study / row.name / "results.json").ok_frames
        assert row.iou_mean == pytest.approx(sum(r.mean_iou for r in ok) / len(ok))
        assert row.fraction_used == len(ok) / len(review_run.results.frames)
    assert alice.warnings == "a warning"
    # Bob's run measured 2 frames: thin evidence, and the row says so.
    assert "thin_evidence" in bob.caveats.split("; ")
    for row in (alice, bob):
        caveats = RunResults.read(study / row.name / "results.json").caveats
        assert row.caveats == "; ".join(c.code for c in caveats)
    assert carol.caveats == ""
    assert list(alice.stats) == list(STAGES)
    # Every measurement of the runs, the core ones first.
    keys = measurement_keys(rows)
    assert keys[:3] == list(CORE_MEASUREMENTS) and set(keys) == set(alice.stats["generative"])
    assert alice.link == "alice/report.html" and bob.link is None
    assert alice.rig == "abc123" and alice.session_path == "/data/alice"
    assert carol.stats == {} and carol.frames_used is None and carol.link is None


def test_html_is_self_contained_and_links_each_report(study):
    files = write_cohort(study)
    html = files.html.read_text()
    for section in ("summary", "sessions", "distribution", "quality", "study"):
        assert f'id="{section}"' in html
    assert not re.search(r'(src|href)="(https?:|file:|//)', html)
    assert "http://" not in html and "https://" not in html
    sources = IMG_SRC.findall(html)
    assert len(sources) == 2  # the distribution and the quality plot
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    for name in NAMES:
        assert f'href="{name}/report.html"' in html
    assert FAILED_REASON in html
    assert "2 <small>of 3</small>" in html  # sessions done


def test_a_done_session_without_readable_results_is_a_failed_row(study):
    (study / "alice" / "results.json").write_text("{not json")
    (study / "bob" / "results.json").unlink()
    rows = cohort_rows(study, _read(study))
    assert [r.status for r in rows] == ["failed", "failed", "failed"]
    assert "results.json" in rows[0].reason and "results.json" in rows[1].reason
    files = write_cohort(study)
    assert len(_read_csv(files.csv)) == 3


def test_no_session_done_is_a_clear_page(tmp_path, monkeypatch):
    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: False)
    _write_study(
        tmp_path,
        [
            StudySession("a", "/data/a", "failed", "line one\nline two"),
            StudySession("b", "/data/b", "pending"),
        ],
    )
    files = write_cohort(tmp_path)  # filterwarnings = error: no numpy warning either
    rows = _read_csv(files.csv)
    assert [r["status"] for r in rows] == ["failed", "pending"]
    assert rows[0]["reason"] == "line one line two"
    html = files.html.read_text()
    assert "No session was measured" in html
    assert len(IMG_SRC.findall(html)) == 1  # the quality plot only


def test_an_empty_study(tmp_path, monkeypatch):
    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: False)
    _write_study(tmp_path, [])
    files = write_cohort(tmp_path)
    assert len(_read_csv(files.csv)) == 0
    assert "The study has no session" in files.html.read_text()


def test_parquet_is_left_out_without_pyarrow(study, monkeypatch):
    (study / "cohort.parquet").write_bytes(b"stale")  # not ours to delete either way
    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: False)
    files = write_cohort(study)
    assert files.parquet is None
    assert (study / "cohort.parquet").read_bytes() == b"stale"


@pytest.mark.skipif(not HAS_PYARROW, reason="pyarrow (optional) is not installed")
def test_parquet_has_the_csv_table_with_pyarrow(study, monkeypatch):
    import pyarrow.parquet as pq

    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: True)
    files = write_cohort(study)
    assert files.parquet == study / "cohort.parquet"
    table = pq.read_table(files.parquet).to_pylist()
    rows = _read_csv(files.csv)
    assert [t["session"] for t in table] == [r["session"] for r in rows]
    assert list(table[0]) == list(rows[0])
    key = "generative_height_mm_mean"
    for t, r in zip(table, rows, strict=True):
        assert (t[key] is None and r[key] == "") or t[key] == float(r[key])
    assert table[2]["frames_kept"] is None and table[0]["frames_kept"] == int(
        rows[0]["frames_kept"]
    )


def test_the_availability_check_matches_the_import():
    assert cohort._pyarrow_available() is HAS_PYARROW


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_report_command_rebuilds_the_cohort(study):
    result = _cli("report", study)
    assert result.exit_code == 0, result.output
    # The console wraps long lines wherever the (temporary) path puts them, inside a
    # file name too: compared without whitespace.
    said = "".join(result.output.split())
    assert "cohort.csv" in said and "cohort.html" in said
    assert "pyarrowisnotinstalled" in said
    assert len(_read_csv(study / "cohort.csv")) == 3
    # The runs themselves are untouched: the cohort reads, it does not rebuild them.
    assert not (study / "alice" / "recording.rrd").exists()


def test_report_command_with_run_options_on_a_study_is_an_input_error(study):
    result = _cli("report", study, "--pdf")
    assert result.exit_code == 2
    assert "--pdf and --recordings apply to one run" in result.output
    assert not (study / "cohort.csv").exists()


def test_a_study_json_of_another_format_is_one_clear_error(study):
    data = json.loads((study / "study.json").read_text())
    data["format"] = 99
    (study / "study.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"not a study\.json"):
        write_cohort(study)
    result = _cli("report", study)
    assert result.exit_code == 2
    assert "not a study.json of `bodymetry batch`" in result.output
    assert "Traceback" not in result.output
    assert not (study / "cohort.csv").exists()
