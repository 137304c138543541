"""run.json: create, resume, refuse or restart a run folder; workers die with their parent."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tiny_run import TINY_TRAIN, tiny_session, tiny_train_overrides

from bodymetry.capture.session import load_session
from bodymetry.cli.common import EXIT_CAVEATS
from bodymetry.errors import InputError
from bodymetry.estimation.records import FrameArrays, FrameRecord
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunLayout, RunManifest, RunResults
from bodymetry.process import process_session
from bodymetry.run_folder import config_fingerprint, prepare_run_folder, session_fingerprint


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return tiny_session(tmp_path_factory.mktemp("runfolder") / "session", seed=4)


@pytest.fixture(scope="module")
def finished(session, tmp_path_factory):
    """A finished run of ``session`` and its model cache (the rig of seed 4), read only."""
    base = tmp_path_factory.mktemp("finished")
    results = process_session(session.folder, base / "run", _config(base))
    return base, results


def test_a_new_folder_gets_run_json_first(session, tmp_path):
    out = tmp_path / "run"
    manifest = prepare_run_folder(out, session, ProcessConfig())
    assert RunManifest.read(out / "run.json") == manifest
    assert manifest.session_path == str(session.folder.resolve())
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]


def test_the_same_session_and_settings_resume(session, tmp_path):
    out = tmp_path / "run"
    first = prepare_run_folder(out, session, ProcessConfig())
    (out / "frames").mkdir()
    (out / "frames" / "000000.json").write_text("{}")
    # Workers, cache and review do not change results: still the same run.
    again = prepare_run_folder(out, session, ProcessConfig(workers=1, review=False))
    assert again == first and (out / "frames" / "000000.json").is_file()


def test_other_settings_are_refused_unless_restarted(session, tmp_path):
    out = tmp_path / "run"
    prepare_run_folder(out, session, ProcessConfig())
    (out / "frames").mkdir()
    (out / "frames" / "000000.json").write_text("{}")
    other = ProcessConfig().with_overrides(["annealing.n_particles=50"])
    with pytest.raises(InputError, match=r"a run of other settings; pass --restart"):
        prepare_run_folder(out, session, other)
    manifest = prepare_run_folder(out, session, other, restart=True)
    assert manifest.config_fingerprint == config_fingerprint(other)
    assert not (out / "frames").exists()


def test_a_setting_added_later_keeps_earlier_runs_hash_at_its_default():
    """The per-frame refinement's thin_px came after runs were made: at its default (0)
    the hash is that of the settings without it, so a finished run resumes after an
    upgrade; set, it is another run."""
    import hashlib
    from dataclasses import replace

    config = ProcessConfig()
    data = config.to_json()
    assert data["fit"]["refinement"].pop("thin_px") == 0.0
    hashed = ("quality", "fit", "training", "frame_step", "working_person_px")
    earlier = {k: data[k] for k in hashed}
    digest = hashlib.sha256(json.dumps(earlier, sort_keys=True).encode()).hexdigest()[:16]
    assert config_fingerprint(config) == digest
    refinement = replace(config.fit.refinement, thin_px=1.2)
    thin = replace(config, fit=replace(config.fit, refinement=refinement))
    assert config_fingerprint(thin) != digest


def test_another_session_is_refused(session, tmp_path):
    out = tmp_path / "run"
    prepare_run_folder(out, session, ProcessConfig())
    copy = tmp_path / "copy"
    shutil.copytree(session.folder, copy)
    text = (copy / "session.yaml").read_text()
    (copy / "session.yaml").write_text(text + "\n# edited\n")
    edited = load_session(copy)
    assert session_fingerprint(edited) != session_fingerprint(session)
    with pytest.raises(InputError, match=r"a run of session .*; pass --restart"):
        prepare_run_folder(out, edited, ProcessConfig())


def test_a_folder_that_is_not_a_run_is_refused_and_kept(session, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    for restart in (False, True):
        with pytest.raises(InputError, match=r"not empty and not a bodymetry run folder \(thesis"):
            prepare_run_folder(out, session, ProcessConfig(), restart=restart)
    assert (out / "thesis.tex").read_text() == "precious"
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(InputError, match="is not a folder"):
        prepare_run_folder(afile, session, ProcessConfig())


def test_a_run_without_run_json_needs_restart(session, tmp_path):
    out = tmp_path / "old"
    (out / "frames").mkdir(parents=True)
    (out / "results.json").write_text("{}")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match=r"without run\.json"):
        prepare_run_folder(out, session, ProcessConfig())
    prepare_run_folder(out, session, ProcessConfig(), restart=True)
    assert not (out / "results.json").exists() and (out / "notes.txt").is_file()


def test_an_unwritable_folder_is_one_error(session, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    with pytest.raises(InputError, match=r"a-file.*cannot write the run folder"):
        prepare_run_folder(blocker / "run", session, ProcessConfig())  # a file in the path


def test_a_read_only_folder_is_one_error(session, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):  # root ignores permissions
            pytest.skip("running with permissions that ignore the mode bits")
        with pytest.raises(InputError, match="cannot write the run folder"):
            prepare_run_folder(locked / "run", session, ProcessConfig())
    finally:
        locked.chmod(0o700)


#: These tests check the run folder, not the session stage's accuracy: one
#: descent of one step (the default 4 x 3 cost ~5 s per run on 2 cores).
SESSION_STAGE = ["session_shape.descents=1", "session_shape.iterations=1"]


def _config(base: Path) -> ProcessConfig:
    return ProcessConfig.preset(
        "fast", training=TINY_TRAIN, workers=1, cache_dir=base / "cache", review=False
    ).with_overrides(["min_iou=0.5", *SESSION_STAGE])


def test_a_truncated_record_is_fitted_again(session, finished, tmp_path):
    base, first = finished
    out = tmp_path / "run"
    shutil.copytree(base / "run", out)
    layout = RunLayout(out)
    frame = first.frames[1].frame
    text = layout.frame_record(frame).read_text()
    layout.frame_record(frame).write_text(text[: len(text) // 2])  # killed mid-write
    mesh_frame = first.frames[2].frame
    layout.frame_mesh(mesh_frame).unlink()  # a frame without its mesh is not whole
    again = process_session(session.folder, out, _config(base))
    assert [r.frame for r in again.frames] == [r.frame for r in first.frames]
    refit = again.frames[1].to_json()
    refit["seconds"] = first.frames[1].to_json()["seconds"]  # timing differs, nothing else
    assert refit == first.frames[1].to_json()  # same seed, same fit
    assert FrameRecord.read(layout.frame_record(frame)).frame == frame
    assert layout.frame_mesh(mesh_frame).is_file()
    assert again.camera_frames == {"cam_00": 3, "cam_01": 3} and again.warnings == ()


def _processes_with_parent(pid: int) -> list[int]:
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            children.append(int(stat.parent.name))
    return children


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")  # a zombie has exited; it only waits to be reaped


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_sigkill_of_the_parent_leaves_no_worker_and_the_rerun_completes(finished, tmp_path):
    # 5 kept frames on the cameras of the module's session, whose trained models
    # are copied in: the run fits at once instead of training first.
    session = tiny_session(tmp_path / "session", seed=5, frames=9, rig_seed=4)
    shutil.copytree(finished[0] / "cache", tmp_path / "cache")
    out = tmp_path / "run"
    overrides = [a for o in (*tiny_train_overrides(), *SESSION_STAGE) for a in ("--set", o)]
    command = [
        sys.executable, "-m", "bodymetry", "process", str(session.folder), "--out", str(out),
        "--quality", "fast", "--workers", "2", "--cache", str(tmp_path / "cache"),
        "--no-review", "--min-iou", "0.5", *overrides,
    ]  # fmt: skip
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    log_path = tmp_path / "stderr.log"
    with log_path.open("wb") as log_file:
        parent = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=log_file)
    frames = out / "frames"
    deadline = time.monotonic() + 180
    while not list(frames.glob("*.json")):  # fitting has started
        if parent.poll() is not None:
            pytest.fail(f"process exited early: {log_path.read_text()[-2000:]}")
        if time.monotonic() > deadline:
            parent.kill()
            pytest.fail("no frame was fitted within 180 s")
        time.sleep(0.05)
    workers = _processes_with_parent(parent.pid)
    assert workers, "the pool's workers should be running"
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    # The workers notice their parent's death and exit; give them up to 5 s.
    deadline = time.monotonic() + 5
    while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    survivors = [pid for pid in workers if _alive(pid)]
    assert survivors == [], f"workers survived their parent: {survivors}"
    done_before = len(list(frames.glob("*.json")))
    assert done_before < 5
    rerun = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    # The tiny models' rough fits may state caveats (status 5), e.g. soles deep in
    # the floor; the run completes either way.
    assert rerun.returncode in (0, EXIT_CAVEATS), rerun.stderr[-2000:]
    results = RunResults.read(out / "results.json")
    assert len(results.frames) == 5
    for record in results.frames:  # every frame whole: record, arrays and (if fitted) mesh
        arrays = FrameArrays.load(out / "frames" / f"{record.frame:06d}.npz")
        assert set(arrays.observed) == {"cam_00", "cam_01"}
        assert not record.fitted or (out / "meshes" / f"{record.frame:06d}.ply").is_file()
    json.loads((out / "results.json").read_text(), parse_constant=lambda c: 1 / 0)
