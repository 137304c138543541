"""Damped least squares: the damping schedule and the two damped normal matrices."""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.least_squares import Damping, damped_inverse, damped_step, marquardt


def test_damped_step_raises_damping_until_a_step_lowers_the_cost():
    tried = []

    def propose(lam):
        tried.append(lam)
        return (12.0 if len(tried) < 3 else 7.0), f"step at {lam:g}"

    damping = Damping()
    payload, cost, improved = damped_step(propose, 10.0, damping, tolerance=1e-4)
    np.testing.assert_allclose(tried, [1e-2, 4e-2, 16e-2], rtol=1e-15)
    assert payload == "step at 0.16" and cost == 7.0 and improved
    np.testing.assert_allclose(damping.lam, 0.16 / 3, rtol=1e-15)
    # A decrease below the tolerance is taken but ends the descent.
    payload, cost, improved = damped_step(lambda lam: (6.99999, "tiny"), 7.0, damping, 1e-4)
    assert payload == "tiny" and cost == 6.99999 and not improved


def test_damped_step_gives_up_after_its_retries_or_past_max_lambda():
    worse = lambda lam: (11.0, "worse")  # noqa: E731
    damping = Damping(1.0)
    assert damped_step(worse, 10.0, damping, 1e-4, retries=5) == (None, 10.0, False)
    assert damping.lam == 4.0**5
    damping = Damping(1.0)
    assert damped_step(worse, 10.0, damping, 1e-4, max_lam=100.0) == (None, 10.0, False)
    assert damping.lam == 256.0  # tried at 1, 4, 16, 64; 256 is past the limit
    # Never below 1e-6 after a success.
    damping = Damping(1e-6)
    damped_step(lambda lam: (1.0, None), 10.0, damping, 1e-4)
    assert damping.lam == 1e-6


def test_marquardt_and_damped_inverse_keep_their_own_floors():
    """marquardt scales its 1e-9 floor by λ; damped_inverse adds its floor at any λ."""
    A = np.array([[4.0, 1.0], [1.0, 2.0]])
    assert np.array_equal(marquardt(A, 0.0), A)
    np.testing.assert_array_equal(marquardt(A, 0.5), A + 0.5 * np.diag(np.diag(A) + 1e-9))
    eps = 1e-9 + 1e-9 * np.trace(A) / 2
    np.testing.assert_array_equal(damped_inverse(A, 0.0), np.linalg.inv(A + eps * np.eye(2)))
    singular = np.zeros((3, 3))
    assert np.all(np.isfinite(damped_inverse(singular, 0.0)))
