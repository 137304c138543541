"""The weight of the studio's skinned body in the kept poses, and the report on it."""

import json

import numpy as np
import pytest

from benchmarks import bench_arm_evidence, bench_rendered_weight
from benchmarks.bench_pipeline import rendered_weight
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, N_POSE, PARTS
from bodymetry.studio.independent import IndependentSpec, IndependentSubject

SPEC = IndependentSpec(0, body=7)


@pytest.fixture(scope="module")
def subject():
    return IndependentSubject(SPEC)


def _session(tmp_path, subject, thetas, skinning=None):
    """A session folder whose ground truth holds ``thetas`` (F, 37) at frames 0, 25, ...
    of the subject, and its truth (naming ``skinning``, as the studio does since
    2026-12-07; None: as it did before)."""
    (tmp_path / "ground_truth").mkdir()
    frames = 25 * np.arange(len(thetas))
    tau = np.tile([0.3, -0.2, 1.0], (len(thetas), 1))
    np.savez(tmp_path / "ground_truth" / "states.npz", frame=frames, tau=tau, theta=thetas)
    bio = subject.biometrics()
    details = {"subject": SPEC.to_text(), **({"skinning": skinning} if skinning else {})}
    return SubjectTruth({"weight_kg": bio.weight_kg, "volume_l": bio.volume_l}, details=details)


def _lbs(truth: SubjectTruth) -> SubjectTruth:
    """``truth`` as written before the studio named its skinning."""
    details = {k: v for k, v in truth.details.items() if k != "skinning"}
    return SubjectTruth(truth.measurements, truth.nu, truth.source, details)


def _bent() -> np.ndarray:
    """θ with both hips flexed and both knees bent (a crouch)."""
    theta = np.zeros(N_POSE)
    for side in "lr":
        hip = JOINT_SLICES[PARTS.index(f"thigh_{side}")]
        knee = JOINT_SLICES[PARTS.index(f"shin_{side}")]
        theta[hip.start] = -1.2
        theta[knee.start] = 1.5
    return theta


def test_a_rigid_motion_keeps_the_rest_weight(tmp_path, subject):
    yawed = np.zeros((2, N_POSE))
    yawed[1, JOINT_SLICES[0].start + 2] = 1.1
    truth = _session(tmp_path, subject, yawed)
    out = rendered_weight(tmp_path, [0, 25], truth)
    assert out["rest_kg"] == pytest.approx(truth.get("weight_kg"), abs=1e-3)
    # Skinning without bending is a rigid motion: no volume lost (rounding: 1 g).
    assert abs(out["loss_kg"]) <= 1e-3
    assert out["posed_low_kg"] <= out["posed_kg"] <= out["posed_high_kg"]


@pytest.mark.parametrize("recorded", [None, "linear_blend", "dual_quaternion"])
def test_the_kept_frames_poses_are_the_ones_weighed(tmp_path, subject, recorded):
    thetas = np.stack([np.zeros(N_POSE), _bent()])
    truth = _session(tmp_path, subject, thetas, recorded)
    tau = np.array([[0.3, -0.2, 1.0]])
    # A session that names no skinning was rendered before the studio's dual quaternions.
    bent = subject.skin(tau, thetas[1:], skinning=recorded or "linear_blend")[0]
    kg_per_m3 = truth.get("weight_kg") / truth.get("volume_l") * 1000.0
    expected = float(geometry.mesh_volume(bent, subject.bank.faces)[0]) * kg_per_m3
    only_bent = rendered_weight(tmp_path, [25], truth)
    assert only_bent["posed_kg"] == pytest.approx(expected, abs=1e-3)
    # The skinning changes the crouching body's volume, which the rest frame does not.
    assert abs(only_bent["loss_kg"]) > 0.05
    if recorded == "dual_quaternion":  # ... less than linear blending does
        linear = rendered_weight(tmp_path, [25], _lbs(truth))
        assert abs(only_bent["loss_kg"]) < abs(linear["loss_kg"])
    both = rendered_weight(tmp_path, [0, 25], truth)
    assert both["posed_low_kg"] == pytest.approx(min(expected, truth.get("weight_kg")), abs=1e-3)


def test_no_rendered_weight_without_an_independent_subject(tmp_path, subject):
    truth = _session(tmp_path, subject, np.zeros((1, N_POSE)))
    model_subject = SubjectTruth(truth.measurements, nu=(0.0,) * 12, details={"subject": "model"})
    assert rendered_weight(tmp_path, [0], model_subject) is None
    assert rendered_weight(tmp_path, [0], None) is None
    assert rendered_weight(tmp_path, [], truth) is None


def _record(name: str, actual: float, session: float, loss: float) -> dict:
    return {
        "session": f"/nowhere/{name}",
        "figure3": {"weight_kg": {"actual": actual, "session": {"mean": session}}},
        "rendered_weight": {"loss_kg": loss},
    }


def test_the_report_gives_both_errors_with_known_answers(tmp_path, monkeypatch):
    records = [
        _record("light", 50.0, 51.0, -1.0),  # +1 against rest, +2 against rendered
        _record("heavy", 100.0, 99.0, 0.0),  # -1 against both
        _record("lost", 70.0, 70.0, -0.5),  # 0 against rest, +0.5 against rendered
    ]
    no_session = {"session": "/nowhere/x", "figure3": {"weight_kg": {"actual": 1.0}}}
    (tmp_path / "pipeline_recheck.json").write_text(
        json.dumps({"sessions": [*records, no_session]})
    )
    monkeypatch.setattr(bench_arm_evidence, "RESULTS", tmp_path)
    out = bench_rendered_weight.run()
    assert [r["session"] for r in out["sessions"]] == ["light", "heavy", "lost"]
    assert out["against_rest"]["mean_kg"] == pytest.approx(0.0, abs=1e-9)
    assert out["against_rendered"]["mean_kg"] == pytest.approx(1.5 / 3, abs=0.005)
    assert out["against_rest"]["mean_abs_kg"] == pytest.approx(2 / 3, abs=0.005)
    assert out["against_rendered"]["within_target"] == pytest.approx(2 / 3, abs=0.001)
    assert out["loss_kg"] == {"mean": -0.5, "low": -1.0, "high": 0.0}
    # Lighter bodies read heavier here: a negative correlation with body weight.
    assert out["against_rest"]["correlation_with_weight"] < -0.9
