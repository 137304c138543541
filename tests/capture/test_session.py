"""session.yaml: a valid session loads; each malformed class -> InputError naming file and field."""

from __future__ import annotations

import copy
import dataclasses
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from yaml_edits import delete_at, set_at

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import save_calibration
from bodymetry.capture.session import (
    SESSION_FORMAT,
    SESSION_MAX_BYTES,
    BoardSpec,
    Session,
    SessionCamera,
    load_session,
    save_session,
)
from bodymetry.errors import InputError

NAMES = ("cam_00", "cam_01", "cam_02")


def _calibration(names: tuple[str, ...]) -> CameraGroup:
    cams = []
    for i, name in enumerate(names):
        a = 2 * np.pi * i / len(names)
        R = np.array(
            [[-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, -1.0], [-np.cos(a), -np.sin(a), 0.0]]
        )
        center = np.array([3 * np.cos(a), 3 * np.sin(a), 1.5])
        K = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]
        cams.append(Camera(name, (640, 480), K, [-0.1, 0.01, 0.0, 0.0, 0.0], R, -R @ center))
    return CameraGroup(cams)


def _valid_data() -> dict[str, Any]:
    return {
        "format": SESSION_FORMAT,
        "name": "test session",
        "fps": 60,
        "frame_step": 25,
        "cameras": [
            {
                "name": n,
                "video": f"videos/{n}.mp4",
                "frame_offset": i,
                "background": f"background/{n}.mp4",
            }
            for i, n in enumerate(NAMES)
        ],
        "calibration": "calibration.yaml",
        "calibration_clips": {n: f"calib/{n}.mp4" for n in NAMES},
        "board": {
            "type": "charuco",
            "squares": [7, 5],
            "square_mm": 40.0,
            "marker_mm": 30.0,
            "dictionary": "DICT_5X5_100",
            "legacy": False,
        },
        "ground_truth": "ground_truth/",
        "subject": {"note": "synthetic", "seed": 3},
    }


@pytest.fixture
def session_dir(tmp_path: Path) -> Path:
    """A complete session folder (files hold placeholder bytes: nothing is decoded)."""
    folder = tmp_path / "session"
    for sub in ("videos", "background", "calib"):
        (folder / sub).mkdir(parents=True)
        for n in NAMES:
            (folder / sub / f"{n}.mp4").write_bytes(b"not really a video")
    (folder / "ground_truth").mkdir()
    # Calibration lists the cameras in another order (plus a spare camera).
    save_calibration(folder / "calibration.yaml", _calibration(("cam_02", "cam_00", "x", "cam_01")))
    (folder / "session.yaml").write_text(yaml.safe_dump(_valid_data(), sort_keys=False))
    return folder


def _write(folder: Path, data: Any) -> None:
    (folder / "session.yaml").write_text(yaml.safe_dump(data, sort_keys=False))


# -- valid sessions ---------------------------------------------------------------------
def test_valid_session_loads(session_dir: Path) -> None:
    s = load_session(session_dir)
    assert s.folder == session_dir.absolute()
    assert s.name == "test session" and s.fps == 60.0 and s.frame_step == 25
    assert s.camera_names == NAMES
    assert [c.frame_offset for c in s.cameras] == [0, 1, 2]
    assert s.video_path("cam_01") == session_dir.absolute() / "videos/cam_01.mp4"
    assert s.background_path("cam_02") == session_dir.absolute() / "background/cam_02.mp4"
    assert s.calibration_clip_path("cam_00").name == "cam_00.mp4"
    assert s.board == BoardSpec((7, 5), 40.0, 30.0, "DICT_5X5_100")
    assert s.board.square_m == 0.04 and s.board.n_markers == 17
    assert s.board.create_board().getChessboardSize() == (7, 5)
    assert s.ground_truth_silhouette_path("cam_01", 50) == (
        session_dir.absolute() / "ground_truth/silhouettes/cam_01/000050.png"
    )
    np.testing.assert_array_equal(s.kept_frames(60), [0, 25, 50])
    group = s.calibration()
    assert group.names == NAMES  # session order, spare camera dropped
    assert load_session(session_dir / "session.yaml") == s


def test_minimal_session_defaults(session_dir: Path) -> None:
    data = {
        "format": SESSION_FORMAT,
        "name": "minimal",
        "fps": 25.0,
        "cameras": [{"name": n, "video": f"videos/{n}.mp4"} for n in NAMES],
    }
    _write(session_dir, data)
    s = load_session(session_dir)
    assert s.frame_step == 25 and s.cameras[0].frame_offset == 0
    assert s.cameras[0].background is None and s.board is None and not s.calibration_clips
    assert s.calibration_file == "calibration.yaml"  # found beside session.yaml
    (session_dir / "calibration.yaml").unlink()
    with pytest.raises(InputError, match=r"session\.yaml: calibration: the session has no cal"):
        load_session(session_dir)


