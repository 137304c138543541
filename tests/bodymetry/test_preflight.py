"""bodymetry.preflight: one up-front check that lists every problem of a session.

Each test breaks its own copy of one tiny studio session (2 cameras, 240x180,
5 frames at 60 fps, every 2nd kept) and checks what ``check_session`` reports.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from tiny_run import tiny_session
from yaml_edits import Edit, delete_at, set_at

from bodymetry.capture.background import read_clip
from bodymetry.capture.person import segmenter_available
from bodymetry.capture.video import H264Writer
from bodymetry.cli import main
from bodymetry.errors import InputError
from bodymetry.preflight import BLACK_MEAN, PreflightReport, check_session


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("preflight") / "tiny"
    tiny_session(folder, seed=3)
    return folder


@pytest.fixture
def session(rendered: Path, tmp_path: Path) -> Path:
    """A fresh copy of the tiny session, to break."""
    return Path(shutil.copytree(rendered, tmp_path / "session"))


def _edit_yaml(path: Path, *edits: Edit) -> None:
    data: dict[str, Any] = yaml.safe_load(path.read_text())
    for edit in edits:
        edit(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _frames(path: Path) -> list[np.ndarray]:
    """Every frame of a video (read_clip keeps all when asked for more than there are)."""
    return list(read_clip(path, path.stem, max_frames=1_000_000))


def _rewrite(path: Path, frames: list[np.ndarray], fps: float = 60.0) -> None:
    """Replace a video with ``frames`` (H.264, as the studio writes)."""
    height, width = frames[0].shape[:2]
    with H264Writer(path, fps, (width, height), crf=0) as writer:
        for frame in frames:
            writer.write(frame)


def _only(report: PreflightReport, text: str):
    hits = [p for p in report.problems if text in p.message]
    assert len(hits) == 1, (text, report.problems)
    return hits[0]


# -- a clean session ----------------------------------------------------------------
def test_clean_session_is_ok(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "runs" / "deep" / "run"
    report = check_session(session, out)
    assert report.ok, report.problems
    assert report.problems == () and report.warnings == ()
    report.raise_if_failed()  # nothing to raise
    # The write test left nothing behind: not the folders it created, not its file.
    assert not (tmp_path / "runs").exists()


def test_existing_empty_out_folder_stays(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "empty"
    out.mkdir()
    assert check_session(session, out).ok
    assert out.is_dir() and list(out.iterdir()) == []


# -- several problems at once --------------------------------------------------------------
def test_three_problems_are_all_listed(session: Path) -> None:
    (session / "videos" / "cam_00.mp4").unlink()
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.size", [320, 180]))
    _edit_yaml(session / "session.yaml", set_at("fps", 30.0))

    report = check_session(session, None)
    assert not report.ok
    assert len(report.problems) == 3, "\n".join(map(str, report.problems))

    missing = _only(report, "not found")
    assert Path(missing.path) == session / "videos" / "cam_00.mp4"
    assert "cameras[0].video" in missing.message and "'cam_00'" in missing.message

    fps = _only(report, "fps")
    assert Path(fps.path) == session / "videos" / "cam_01.mp4"
    assert "'cam_01'" in fps.message and "60 fps" in fps.message and "fps: 30" in fps.message

    size = _only(report, "says 320x180")
    assert Path(size.path) == session / "calibration.yaml"
    assert "'cam_01'" in size.message and "is 240x180" in size.message
    assert "cameras[1].size" in size.message

    with pytest.raises(InputError) as info:
        report.raise_if_failed()
    lines = str(info.value).splitlines()
    assert lines[0] == f"3 problem(s) in {session}:"
    assert len(lines) == 4
    assert any("cam_00.mp4" in line for line in lines[1:])


def test_process_lists_every_problem_before_creating_the_run(session: Path, tmp_path: Path):
    (session / "videos" / "cam_00.mp4").unlink()
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.size", [320, 180]))
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["process", str(session), "--out", str(out)])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert lines[0].startswith("error: 2 problem(s) in ") and len(lines) == 3, res.output
    assert "cam_00.mp4" in lines[1] + lines[2] and "says 320x180" in lines[1] + lines[2]
    assert not out.exists()  # nothing left behind
    assert "Traceback" not in res.output


def test_sizes_may_differ_across_cameras(session: Path) -> None:
    """A rig of mixed cameras is fine: only each camera's calibration against its video."""
    frames = [cv2.resize(f, (320, 240)) for f in _frames(session / "videos" / "cam_01.mp4")]
    _rewrite(session / "videos" / "cam_01.mp4", frames)
    bg = [cv2.resize(f, (320, 240)) for f in _frames(session / "background" / "cam_01.mp4")]
    _rewrite(session / "background" / "cam_01.mp4", bg)
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.size", [320, 240]))
    report = check_session(session)
    assert report.ok, report.problems


