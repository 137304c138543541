"""The weight against the volume the studio rendered: ``python -m benchmarks rendered_weight``.

The studio's independent subjects were posed by linear blend skinning until
2026-12-07, which does not keep a body's volume: where joints bend the skin folds
into itself (up to 3 L with the arms overhead). Since then they are posed by dual
quaternion skinning (``estimation/body_model/skinning.py``), which keeps it within about half a
litre; each session is weighed the way it was rendered
(:func:`benchmarks.bench_pipeline.rendered_weight`). The
silhouettes show those posed bodies, and the pipeline reads the weight from its
own posed bodies (``estimation/posed_weight.py``), which is right for a real
person, whose volume does not change when they move. Against the studio's truth
(the rest body's weight) the skinning's loss therefore reads as the pipeline's
own error, and the pipeline's own bias is hidden wherever the two cancel.

This report reads the committed end-to-end results the studio's accuracy is
scored on (:data:`benchmarks.bench_studio_accuracy.SETS`; no fitting) and, per
session, the weight of the skinned nude body in the measured frames' true poses
(:func:`benchmarks.bench_pipeline.rendered_weight`: the record's
``rendered_weight`` when it has one, otherwise computed from the rendered
session's ``ground_truth``, looked up at the recorded path or by name in the
folders of ``BODYMETRY_BENCH_RENDER_DIRS``, colon-separated; sessions found
nowhere are counted and left out). It gives the session stage's weight error
against both, per session and over all (mean, mean absolute, RMS, the share
within issue 15's 1.5 kg), and the correlation of each error with the body's
weight (the "heavy bodies read light" pattern). The truth is in between: a real
person keeps the rest body's volume, but the skinning's loss lies partly in
folds no silhouette shows.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from benchmarks.bench_arm_evidence import committed_sessions
from benchmarks.bench_pipeline import _outfit, rendered_weight
from benchmarks.bench_studio_accuracy import SETS
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.capture.session import load_session
from bodymetry.fileio import load_npz

#: Issue 15's weight target for the session stage, kg.
TARGET_KG = 1.5


def _session_folder(recorded: str) -> Path | None:
    """The rendered session at its recorded path, or by name in the render folders."""
    path = Path(recorded)
    if (path / "ground_truth").is_dir():
        return path
    for root in filter(None, os.environ.get("BODYMETRY_BENCH_RENDER_DIRS", "").split(":")):
        if (Path(root) / path.name / "ground_truth").is_dir():
            return Path(root) / path.name
    return None


def _rendered(record: dict) -> dict | None:
    """The record's rendered weight, or computed from its render (None: not found)."""
    if record.get("rendered_weight"):
        return record["rendered_weight"]
    folder = _session_folder(record["session"])
    if folder is None:
        return None
    left_out = {int(f) for f in record.get("left_out", {})}
    frames = [f for f in _kept_frames(folder) if f not in left_out]
    return rendered_weight(folder, frames, SubjectTruth.read(folder / "ground_truth"))


def _kept_frames(folder: Path) -> list[int]:
    """The frames the pipeline keeps of a rendered session (the session's frame step
    over the rendered frames)."""
    rendered = load_npz(folder / "ground_truth" / "states.npz")["frame"]
    return load_session(folder).kept_frames(len(rendered)).tolist()


def _summary(errors: np.ndarray, weights: np.ndarray) -> dict:
    return {
        "mean_kg": round(float(errors.mean()), 2),
        "mean_abs_kg": round(float(np.abs(errors).mean()), 2),
        "rms_kg": round(float(np.sqrt(np.mean(errors**2))), 2),
        "within_target": round(float(np.mean(np.abs(errors) <= TARGET_KG)), 3),
        "correlation_with_weight": round(float(np.corrcoef(errors, weights)[0, 1]), 2),
    }


def run() -> dict:
    rows, missing = [], []
    for name in SETS:
        for record in committed_sessions((name,)):
            row = record["figure3"]["weight_kg"]
            folder = Path(record["session"]).name
            # Tight clothing only, as the scored sessions: loose clothes are issue 31's.
            if "session" not in row or _outfit(record.get("subject") or folder) != "tight":
                continue
            rendered = _rendered(record)
            if rendered is None:
                missing.append(Path(record["session"]).name)
                continue
            error = row["session"]["mean"] - row["actual"]
            rows.append(
                {
                    "set": name.removesuffix(".json"),
                    "session": Path(record["session"]).name,
                    "weight_kg": round(row["actual"], 2),
                    "loss_kg": rendered["loss_kg"],
                    "error_rest_kg": round(error, 2),
                    "error_rendered_kg": round(error - rendered["loss_kg"], 2),
                }
            )
    weights = np.array([r["weight_kg"] for r in rows])
    loss = np.array([r["loss_kg"] for r in rows])
    return {
        "setup": (
            f"committed results {list(SETS)} (those present); the skinned nude body's "
            "volume in the measured frames' true poses (median) times the truth's density"
        ),
        "sessions": rows,
        "not_found": missing,
        "loss_kg": {
            "mean": round(float(loss.mean()), 2),
            "low": round(float(loss.min()), 2),
            "high": round(float(loss.max()), 2),
        },
        "against_rest": _summary(np.array([r["error_rest_kg"] for r in rows]), weights),
        "against_rendered": _summary(np.array([r["error_rendered_kg"] for r in rows]), weights),
    }
