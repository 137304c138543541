"""Mixture of experts (paper §4): EM, known answers, degenerate data, round trips."""

from __future__ import annotations

import numpy as np
import pytest
from moe_reference import reference_fit_moe

from bodymetry.estimation.moe import MixtureOfExperts, fit_moe, select_moe

#: Known-answer tolerance on a noise-free-ish piecewise-linear function (output units).
PIECEWISE_RMSE = 0.05
#: EM may stall by round-off only.
EM_MONOTONE_TOL = 1e-9


def piecewise(n: int, rng: np.random.Generator, noise: float = 0.02):
    x = rng.uniform(-3, 3, (n, 1))
    X = np.hstack([x, rng.normal(0, 1, (n, 3))])  # three irrelevant inputs
    y = np.where(x < 0, 2 * x + 1, -x + 1)
    Y = np.hstack([y, 0.5 * y]) + rng.normal(0, noise, (n, 2))
    return X, Y


def test_em_increases_the_objective_every_iteration():
    X, Y = piecewise(600, np.random.default_rng(0))
    for M in (1, 2, 3, 5):
        fit = fit_moe(X, Y, M, 1.0, np.random.default_rng(1), max_iter=40, tol=0)
        assert np.all(np.diff(fit.history) >= -EM_MONOTONE_TOL), M


def test_recovers_a_known_piecewise_linear_function():
    X, Y = piecewise(1500, np.random.default_rng(2))
    model = fit_moe(X, Y, 2, 0.1, np.random.default_rng(0)).model
    xt = np.linspace(-2.5, 2.5, 41)[:, None]
    Xt = np.hstack([xt, np.zeros((41, 3))])
    yt = np.where(xt < 0, 2 * xt + 1, -xt + 1)
    truth = np.hstack([yt, 0.5 * yt])
    keep = np.abs(xt[:, 0]) > 0.2  # the gates blend near the kink
    rmse = np.sqrt(np.mean((model.predict(Xt, mode="gate")[keep] - truth[keep]) ** 2))
    assert rmse < PIECEWISE_RMSE
    # One linear expert cannot represent it.
    single = fit_moe(X, Y, 1, 0.1, np.random.default_rng(0)).model
    assert np.sqrt(np.mean((single.predict(Xt)[keep] - truth[keep]) ** 2)) > 10 * PIECEWISE_RMSE


def test_selection_prefers_several_experts_for_piecewise_data():
    rng = np.random.default_rng(3)
    X, Y = piecewise(800, rng)
    Xv, Yv = piecewise(300, rng)
    sel = select_moe(X, Y, Xv, Yv, experts=(1, 2, 4), ridges=(0.1, 100.0))
    assert sel.n_experts >= 2
    assert len(sel.table) == 6
    assert all(np.isfinite(row["val_loglik"]) for row in sel.table)


def test_early_stop_in_m_keeps_the_full_grids_choice():
    """Held-out likelihood peaks at M = 2 on two linear pieces: the search stops at M = 4."""
    rng = np.random.default_rng(3)
    X, Y = piecewise(800, rng)
    Xv, Yv = piecewise(300, rng)
    grid = {"experts": (1, 2, 4, 8), "ridges": (0.1, 100.0)}
    full = select_moe(X, Y, Xv, Yv, **grid)
    early = select_moe(X, Y, Xv, Yv, **grid, stop_when_worse=True)
    assert (early.n_experts, early.ridge) == (full.n_experts, full.ridge)
    assert early.table == full.table[: len(early.table)]
    assert len(early.table) < len(full.table)
    by_m = {}
    for row in full.table:
        by_m[row["n_experts"]] = max(by_m.get(row["n_experts"], -np.inf), row["val_loglik"])
    last = early.table[-1]["n_experts"]
    assert by_m[last] < by_m[max(m for m in by_m if m < last)]


