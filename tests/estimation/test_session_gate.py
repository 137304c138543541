"""The session's quality gate: unchanged where good frames reach min_iou, relative to
the session's good frames where a real person cannot, never below the floor."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import BodyState
from bodymetry.estimation.fit import (
    MAX_WIDTH_SCALE,
    REFERENCE_WIDTH_M,
    FitConfig,
    poor_fit_hint,
    session_gate,
    shared_body_model,
    width_scale,
)
from bodymetry.estimation.records import FrameRecord, SessionGate, StageEstimate


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


def _sized(ious: list[float], height_mm: float, volume_l: float) -> list[FrameRecord]:
    state = BodyState.rest()
    bios = {"height_mm": height_mm, "volume_l": volume_l}
    est = {s: StageEstimate(state, bios) for s in ("discriminative", "generative")}
    return [
        FrameRecord(i, "ok", estimates=est, silhouette_iou={"a": v, "b": v})
        for i, v in enumerate(ious)
    ]


def test_the_reference_width_is_the_mean_adults():
    body = shared_body_model()
    mean = measure(body, np.zeros((1, body.n_shape)))[0].to_dict()
    width = np.sqrt(mean["volume_l"] / mean["height_mm"])  # l/mm = m³/m
    assert width == pytest.approx(REFERENCE_WIDTH_M, abs=0.001)


def test_a_slim_or_small_body_widens_the_gates_deficits():
    # Known answers: the mean adult keeps the gate; a 10-year-old (1377 mm, 31.4 l) is
    # W = sqrt(0.0314 / 1.377) = 0.151 m wide, s = 0.199 / 0.151 = 1.318, so the gate
    # is 1 - 1.318 * 0.1 = 0.868: a right pose at 0.897 counts, a wrong one at 0.85 not.
    ious = [0.94, 0.946, 0.934, 0.93, 0.897, 0.85]
    adult, out = session_gate(_sized(ious, 1689.0, 66.7), FitConfig())
    assert adult.width_scale == pytest.approx(1.0, abs=2e-3)
    assert adult.threshold == pytest.approx(0.9, abs=2e-4)
    assert [r.ok for r in out] == [True, True, True, True, False, False]
    child, out = session_gate(_sized(ious, 1377.0, 31.4), FitConfig())
    assert child.width_scale == pytest.approx(0.199 / np.sqrt(0.0314 / 1.377), rel=1e-6)
    assert child.threshold == pytest.approx(1 - child.width_scale * 0.1)
    assert [r.ok for r in out] == [True, True, True, True, True, False]
    # Broader than the reference: never stricter than configured. Tiny: capped.
    broad, _ = session_gate(_sized(ious, 1750.0, 110.0), FitConfig())
    assert broad.width_scale == 1.0 and broad.threshold == 0.9
    assert width_scale(_sized(ious, 1000.0, 10.0)) == MAX_WIDTH_SCALE
    # The relative gate's margin widens too (real footage of a child).
    real = [0.86, 0.87, 0.85, 0.88, 0.80]
    gate, _ = session_gate(_sized(real, 1377.0, 31.4), FitConfig())
    p75 = np.percentile(real, 75)
    assert gate.threshold == pytest.approx(p75 - gate.width_scale * 0.03)


def test_the_gate_round_trips_and_old_gates_read_with_no_widening():
    gate, _ = session_gate(_sized([0.95, 0.9], 1377.0, 31.4), FitConfig())
    data = gate.to_json()
    back = SessionGate.from_json(data)
    assert back.width_scale == pytest.approx(gate.width_scale, abs=1e-4)
    del data["width_scale"]
    assert SessionGate.from_json(data).width_scale == 1.0


def test_the_gate_says_whether_the_frames_or_the_widened_min_iou_set_it():
    studio = [0.94, 0.946, 0.934, 0.93, 0.897, 0.85]
    real = [0.86, 0.87, 0.85, 0.88, 0.80]
    for height, volume in ((1689.0, 66.7), (1377.0, 31.4)):
        assert not session_gate(_sized(studio, height, volume), FitConfig())[0].follows_frames
        assert session_gate(_sized(real, height, volume), FitConfig())[0].follows_frames
    assert not SessionGate(0.9, 0.9, None).follows_frames


def test_every_frame_a_poor_fit_gets_a_hint_and_only_then():
    """The studio's long skirts: every frame fitted, none well. The hint names the best
    frame's mean IoU and what can cause it; a run with a good frame, or frames lost for
    another reason, gets none."""
    _, out = session_gate(_records([0.62, 0.70, 0.66, 0.64]), FitConfig())
    assert not any(r.ok for r in out)
    hint = poor_fit_hint(out)
    assert hint.startswith("the body model fitted no frame's silhouettes well")
    assert "(the best frame's mean IoU 0.70)" in hint and "a long skirt or coat" in hint
    _, some = session_gate(_records([0.95, 0.62, 0.70]), FitConfig())
    assert poor_fit_hint(some) == ""
    assert poor_fit_hint([*out[:2], FrameRecord(9, "no silhouette in any camera")]) == ""
    assert poor_fit_hint([]) == ""
