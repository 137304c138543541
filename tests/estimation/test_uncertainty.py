"""The 95 % interval a run states (estimation/uncertainty.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from bodymetry.estimation.studio_accuracy import MeasuredAccuracy
from bodymetry.estimation.uncertainty import (
    COVERAGE,
    MEASURED_AMONG,
    MEASURED_COVERAGE,
    MEASURED_SESSIONS,
    stated_interval,
    stated_intervals,
)

RESULTS = Path(__file__).parents[2] / "benchmarks" / "results" / "studio_accuracy.json"


def _accuracy(rms: float, sessions: int) -> MeasuredAccuracy:
    return MeasuredAccuracy(rms=rms, worst=rms, bias=0.0, sessions=sessions)


def test_with_no_statistical_error_the_factor_is_student_t_of_the_studio_sessions():
    # u_A = 0: nu_eff = nu_B = n sessions, so the factor is t_0.975(n), known answers.
    for n, t in [(2, 4.3027), (4, 2.7764), (20, 2.0860)]:
        interval = stated_interval(100.0, 0.0, 16, _accuracy(3.0, n))
        assert interval.degrees_of_freedom == pytest.approx(n)
        assert interval.coverage_factor == pytest.approx(t, abs=1e-4)
        assert (interval.low, interval.high) == pytest.approx((100 - 3 * t, 100 + 3 * t), abs=1e-3)


def test_the_parts_add_in_quadrature_with_welch_satterthwaite_degrees_of_freedom():
    # Equal parts of equal degrees of freedom: u_c = sqrt(2) u, nu_eff = 2 nu.
    interval = stated_interval(5.0, 0.4, 11, _accuracy(0.4, 10))
    assert interval.standard_uncertainty == pytest.approx(0.4 * math.sqrt(2))
    assert interval.degrees_of_freedom == pytest.approx(20.0)
    assert interval.coverage_factor == pytest.approx(stats.t.ppf(0.975, 20))
    assert interval.half_width == pytest.approx(interval.coverage_factor * 0.4 * math.sqrt(2))
    # More like sessions narrow it; a larger standard error widens it.
    fewer = stated_interval(5.0, 0.4, 11, _accuracy(0.4, 3))
    larger = stated_interval(5.0, 0.8, 11, _accuracy(0.4, 10))
    assert fewer.half_width > interval.half_width < larger.half_width


def test_the_interval_is_symmetric_about_the_value_and_holds_its_ends():
    interval = stated_interval(1751.3, 0.7, 16, _accuracy(3.2, 14))
    assert interval.value - interval.low == pytest.approx(interval.high - interval.value)
    assert interval.contains(interval.low) and interval.contains(interval.high)
    assert interval.contains(1751.3) and not interval.contains(interval.high + 1e-6)
    # One frame: the classical covariance, not a sample's (no t for the statistical part).
    one = stated_interval(10.0, 1.0, 1, _accuracy(0.0, 5))
    assert one.coverage_factor == pytest.approx(stats.norm.ppf(0.975))
    record = interval.to_json()
    assert record["coverage"] == COVERAGE and record["studio_sessions"] == 14
    assert record["half_width"] == pytest.approx(interval.half_width, abs=1e-4)


def test_the_interval_holds_the_truth_95_times_in_100_where_its_model_holds():
    # Sessions' errors e ~ N(0, s); the studio's RMS over n of them: e / RMS is Student t
    # with n degrees of freedom, so the interval's coverage is 95 % whatever s and n.
    rng = np.random.default_rng(7)
    trials, n = 40_000, 4
    studio = rng.normal(0.0, 2.5, size=(trials, n))
    rms = np.sqrt((studio**2).mean(axis=1))
    error = rng.normal(0.0, 2.5, size=trials)
    k = stated_interval(0.0, 0.0, 16, _accuracy(1.0, n)).coverage_factor
    covered = np.abs(error) <= k * rms
    assert covered.mean() == pytest.approx(COVERAGE, abs=0.005)  # MC s.e. about 0.001


def test_no_interval_without_a_session_value_a_standard_error_or_like_bodies():
    accuracy = {"height_mm": _accuracy(3.0, 5), "weight_kg": _accuracy(0.8, 5)}
    values = {"height_mm": 1700.0, "arm_span_mm": 1650.0, "weight_kg": math.nan}
    errors = {"height_mm": 1.0, "arm_span_mm": 2.0, "weight_kg": 0.3}
    out = stated_intervals(values, errors, 12, accuracy)
    assert list(out) == ["height_mm"]  # no like arm span; no finite weight


@pytest.mark.parametrize(
    ("value", "standard_error"), [(math.nan, 1.0), (1.0, -0.1), (1.0, math.inf)]
)
def test_bad_inputs_are_refused_with_a_clear_error(value, standard_error):
    with pytest.raises(ValueError, match="stated_interval"):
        stated_interval(value, standard_error, 10, _accuracy(1.0, 5))


def test_the_coverage_the_report_quotes_is_the_committed_benchmark_s():
    leave_one_out = json.loads(RESULTS.read_text())["leave_one_out"]
    assert len(leave_one_out["sessions"]) == MEASURED_SESSIONS
    for key, share in MEASURED_COVERAGE.items():
        assert leave_one_out[key]["coverage"] == pytest.approx(share, abs=5e-4), key
    among = json.loads(RESULTS.read_text())["among_others"]
    for key, (inside, stated) in MEASURED_AMONG.items():
        assert (among[key]["truth_inside"], among[key]["intervals_stated"]) == (inside, stated)
