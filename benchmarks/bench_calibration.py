"""Calibration accuracy on studio sessions with known cameras (issue 4).

Renders three studio sessions (seeds 1, 2, 3; 4 cameras, 640x480, the default
300-frame ChArUco clip, ``--frames 2``), solves their cameras from the clips with
exactly what ``bodymetry calibrate`` runs (detection with corner refinement,
then the solve), and compares with the true cameras. No alignment is done: the
solved world frame is the floor board's frame, which is the studio's world
frame by construction. The solver never sees the truth; it is read afterwards.

Targets: reprojection RMS < 0.5 px; focal error < 0.5 %; camera centre error
< 10 mm; rotation error < 0.2 deg; principal point and distortion errors reported.

``python -m benchmarks calibration``; ``BODYMETRY_BENCH_SESSIONS=dir1:dir2`` reuses
rendered sessions instead of rendering.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bodymetry.calibration.io import load_calibration
from bodymetry.calibration.session_calibration import calibrate_session, detect_session
from bodymetry.capture.ground_truth import StudioRecord
from bodymetry.capture.session import load_session
from bodymetry.studio.synth import SynthConfig, synthesize

SEEDS = (1, 2, 3)
TARGETS = {
    "rms_px": 0.5,
    "focal_error_pct": 0.5,
    "centre_error_mm": 10.0,
    "rotation_error_deg": 0.2,
}


def _rot_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1.0, 1.0))))


def evaluate(folder: Path) -> dict:
    """Solve one session and compare with its true cameras."""
    session = load_session(folder)
    true = load_calibration(session.calibration_path)
    t0 = time.perf_counter()
    detections = detect_session(session)
    t1 = time.perf_counter()
    result, _ = calibrate_session(session, detections=detections)
    t2 = time.perf_counter()
    cams = {}
    for cam in result.cameras:
        tc = true[cam.name]
        w, h = cam.size
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, h / 2]])
        # Distortion as pixels: where the true lens sends the image corners vs the solved one.
        ray = tc.undistort_points(corners)
        d_true = tc.distort_normalized(ray) @ tc.K[:2, :2].T + tc.K[:2, 2]
        d_est = cam.distort_normalized(ray) @ tc.K[:2, :2].T + tc.K[:2, 2]
        cams[cam.name] = {
            "rms_px": result.per_camera[cam.name]["rms_px"],
            "corners_used": result.per_camera[cam.name]["corners_used"],
            "corners_refined": result.per_camera[cam.name]["corners_refined"],
            "boards_detected": result.per_camera[cam.name]["boards_detected"],
            "focal_error_pct": [
                round(float(100 * (cam.K[i, i] / tc.K[i, i] - 1)), 4) for i in (0, 1)
            ],
            "principal_point_error_px": [round(float(cam.K[i, 2] - tc.K[i, 2]), 3) for i in (0, 1)],
            "centre_error_mm": round(float(1000 * np.linalg.norm(cam.center - tc.center)), 2),
            "rotation_error_deg": round(_rot_deg(cam.R, tc.R), 4),
            "dist_true": [round(float(v), 5) for v in tc.dist[:5]],
            "dist_solved": [round(float(v), 5) for v in cam.dist[:5]],
            "distortion_error_at_image_corners_px": round(
                float(np.max(np.linalg.norm(d_est[:4] - d_true[:4], axis=1))), 3
            ),
        }
    return {
        "session": str(folder.name),
        "detection_seconds": round(t1 - t0, 1),
        "solve_seconds": round(t2 - t1, 1),
        "rms_px": round(result.rms_px, 4),
        "outliers_rejected": result.outliers,
        "cameras": cams,
    }


def _summary(sessions: list[dict]) -> dict:
    cams = [c for s in sessions for c in s["cameras"].values()]
    worst = {
        "rms_px": max(s["rms_px"] for s in sessions),
        "focal_error_pct": max(max(abs(v) for v in c["focal_error_pct"]) for c in cams),
        "centre_error_mm": max(c["centre_error_mm"] for c in cams),
        "rotation_error_deg": max(c["rotation_error_deg"] for c in cams),
        "principal_point_error_px": max(
            max(abs(v) for v in c["principal_point_error_px"]) for c in cams
        ),
        "distortion_error_at_image_corners_px": max(
            c["distortion_error_at_image_corners_px"] for c in cams
        ),
    }
    median = {
        "focal_error_pct": float(np.median([abs(v) for c in cams for v in c["focal_error_pct"]])),
        "centre_error_mm": float(np.median([c["centre_error_mm"] for c in cams])),
        "rotation_error_deg": float(np.median([c["rotation_error_deg"] for c in cams])),
        "principal_point_error_px": float(
            np.median([abs(v) for c in cams for v in c["principal_point_error_px"]])
        ),
        "distortion_error_at_image_corners_px": float(
            np.median([c["distortion_error_at_image_corners_px"] for c in cams])
        ),
    }
    passed = {k: worst[k] < v for k, v in TARGETS.items()}
    return {"worst": worst, "median": median, "targets": TARGETS, "pass": passed}


SETUP = (
    "3 studio sessions (seeds 1-3), 4 cameras 640x480, 300-frame ChArUco clips (floor, pair "
    "views, close sweeps over each image), solved with the defaults of `bodymetry calibrate` "
    "(refined corners, k1 k2 p1 p2); no alignment to the truth"
)


def _seed(folder: Path) -> int | None:
    studio = StudioRecord.read(folder / "ground_truth")
    return None if studio is None else studio.config["seed"]


def run() -> dict:
    reuse = os.environ.get("BODYMETRY_BENCH_SESSIONS")
    if reuse:
        folders = [Path(p) for p in reuse.split(":") if p]
        sessions = [evaluate(f) | {"seed": _seed(f)} for f in folders]
        return {
            "setup": SETUP + f"; sessions rendered beforehand: {[str(f) for f in folders]}",
            "sessions": sessions,
            "summary": _summary(sessions),
        }
    sessions = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in SEEDS:
            folder = Path(tmp) / f"seed{seed}"
            synthesize(folder, SynthConfig(frames=2, seed=seed))
            sessions.append(evaluate(folder) | {"seed": seed})
    return {"setup": SETUP, "sessions": sessions, "summary": _summary(sessions)}
