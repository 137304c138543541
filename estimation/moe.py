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
from scipy.linalg import cho_factor, cho_solve
from scipy.linalg.blas import dsyrk
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
    return _logpdf_chol(X[:, None, :] - means[None], np.linalg.cholesky(covs))


def _gauss_logpdf_each(Y: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """log N(y_n; m_nk, Λ_k) -> (N, M) for per-example means (N, M, P)."""
    return _logpdf_chol(Y[:, None, :] - means, np.linalg.cholesky(covs))


def _logpdf_chol(diff: np.ndarray, L: np.ndarray) -> np.ndarray:
    """log N(diff_nk; 0, L_k L_k^T) -> (N, M) for diff (N, M, G) and Cholesky factors (M, G, G).

    All components at once: L_k^-1 (small, G <= a few dozen) by one batched
    inverse, then one batched product instead of a triangular solve per component.
    """
    L_inv = _tril_inv(L)
    sol = np.matmul(diff.transpose(1, 0, 2), L_inv.transpose(0, 2, 1))  # (M, N, G)
    logdet = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    d = diff.shape[2]
    return -0.5 * ((sol**2).sum(axis=2).T + logdet + d * np.log(2 * np.pi))


def _tril_inv(L: np.ndarray) -> np.ndarray:
    """Inverses of lower-triangular factors (M, G, G), kept exactly lower-triangular."""
    return np.tril(np.linalg.inv(L))


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
    X, Y, M = _checked(X, Y, n_experts, ridge)
    N, D = X.shape

    x_mean, x_scale, Xs, basis = _standardized(X, n_gate_dims)
    Xg = Xs @ basis
    y_scale = Y.std(axis=0).mean() + 1e-12
    Z = _initial_ownerships(Y, M, y_scale, rng)

    A = np.hstack([Xs, np.ones((N, 1))])  # design with offset
    floors = (GATE_FLOOR, EXPERT_FLOOR * y_scale**2)
    history = []
    state = None
    for _ in range(max_iter):
        state = _m_step(Xg, Y, A, Z, ridge, floors)
        # E-step (Eq. 4) and the penalized objective of this M-step's parameters.
        log_joint = _log_joint(Xg, Y, state)
        obj = logsumexp(log_joint, axis=1).sum() + _log_prior(state, ridge, floors, D)
        history.append(obj / N)
        Z = np.exp(log_joint - logsumexp(log_joint, axis=1, keepdims=True))
        if len(history) > 1 and history[-1] - history[-2] < tol:
            break
    log_w, means_g, covs_g, W, covs_e = (
        state.log_w,
        state.means_g,
        state.covs_g,
        state.W,
        state.covs_e,
    )
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


def _checked(
    X: np.ndarray, Y: np.ndarray, n_experts: int, ridge: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`fit_moe`'s inputs as float arrays (N, D) and (N, P), and M.

    Raises
    ------
    ValueError
        For shapes that do not match, non-finite values, ``n_experts < 1``,
        ``ridge < 0`` or fewer than ``2 M`` examples.
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
    M = int(n_experts)
    if len(X) < 2 * M:
        raise ValueError(f"too few examples ({len(X)}) for {M} experts")
    return X, Y, M


def _standardized(
    X: np.ndarray, n_gate_dims: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Standardized inputs and the gates' principal directions.

    Parameters
    ----------
    X : (N, D) float
    n_gate_dims : int
        Principal components the gates see (at most D and N - 1).

    Returns
    -------
    x_mean, x_scale : (D,) float
        Per-input mean and standard deviation (1 for a constant input).
    Xs : (N, D) float
        The standardized inputs.
    basis : (D, G) float
        The first G principal directions of ``Xs``, each with a deterministic sign.
    """
    N, D = X.shape
    x_mean = X.mean(axis=0)
    x_scale = X.std(axis=0)
    x_scale[x_scale < 1e-12] = 1.0  # constant inputs carry no information
    Xs = (X - x_mean) / x_scale
    G = min(n_gate_dims, D, N - 1)
    _, _, Vt = np.linalg.svd(Xs - Xs.mean(axis=0), full_matrices=False)
    basis = Vt[:G].T
    # Deterministic sign of each direction.
    basis *= np.sign(basis[np.argmax(np.abs(basis), axis=0), np.arange(G)])
    return x_mean, x_scale, Xs, basis


def _initial_ownerships(
    Y: np.ndarray, M: int, y_scale: float, rng: np.random.Generator
) -> np.ndarray:
    """EM's starting ownerships (N, M): k-means on the outputs (paper), softened.

    Hard k-means labels (random ones when there are fewer distinct outputs
    than experts), then ``0.98 * hard + 0.02 / M`` so every expert starts alive.
    """
    N = len(Y)
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
    return 0.98 * Z + 0.02 / M  # keep every component alive at the start


#: Ownerships below this fraction of an expert's largest are left out of its
#: weighted least squares: such a row weighs less than 1e-12 of an owned one in
#: the Gram matrix, below the round-off of the normal equations, and an expert
#: of a sharp mixture owns a fraction of the rows, so its Gram costs that fraction.
OWNERSHIP_SKIP = 1e-12


@dataclass(frozen=True)
class _Params:
    """One M-step's parameters with the Cholesky factors the E-step and prior share.

    Shapes: log_w (M,), means_g (M, G), covs_g / chol_g (M, G, G), W (M, D+1, P),
    covs_e / chol_e (M, P, P), means_y (N, M, P) = each expert's prediction per example.
    """

    log_w: np.ndarray
    means_g: np.ndarray
    covs_g: np.ndarray
    chol_g: np.ndarray
    W: np.ndarray
    covs_e: np.ndarray
    chol_e: np.ndarray
    means_y: np.ndarray


def _m_step(
    Xg: np.ndarray,
    Y: np.ndarray,
    A: np.ndarray,
    Z: np.ndarray,
    ridge: float,
    floors: tuple[float, float],
) -> _Params:
    """MAP M-step for ownerships Z (N, M): gates, weighted ridge experts (Eq. 3), noise."""
    N, M = Z.shape
    D1, P, G = A.shape[1], Y.shape[1], Xg.shape[1]
    gate_floor, expert_floor = floors
    Nk = Z.sum(axis=0)
    log_w = np.log((Nk + 1.0) / (N + M))  # Dirichlet(2) prior keeps π_k > 0
    means_g = (Z.T @ Xg) / np.maximum(Nk, 1e-12)[:, None]
    d = (Xg[:, None, :] - means_g).transpose(1, 0, 2)  # (M, N, G)
    covs_g = np.matmul(d.transpose(0, 2, 1) * Z.T[:, None, :], d)
    covs_g = (covs_g + gate_floor * np.eye(G)) / (Nk + 1.0)[:, None, None]
    # Eq. (3) per expert: the weighted Gram matrix dominates the cost (N (D+1)^2 per
    # expert); a symmetric rank-k update on the rows the expert owns does half of
    # it, and one Cholesky factor solves the normal equations.
    W = np.empty((M, D1, P))
    for k in range(M):
        rows = np.flatnonzero(Z[:, k] > OWNERSHIP_SKIP * Z[:, k].max())
        sz = np.sqrt(Z[rows, k])[:, None]
        B = A[rows] * sz
        W[k] = _ridge_solve(_syrk(B), B.T @ (Y[rows] * sz), ridge)
    means_y = (A @ W.transpose(1, 0, 2).reshape(D1, M * P)).reshape(N, M, P)
    r = (Y[:, None, :] - means_y).transpose(1, 0, 2)  # (M, N, P)
    covs_e = np.matmul(r.transpose(0, 2, 1) * Z.T[:, None, :], r)
    beta = W[:, : D1 - 1]
    covs_e += ridge * np.matmul(beta.transpose(0, 2, 1), beta) + expert_floor * np.eye(P)
    covs_e /= (Nk + D1)[:, None, None]
    return _Params(
        log_w,
        means_g,
        covs_g,
        np.linalg.cholesky(covs_g),
        W,
        covs_e,
        np.linalg.cholesky(covs_e),
        means_y,
    )


def _ridge_solve(gram: np.ndarray, rhs: np.ndarray, ridge: float) -> np.ndarray:
    """(gram + λ I without the offset) W = rhs, for gram's upper triangle (D+1, D+1)."""
    idx = np.arange(len(gram) - 1)
    gram[idx, idx] += ridge
    try:
        factor = cho_factor(gram, lower=False, check_finite=False)
    except np.linalg.LinAlgError:
        # Semi-definite (λ = 0 with constant or collinear inputs, or an expert that
        # owns nothing): the general solver, as the first version always used.
        upper = np.triu(gram)
        return np.linalg.solve(upper + np.triu(upper, 1).T, rhs)
    return cho_solve(factor, rhs, check_finite=False)


def _syrk(B: np.ndarray) -> np.ndarray:
    """B^T B (upper triangle only; the lower is left zero) by BLAS syrk, (D, D)."""
    if len(B) == 0:
        return np.zeros((B.shape[1], B.shape[1]))
    # B.T of a C-ordered B is Fortran-ordered: syrk reads it without a copy.
    return dsyrk(1.0, B.T, trans=0, lower=0)


def _log_joint(Xg: np.ndarray, Y: np.ndarray, state: _Params) -> np.ndarray:
    """log π_k N(x_g; μ_k, Σ_k) N(y; β_k x + α_k, Λ_k) -> (N, M)."""
    return (
        state.log_w
        + _logpdf_chol(Xg[:, None, :] - state.means_g[None], state.chol_g)
        + _logpdf_chol(Y[:, None, :] - state.means_y, state.chol_e)
    )


def _log_prior(state: _Params, ridge: float, floors: tuple[float, float], D: int) -> float:
    """Log of the priors that make the M-step a MAP step (up to constants).

    With Σ = L L^T: tr(c Σ^-1) = c ||L^-1||², tr(Λ^-1 β^T β) = ||β L^-T||², log|Σ| = 2 Σ log diag L.
    """
    gate_floor, expert_floor = floors
    inv_g = _tril_inv(state.chol_g)
    inv_e = _tril_inv(state.chol_e)
    logdet_g = 2.0 * np.log(np.diagonal(state.chol_g, axis1=1, axis2=2)).sum()
    logdet_e = 2.0 * np.log(np.diagonal(state.chol_e, axis1=1, axis2=2)).sum()
    beta_white = np.matmul(state.W[:, :D], inv_e.transpose(0, 2, 1))
    total = state.log_w.sum()  # Dirichlet(2)
    total += -0.5 * gate_floor * np.sum(inv_g**2) - 0.5 * logdet_g
    total += -0.5 * ridge * np.sum(beta_white**2) - 0.5 * D * logdet_e
    total += -0.5 * expert_floor * np.sum(inv_e**2) - 0.5 * logdet_e
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
    stop_when_worse: bool = False,
    **fit_kwargs,
) -> Selection:
    """Choose M and λ by the held-out conditional log-likelihood (paper §4).

    Candidates are fitted in increasing M, every λ for each M. With
    ``stop_when_worse`` the search ends at the first M whose best held-out
    log-likelihood (over λ) is below the previous M's: larger mixtures, which
    cost in proportion to M, are fitted only while adding experts still helps.
    That gives the full grid's choice whenever the held-out likelihood rises
    to a single peak in M (``table`` lists the candidates fitted).
    """
    table = []
    best = None
    previous = -np.inf
    for M in sorted(experts):
        if len(X) < 2 * M:
            continue
        best_here = -np.inf
        for lam in ridges:
            fit = fit_moe(X, Y, M, lam, np.random.default_rng(seed), **fit_kwargs)
            ll = float(np.mean(fit.model.log_likelihood(X_val, Y_val)))
            rmse = float(np.sqrt(np.mean((fit.model.predict(X_val) - Y_val) ** 2)))
            table.append({"n_experts": M, "ridge": lam, "val_loglik": ll, "val_rmse": rmse})
            best_here = max(best_here, ll)
            if best is None or ll > best[0]:
                best = (ll, M, lam, fit.model)
        if stop_when_worse and best_here < previous:
            break
        previous = best_here
    if best is None:
        raise ValueError("select_moe: no candidate could be fitted")
    return Selection(best[3], best[1], best[2], table)
