"""Studio: rendering speed, silhouette ground-truth fidelity and cast shadows.

Targets (issue 3): a 200-frame 4-camera session renders in under 2 minutes;
ground-truth silhouettes agree with the rendered person (IoU >= 0.99 against a
mask recomputed from the clean rendered frame: the frame before noise and
compression, differenced against the clean empty scene); cast shadows are
present in every camera (shadow area as a fraction of the person's area).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bodymetry.capture.ground_truth import StudioRecord
from bodymetry.capture.session import load_session
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.fileio import load_npz
from bodymetry.studio.render import Studio
from bodymetry.studio.synth import SynthConfig, synthesize

#: A pixel differs from the empty scene when some channel changes by more than this (DN).
DIFF_THRESHOLD = 4


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def silhouette_fidelity(folder: Path) -> dict:
    """IoU of each kept frame's ground-truth silhouette against a recomputed mask."""
    session = load_session(folder)
    states = load_npz(folder / "ground_truth" / "states.npz")
    model = BodyModel.load(n_shape=len(states["nu"]))
    # Same geometry, no shadow (a shadow also differs from the empty scene).
    studio = Studio.from_model(model, shadows=False)
    kept = session.kept_frames(len(states["frame"]))
    out = {}
    for cam in session.calibration():
        background = studio.render_background(cam, effects=False).astype(int)
        ious = []
        for frame in kept:
            state = BodyState(states["tau"][frame], states["theta"][frame], states["nu"][None])
            clean = studio.render_frame(cam, model.pose(state).vertices[0], effects=False).image
            recomputed = np.abs(clean.astype(int) - background).max(axis=2) > DIFF_THRESHOLD
            truth = (
                cv2.imread(str(session.ground_truth_silhouette_path(cam.name, int(frame))), 0) > 0
            )
            ious.append(_iou(truth, recomputed))
        out[cam.name] = {
            "iou_mean": float(np.mean(ious)),
            "iou_min": float(np.min(ious)),
            "frames": len(ious),
        }
    return out


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "bench"
        t0 = time.perf_counter()
        synthesize(folder, SynthConfig(frames=200, seed=11))
        seconds = time.perf_counter() - t0
        studio = StudioRecord.read(folder / "ground_truth").to_json()
        size_mb = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
        result = {
            "session": "200 frames, 4 cameras, 640x480, + 30 background and 300 "
            "calibration frames per camera",
            "render_seconds": round(seconds, 1),
            "target_seconds": 120,
            "session_megabytes": round(size_mb, 2),
            "shadow_to_person_area_mean": studio["shadow_to_person_area_mean"],
            "silhouette_iou_vs_recomputed": silhouette_fidelity(folder),
            "target_iou": 0.99,
        }
    return result
