"""`bodymetry import`: sessions from Pose2Sim, anipose / FreeMoCap and plain recordings."""

from __future__ import annotations

import logging
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner, Result

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import load_calibration, save_calibration
from bodymetry.calibration.qualisys import import_qca
from bodymetry.capture.session import load_session
from bodymetry.cli import main
from bodymetry.errors import InputError
from bodymetry.importers import (
    default_frame_step,
    find_recording,
    fit_size,
    import_recording,
    match_cameras,
)
from bodymetry.preflight import check_session

QCA = Path(__file__).resolve().parents[1] / "data" / "pose2sim" / "calibration" / "Calib.qca.txt"
FRAMES = 24  # default frame step 2: keeps 12 frames
FPS = 60.0


def _video(path: Path, size: tuple[int, int], frames: int = FRAMES, fps: float = FPS) -> Path:
    """A short MJPG (.avi) or mp4v (.mp4) clip of ``size`` (width, height): a grey ramp."""
    path.parent.mkdir(parents=True, exist_ok=True)
    codec = "mp4v" if path.suffix == ".mp4" else "MJPG"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, size)
    assert writer.isOpened()
    w, h = size
    ramp = np.linspace(60, 200, w, dtype=np.uint8)[None, :, None]
    for i in range(frames):
        writer.write(np.broadcast_to(ramp + i % 50, (h, w, 3)).copy())
    writer.release()
    return path


@pytest.fixture(scope="module")
def pose2sim_videos(tmp_path_factory) -> Path:
    """Pose2Sim demo-like videos at the QCA's 1088x1920, cam01 8 px narrower (as in the demo)."""
    folder = tmp_path_factory.mktemp("p2s_videos")
    for i in range(1, 5):
        size = (1080, 1920) if i == 1 else (1088, 1920)
        _video(folder / f"cam0{i}{'.mp4' if i == 2 else '.avi'}", size)
    return folder


def _pose2sim(root: Path, videos: Path, config: str | None = None) -> Path:
    project = root / "Demo_SinglePerson"
    (project / "calibration").mkdir(parents=True)
    shutil.copy(QCA, project / "calibration" / "Calib.qca.txt")
    shutil.copytree(videos, project / "videos")
    (project / "Config.toml").write_text(
        config
        or "[project]\nframe_rate = 'auto'\n\n[calibration]\ncalibration_type = 'convert'\n"
        "[calibration.convert]\nconvert_from = 'qualisys'\n"
        "[calibration.convert.qualisys]\nbinning_factor = 1\n"
    )
    return project


def _run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args))


def _assert_user_error(result: Result, *patterns: str) -> str:
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for pattern in patterns:
        assert re.search(pattern, lines[0]), (pattern, lines[0])
    return lines[0]


def _links_stay_inside(folder: Path) -> None:
    session = load_session(folder)
    root = folder.resolve()
    for cam in session.cameras:
        assert not cam.video.startswith("/") and ".." not in cam.video.split("/")
        assert session.video_path(cam.name).resolve().is_relative_to(root)


# --- Pose2Sim ----------------------------------------------------------------------------------


def test_pose2sim_project(tmp_path, pose2sim_videos, caplog):
    project = _pose2sim(tmp_path, pose2sim_videos)
    out = tmp_path / "session"
    with caplog.at_level(logging.INFO, logger="bodymetry.importers"):
        result = import_recording(project, out)
    session = load_session(out)
    assert result.kind == "pose2sim"
    assert session.camera_names == ("cam01", "cam02", "cam03", "cam04")
    assert session.fps == FPS
    assert session.frame_step == 2 and len(session.kept_frames(FRAMES)) == 12
    assert "frame_step 2: the shortest video has 24 frames" in caplog.text
    group = session.calibration()
    assert [c.size for c in group] == [(1080, 1920)] + [(1088, 1920)] * 3
    qca = import_qca(QCA)
    for ours, theirs in zip(group, qca, strict=True):
        # The decoded size is written; intrinsics, lens and pose are kept bit for bit.
        np.testing.assert_array_equal(ours.K, theirs.K)
        np.testing.assert_array_equal(ours.dist, theirs.dist)
        np.testing.assert_array_equal(ours.R, theirs.R)
        np.testing.assert_array_equal(ours.t, theirs.t)
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "decodes as 1080x1920 but Calib.qca.txt says 1088x1920" in warned[0]
    report = check_session(out)
    assert report.ok, report.problems
    assert not report.warnings, report.warnings
    _links_stay_inside(out)
    # Hard links by default: the same file, no space used.
    assert os.path.samefile(out / "videos" / "cam01.avi", project / "videos" / "cam01.avi")


