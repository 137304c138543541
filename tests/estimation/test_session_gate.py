"""The session's quality gate: unchanged where good frames reach min_iou, relative to
the session's good frames where a real person cannot, never below the floor."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyState
from bodymetry.estimation.fit import FitConfig, session_gate
from bodymetry.estimation.records import FrameRecord, StageEstimate


def _records(ious: list[float]) -> list[FrameRecord]:
    state = BodyState.rest()
    est = {s: StageEstimate(state, {"height_mm": 1800.0}) for s in ("discriminative", "generative")}
    return [
        FrameRecord(i, "ok", estimates=est, silhouette_iou={"a": v, "b": v})
        for i, v in enumerate(ious)
    ]


def test_studio_session_keeps_min_iou():
    gate, out = session_gate(_records([0.95, 0.94, 0.93, 0.85, 0.96, 0.89]), FitConfig())
    assert gate.threshold == pytest.approx(0.9)
    assert [r.ok for r in out] == [True, True, True, False, True, False]
    assert out[3].status == "poor fit: mean silhouette IoU 0.85 < 0.90"


def test_real_session_is_held_to_its_good_frames():
    ious = [0.83, 0.84, 0.85, 0.82, 0.84, 0.79]
    gate, out = session_gate(_records(ious), FitConfig())
    p75 = np.percentile(ious, 75)
    assert gate.reference == pytest.approx(p75)
    assert gate.threshold == pytest.approx(p75 - 0.03)
    assert [r.ok for r in out] == [True, True, True, True, True, False]
    # The order of the frames does not matter.
    again, _ = session_gate(_records(ious[::-1]), FitConfig())
    assert again.threshold == pytest.approx(gate.threshold)


def test_the_floor_holds_for_a_session_of_bad_fits():
    gate, out = session_gate(_records([0.6, 0.62, 0.65]), FitConfig())
    assert gate.threshold == pytest.approx(0.8)
    assert not any(r.ok for r in out)


def test_unfitted_frames_keep_their_status():
    failed = FrameRecord(7, "no silhouette in any camera")
    gate, out = session_gate([failed], FitConfig())
    assert gate.reference is None and gate.threshold == 0.9
    assert out == [failed]
    with pytest.raises(ValueError, match="gate_floor"):
        FitConfig(gate_floor=1.2)


def test_a_gate_below_the_floor_is_kept():
    # min_iou under gate_floor: the configured gate stands (it is the lower one).
    gate, out = session_gate(_records([0.6, 0.55, 0.7]), FitConfig(min_iou=0.5))
    assert gate.threshold == pytest.approx(0.5)
    assert all(r.ok for r in out)
