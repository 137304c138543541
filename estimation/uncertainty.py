"""The uncertainty a run states for each measurement: a 95 % interval (issue 33).

Two errors apply to a session value, and neither alone says how far it may lie
from the truth:

* the session stage's **standard error** ``u_A`` (:mod:`~bodymetry.estimation.
  session_shape`): statistical, how well the frames agree and how far the stage's
  descents spread; it knows nothing of what every frame shares;
* the **studio's error on sessions of bodies like this one** (the RMS ``u_B`` over
  ``n`` sessions, :func:`~bodymetry.estimation.studio_accuracy.like_accuracy`):
  what the frames share (the body model's shape space and posing, the
  segmentation), measured against the truth on bodies the model was not built
  from. Its bias is part of the RMS, so an interval from it does not claim a
  bias was corrected: none was.

They are combined as the GUM combines a statistical (type A) and another (type B)
standard uncertainty (JCGM 100:2008, 5.1.2 and annex G)::

    u_c   = sqrt(u_A² + u_B²)
    ν_eff = u_c⁴ / (u_A⁴ / ν_A + u_B⁴ / ν_B)     (Welch-Satterthwaite)
    U     = t_{0.975}(ν_eff) · u_c                 interval: value ± U

with ``ν_A = frames - 1`` (the frames are the clusters of the stage's
covariance) and ``ν_B = n`` (an RMS about zero over ``n`` sessions). Few like
sessions make ``ν_eff`` small and the coverage factor large: two sessions of a
like body say less than twenty. The studio's RMS already holds those sessions'
own statistical errors, so adding the run's counts part of it twice: the
interval errs wide for that, never narrow.

Whether 95 % of the truths fall inside is measured, not assumed: ``python -m
benchmarks studio_accuracy`` states every scored session's interval from the
other sessions alone (leave one out) and counts how often the truth lay inside
(docs/outputs.md, "The 95 % interval").

No interval is stated where the studio scored fewer than
:data:`~bodymetry.estimation.studio_accuracy.MIN_LIKE` sessions of a like body
(the ``outside_validated`` caveat), nor for a value without a standard error (a
per-frame mean where the session stage gave none): nothing measured its error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from scipy import stats

from bodymetry.estimation.studio_accuracy import MeasuredAccuracy

__all__ = [
    "COVERAGE",
    "MEASURED_AMONG",
    "MEASURED_COVERAGE",
    "MEASURED_SESSIONS",
    "StatedInterval",
    "stated_interval",
    "stated_intervals",
]

#: The probability the stated interval is meant to hold the truth with.
COVERAGE = 0.95

#: How often it did: per core measurement, the share of the studio's scored sessions
#: whose truth lay inside the interval each would have stated from the other sessions
#: alone (``python -m benchmarks studio_accuracy``, ``leave_one_out``; 118 sessions,
#: 2026-12-08, the edge bodies' fourth draw, the fresh children, ten more sessions in
#: neutral clothing, the eleven tight ones of ``--loose-gaps`` and ``--tight-night`` and
#: the seven tight subjects in shorts of ``--shorts`` included).
#: ``tests/estimation/test_uncertainty.py`` reads them back from
#: ``benchmarks/results/studio_accuracy.json``, so they cannot drift from what was measured.
MEASURED_COVERAGE: Mapping[str, float] = {
    "height_mm": 0.949,
    "arm_span_mm": 0.958,
    "weight_kg": 0.983,
}
#: ... over this many sessions.
MEASURED_SESSIONS = 118
#: A person measured among others: per core measurement, of the studio's two-person
#: sessions' persons each given the interval it would have stated from the others (and
#: every single-person session), how many held the truth, of how many stated
#: (``studio_accuracy.json``, ``among_others``; 2026-12-08, 29 persons; the test reads
#: them back).
MEASURED_AMONG: Mapping[str, tuple[int, int]] = {
    "height_mm": (29, 29),
    "arm_span_mm": (27, 29),
    "weight_kg": (28, 29),
}


@dataclass(frozen=True)
class StatedInterval:
    """One measurement's stated interval: ``value ± coverage_factor · standard_uncertainty``.

    Attributes
    ----------
    value : float
        The session value (mm or kg).
    standard_uncertainty : float
        ``u_c``, the standard error and the studio's RMS on like bodies combined.
    degrees_of_freedom : float
        ``ν_eff`` (Welch-Satterthwaite; infinite when both parts are).
    coverage_factor : float
        ``t`` at :data:`COVERAGE` (two-sided) for ``ν_eff``.
    low, high : float
        The interval's ends.
    studio_sessions : int
        How many studio sessions the type-B part came from.
    """

    value: float
    standard_uncertainty: float
    degrees_of_freedom: float
    coverage_factor: float
    low: float
    high: float
    studio_sessions: int

    @property
    def half_width(self) -> float:
        """``U``, the expanded uncertainty."""
        return self.coverage_factor * self.standard_uncertainty

    def contains(self, truth: float) -> bool:
        """Whether ``truth`` lies within the interval (ends included)."""
        return self.low <= truth <= self.high

    def to_json(self) -> dict:
        """For ``results.json`` (4 decimals; an infinite ν_eff as null)."""
        out = {**self.__dict__, "half_width": self.half_width, "coverage": COVERAGE}
        return {
            k: (round(v, 4) if math.isfinite(v) else None) if isinstance(v, float) else v
            for k, v in out.items()
        }


def stated_interval(
    value: float, standard_error: float, frames: int, accuracy: MeasuredAccuracy
) -> StatedInterval:
    """The 95 % interval of a session value (the module's equations).

    Parameters
    ----------
    value : float
        The session stage's value.
    standard_error : float
        Its standard error (``u_A``, >= 0).
    frames : int
        How many frames the session stage used (``ν_A = frames - 1``; with one
        frame the statistical part's degrees of freedom are taken as infinite:
        the stage then states the classical covariance, not a sample's).
    accuracy : MeasuredAccuracy
        The studio's error on sessions of like bodies (``u_B`` its RMS, ``ν_B``
        its session count).

    Raises
    ------
    ValueError
        For a non-finite value or a negative or non-finite standard error.
    """
    if not math.isfinite(value):
        raise ValueError(f"stated_interval: value must be finite, got {value}")
    if not (math.isfinite(standard_error) and standard_error >= 0):
        raise ValueError(f"stated_interval: standard_error must be >= 0, got {standard_error}")
    u_a, u_b = float(standard_error), float(accuracy.rms)
    u_c = math.hypot(u_a, u_b)
    nu_a = frames - 1 if frames >= 2 else math.inf
    nu_b = max(accuracy.sessions, 1)
    denominator = u_a**4 / nu_a + u_b**4 / nu_b
    nu = u_c**4 / denominator if denominator > 0 else math.inf
    k = float(stats.t.ppf(0.5 + COVERAGE / 2, nu))  # infinite nu: the normal quantile
    return StatedInterval(
        value=float(value),
        standard_uncertainty=u_c,
        degrees_of_freedom=nu,
        coverage_factor=k,
        low=value - k * u_c,
        high=value + k * u_c,
        studio_sessions=int(accuracy.sessions),
    )


def stated_intervals(
    values: Mapping[str, float],
    standard_errors: Mapping[str, float],
    frames: int,
    accuracy: Mapping[str, MeasuredAccuracy],
) -> dict[str, StatedInterval]:
    """Per measurement with a session value, a standard error and the studio's
    accuracy on like bodies, its :func:`stated_interval` (the others get none)."""
    out = {}
    for key, acc in accuracy.items():
        value, se = values.get(key), standard_errors.get(key)
        if value is None or se is None or not math.isfinite(value) or not math.isfinite(se):
            continue
        out[key] = stated_interval(value, se, frames, acc)
    return out
