"""The arm span's error by its evidence: ``python -m benchmarks arm_evidence``.

Reads the committed end-to-end results (no rendering, no fitting): issue 15's
eleven evaluated again (``pipeline_recheck.json``), the edge, looks and unseen
edge sets, and the checks rendered after the caveat (``pipeline_arms.json``,
``pipeline_weight.json``, when present), and splits
their sessions by how many measured frames had an arm raised
(``arm_raised_frames``, :func:`bodymetry.estimation.arm_evidence.raised_frames`):
fewer than :data:`~bodymetry.estimation.arm_evidence.MIN_RAISED_FRAMES` is
"arms down", the ``arms_down`` caveat's condition. Per group: the sessions, the
session stage's arm span error (mean, smallest, largest, RMS, the share within
issue 15's 15 mm) and the sessions' names with their errors.

:func:`bodymetry.estimation.caveats.arms_down_studio`, which the caveat quotes,
reads the "arms down" sessions of every scored studio session instead (the
shipped ``estimation/data/studio_sessions.json`` of ``python -m benchmarks
studio_accuracy``, which holds these sets and more); this benchmark keeps the
split of the four sets the caveat was written on (``CAVEAT_SETS``) and its check.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bodymetry.estimation.arm_evidence import MIN_RAISED_FRAMES, arms_raised

RESULTS = Path(__file__).with_name("results")
#: The results the caveat's figures come from (the caveat was written on them).
CAVEAT_SETS = (
    "pipeline_recheck.json",
    "pipeline_edge.json",
    "pipeline_looks.json",
    "pipeline_edge_unseen.json",
)
#: Rendered after the caveat was written (``pipeline --arms``, ``--weight``,
#: ``--edge-fresh``, ``--edge-fourth``, ``--children-fresh``): its check.
CHECK_SETS = (
    "pipeline_arms.json",
    "pipeline_weight.json",
    "pipeline_edge_fresh.json",
    "pipeline_edge_fourth.json",
    "pipeline_children_fresh.json",
)
#: Issue 15's arm span target for the session stage, mm.
TARGET_MM = 15.0


def _arm_error(session: dict) -> float | None:
    """The session stage's arm span error (mm), or None without a session value."""
    row = session["figure3"]["arm_span_mm"]
    return None if "session" not in row else float(row["session"]["mean"] - row["actual"])


def arm_span_by_evidence(sessions: list[dict]) -> dict:
    """Sessions split by their arm evidence, with the arm span error of each group.

    Parameters
    ----------
    sessions : list of dict
        ``bench_pipeline.evaluate_session`` records with ``arm_raised_frames``
        (records without it, or without a session stage value, are left out).

    Returns
    -------
    dict
        ``arms_down`` and ``arms_raised``: ``sessions`` (count), ``mean_mm``,
        ``low_mm``, ``high_mm``, ``rms_mm``, ``within_target`` (share within
        :data:`TARGET_MM`) and ``errors`` (session name -> error, mm).
    """
    groups: dict[str, dict[str, float]] = {"arms_down": {}, "arms_raised": {}}
    for s in sessions:
        err = _arm_error(s)
        if err is None or "arm_raised_frames" not in s:
            continue
        down = not arms_raised(s["arm_raised_frames"])
        groups["arms_down" if down else "arms_raised"][Path(s["session"]).name] = round(err, 2)
    out = {}
    for name, errors in groups.items():
        e = np.array(list(errors.values()))
        out[name] = {
            "sessions": len(e),
            **(
                {
                    "mean_mm": round(float(e.mean()), 1),
                    "low_mm": round(float(e.min()), 1),
                    "high_mm": round(float(e.max()), 1),
                    "rms_mm": round(float(np.sqrt(np.mean(e**2))), 1),
                    "within_target": round(float(np.mean(np.abs(e) <= TARGET_MM)), 3),
                }
                if len(e)
                else {}
            ),
            "errors": errors,
        }
    return out


def committed_sessions(names: tuple[str, ...]) -> list[dict]:
    """The session records of the committed results files ``names`` (those present)."""
    out = []
    for name in names:
        path = RESULTS / name
        if path.is_file():
            out += json.loads(path.read_text())["sessions"]
    return out


def run() -> dict:
    caveat = committed_sessions(CAVEAT_SETS)
    check = committed_sessions(CHECK_SETS)
    return {
        "setup": (
            f"committed results, sessions split by measured frames with an arm raised "
            f"(< {MIN_RAISED_FRAMES}: arms down); the caveat's sets {list(CAVEAT_SETS)}, "
            f"its check {list(CHECK_SETS)}"
        ),
        "caveat_sets": arm_span_by_evidence(caveat),
        "check_sets": arm_span_by_evidence(check),
    }
