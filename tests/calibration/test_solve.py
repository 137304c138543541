"""Multi-camera calibration from ChArUco corner observations (calibration/solve.py).

Observations are made by projecting the board's corners with known cameras and
adding pixel noise, so the tests are fast and the truth is exact.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodymetry.calibration import solve
from bodymetry.calibration.bundle_adjustment import SolveResult
from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.charuco import CameraDetections, board_geometry
from bodymetry.calibration.solve import (
    FLOOR_BOARD_POSE,
    CalibrationError,
    CalibrationOptions,
    calibrate_cameras,
)
from bodymetry.capture.session import BoardSpec

BOARD = BoardSpec(squares=(5, 4), square_mm=200.0, marker_mm=150.0, dictionary="DICT_4X4_50")
GEOM = board_geometry(BOARD.create_board(), BOARD.square_m)
N_FLOOR = 10


def _look_at(center: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])  # camera_from_world rows


def make_rig(n: int = 3) -> CameraGroup:
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        c = np.array([3.0 * np.cos(a), 3.0 * np.sin(a), 2.2])
        R = _look_at(c, np.array([0.3, -0.3, 0.7]))
        f = 800.0 + 20 * i
        K = [[f, 0, 320 + 3 * i], [0, f * 1.001, 240 - 2 * i], [0, 0, 1]]
        cams.append(Camera(f"cam_{i:02d}", (640, 480), K, [-0.12, 0.03, 0, 0, 0], R, -R @ c))
    return CameraGroup(cams)


def board_poses(n_moving: int, rig: CameraGroup, rng: np.random.Generator) -> np.ndarray:
    """N_FLOOR floor poses then moving poses facing random camera pairs (world_from_board)."""
    out = [FLOOR_BOARD_POSE.copy() for _ in range(N_FLOOR)]
    centers = rig.centers
    for k in range(n_moving):
        i = k % len(rig)
        target = 0.5 * (centers[i] + centers[(i + 1) % len(rig)])
        pos = rng.uniform([-0.5, -0.5, 0.6], [0.5, 0.5, 1.4])
        normal = target - pos
        normal /= np.linalg.norm(normal)
        zb = -normal
        xb = np.cross([0.0, 0.0, 1.0], zb)
        xb /= np.linalg.norm(xb)
        yb = np.cross(zb, xb)
        R = np.stack([xb, yb, zb], axis=1)
        ang = rng.uniform(-0.5, 0.5, 3)
        R = R @ Rotation.from_rotvec(ang).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = pos - R @ np.array([0.5, 0.4, 0.0])
        out.append(T)
    return np.stack(out)


def observe(
    rig: CameraGroup, poses: np.ndarray, noise: float, rng: np.random.Generator
) -> list[CameraDetections]:
    """Project every board corner; keep those in front, facing the camera, inside the image."""
    W = np.einsum("fij,nj->fni", poses[:, :3, :3], GEOM.points) + poses[:, None, :3, 3]
    dets = []
    for cam in rig:
        uv = cam.project(W)
        uv = uv + rng.normal(0, noise, uv.shape)
        normal = -poses[:, :3, 2]  # printed side
        facing = np.einsum("fi,fni->fn", normal, cam.center - W) > 0.2
        w, h = cam.size
        inside = (uv[..., 0] > 5) & (uv[..., 0] < w - 5) & (uv[..., 1] > 5) & (uv[..., 1] < h - 5)
        uv[~(facing & inside)] = np.nan
        frames = np.arange(len(poses))
        dets.append(CameraDetections(cam.name, cam.size, len(poses), frames, uv, "synthetic"))
    return dets


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(4)
    rig = make_rig(3)
    poses = board_poses(90, rig, rng)
    return rig, poses, observe(rig, poses, 0.15, rng)


OPTS = CalibrationOptions(floor_frames=(0, N_FLOOR))


def _rot_err_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1))))


def test_bundle_adjustment_recovers_known_cameras(scene) -> None:
    rig, _, dets = scene
    result = calibrate_cameras(dets, GEOM, OPTS)
    assert result.rms_px < 0.3
    for cam in result.cameras:
        true = rig[cam.name]
        # The world is the floor board's frame: compared without any alignment.
        assert np.linalg.norm(cam.center - true.center) < 0.01
        assert _rot_err_deg(cam.R, true.R) < 0.2
        assert np.all(np.abs(np.diag(cam.K)[:2] / np.diag(true.K)[:2] - 1) < 0.005)
        assert np.all(np.abs(cam.K[:2, 2] - true.K[:2, 2]) < 3.0)
        assert abs(cam.dist[0] - true.dist[0]) < 0.03
        fig = result.per_camera[cam.name]
        assert fig["frames_read"] == len(scene[1])
        assert fig["corners_used"] > 100
        assert fig["rms_px"] < 0.3
        # k2 is solved only where the corners reach the image borders
        assert fig["radial_terms"] == (["k1", "k2"] if fig["image_coverage"] >= 0.7 else ["k1"])
    assert result.world["frame"].startswith("ChArUco board on the floor")
    # Points triangulated with the solution land where the truth says (metric, z up).
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.3, 1.5]])
    got = result.cameras.triangulate(rig.project(X), refine=True)
    np.testing.assert_allclose(got, X, atol=0.01)


def test_outliers_are_rejected(scene) -> None:
    rig, _, dets = scene
    rng = np.random.default_rng(9)
    bad = []
    for d in dets:
        c = d.corners.copy()
        found = np.argwhere(np.isfinite(c[N_FLOOR:, :, 0]))
        pick = found[rng.choice(len(found), 15, replace=False)]
        c[pick[:, 0] + N_FLOOR, pick[:, 1]] += rng.choice([-1, 1], (15, 2)) * 8.0
        bad.append(CameraDetections(d.name, d.size, d.frames_read, d.frames, c, d.source))
    result = calibrate_cameras(bad, GEOM, OPTS)
    assert result.outliers >= 40
    assert result.rms_px < 0.3
    for cam in result.cameras:
        assert np.linalg.norm(cam.center - rig[cam.name].center) < 0.01


def test_no_floor_frames_puts_the_world_at_the_root_camera(scene) -> None:
    rig, _, dets = scene
    result = calibrate_cameras(dets, GEOM, CalibrationOptions(floor_frames=None))
    cam0 = result.cameras[0]
    np.testing.assert_allclose(cam0.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(cam0.t, 0, atol=1e-12)
    assert "NOT up" in result.world["frame"]
    # Relative geometry is still right: baseline lengths match the truth.
    d_est = np.linalg.norm(result.cameras.centers[1] - result.cameras.centers[0])
    d_true = np.linalg.norm(rig.centers[1] - rig.centers[0])
    assert abs(d_est - d_true) < 0.01


def test_floor_not_seen_is_an_error(scene) -> None:
    _, _, dets = scene
    hidden = []
    for d in dets:
        c = d.corners.copy()
        c[:N_FLOOR] = np.nan
        hidden.append(CameraDetections(d.name, d.size, d.frames_read, d.frames, c, d.source))
    with pytest.raises(CalibrationError, match="no camera saw the board lying on the floor"):
        calibrate_cameras(hidden, GEOM, OPTS)


def test_board_moving_during_floor_frames_is_an_error(scene) -> None:
    _, _, dets = scene
    moved = [
        CameraDetections(d.name, d.size, d.frames_read, d.frames, d.corners.copy(), d.source)
        for d in dets
    ]
    # Floor frames 0:20 include 10 frames where the board is already in the air.
    with pytest.raises(CalibrationError, match="moved during the floor frames"):
        calibrate_cameras(moved, GEOM, CalibrationOptions(floor_frames=(0, 14)))


def test_board_never_found_names_camera_and_causes(scene) -> None:
    _, _, dets = scene
    d = dets[1]
    nothing = np.full_like(d.corners, np.nan)
    blind = CameraDetections(d.name, d.size, 321, d.frames, nothing, "c.mp4")
    with pytest.raises(CalibrationError) as info:
        calibrate_cameras([dets[0], blind, dets[2]], GEOM, OPTS)
    msg = str(info.value)
    assert "'cam_01'" in msg and "never found" in msg and "321 frames read" in msg
    assert "dictionary" in msg and "too small" in msg and "mirrored" in msg


def test_too_few_shared_views_names_the_camera(scene) -> None:
    _, _, dets = scene
    # cam_02's clip holds good views, but none at the same time as the others'.
    d = dets[2]
    lonely = CameraDetections(d.name, d.size, d.frames_read, d.frames + 1000, d.corners, d.source)
    with pytest.raises(CalibrationError) as info:
        calibrate_cameras([dets[0], dets[1], lonely], GEOM, OPTS)
    msg = str(info.value)
    assert "too few shared views to link camera(s) ['cam_02']" in msg
    assert "'cam_00': 0" in msg


def test_unsynchronized_clip_fails_instead_of_writing_a_bad_file(scene) -> None:
    _, _, dets = scene
    # cam_01's clip is shifted by 3 frames: the board poses disagree between cameras.
    d = dets[1]
    c = d.corners.copy()
    c[N_FLOOR + 3 :] = d.corners[N_FLOOR:-3]
    shifted = CameraDetections(d.name, d.size, d.frames_read, d.frames, c, d.source)
    opts = CalibrationOptions(floor_frames=(0, N_FLOOR), max_iterations=15)
    with pytest.raises(CalibrationError, match="did not converge"):
        calibrate_cameras([dets[0], shifted, dets[2]], GEOM, opts)


def test_nan_in_bundle_adjustment_is_an_error(scene, monkeypatch) -> None:
    _, _, dets = scene

    def broken(pb, x0, opts, loss):
        x = x0.copy()
        x[0] = np.nan
        return x, SolveResult(True, 1, "converged", 1, 1)

    monkeypatch.setattr(solve, "solve_bundle", broken)
    with pytest.raises(CalibrationError, match="NaN"):
        calibrate_cameras(dets, GEOM, OPTS)


def test_corners_the_refiner_could_not_place_are_down_weighted(scene) -> None:
    """Precise (refined) corners plus 20 % biased ones marked unrefined: the
    down-weighted solve stays with the precise ones."""
    rig, poses, _ = scene
    rng = np.random.default_rng(11)
    dets = observe(rig, poses, 0.02, rng)
    marked = []
    for d in dets:
        c = d.corners.copy()
        refined = np.ones(d.found.shape, dtype=bool)
        pick = d.found & (rng.random(d.found.shape) < 0.2)
        pick[:N_FLOOR] = False
        c[pick] += [0.6, 0.0]  # under the 1 px outlier floor
        refined[pick] = False
        marked.append(
            CameraDetections(d.name, d.size, d.frames_read, d.frames, c, d.source, refined)
        )
    plain = [
        CameraDetections(d.name, d.size, d.frames_read, d.frames, d.corners, d.source)
        for d in marked
    ]

    def cx_error(result) -> float:
        return max(abs(c.K[0, 2] - rig[c.name].K[0, 2]) for c in result.cameras)

    weighted = calibrate_cameras(marked, GEOM, OPTS)
    unweighted = calibrate_cameras(plain, GEOM, OPTS)
    assert cx_error(weighted) < 0.3 * cx_error(unweighted)
    for d in marked:
        fig = weighted.per_camera[d.name]
        assert fig["corners_refined"] == int((d.refined & d.found).sum())
        assert unweighted.per_camera[d.name]["corners_refined"] is None
