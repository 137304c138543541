"""The mixture-of-experts EM as first written (a loop over experts, one solve each).

Kept for the tests only: ``fit_moe`` (batched, syrk + Cholesky) must reproduce its
objective trace and parameters on small problems (tests/estimation/test_moe.py).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

from bodymetry.estimation.moe import EXPERT_FLOOR, GATE_FLOOR


def _gauss_logpdf(X: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """log N(x_n; μ_k, Σ_k) for all n, k -> (N, M)."""
    L = np.linalg.cholesky(covs)  # (M, G, G)
    diff = X[:, None, :] - means[None]  # (N, M, G)
    sol = np.stack([_solve_lower(L[k], diff[:, k].T).T for k in range(len(means))], axis=1)
    logdet = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    d = X.shape[1]
    return -0.5 * ((sol**2).sum(axis=2) + logdet + d * np.log(2 * np.pi))


def _gauss_logpdf_each(Y: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """log N(y_n; m_nk, Λ_k) -> (N, M) for per-example means (N, M, P)."""
    L = np.linalg.cholesky(covs)
    diff = Y[:, None, :] - means
    sol = np.stack([_solve_lower(L[k], diff[:, k].T).T for k in range(covs.shape[0])], axis=1)
    logdet = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    return -0.5 * ((sol**2).sum(axis=2) + logdet + Y.shape[1] * np.log(2 * np.pi))


def _solve_lower(L: np.ndarray, B: np.ndarray) -> np.ndarray:

    return solve_triangular(L, B, lower=True, check_finite=False)


def reference_fit_moe(
    X: np.ndarray,
    Y: np.ndarray,
    n_experts: int,
    ridge: float,
    rng: np.random.Generator,
    n_gate_dims: int = 16,
    max_iter: int = 60,
    tol: float = 1e-5,
) -> tuple[dict, np.ndarray]:
    """Fit a mixture of experts by EM.

    Parameters
    ----------
    X : (N, D) float
        Inputs (features).
    Y : (N, P) float
        Outputs.
    n_experts : int
        M, at least 1.
    ridge : float
        λ >= 0 of the experts' ridge penalty (on standardized inputs).
    rng : Generator
        Seeds the k-means initialization.
    n_gate_dims : int
        Principal components of the inputs the gates see.
    max_iter, tol : EM stops after ``max_iter`` iterations or when the
        objective improves by less than ``tol`` per example.
    """
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if X.ndim != 2 or Y.ndim != 2 or len(X) != len(Y):
        raise ValueError(
            f"X, Y: expected (N, D) and (N, P) with the same N, got {X.shape} and {Y.shape}"
        )
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("X, Y: contain NaN or infinity")
    if n_experts < 1:
        raise ValueError(f"n_experts: expected at least 1, got {n_experts}")
    if ridge < 0:
        raise ValueError(f"ridge: expected >= 0, got {ridge}")
    N, D = X.shape
    P = Y.shape[1]
    M = int(n_experts)
    if N < 2 * M:
        raise ValueError(f"too few examples ({N}) for {M} experts")

    x_mean = X.mean(axis=0)
    x_scale = X.std(axis=0)
    x_scale[x_scale < 1e-12] = 1.0  # constant inputs carry no information
    Xs = (X - x_mean) / x_scale
    G = min(n_gate_dims, D, N - 1)
    _, _, Vt = np.linalg.svd(Xs - Xs.mean(axis=0), full_matrices=False)
    basis = Vt[:G].T
    # Deterministic sign of each direction.
    basis *= np.sign(basis[np.argmax(np.abs(basis), axis=0), np.arange(G)])
    Xg = Xs @ basis
    y_scale = Y.std(axis=0).mean() + 1e-12

    # k-means on outputs (paper) -> hard ownerships.
    n_distinct = len(np.unique(np.round(Y / y_scale, 9), axis=0))
    if M == 1:
        labels = np.zeros(N, dtype=int)
    elif n_distinct < M:
        # Fewer distinct outputs than experts: k-means is undefined; start at random.
        labels = rng.integers(M, size=N)
    else:
        seed = int(rng.integers(2**31 - 1))
        with warnings.catch_warnings():
            # An empty cluster is harmless here: the soft start below revives it.
            warnings.simplefilter("ignore", UserWarning)
            _, labels = kmeans2(Y / y_scale, M, minit="++", seed=seed, iter=30)
    Z = np.zeros((N, M))
    Z[np.arange(N), labels] = 1.0
    Z = 0.98 * Z + 0.02 / M  # keep every component alive at the start

    A = np.hstack([Xs, np.ones((N, 1))])  # design with offset
    penalty = np.diag(np.r_[np.full(D, ridge), 0.0])
    gate_floor = GATE_FLOOR * np.eye(G)
    expert_floor = EXPERT_FLOOR * y_scale**2 * np.eye(P)
    history = []
    state = None
    for _ in range(max_iter):
        # M-step.
        Nk = Z.sum(axis=0)
        log_w = np.log((Nk + 1.0) / (N + M))  # Dirichlet(2) prior keeps π_k > 0
        means_g = (Z.T @ Xg) / np.maximum(Nk, 1e-12)[:, None]
        covs_g = np.empty((M, G, G))
        W = np.empty((M, D + 1, P))
        covs_e = np.empty((M, P, P))
        for k in range(M):
            d = Xg - means_g[k]
            covs_g[k] = ((Z[:, k, None] * d).T @ d + gate_floor) / (Nk[k] + 1.0)
            Az = A * Z[:, k, None]
            W[k] = np.linalg.solve(Az.T @ A + penalty, Az.T @ Y)  # Eq. (3)
            r = Y - A @ W[k]
            beta = W[k][:D]
            covs_e[k] = ((Z[:, k, None] * r).T @ r + ridge * beta.T @ beta + expert_floor) / (
                Nk[k] + D + 1.0
            )
        state = (log_w, means_g, covs_g, W, covs_e)
        # E-step (Eq. 4) and the penalized objective of this M-step's parameters.
        log_joint = _log_joint(Xg, Y, A, state)
        obj = logsumexp(log_joint, axis=1).sum() + _log_prior(
            state, ridge, gate_floor, expert_floor, D, M
        )
        history.append(obj / N)
        Z = np.exp(log_joint - logsumexp(log_joint, axis=1, keepdims=True))
        if len(history) > 1 and history[-1] - history[-2] < tol:
            break
    log_w, means_g, covs_g, W, covs_e = state
    params = {
        "log_weights": log_w,
        "gate_means": means_g,
        "gate_covs": covs_g,
        "betas": W[:, :D],
        "alphas": W[:, D],
        "covs": covs_e,
    }
    return params, np.asarray(history)


def _log_joint(Xg: np.ndarray, Y: np.ndarray, A: np.ndarray, state) -> np.ndarray:
    log_w, means_g, covs_g, W, covs_e = state
    means_y = np.einsum("nd,mdp->nmp", A, W)
    return log_w + _gauss_logpdf(Xg, means_g, covs_g) + _gauss_logpdf_each(Y, means_y, covs_e)


def _log_prior(state, ridge: float, gate_floor, expert_floor, D: int, M: int) -> float:
    """Log of the priors that make the M-step a MAP step (up to constants)."""
    log_w, _, covs_g, W, covs_e = state
    total = log_w.sum()  # Dirichlet(2)
    for k in range(M):
        inv_g = np.linalg.inv(covs_g[k])
        total += -0.5 * np.trace(gate_floor @ inv_g) - 0.5 * np.linalg.slogdet(covs_g[k])[1]
        inv_e = np.linalg.inv(covs_e[k])
        beta = W[k][:D]
        total += (
            -0.5 * ridge * np.trace(inv_e @ beta.T @ beta)
            - 0.5 * D * np.linalg.slogdet(covs_e[k])[1]
        )
        total += -0.5 * np.trace(expert_floor @ inv_e) - 0.5 * np.linalg.slogdet(covs_e[k])[1]
    return float(total)