def test_save_load_round_trip(session_dir: Path, tmp_path: Path) -> None:
    s = load_session(session_dir)
    written = save_session(s)
    assert written == session_dir.absolute() / "session.yaml"
    text = written.read_text()
    assert text.startswith("# bodymetry session") and f"format: {SESSION_FORMAT}\n" in text
    again = load_session(session_dir)
    assert again == s
    save_session(again)
    assert written.read_text() == text
    # Written elsewhere (e.g. by the studio before its videos exist): no file checks.
    other = save_session(dataclasses.replace(s, folder=tmp_path / "new"), tmp_path / "new")
    assert other.read_text() == text


def test_studio_style_construction(tmp_path: Path) -> None:
    s = Session(
        folder=tmp_path,
        name="synth",
        fps=60,
        cameras=[SessionCamera(n, f"videos/{n}.mkv") for n in NAMES],
        calibration_file="calibration.yaml",
        ground_truth="ground_truth",
    )
    text = save_session(s).read_text()
    assert "fps: 60.0\n" in text and "frame_step: 25\n" in text
    bad = dataclasses.replace(s, cameras=(SessionCamera("a", "../outside.mkv"),))
    with pytest.raises(InputError, match=r"cameras\[0\]\.video: .*leaves the session folder"):
        save_session(bad)
    bad = dataclasses.replace(s, cameras=(SessionCamera("a", "x.mkv"), SessionCamera("a", "y")))
    with pytest.raises(InputError, match=r"cameras\[1\]\.name: duplicate"):
        save_session(bad)


# -- malformed session.yaml: one case per class ---------------------------------------------


def _too_many_markers(data: dict[str, Any]) -> None:
    data["board"].update(squares=[12, 10], dictionary="DICT_4X4_50")


CASES = [
    # missing key
    (delete_at("format"), "format", "missing key 'format'"),
    (delete_at("name"), "name", "missing key 'name'"),
    (delete_at("fps"), "fps", "missing key 'fps'"),
    (delete_at("cameras"), "cameras", "missing key 'cameras'"),
    (delete_at("cameras.1.video"), r"cameras\[1\]\.video", "missing key 'video'"),
    (delete_at("board.dictionary"), r"board\.dictionary", "missing key 'dictionary'"),
    (delete_at("board"), "board", "calibration_clips need a description of the board"),
    # unknown keys
    (set_at("frame_stpe", 5), "frame_stpe", "unknown key"),
    (set_at("cameras.0.offset", 5), r"cameras\[0\]\.offset", "unknown key"),
    # wrong type
    (set_at("fps", "fast"), "fps", "expected a number"),
    (set_at("name", 12), "name", "expected a string"),
    (set_at("frame_step", 2.5), "frame_step", "expected an integer"),
    (set_at("cameras", "cam_00"), "cameras", "expected a list"),
    (set_at("cameras.2", "cam_02"), r"cameras\[2\]", "expected a mapping"),
    (set_at("cameras.0.video", ["a.mp4"]), r"cameras\[0\]\.video", "expected a string"),
    (set_at("board.legacy", "no"), r"board\.legacy", "expected true or false"),
    (set_at("board.squares", [7]), r"board\.squares", r"expected \[x, y\]"),
    (set_at("subject", 5), "subject", "expected notes"),
    # out of range
    (set_at("fps", 0), "fps", "> 0"),
    (set_at("fps", -30), "fps", "> 0"),
    (set_at("fps", float("nan")), "fps", "finite"),
    (set_at("frame_step", 0), "frame_step", ">= 1"),
    (set_at("cameras.1.frame_offset", -3), r"cameras\[1\]\.frame_offset", ">= 0"),
    (set_at("cameras", []), "cameras", "at least one camera"),
    # unknown format version / kind
    (set_at("format", "bodymetry-session/2"), "format", "unknown format version"),
    (set_at("format", "bodymetry-calibration/1"), "format", "wrong kind of file"),
    # duplicate camera
    (set_at("cameras.2.name", "cam_00"), r"cameras\[2\]\.name", r"duplicate.*cameras\[0\]"),
    # paths outside the folder
    (set_at("cameras.0.video", "../x.mp4"), r"cameras\[0\]\.video", "leaves the session folder"),
    (set_at("cameras.0.video", "videos/../../x.mp4"), r"cameras\[0\]\.video", "leaves the"),
    (set_at("cameras.0.video", "/tmp/x.mp4"), r"cameras\[0\]\.video", "absolute path"),
    (set_at("cameras.0.video", "C:/data/x.mp4"), r"cameras\[0\]\.video", "absolute path"),
    (set_at("cameras.0.video", "videos\\cam_00.mp4"), r"cameras\[0\]\.video", "forward slashes"),
    (set_at("calibration", "../calibration.yaml"), "calibration", "leaves the session folder"),
    (set_at("ground_truth", "/"), "ground_truth", "absolute path"),
    # missing files (message names the camera and the file)
    (
        set_at("cameras.1.video", "videos/missing.mp4"),
        r"cameras\[1\]\.video",
        r"video of camera 'cam_01' not found: .*videos/missing\.mp4",
    ),
    (
        set_at("cameras.2.background", "background/none.mp4"),
        r"cameras\[2\]\.background",
        r"background clip of camera 'cam_02' not found",
    ),
    (
        set_at("calibration_clips.cam_01", "calib/none.mp4"),
        r"calibration_clips\.cam_01",
        r"calibration clip of camera 'cam_01' not found",
    ),
    (set_at("calibration", "calib.yaml"), "calibration", "calibration file not found"),
    (set_at("ground_truth", "gt"), "ground_truth", "ground-truth folder not found"),
    (set_at("ground_truth", "videos/cam_00.mp4"), "ground_truth", "must be a folder"),
    (set_at("cameras.0.video", "videos"), r"cameras\[0\]\.video", "must be a file"),
    # calibration clips / board
    (set_at("calibration_clips.cam_07", "calib/cam_00.mp4"), r"calibration_clips\.cam_07", "no "),
    (delete_at("calibration_clips.cam_02"), "calibration_clips", "no clip for camera.*'cam_02'"),
    (set_at("board.dictionary", "DICT_5X5_99"), r"board\.dictionary", "unknown ArUco dictionary"),
    (_too_many_markers, r"board\.dictionary", "60 markers but DICT_4X4_50 holds only 50"),
    (set_at("board.marker_mm", 45), r"board\.marker_mm", "smaller than the square"),
    (set_at("board.type", "chessboard"), r"board\.type", "unknown board type"),
    # not a mapping
    (lambda d: [d], "", "expected a mapping"),
]