def test_background_of_another_size(session: Path) -> None:
    bg = [cv2.resize(f, (320, 240)) for f in _frames(session / "background" / "cam_00.mp4")]
    _rewrite(session / "background" / "cam_00.mp4", bg)
    report = check_session(session)
    problem = _only(report, "background clip")
    assert Path(problem.path) == session / "background" / "cam_00.mp4"
    assert "320x240" in problem.message and "240x180" in problem.message


def test_missing_and_corrupt_files_each_listed(session: Path) -> None:
    (session / "background" / "cam_01.mp4").unlink()
    (session / "videos" / "cam_01.mp4").write_bytes(b"\x00" * 4096)
    report = check_session(session)
    assert len(report.problems) == 2, report.problems
    assert _only(report, "cannot open the video").path.endswith("videos/cam_01.mp4")
    assert _only(report, "background clip of camera 'cam_01' not found")


# -- warnings ----------------------------------------------------------------
def test_black_camera_is_a_warning(session: Path) -> None:
    n = len(_frames(session / "videos" / "cam_01.mp4"))
    _rewrite(session / "videos" / "cam_01.mp4", [np.zeros((180, 240, 3), np.uint8)] * n)
    report = check_session(session)
    assert report.ok, report.problems
    assert len(report.warnings) == 1
    warning = report.warnings[0]
    assert Path(warning.path) == session / "videos" / "cam_01.mp4"
    assert "'cam_01'" in warning.message and "black" in warning.message
    assert f"< {BLACK_MEAN:g}" in warning.message


def test_frame_counts_that_differ_are_a_warning(session: Path) -> None:
    frames = _frames(session / "videos" / "cam_00.mp4")
    _rewrite(session / "videos" / "cam_00.mp4", frames[:3])
    report = check_session(session)
    assert report.ok, report.problems
    assert len(report.warnings) == 1
    assert "frame counts differ" in report.warnings[0].message
    assert "'cam_00' has 3" in report.warnings[0].message


# -- calibration ----------------------------------------------------------------
def test_no_calibration_and_no_clips(session: Path) -> None:
    (session / "calibration.yaml").unlink()
    (session / "background" / "cam_00.mp4").unlink()
    _edit_yaml(
        session / "session.yaml",
        delete_at("calibration"),
        delete_at("calibration_clips"),
        delete_at("board"),
    )
    report = check_session(session)
    assert len(report.problems) == 2, report.problems
    problem = _only(report, "no calibration")
    assert Path(problem.path) == session / "session.yaml"
    assert "calibration.yaml" in problem.message and "calibration_clips" in problem.message
    _only(report, "background clip of camera 'cam_00' not found")

    # For work that needs no cameras it is only a warning.
    lenient = check_session(session, need_calibration=False)
    assert len(lenient.problems) == 1 and len(lenient.warnings) == 1
    assert "no calibration" in lenient.warnings[0].message


def test_calibration_from_clips_is_enough(session: Path) -> None:
    (session / "calibration.yaml").unlink()
    _edit_yaml(session / "session.yaml", delete_at("calibration"))
    assert check_session(session).ok
    # ... as long as the clips decode.
    (session / "calibration" / "cam_01.mp4").write_bytes(b"\x00" * 4096)
    report = check_session(session)
    problem = _only(report, "calibration clip")
    assert Path(problem.path) == session / "calibration" / "cam_01.mp4"
    assert "'cam_01'" in problem.message


def test_negative_focal_length_reads_plainly(session: Path) -> None:
    _edit_yaml(session / "calibration.yaml", set_at("cameras.0.K.0.0", -706.03))
    report = check_session(session)
    problem = _only(report, "focal")
    assert Path(problem.path) == session / "calibration.yaml"
    assert "cameras[0].K" in problem.message and "fx=-706.03" in problem.message
    assert "np.float64" not in str(problem)


def test_principal_point_outside_the_image(session: Path) -> None:
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.K.1.2", 700.0))
    report = check_session(session)
    problem = _only(report, "principal point")
    assert "cameras[1].K" in problem.message and "cy=700" in problem.message
    assert "240x180" in problem.message


