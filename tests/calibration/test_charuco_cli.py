"""ChArUco detection on images, and ``bodymetry calibrate`` end to end on a tiny session.

Board images are made by warping OpenCV's board image with the homography of a
known (distortion-free) camera: exact ground truth, no renderer needed.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.charuco import board_geometry, detect_clip, detect_image, make_detector
from bodymetry.calibration.io import load_calibration
from bodymetry.calibration.session_calibration import CalibrationReport
from bodymetry.capture.session import BoardSpec, Session, SessionCamera, save_session
from bodymetry.cli import main
from bodymetry.errors import InputError

BOARD = BoardSpec(squares=(5, 4), square_mm=200.0, marker_mm=150.0, dictionary="DICT_4X4_50")
PX_PER_M = 1000


def _board_image() -> np.ndarray:
    board = BOARD.create_board()
    w, h = (round(s * BOARD.square_m * PX_PER_M) for s in BOARD.squares)
    return board.generateImage((w, h), marginSize=0, borderBits=1)


def render(cam: Camera, world_from_board: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The board seen by a pinhole camera (no distortion), grey background, light noise."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cam.R, cam.t
    cb = T @ world_from_board  # camera_from_board
    s = 1.0 / PX_PER_M
    # board image pixel (u, v) -> board metres ((u + 0.5) s, (v + 0.5) s, 0)
    A = np.array([[s, 0, 0.5 * s], [0, s, 0.5 * s], [0, 0, 1]])
    H = cam.K @ np.column_stack([cb[:3, 0], cb[:3, 1], cb[:3, 3]]) @ A
    img = cv2.warpPerspective(
        _board_image(), H, cam.size, flags=cv2.INTER_AREA, borderValue=110
    ).astype(float)
    img = cv2.GaussianBlur(img, (0, 0), 0.6) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _look_at(center, target):
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def make_rig() -> CameraGroup:
    cams = []
    for i in range(3):
        a = 2 * np.pi * i / 3 - np.pi / 2
        c = np.array([0.5 + 2.2 * np.cos(a), -0.4 + 2.2 * np.sin(a), 1.6])
        R = _look_at(c, [0.5, -0.4, 0.5])
        K = [[560.0 + 10 * i, 0, 322], [0, 560.0 + 10 * i, 238], [0, 0, 1]]
        cams.append(Camera(f"cam_{i:02d}", (640, 480), K, np.zeros(5), R, -R @ c))
    return CameraGroup(cams)


def board_poses(rig: CameraGroup, rng: np.random.Generator, n_floor=6, n_moving=48):
    out = [np.diag([1.0, -1.0, -1.0, 1.0])] * n_floor
    centers = rig.centers
    for k in range(n_moving):
        i = k % 3
        target = 0.5 * (centers[i] + centers[(i + 1) % 3])
        pos = np.array([0.5, -0.4, 0.8]) + rng.uniform(-0.25, 0.25, 3)
        zb = -(target - pos) / np.linalg.norm(target - pos)
        xb = np.cross([0.0, 0.0, 1.0], zb)
        xb /= np.linalg.norm(xb)
        R = np.stack([xb, np.cross(zb, xb), zb], axis=1)
        R = R @ Rotation.from_rotvec(rng.uniform(-0.45, 0.45, 3)).as_matrix()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, pos - R @ np.array([0.5, 0.4, 0.0])
        out.append(T)
    return np.stack(out)


def test_detect_image_finds_corners_where_the_camera_projects_them() -> None:
    rng = np.random.default_rng(0)
    cam = make_rig()[0]
    pose = board_poses(make_rig(), rng, n_floor=0, n_moving=1)[0]
    board = BOARD.create_board()
    geom = board_geometry(board, BOARD.square_m)
    img = render(cam, pose, rng)
    found = detect_image(make_detector(board), img, geom.n_corners)
    truth = cam.project(geom.points @ pose[:3, :3].T + pose[:3, 3])
    ok = np.isfinite(found).all(axis=1)
    assert ok.sum() >= 10
    err = np.linalg.norm(found[ok] - truth[ok], axis=1)
    # (the warped test image is aliased: a corner may be off by ~1 px)
    assert np.median(err) < 0.2 and np.max(err) < 1.5
    # A mirrored video shows no decodable board.
    mirrored = detect_image(make_detector(board), cv2.flip(img, 1), geom.n_corners)
    assert not np.isfinite(mirrored).any()


def test_detect_clip_errors_name_camera_and_file(tmp_path: Path) -> None:
    board = BOARD.create_board()
    with pytest.raises(InputError, match=r"camera 'cam_07': calibration clip .*missing.mp4 does"):
        detect_clip(tmp_path / "missing.mp4", board, "cam_07")
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(InputError, match="cam_07"):
        detect_clip(tmp_path / "junk.mp4", board, "cam_07")


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory) -> tuple[Path, CameraGroup]:
    """3 cameras, 54-frame MJPG calibration clips (6 floor frames), no calibration yet."""
    folder = tmp_path_factory.mktemp("calib") / "session"
    (folder / "calib").mkdir(parents=True)
    (folder / "videos").mkdir()
    rng = np.random.default_rng(1)
    rig = make_rig()
    poses = board_poses(rig, rng)
    for cam in rig:
        writer = cv2.VideoWriter(
            str(folder / "calib" / f"{cam.name}.avi"),
            cv2.VideoWriter_fourcc(*"MJPG"),
            30.0,
            cam.size,
            isColor=False,
        )
        for T in poses:
            writer.write(render(cam, T, rng))
        writer.release()
        (folder / "videos" / f"{cam.name}.mp4").write_bytes(b"unused here")
    session = Session(
        folder=folder,
        name="tiny",
        fps=30.0,
        cameras=tuple(SessionCamera(c.name, f"videos/{c.name}.mp4") for c in rig),
        calibration_clips={c.name: f"calib/{c.name}.avi" for c in rig},
        board=BOARD,
    )
    save_session(session)
    return folder, rig


def test_calibrate_command_end_to_end(tiny_session) -> None:
    folder, rig = tiny_session
    runner = CliRunner()
    res = runner.invoke(main, ["calibrate", str(folder), "--floor-frames", "0:6"])
    assert res.exit_code == 0, res.output
    assert "corners used" in res.output and "cam_02" in res.output
    solved = load_calibration(folder / "calibration.yaml")
    assert solved.names == rig.names
    for cam in solved:
        true = rig[cam.name]
        assert np.linalg.norm(cam.center - true.center) < 0.02
        assert abs(cam.K[0, 0] / true.K[0, 0] - 1) < 0.01
    report = json.loads((folder / "calibration-report.json").read_text())
    typed = CalibrationReport.read(folder / "calibration-report.json")
    assert typed.to_json() == report and typed.session == str(folder)
    assert report["rms_px"] < 0.5
    assert set(report["cameras"]) == set(rig.names)
    for fig in report["cameras"].values():
        assert fig["frames_read"] == 54 and fig["boards_detected"] > 10 and fig["corners_used"] > 50

    # An existing file is not replaced without --overwrite ...
    before = (folder / "calibration.yaml").read_bytes()
    res = runner.invoke(main, ["calibrate", str(folder), "--floor-frames", "0:6"])
    assert res.exit_code == 2 and "--overwrite" in res.output
    assert (folder / "calibration.yaml").read_bytes() == before
    # ... and a bad option is one clear line.
    res = runner.invoke(main, ["calibrate", str(folder), "--floor-frames", "six", "--overwrite"])
    assert res.exit_code == 2 and "--floor-frames 'six'" in res.output


def test_missing_and_unreadable_clips_are_all_named_before_detection(tiny_session, tmp_path):
    folder, _ = tiny_session
    copy = tmp_path / "session"
    shutil.copytree(folder, copy)
    (copy / "calib" / "cam_00.avi").write_bytes(b"")
    (copy / "calib" / "cam_01.avi").write_bytes(b"not a video")
    res = CliRunner().invoke(main, ["calibrate", str(copy), "--overwrite"])
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())  # rich may wrap the line
    assert "calibration clips cannot be read" in text
    assert "cam_00.avi (no readable frames)" in text and "cam_01.avi (no readable frames)" in text
    assert "cam_02" not in text and "Traceback" not in text