def test_import_twice_refuses_unless_overwrite_and_copy(tmp_path, pose2sim_videos):
    project = _pose2sim(tmp_path, pose2sim_videos)
    out = tmp_path / "session"
    assert _run("import", str(project), str(out)).exit_code == 0
    _assert_user_error(_run("import", str(project), str(out)), "not empty", "--overwrite")
    result = _run("import", str(project), str(out), "--overwrite", "--copy", "--frame-step", "5")
    assert result.exit_code == 0, result.output
    assert "4 cameras (cam01, cam02, cam03, cam04), 60 fps, frame_step 5" in result.stdout
    session = load_session(out)
    assert session.frame_step == 5
    assert not os.path.samefile(out / "videos" / "cam01.avi", project / "videos" / "cam01.avi")
    assert check_session(out).ok
    # A non-empty folder that is not a session is never overwritten.
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    _assert_user_error(
        _run("import", str(project), str(other), "--overwrite"), "holds no session.yaml"
    )
    _assert_user_error(_run("import", str(project), str(project)), "may not be the source")


def test_pose2sim_toml_calibration_with_pose2sim_names(tmp_path, pose2sim_videos):
    """Pose2Sim's own calibration names its cameras after the intrinsics folders."""
    project = _pose2sim(tmp_path, pose2sim_videos)
    qca = import_qca(QCA)
    lines = []
    for cam in qca:
        rvec = cv2.Rodrigues(cam.R)[0].ravel()
        name = f"int_{cam.name}_img"
        lines += [
            f"[{name}]",
            f'name = "{name}"',
            f"size = [ {float(cam.size[0])}, {float(cam.size[1])}]",
            f"matrix = {cam.K.tolist()}",
            f"distortions = {cam.dist[:4].tolist()}",
            f"rotation = {rvec.tolist()}",
            f"translation = {cam.t.tolist()}",
            "fisheye = false",
            "",
        ]
    lines += ["[metadata]", "adjusted = false", "error = 0.0"]
    (project / "calibration" / "Calib_board.toml").write_text("\n".join(lines) + "\n")
    out = tmp_path / "session"
    result = import_recording(project, out)
    assert result.calibration_source.name == "Calib_board.toml"  # preferred over the .qca.txt
    group = load_session(out).calibration()
    assert group.names == ("cam01", "cam02", "cam03", "cam04")
    for ours, theirs in zip(group, qca, strict=True):
        np.testing.assert_allclose(ours.t, theirs.t, rtol=0, atol=1e-12)  # read as metres
        np.testing.assert_allclose(ours.R, theirs.R, rtol=0, atol=1e-12)
    assert check_session(out).ok


@pytest.mark.parametrize(
    ("where", "edit", "match"),
    [
        ("Config.toml", lambda s: s + "[project\n", r"Config\.toml: not valid TOML"),
        (
            "Config.toml",
            lambda s: s.replace("binning_factor = 1", "binning_factor = 'two'"),
            r"Config\.toml: calibration\.convert\.qualisys\.binning_factor",
        ),
        ("calibration/Calib.qca.txt", lambda s: s[:300], r"Calib\.qca\.txt: not valid XML"),
        (
            "calibration/Calib.qca.txt",
            lambda s: s.replace('centerPointV="60680.792969" ', ""),
            r"Calib\.qca\.txt: camera 0 \(serial 'cam01'\): .*centerPointV",
        ),
    ],
)
def test_malformed_pose2sim_inputs_are_one_line_errors(
    tmp_path, pose2sim_videos, where, edit, match
):
    project = _pose2sim(tmp_path, pose2sim_videos)
    path = project / where
    path.write_text(edit(path.read_text()))
    out = tmp_path / "session"
    _assert_user_error(_run("import", str(project), str(out)), match)
    assert not out.exists()  # nothing written before everything was read


def test_unmatched_video_lists_the_names(tmp_path, pose2sim_videos):
    project = _pose2sim(tmp_path, pose2sim_videos)
    shutil.copy(project / "videos" / "cam03.avi", project / "videos" / "side.avi")
    line = _assert_user_error(
        _run("import", str(project), str(tmp_path / "s")), r"Calib\.qca\.txt: cannot match"
    )
    assert "videos without a camera ['side']" in line and "cameras without a video []" in line


