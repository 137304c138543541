"""bodymetry batch on a local Dask cluster: rigs trained once, results as process writes them."""

from __future__ import annotations

import csv
import re
import shutil
import socket
import time

import pytest
from click.testing import CliRunner
from distributed import Client
from tiny_run import TINY_TRAIN, tiny_session

import bodymetry.batch as batch_module
from bodymetry.batch import dask_client, find_sessions, run_batch, run_names
from bodymetry.cli import main
from bodymetry.errors import InputError
from bodymetry.estimation.registration import read_registration
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults, StudyResults
from bodymetry.process import process_session

#: The batch tests check the plumbing, not the session stage's accuracy: one
#: descent of one step (the default 4 x 3 cost ~5 s per session on 2 cores).
SESSION_STAGE = ["session_shape.descents=1", "session_shape.iterations=1"]


def _config(base) -> ProcessConfig:
    return ProcessConfig.preset(
        "fast", training=TINY_TRAIN, cache_dir=base / "cache", review=False
    ).with_overrides(["min_iou=0.5", *SESSION_STAGE])


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    base = tmp_path_factory.mktemp("batch")
    sessions = base / "sessions"
    # Two kept frames each (0 and 2): enough for the session stage, one fit less.
    tiny_session(sessions / "anna", seed=11, frames=3, rig_seed=1)
    tiny_session(sessions / "ben", seed=12, frames=3, rig_seed=1)  # same rig as anna
    tiny_session(sessions / "cleo", seed=13, frames=3, rig_seed=2)  # another rig
    broken = sessions / "dora"
    shutil.copytree(sessions / "anna", broken)
    (broken / "videos" / "cam_01.mp4").unlink()
    paths = find_sessions([sessions])
    # The cluster stays up for the module: the --scheduler test submits to it
    # (starting a cluster of its own cost ~10 s on 2 cores).
    with dask_client(workers=2) as client:
        first = run_batch(paths, base / "study", _config(base), client)
        again = run_batch(paths, base / "study", _config(base), client)
        yield base, paths, first, again, client.scheduler.address


def test_each_rig_is_trained_exactly_once(study):
    _, _, first, *_ = study
    rigs = first.study.rigs
    assert len(rigs) == 2
    assert sorted(list(r.sessions) for r in rigs.values()) == [["anna", "ben"], ["cleo"]]
    assert all(r.trained is True for r in rigs.values())


def test_every_frame_is_fitted_and_a_bad_session_does_not_stop_the_others(study):
    base, _, first, *_ = study
    status = {s.name: s for s in first.study.sessions}
    assert [status[n].status for n in ("anna", "ben", "cleo")] == ["done"] * 3
    assert status["dora"].status == "failed" and "cam_01.mp4" in status["dora"].reason
    assert not first.ok
    for name in ("anna", "ben", "cleo"):
        results = RunResults.read(base / "study" / name / "results.json")
        assert [r.frame for r in results.frames] == [0, 2]
        assert all(r.fitted for r in results.frames)
    # study.json describes the last call (the rerun below).
    assert StudyResults.read(base / "study" / "study.json").sessions == first.study.sessions


def test_a_session_of_a_batch_is_what_process_writes(study):
    base, paths, *_ = study
    alone = process_session(paths[0], base / "alone", _config(base))
    batch = RunResults.read(base / "study" / "anna" / "results.json")
    strip = [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in alone.frames]
    assert strip == [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in batch.frames]
    assert batch.summary == alone.summary

    assert batch.config == alone.config and batch.models == alone.models
    for name in ("calibration.yaml", "run.json"):
        assert (base / "study" / "anna" / name).is_file()


def test_the_cohort_table_matches_each_session(study):
    base = study[0]
    with (base / "study" / "cohort.csv").open() as f:
        rows = {row["session"]: row for row in csv.DictReader(f)}
    assert set(rows) == {"anna", "ben", "cleo", "dora"}
    for name in ("anna", "ben", "cleo"):
        results = RunResults.read(base / "study" / name / "results.json")
        mean = results.summary["generative"]["height_mm"].mean
        column = next(k for k in rows[name] if "generative" in k and "height" in k and "mean" in k)
        assert float(rows[name][column]) == pytest.approx(mean, abs=0.1)
    assert (base / "study" / "cohort.html").is_file()


def test_a_rerun_skips_finished_sessions(study):
    _, _, first, again, _ = study
    assert {s.name: s.status for s in again.study.sessions} == {
        s.name: s.status for s in first.study.sessions
    }
    assert again.results == {}  # nothing was summarized again
    assert all(r.trained is not True for r in again.study.rigs.values())