def test_calibration_without_a_camera(session: Path) -> None:
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.name", "cam_09"))
    report = check_session(session)
    assert len(report.problems) == 1, report.problems
    assert "has no camera named 'cam_01'" in report.problems[0].message


# -- session.yaml itself ----------------------------------------------------------------
def test_malformed_session_yaml_is_one_problem(session: Path) -> None:
    _edit_yaml(session / "session.yaml", set_at("fps", 0))
    report = check_session(session)
    assert len(report.problems) == 1
    assert "fps: expected a number > 0, got 0" in report.problems[0].message


def test_missing_session_folder(tmp_path: Path) -> None:
    report = check_session(tmp_path / "nowhere")
    assert len(report.problems) == 1 and "not found" in report.problems[0].message


# -- the output folder ----------------------------------------------------------------
def test_out_folder_that_is_not_a_run(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"jpeg")
    report = check_session(session, out)
    problem = _only(report, "not a bodymetry run folder")
    assert Path(problem.path) == out and "choose another --out" in problem.message
    assert sorted(p.name for p in out.iterdir()) == ["holiday.jpg"]


def test_out_folder_that_is_a_run_resumes(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / "frames").mkdir(parents=True)
    (out / "calibration.yaml").write_text("x")
    assert check_session(session, out).ok
    assert sorted(p.name for p in out.iterdir()) == ["calibration.yaml", "frames"]


def test_out_folder_that_cannot_be_created(session: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("in the way")
    report = check_session(session, blocker / "run")
    problem = _only(report, "cannot create the run folder")
    assert Path(problem.path) == blocker / "run"
    report = check_session(session, blocker)
    assert _only(report, "found a file")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_out_folder_that_cannot_be_written(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "locked"
    out.mkdir()
    out.chmod(0o500)
    try:
        report = check_session(session, out / "run")
        assert _only(report, "cannot create the run folder")
    finally:
        out.chmod(0o700)
    assert list(out.iterdir()) == []


def test_out_folder_without_write_permission(session: Path, tmp_path: Path, monkeypatch) -> None:
    """What a read-only folder gives (simulated: root may write anywhere)."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("bodymetry.preflight.tempfile.NamedTemporaryFile", refuse)
    out = tmp_path / "run"
    out.mkdir()
    problem = _only(check_session(session, out), "cannot write in the run folder")
    assert "Permission denied" in problem.message and "choose another --out" in problem.message
    # A folder the check created for the test is removed again.
    problem = _only(check_session(session, tmp_path / "new" / "run"), "cannot write")
    assert not (tmp_path / "new").exists()


# -- the command ----------------------------------------------------------------
def test_check_command(session: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(main, ["check", str(session), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "ok" in result.stdout

    (session / "videos" / "cam_00.mp4").unlink()
    _edit_yaml(session / "calibration.yaml", set_at("cameras.1.size", [320, 180]))
    result = runner.invoke(main, ["check", str(session)])
    assert result.exit_code == 2
    assert "2 problem(s)" in result.stderr
    listed = [line for line in result.stderr.splitlines() if line.startswith("  - ")]
    assert len(listed) == 2, result.stderr  # one line per problem
    assert "cam_00.mp4" in result.stderr and "320x180" in result.stderr
    assert "Traceback" not in result.output

    result = runner.invoke(main, ["check", str(session), "--json"])
    assert result.exit_code == 2
    data = json.loads(result.stdout)
    assert data["ok"] is False and len(data["problems"]) == 2
    assert {Path(p["path"]).name for p in data["problems"]} == {"cam_00.mp4", "calibration.yaml"}


def test_no_background_clip_without_the_segmenter_is_a_warning(
    session: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def drop_clips(data: dict[str, Any]) -> None:
        for cam in data["cameras"]:
            cam.pop("background", None)

    _edit_yaml(session / "session.yaml", drop_clips)
    monkeypatch.setenv("BODYMETRY_PERSON_SEGMENTER", "0")
    report = check_session(session)
    assert report.ok
    (warning,) = [w for w in report.warnings if "background clip" in w.message]
    assert "cam_00, cam_01" in warning.message and "pip install --no-deps" in warning.message
    monkeypatch.setenv("BODYMETRY_PERSON_SEGMENTER", "1")
    if segmenter_available():  # with the segmenter, no clip is needed
        assert not any("background clip" in w.message for w in check_session(session).warnings)