# --- anipose / FreeMoCap / plain ---------------------------------------------------------------


def _small_rig(names: list[str]) -> CameraGroup:
    K = [[200.0, 0.0, 80.0], [0.0, 200.0, 60.0], [0.0, 0.0, 1.0]]
    cams = []
    for i, name in enumerate(names):
        # Cameras 3 m from the origin, looking at it, upright (world z up).
        angle = i * np.pi / 2
        centre = np.array([3 * np.cos(angle), 3 * np.sin(angle), 1.0])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])
        cams.append(Camera(name, (160, 120), K, np.zeros(5), R, -R @ centre))
    return CameraGroup(cams)


def _anipose_toml(path: Path, group: CameraGroup, scale: float = 1000.0) -> Path:
    """The TOML as aniposelib writes it: translations in mm, no metadata.units."""
    lines = []
    for i, cam in enumerate(group):
        lines += [
            f"[cam_{i}]",
            f'name = "{cam.name}"',
            f"size = {list(cam.size)}",
            f"matrix = {cam.K.tolist()}",
            f"distortions = {cam.dist.tolist()}",
            f"rotation = {cv2.Rodrigues(cam.R)[0].ravel().tolist()}",
            f"translation = {(cam.t * scale).tolist()}",
            "",
        ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines + ["[metadata]", "adjusted = true", "error = 0.3"]) + "\n")
    return path


def test_anipose_session(tmp_path):
    source = tmp_path / "session1"
    group = _small_rig(["A", "B", "C"])
    _anipose_toml(source / "calibration" / "calibration.toml", group)
    for name in "ABC":
        _video(source / "videos-raw" / f"vid-cam{name}.avi", (160, 120), frames=300)
    out = tmp_path / "out"
    result = import_recording(source, out)
    session = load_session(out)
    assert result.kind == "anipose"
    assert session.camera_names == ("vid-camA", "vid-camB", "vid-camC")
    assert session.frame_step == 25  # 300 frames: the format's default keeps 12
    for ours, theirs in zip(session.calibration(), group, strict=True):
        np.testing.assert_allclose(ours.t, theirs.t, rtol=0, atol=1e-12)  # mm -> m
    assert check_session(out).ok
    _links_stay_inside(out)


def test_freemocap_recording(tmp_path):
    source = tmp_path / "recording_12_00_00"
    group = _small_rig(["cam_0", "cam_1"])
    _anipose_toml(source / "recording_12_00_00_camera_calibration.toml", group)
    for i in range(2):
        _video(source / "synchronized_videos" / f"Camera_00{i}_synchronized.mp4", (160, 120))
    out = tmp_path / "out"
    import_recording(source, out)
    session = load_session(out)
    assert session.camera_names == ("Camera_000_synchronized", "Camera_001_synchronized")
    assert [c.size for c in session.calibration()] == [(160, 120)] * 2
    assert check_session(out).ok


def test_plain_folder_with_calibration_option(tmp_path):
    source = tmp_path / "plain"
    group = _small_rig(["cam_00", "cam_01"])
    for name in ("cam00", "CAM-01"):
        _video(source / f"{name}.avi", (160, 120), fps=30.0)
    _assert_user_error(_run("import", str(source), str(tmp_path / "x")), "no calibration found")
    calib = tmp_path / "rig.yaml"
    save_calibration(calib, group)
    out = tmp_path / "out"
    result = _run("import", str(source), str(out), "--calibration", str(calib))
    assert result.exit_code == 0, result.output
    session = load_session(out)
    assert session.camera_names == ("cam00", "CAM-01") and session.fps == 30.0
    assert check_session(out).ok
    # A unitless TOML in a plain folder: the unit must be said.
    toml = _anipose_toml(tmp_path / "rig.toml", group)
    _assert_user_error(
        _run("import", str(source), str(tmp_path / "o2"), "--calibration", str(toml)),
        r"rig\.toml: .*--units",
    )
    ok = _run(
        "import", str(source), str(tmp_path / "o2"), "--calibration", str(toml), "--units", "mm"
    )
    assert ok.exit_code == 0, ok.output
    np.testing.assert_allclose(
        load_calibration(tmp_path / "o2" / "calibration.yaml")[0].t, group[0].t, atol=1e-12
    )