def test_sessions_from_folders_lists_and_files(tmp_path, study):
    _, paths, *_ = study
    listing = tmp_path / "sessions.txt"
    listing.write_text(f"# the study\n{paths[2]}\n\n{paths[0] / 'session.yaml'}\n{paths[2]}\n")
    assert find_sessions([listing]) == [paths[2], paths[0]]
    with pytest.raises(InputError, match="no such session folder"):
        find_sessions([tmp_path / "nope"])
    with pytest.raises(InputError, match="no session folder"):
        find_sessions([tmp_path])
    assert run_names([paths[0], paths[0].parent / "x" / "anna", paths[1]]) == [
        "anna",
        "anna-2",
        "ben",
    ]


#: A log record's first line (``logging``'s format in bodymetry.log): a running cluster
#: in this process logs while the command prints.
_LOG_LINE = re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2} [A-Z]+ ")


def _printed(output: str) -> str:
    """The command's printed text, whitespace collapsed, without the log records that
    the scheduler in this process may write between its wrapped lines."""
    return " ".join(
        " ".join(line for line in output.splitlines() if not _LOG_LINE.match(line)).split()
    )


def test_the_command_on_a_running_scheduler(study, monkeypatch):
    """--scheduler: submit to a cluster that is already running (the fixture's)."""
    base, paths, *_, scheduler = study
    options = [f"--set=training.{k}={list(v) if isinstance(v, tuple) else v}"
               for k, v in TINY_TRAIN.__dict__.items()]  # fmt: skip
    options += [f"--set={item}" for item in SESSION_STAGE]
    res = CliRunner().invoke(
        main,
        [
            "batch", str(paths[0].parent), "--out", str(base / "study"),
            "--scheduler", scheduler, "--quality", "fast",
            "--cache", str(base / "cache"), "--no-review", "--set=min_iou=0.5", *options,
        ],
    )  # fmt: skip
    assert res.exit_code == 4, res.output  # dora fails, the rest is done (skipped)
    text = _printed(res.output)
    assert "4 session(s)" in text and "failed" in text and "cohort.csv" in text
    assert "Traceback" not in res.output
    # Sessions measured on thin or ambiguous evidence are counted and named.
    with open(base / "study" / "cohort.csv", newline="", encoding="utf-8") as f:
        flagged = [r for r in csv.DictReader(f) if r["caveats"]]
    line = f"{len(flagged)} session(s) measured with caveats"
    assert (line in text) == bool(flagged), text
    assert ("caveats:" in text) == bool(flagged), text
    for row in flagged:
        # Each code, not the line: the table may wrap its detail column.
        for code in row["caveats"].split("; "):
            assert code in text, (code, text)
    # Nothing listens there: refused at once, without waiting for Dask's timeout.
    start = time.perf_counter()
    with pytest.raises(InputError, match="cannot connect"), dask_client("tcp://127.0.0.1:1"):
        pass
    assert time.perf_counter() - start < 5.0
    # Past the TCP check (something answers), Dask's own error is reported the same way.
    monkeypatch.setattr(batch_module, "scheduler_unreachable", lambda address: None)
    monkeypatch.setattr(
        batch_module, "Client", lambda address, timeout: Client(address, timeout="1s")
    )
    with pytest.raises(InputError, match="cannot connect"), dask_client("tcp://127.0.0.1:1"):
        pass


def test_scheduler_unreachable_reads_the_address_forms():
    from bodymetry.batch import scheduler_unreachable

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        assert scheduler_unreachable(f"tcp://127.0.0.1:{port}") is None
        assert scheduler_unreachable(f"127.0.0.1:{port}") is None
    assert scheduler_unreachable(f"tcp://127.0.0.1:{port}")  # closed now: refused
    assert scheduler_unreachable("tcp://127.0.0.1:notaport")
    assert scheduler_unreachable("inproc://somewhere") is None  # only Dask can tell


def test_a_camera_registered_in_a_batch_is_what_process_registers(study, moved_camera, tmp_path):
    """The registration's second fit of every frame runs on Dask as in process:
    camera 1 of a 4-camera session moved 5 px down is registered alike, and the
    runs hold the same frames and summary."""
    *_, address = study
    session, alone, config = moved_camera.session, moved_camera.results, moved_camera.config
    with Client(address) as client:
        run_batch([session.folder], tmp_path / "study", config, client)
    batch = RunResults.read(tmp_path / "study" / session.folder.name / "results.json")
    registered = [
        read_registration(where / "registration.json")
        for where in (moved_camera.out, tmp_path / "study" / session.folder.name)
    ]
    assert registered[0] == registered[1]
    assert [s.camera for s in registered[0] if s.applied] == ["cam_01"]
    strip = [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in alone.frames]
    assert strip == [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in batch.frames]
    assert batch.summary == alone.summary and batch.warnings == alone.warnings
