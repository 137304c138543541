"""Mixture of experts p(Y | X) with ridge-regularized linear experts and Gaussian gates (paper §4).

    p(Y | X) = Σ_k g_k(X) N(Y; β_k^T x̃ + α_k, Λ_k),
    g_k(X) = π_k N(x_g; μ_k, Σ_k) / Σ_j π_j N(x_g; μ_j, Σ_j)

Inputs are standardized by their standard deviation per dimension before the
ridge regression (the paper: "the solution of the ridge regressors is not
symmetric under the scaling of the inputs"); the gates work on the leading
principal components of the standardized inputs (full-covariance Gaussians in
100-300 dimensions are singular with a few hundred examples per expert).

Learning is EM on the joint model p(x, y) = Σ π_k N(x; μ_k, Σ_k) N(y; β_k x + α_k, Λ_k),
whose conditional is the mixture above: the E-step gives the ownerships of
Eq. (4), the M-step the weighted ridge regression of Eq. (3) and the weighted
Gaussian fits of the gates. The ridge penalty and small covariance floors are
written as conjugate priors, so EM increases the penalized log-likelihood
(``fit_moe``'s ``history``) at every iteration, and a component that loses all
its examples keeps a proper, broad covariance instead of collapsing. EM starts
from k-means on the outputs, as the paper does.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

#: Covariance floors (priors), relative to the standardized data (unit variance).
GATE_FLOOR = 1e-2
EXPERT_FLOOR = 1e-4


@dataclass(frozen=True)
class MixtureOfExperts:
    """A fitted mixture of experts (all arrays; save with :meth:`to_arrays`).

    Attributes
    ----------
    x_mean, x_scale : (D,) float
        Input standardization.
    gate_basis : (D, G) float
        Principal directions of the standardized inputs used by the gates.
    log_weights : (M,) float
        log π_k.
    gate_means : (M, G) float
    gate_covs : (M, G, G) float
    betas : (M, D, P) float
        Expert regression matrices on standardized inputs.
    alphas : (M, P) float
    covs : (M, P, P) float
        Expert output covariances Λ_k.
    ridge : float
        λ used in training.
    """

    x_mean: np.ndarray
    x_scale: np.ndarray
    gate_basis: np.ndarray
    log_weights: np.ndarray
    gate_means: np.ndarray
    gate_covs: np.ndarray
    betas: np.ndarray
    alphas: np.ndarray
    covs: np.ndarray
    ridge: float = 0.0
    _chol: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_experts(self) -> int:
        return len(self.log_weights)

    @property
    def n_inputs(self) -> int:
        return len(self.x_mean)

    @property
    def n_outputs(self) -> int:
        return self.alphas.shape[1]

    def _inputs(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != self.n_inputs:
            raise ValueError(f"X: expected shape (N, {self.n_inputs}), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError("X: contains NaN or infinity")
        Xs = (X - self.x_mean) / self.x_scale
        return Xs, Xs @ self.gate_basis

    def gate_log_probs(self, X: np.ndarray) -> np.ndarray:
        """log g_k(X), (N, M)."""
        _, Xg = self._inputs(X)
        logp = self.log_weights + _gauss_logpdf(Xg, self.gate_means, self.gate_covs)
        return logp - logsumexp(logp, axis=1, keepdims=True)

    def expert_means(self, X: np.ndarray) -> np.ndarray:
        """Each expert's prediction β_k^T x + α_k, (N, M, P)."""
        Xs, _ = self._inputs(X)
        return np.einsum("nd,mdp->nmp", Xs, self.betas) + self.alphas

    def predict(self, X: np.ndarray, mode: str = "mean") -> np.ndarray:
        """Point predictions (N, P).

        ``mode="mean"`` gives the mixture mean; ``"gate"`` the prediction of the
        most probable expert (better when the posterior is multimodal).
        """
        g = np.exp(self.gate_log_probs(X))
        means = self.expert_means(X)
        if mode == "mean":
            return np.einsum("nm,nmp->np", g, means)
        if mode == "gate":
            return means[np.arange(len(g)), np.argmax(g, axis=1)]
        raise ValueError(f"mode: expected 'mean' or 'gate', got {mode!r}")

    def log_likelihood(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Conditional log p(y | x) per example, (N,)."""
        Y = np.atleast_2d(np.asarray(Y, dtype=float))
        means = self.expert_means(X)
        logp = self.gate_log_probs(X) + _gauss_logpdf_each(Y, means, self.covs)
        return logsumexp(logp, axis=1)

    def sample(self, x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` outputs from p(Y | x) for one input ``x`` (D,) -> (n, P)."""
        g = np.exp(self.gate_log_probs(x[None]))[0]
        means = self.expert_means(x[None])[0]
        k = rng.choice(self.n_experts, size=n, p=g / g.sum())
        L = np.linalg.cholesky(self.covs)
        eps = rng.standard_normal((n, self.n_outputs))
        return means[k] + np.einsum("nij,nj->ni", L[k], eps)

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Arrays for an ``.npz`` (names prefixed)."""
        out = {}
        for f in fields(self):
            if f.name.startswith("_"):
                continue
            out[f"{prefix}{f.name}"] = np.asarray(getattr(self, f.name))
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> MixtureOfExperts:
        kwargs = {}
        for f in fields(cls):
            if f.name.startswith("_"):
                continue
            key = f"{prefix}{f.name}"
            if key not in arrays:
                raise ValueError(f"mixture of experts: array {key!r} missing")
            value = arrays[key]
            kwargs[f.name] = float(value) if f.name == "ridge" else np.asarray(value, dtype=float)
        return cls(**kwargs)


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


@dataclass(frozen=True)
class FitResult:
    """A fitted model and its EM trace.

    Attributes
    ----------
    model : MixtureOfExperts
    history : (iterations,) float
        Penalized joint log-likelihood per example after each EM iteration
        (non-decreasing).
    """

    model: MixtureOfExperts
    history: np.ndarray


def fit_moe(
    X: np.ndarray,
    Y: np.ndarray,
    n_experts: int,
    ridge: float,
    rng: np.random.Generator,
    n_gate_dims: int = 16,
    max_iter: int = 60,
    tol: float = 1e-5,
) -> FitResult:
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
    model = MixtureOfExperts(
        x_mean=x_mean,
        x_scale=x_scale,
        gate_basis=basis,
        log_weights=log_w,
        gate_means=means_g,
        gate_covs=covs_g,
        betas=W[:, :D, :],
        alphas=W[:, D, :],
        covs=covs_e,
        ridge=float(ridge),
    )
    return FitResult(model, np.asarray(history))


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


@dataclass(frozen=True)
class Selection:
    """Cross-validated choice of M and λ.

    Attributes
    ----------
    model : MixtureOfExperts
        Refitted on all training data with the chosen M and λ.
    n_experts, ridge : the choice.
    table : list of dict
        Per candidate: ``n_experts``, ``ridge``, ``val_loglik`` (mean conditional
        log-likelihood per validation example), ``val_rmse``.
    """

    model: MixtureOfExperts
    n_experts: int
    ridge: float
    table: list[dict]


def select_moe(
    X: np.ndarray,
    Y: np.ndarray,
    X_val: np.ndarray,
    Y_val: np.ndarray,
    experts: tuple[int, ...] = (1, 2, 4, 8),
    ridges: tuple[float, ...] = (1.0, 10.0, 100.0, 1000.0),
    seed: int = 0,
    **fit_kwargs,
) -> Selection:
    """Choose M and λ by the held-out conditional log-likelihood (paper §4)."""
    table = []
    best = None
    for M in experts:
        for lam in ridges:
            if len(X) < 2 * M:
                continue
            fit = fit_moe(X, Y, M, lam, np.random.default_rng(seed), **fit_kwargs)
            ll = float(np.mean(fit.model.log_likelihood(X_val, Y_val)))
            rmse = float(np.sqrt(np.mean((fit.model.predict(X_val) - Y_val) ** 2)))
            table.append({"n_experts": M, "ridge": lam, "val_loglik": ll, "val_rmse": rmse})
            if best is None or ll > best[0]:
                best = (ll, M, lam, fit.model)
    if best is None:
        raise ValueError("select_moe: no candidate could be fitted")
    return Selection(best[3], best[1], best[2], table)