def test_degenerate_data_stays_finite():
    rng = np.random.default_rng(4)
    # More experts than distinct outputs, constant input columns, duplicated rows.
    X = np.hstack([rng.normal(0, 1, (60, 2)), np.ones((60, 3))])
    X = np.vstack([X, X])
    Y = np.repeat(np.array([[0.0], [1.0]]), 60, axis=0)
    fit = fit_moe(X, Y, 6, 1.0, np.random.default_rng(0))
    m = fit.model
    assert np.all(np.isfinite(m.covs)) and np.all(np.linalg.eigvalsh(m.covs) > 0)
    assert np.all(np.isfinite(m.predict(X)))
    assert np.all(np.isfinite(m.log_likelihood(X, Y)))


def test_gate_probabilities_and_sampling():
    X, Y = piecewise(800, np.random.default_rng(5))
    m = fit_moe(X, Y, 2, 1.0, np.random.default_rng(0)).model
    g = np.exp(m.gate_log_probs(X[:20]))
    np.testing.assert_allclose(g.sum(axis=1), 1.0, atol=1e-12)
    x = np.array([-2.0, 0, 0, 0])
    samples = m.sample(x, 4000, np.random.default_rng(1))
    np.testing.assert_allclose(samples.mean(axis=0), [-3.0, -1.5], atol=0.05)


def test_arrays_round_trip():
    X, Y = piecewise(300, np.random.default_rng(6))
    m = fit_moe(X, Y, 2, 1.0, np.random.default_rng(0)).model
    back = MixtureOfExperts.from_arrays(m.to_arrays("p_"), "p_")
    np.testing.assert_array_equal(back.predict(X), m.predict(X))
    with pytest.raises(ValueError, match="missing"):
        MixtureOfExperts.from_arrays({}, "p_")


@pytest.mark.parametrize(
    "X, Y, M, lam, message",
    [
        (np.zeros((10, 2)), np.zeros((9, 1)), 1, 1.0, "same N"),
        (np.full((10, 2), np.nan), np.zeros((10, 1)), 1, 1.0, "NaN"),
        (np.zeros((10, 2)), np.zeros((10, 1)), 0, 1.0, "n_experts"),
        (np.zeros((10, 2)), np.zeros((10, 1)), 1, -1.0, "ridge"),
        (np.zeros((10, 2)), np.zeros((10, 1)), 8, 1.0, "too few"),
    ],
)
def test_bad_inputs(X, Y, M, lam, message):
    with pytest.raises(ValueError, match=message):
        fit_moe(X, Y, M, lam, np.random.default_rng(0))


def test_predict_checks_input_width():
    X, Y = piecewise(100, np.random.default_rng(7))
    m = fit_moe(X, Y, 1, 1.0, np.random.default_rng(0)).model
    with pytest.raises(ValueError, match="expected shape"):
        m.predict(np.zeros((3, 2)))


#: The batched EM against the loop it replaced: the same objective trace and parameters
#: up to round-off (per-example log-likelihood, standardized parameters).
REFERENCE_TOL = 1e-9


@pytest.mark.parametrize(
    "n, d, p, m, lam", [(300, 4, 2, 3, 1.0), (400, 30, 5, 4, 10.0), (200, 12, 3, 1, 0.0)]
)
def test_batched_em_reproduces_the_reference_loop(n, d, p, m, lam):
    rng = np.random.default_rng(11)
    X = rng.normal(size=(n, d))
    Y = np.tanh(2 * X[:, :p]) + (X[:, :1] > 0) + 0.1 * rng.normal(size=(n, p))
    ref, ref_history = reference_fit_moe(X, Y, m, lam, np.random.default_rng(1), max_iter=25)
    fit = fit_moe(X, Y, m, lam, np.random.default_rng(1), max_iter=25)
    assert len(fit.history) == len(ref_history)
    np.testing.assert_allclose(fit.history, ref_history, rtol=0, atol=REFERENCE_TOL)
    for name, value in ref.items():
        np.testing.assert_allclose(getattr(fit.model, name), value, rtol=0, atol=REFERENCE_TOL)


def test_fit_is_deterministic_for_a_seed():
    X, Y = piecewise(400, np.random.default_rng(12))
    a = fit_moe(X, Y, 3, 1.0, np.random.default_rng(5)).model
    b = fit_moe(X, Y, 3, 1.0, np.random.default_rng(5)).model
    np.testing.assert_array_equal(a.betas, b.betas)
    np.testing.assert_array_equal(a.covs, b.covs)