def test_malformed_toml_is_one_line_error(tmp_path):
    source = tmp_path / "s"
    _video(source / "videos-raw" / "vid-camA.avi", (160, 120))
    (source / "calibration").mkdir()
    (source / "calibration" / "calibration.toml").write_text("[cam_0\nname = 1\n")
    _assert_user_error(
        _run("import", str(source), str(tmp_path / "o")), r"calibration\.toml: not valid TOML"
    )


def test_size_far_from_the_calibration_is_refused(tmp_path):
    source = tmp_path / "plain"
    _video(source / "cam_00.avi", (120, 160))  # portrait, the calibration is landscape
    calib = tmp_path / "rig.yaml"
    save_calibration(calib, _small_rig(["cam_00"]))
    line = _assert_user_error(
        _run("import", str(source), str(tmp_path / "o"), "--calibration", str(calib)),
        r"decodes as 120x160 .* rig\.yaml says 160x120",
    )
    assert "rotated" in line


# --- the rules ---------------------------------------------------------------------------------


def test_matching_rule():
    assert match_cameras(["cam01", "cam02"], ["cam02", "cam01"]) == {
        "cam01": "cam01",
        "cam02": "cam02",
    }
    assert match_cameras(["cam01", "cam02"], ["cam_02", "cam_01"]) == {
        "cam01": "cam_01",
        "cam02": "cam_02",
    }
    assert match_cameras(["cam01", "cam10"], ["int_cam10_img", "int_cam01_img"]) == {
        "cam01": "int_cam01_img",
        "cam10": "int_cam10_img",
    }
    # By the last number: QCA serials, QTM's exported video names, FreeMoCap's.
    assert match_cameras(["cam01", "cam02"], ["2", "1"]) == {"cam01": "1", "cam02": "2"}
    assert match_cameras(["trial_Miqus_1_28519", "trial_Miqus_2_28520"], ["28520", "28519"]) == {
        "trial_Miqus_1_28519": "28519",
        "trial_Miqus_2_28520": "28520",
    }
    # By suffix: anipose's cam_regex names.
    assert match_cameras(["vid-camA", "vid-camB"], ["B", "A"]) == {
        "vid-camA": "A",
        "vid-camB": "B",
    }
    # Extra calibration cameras (marker-only) are fine; exact names win over numbers.
    assert match_cameras(["cam1"], ["cam1", "1", "cam_2"]) == {"cam1": "cam1"}
    with pytest.raises(InputError) as info:
        match_cameras(["left", "cam01"], ["cam_01", "cam_02"], calibration="rig.toml")
    message = str(info.value)
    assert message.startswith("rig.toml: cannot match")
    assert "videos without a camera ['left']" in message
    assert "cameras without a video ['cam_02']" in message
    # Ambiguous: two videos with the same number are not paired by number.
    with pytest.raises(InputError, match=r"\['a1', 'b1'\]"):
        match_cameras(["a1", "b1"], ["1", "2"])


def test_fit_size_rule(tmp_path):
    cam = _small_rig(["c"])[0]
    same, warning = fit_size(cam, (160, 120), Path("v.avi"), Path("rig.yaml"))
    assert same is cam and warning is None
    cropped, warning = fit_size(cam, (152, 112), Path("v.avi"), Path("rig.yaml"))
    assert cropped.size == (152, 112) and np.array_equal(cropped.K, cam.K)
    assert "decodes as 152x112 but rig.yaml says 160x120" in warning
    with pytest.raises(InputError, match=r"scaled by 2.*binning"):
        fit_size(cam, (320, 240), Path("v.avi"), Path("rig.yaml"))
    with pytest.raises(InputError, match=r"v\.avi decodes as 100x120 .* rig\.yaml says 160x120"):
        fit_size(cam, (100, 120), Path("v.avi"), Path("rig.yaml"))


def test_default_frame_step():
    assert default_frame_step(100) == 10  # the Pose2Sim demo: frames 0, 10, ..., 90
    assert len(range(0, 100, default_frame_step(100))) >= 10
    assert default_frame_step(250) == 25 and default_frame_step(10_000) == 25
    assert default_frame_step(5) == 1


def test_find_recording_layouts(tmp_path, pose2sim_videos):
    project = _pose2sim(tmp_path, pose2sim_videos)
    rec = find_recording(project)
    assert rec.kind == "pose2sim" and rec.calibration.name == "Calib.qca.txt"
    assert [p.name for p in rec.videos] == ["cam01.avi", "cam02.mp4", "cam03.avi", "cam04.avi"]
    with pytest.raises(InputError, match="source folder not found"):
        find_recording(tmp_path / "nope")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no videos"):
        find_recording(empty)