@pytest.mark.parametrize(("edit", "field", "message"), CASES)
def test_malformed_session(
    session_dir: Path, edit: Callable[[dict[str, Any]], Any], field: str, message: str
) -> None:
    data = copy.deepcopy(_valid_data())
    result = edit(data)
    _write(session_dir, data if result is None else result)
    with pytest.raises(InputError) as info:
        load_session(session_dir)
    err = str(info.value)
    assert str(session_dir / "session.yaml") in err
    if field:
        assert re.search(rf"session\.yaml: {field}: ", err), err
    assert re.search(message, err), err


def test_symlink_outside_folder(session_dir: Path, tmp_path: Path) -> None:
    outside = tmp_path / "elsewhere.mp4"
    outside.write_bytes(b"x")
    (session_dir / "videos" / "link.mp4").symlink_to(outside)
    data = _valid_data()
    data["cameras"][1]["video"] = "videos/link.mp4"
    _write(session_dir, data)
    with pytest.raises(InputError, match=r"session\.yaml: cameras\[1\]\.video: .*outside the ses"):
        load_session(session_dir)
    # A symbolic link that stays inside the folder is fine.
    (session_dir / "videos" / "inside.mp4").symlink_to(session_dir / "videos" / "cam_00.mp4")
    data["cameras"][1]["video"] = "videos/inside.mp4"
    _write(session_dir, data)
    assert load_session(session_dir).cameras[1].video == "videos/inside.mp4"


def test_calibration_name_mismatch(session_dir: Path) -> None:
    save_calibration(session_dir / "calibration.yaml", _calibration(("cam_00", "cam_1", "cam_02")))
    with pytest.raises(InputError) as info:
        load_session(session_dir)
    err = str(info.value)
    assert "session.yaml: calibration: calibration.yaml has no camera named 'cam_01'" in err
    assert "cam_1" in err


def test_malformed_calibration_file(session_dir: Path) -> None:
    path = session_dir / "calibration.yaml"
    path.write_text(path.read_text().replace("      - [0.0, 0.0, 1.0]\n", "", 1))
    with pytest.raises(InputError, match=r"calibration\.yaml: cameras\[0\]\.K: expected a 3x3"):
        load_session(session_dir)


def test_malformed_yaml_and_missing(session_dir: Path, tmp_path: Path) -> None:
    (session_dir / "session.yaml").write_text("format: bodymetry-session/1\nname: [a\n")
    with pytest.raises(InputError, match=r"session\.yaml: not valid YAML at line"):
        load_session(session_dir)
    with pytest.raises(InputError, match="session folder not found"):
        load_session(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"session\.yaml: session file not found"):
        load_session(tmp_path / "empty")


def test_oversized_session_file(session_dir: Path) -> None:
    """A huge session.yaml (the wrong file) is refused by its size before it is parsed."""
    path = session_dir / "session.yaml"
    with open(path, "r+b") as fh:
        fh.truncate(52_400_000)  # sparse: instant
    with pytest.raises(InputError) as info:
        load_session(session_dir)
    assert str(info.value) == (f"{path}: 52.4 MB, larger than the 1 MB limit for a session file")
    # Just over the limit: spaces after valid YAML still count.
    _write(session_dir, _valid_data())
    with open(path, "ab") as fh:
        fh.write(b" " * (SESSION_MAX_BYTES - path.stat().st_size + 1))
    with pytest.raises(InputError, match=r"session\.yaml: 1,000,001 bytes, larger than the 1 MB"):
        load_session(session_dir)


def test_calibration_method_without_file(session_dir: Path) -> None:
    s = dataclasses.replace(load_session(session_dir), calibration_file=None)
    with pytest.raises(InputError, match="no calibration file yet"):
        s.calibration()
