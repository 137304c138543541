"""The arm span's error by its evidence (benchmarks/bench_arm_evidence.py)."""

from __future__ import annotations

import pytest

from benchmarks.bench_arm_evidence import arm_span_by_evidence
from benchmarks.bench_pipeline import session_name


def _session(name: str, raised: list[int] | None, error: float | None) -> dict:
    row = {"actual": 1500.0}
    if error is not None:
        row["session"] = {"mean": 1500.0 + error}
    out = {"session": f"/renders/{name}", "figure3": {"arm_span_mm": row}}
    if raised is not None:
        out["arm_raised_frames"] = raised
    return out


def test_sessions_split_at_three_frames_with_an_arm_raised():
    sessions = [
        _session("a", [], 20.0),
        _session("b", [25, 50], 10.0),
        _session("c", [0, 25, 50], -4.0),
        _session("d", [0, 25, 50, 75], 2.0),
        _session("old", None, 99.0),  # a record from before the field: not judged
        _session("no_session_stage", [], None),
    ]
    out = arm_span_by_evidence(sessions)
    down, raised = out["arms_down"], out["arms_raised"]
    assert down["errors"] == {"a": 20.0, "b": 10.0}
    assert raised["errors"] == {"c": -4.0, "d": 2.0}
    assert (down["sessions"], down["mean_mm"], down["low_mm"], down["high_mm"]) == (
        2,
        15.0,
        10.0,
        20.0,
    )
    assert down["rms_mm"] == pytest.approx((250.0) ** 0.5, abs=0.05)
    assert down["within_target"] == 0.5 and raised["within_target"] == 1.0
    assert arm_span_by_evidence([])["arms_down"] == {"sessions": 0, "errors": {}}


def test_session_names_say_seed_motion_and_subject():
    assert session_name(371, "walk_turn", "independent:371") == "seed371_walk_turn_371"
    assert (
        session_name(374, "walk_turn", "independent:374,edge=girl_age14")
        == "seed374_walk_turn_374_edge-girl_age14"
    )
