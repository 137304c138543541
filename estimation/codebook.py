"""The shape-context codebook (paper §3): k-means centres per scale and the
soft-vote encoding of a silhouette's shape contexts into ``X_sc``.

Each sampled contour point's shape context votes into its nearest centres;
the votes are summed and normalized to unit length. Deterministic by seed.
See ``docs/features.md``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.features import RngLike, as_rng, compiled_kernels, positive_int
from bodymetry.estimation.shape_context import ShapeContextConfig

__all__ = ["Codebook", "fit_codebook"]


def _sq_dists(
    x: NDArray[np.float64], c: NDArray[np.float64], x_sq: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Squared Euclidean distances ``(N, K)`` between rows of x and c.

    ``x_sq``, the squared norms of x's rows, may be passed when x is reused:
    k-means++ seeding measures 100,000 descriptors against one new centre at a
    time, and recomputing them dominated that (the result is the same bits).
    """
    if x_sq is None:
        x_sq = (x * x).sum(1)
    d2 = x_sq[:, None] - 2.0 * (x @ c.T) + (c * c).sum(1)[None, :]
    return np.maximum(d2, 0.0)


def _kmeans(
    x: NDArray[np.float64], k: int, rng: np.random.Generator, max_iter: int, tol: float
) -> NDArray[np.float64]:
    """Lloyd's k-means with k-means++ seeding; deterministic given ``rng``."""
    n = x.shape[0]
    # k-means++ seeding
    centers = np.empty((k, x.shape[1]))
    centers[0] = x[rng.integers(n)]
    x_sq = (x * x).sum(1)
    closest = _sq_dists(x, centers[:1], x_sq)[:, 0]
    for j in range(1, k):
        total = closest.sum()
        if total <= 0.0:  # fewer distinct points than k: duplicate centres
            centers[j] = x[rng.integers(n)]
        else:
            i = int(np.searchsorted(np.cumsum(closest), rng.random() * total, side="right"))
            centers[j] = x[min(i, n - 1)]
        closest = np.minimum(closest, _sq_dists(x, centers[j : j + 1], x_sq)[:, 0])
    prev = np.inf  # no inertia before the first iteration: never "converged" there
    rows = np.arange(n)
    for _ in range(max_iter):
        # ||x||^2 is the same for every centre: the nearest centre is the argmin of
        # ||c||^2 - 2 x.c, one (N, K) array updated in place (the full expansion
        # made three such temporaries, which cost more than the product)
        g = x @ centers.T
        g *= -2.0
        g += (centers * centers).sum(1)
        label = g.argmin(1)
        fit = np.maximum(g[rows, label] + x_sq, 0.0)  # squared distance to its centre
        inertia = float(fit.sum())
        counts = np.bincount(label, minlength=k)
        sums = np.zeros_like(centers)
        _add_rows(sums, label, x)
        nonempty = counts > 0
        centers[nonempty] = sums[nonempty] / counts[nonempty, None]
        empty = np.flatnonzero(~nonempty)
        if empty.size:  # re-seed empty clusters at the worst-fit points
            far = np.argsort(-fit, kind="stable")[: empty.size]
            centers[empty] = x[far]
        # (On the first iteration inf - inertia <= tol * inf held, and Lloyd
        # stopped after one step: the codebook was the seeds' cluster means.)
        if empty.size == 0 and np.isfinite(prev) and prev - inertia <= tol * max(prev, 1e-300):
            break
        prev = inertia
    return centers


def _nearest(d2: NDArray[np.float64], nn: int) -> NDArray[np.intp]:
    """Columns of the ``nn`` smallest entries of each row of ``d2`` (N, K), nearest first.

    For the few votes of soft voting, ``nn`` passes of ``argmin`` are 3-4x
    faster than ``argpartition`` on a silhouette's (200, 100) distances (the
    same centres; ties, which distinct centres practically never give, go to
    the lower index); more votes use ``argpartition``.
    """
    if nn > 4:
        return np.argpartition(d2, nn - 1, axis=1)[:, :nn]
    work = d2.copy()
    rows = np.arange(d2.shape[0])
    idx = np.empty((d2.shape[0], nn), np.intp)
    for j in range(nn):
        idx[:, j] = work.argmin(axis=1)
        work[rows, idx[:, j]] = np.inf
    return idx


def _add_rows(sums: NDArray[np.float64], label: NDArray[np.int64], x: NDArray[np.float64]) -> None:
    """``sums[label[i]] += x[i]`` for all i (fast, via one bincount per column)."""
    k = sums.shape[0]
    for j in range(x.shape[1]):
        sums[:, j] = np.bincount(label, weights=x[:, j], minlength=k)


def _as_scaled_descriptors(descriptors: ArrayLike, name: str) -> NDArray[np.float64]:
    d = np.asarray(descriptors, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    if d.ndim != 3:
        raise ValueError(
            f"{name}: expected an (N, D) or (S, N, D) array of descriptors, got shape {d.shape}"
        )
    if d.shape[1] < 1 or d.shape[2] < 1:
        raise ValueError(f"{name}: expected at least one descriptor, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name}: contains non-finite values")
    return d


def _readonly(a: ArrayLike, dtype: type = np.float64) -> NDArray:
    arr = np.array(a, dtype=dtype, copy=True)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Codebook:
    """Shape-context codebook: ``K`` k-means centres per scale, with soft voting.

    Attributes
    ----------
    centers : (S, K, D) float64
        Codewords per scale (``D = n_theta * n_r``).
    sigma : (S,) float64
        Soft-voting bandwidth per scale: the median distance of the training
        descriptors to their nearest centre (the codebook's typical
        quantization error).
    config : ShapeContextConfig
        Descriptor parameters the codebook was learned with; :func:`sc_features`
        uses them, so training and run time agree.
    n_nearest : int
        Each descriptor votes into its ``n_nearest`` closest centres.
    """

    centers: NDArray[np.float64]
    sigma: NDArray[np.float64]
    config: ShapeContextConfig = field(default_factory=ShapeContextConfig)
    n_nearest: int = 3

    def __post_init__(self) -> None:
        c = np.asarray(self.centers, dtype=np.float64)
        if c.ndim != 3 or c.shape[1] < 1:
            raise ValueError(f"centers: expected an (S, K, D) array, got shape {c.shape}")
        s, k, d = c.shape
        if not isinstance(self.config, ShapeContextConfig):
            raise ValueError(
                f"config: expected a ShapeContextConfig, got {type(self.config).__name__}"
            )
        if s != len(self.config.kappas) or d != self.config.n_bins:
            raise ValueError(
                f"centers: expected shape ({len(self.config.kappas)}, K, {self.config.n_bins}) "
                f"for config {self.config}, got {c.shape}"
            )
        sig = np.asarray(self.sigma, dtype=np.float64)
        if sig.shape != (s,) or not np.all(np.isfinite(sig)) or np.any(sig <= 0):
            raise ValueError(f"sigma: expected ({s},) positive values, got {sig!r}")
        nn = positive_int(self.n_nearest, "n_nearest")
        if nn > k:
            raise ValueError(f"n_nearest: expected at most K = {k}, got {nn}")
        object.__setattr__(self, "centers", _readonly(c))
        object.__setattr__(self, "sigma", _readonly(sig))
        object.__setattr__(self, "n_nearest", nn)

    @property
    def k(self) -> int:
        """Codewords per scale, ``K``."""
        return int(self.centers.shape[1])

    @property
    def n_scales(self) -> int:
        """Number of scales, ``S``."""
        return int(self.centers.shape[0])

    @property
    def dim(self) -> int:
        """Length of an encoding, ``S * K``."""
        return self.n_scales * self.k

    def encode(self, descriptors: ArrayLike) -> NDArray[np.float64]:
        """Soft-voted bag-of-words histogram of one silhouette's descriptors.

        Each descriptor ``x`` votes into its ``n_nearest`` closest centres
        ``c_j`` with weights ``w_j ∝ exp(-||x - c_j||^2 / (2 sigma^2))``,
        normalized to sum to 1 over those centres (one vote per descriptor;
        computed relative to the nearest centre, so it never underflows).
        Each scale's ``K``-bin histogram is normalized to unit length, and the
        concatenation is divided by ``sqrt(S)``: every scale weighs the same
        and the whole vector has unit length.

        Parameters
        ----------
        descriptors : (S, N, D) or, for one scale, (N, D) float
            From :func:`sc_descriptors` / :func:`multiscale_shape_contexts`.

        Returns
        -------
        x_sc : (S * K,) float64
            Non-negative, unit length; scale ``s`` in ``[s * K, (s + 1) * K)``.
        """
        d = _as_scaled_descriptors(descriptors, "descriptors")
        s, k, dim = self.centers.shape
        if d.shape[0] != s or d.shape[2] != dim:
            raise ValueError(
                f"descriptors: expected shape ({s}, N, {dim}) for this codebook, got "
                f"{d.shape if np.ndim(descriptors) == 3 else np.shape(descriptors)}"
            )
        kernels = compiled_kernels()
        if kernels is None:
            return self._encode_numpy(d)
        out = np.empty((s, k))
        centers_t, centers_sq = self._transposed
        kernels.encode_kernel(
            np.ascontiguousarray(d), centers_t, centers_sq, self.sigma, self.n_nearest, out
        )
        return (out / np.sqrt(s)).ravel()

    @functools.cached_property
    def _transposed(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The centres as the compiled encoding reads them: (S, D, K) and their
        squared norms (S, K)."""
        return (
            np.ascontiguousarray(self.centers.transpose(0, 2, 1)),
            (self.centers * self.centers).sum(axis=2),
        )

    def _encode_numpy(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        """The numpy reference of :meth:`encode` on checked (S, N, D) descriptors."""
        s, k, _ = self.centers.shape
        nn = self.n_nearest
        out = np.empty((s, k))
        for i in range(s):
            d2 = _sq_dists(d[i], self.centers[i])  # (N, K)
            if nn < k:
                idx = _nearest(d2, nn)
                near = np.take_along_axis(d2, idx, axis=1)
            else:
                idx = np.broadcast_to(np.arange(k), d2.shape)
                near = d2
            w = np.exp(-(near - near.min(1, keepdims=True)) / (2.0 * self.sigma[i] ** 2))
            w /= w.sum(1, keepdims=True)
            out[i] = np.bincount(idx.ravel(), weights=w.ravel(), minlength=k)
            out[i] /= np.linalg.norm(out[i])
        return (out / np.sqrt(s)).ravel()

    def to_arrays(self, prefix: str = "") -> dict[str, NDArray]:
        """Plain arrays for ``np.savez`` (no pickle); inverse of :meth:`from_arrays`.

        Keys (each with ``prefix``): ``centers`` (S, K, D), ``sigma`` (S,),
        ``kappas`` (S,), ``n_theta``, ``n_r``, ``n_points``, ``n_nearest`` (int64
        scalars), ``r_in_fraction`` (float64 scalar).
        """
        cfg = self.config
        return {
            f"{prefix}centers": np.array(self.centers),
            f"{prefix}sigma": np.array(self.sigma),
            f"{prefix}kappas": np.array(cfg.kappas, dtype=np.float64),
            f"{prefix}n_theta": np.array(cfg.n_theta, dtype=np.int64),
            f"{prefix}n_r": np.array(cfg.n_r, dtype=np.int64),
            f"{prefix}n_points": np.array(cfg.n_points, dtype=np.int64),
            f"{prefix}r_in_fraction": np.array(cfg.r_in_fraction, dtype=np.float64),
            f"{prefix}n_nearest": np.array(self.n_nearest, dtype=np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike], prefix: str = "") -> Codebook:
        """Rebuild a codebook from :meth:`to_arrays` output (or an open ``np.load``)."""
        keys = ("centers", "sigma", "kappas", "n_theta", "n_r", "n_points", "r_in_fraction")
        missing = [prefix + key for key in (*keys, "n_nearest") if prefix + key not in arrays]
        if missing:
            raise ValueError(f"arrays: missing codebook keys {missing}")

        def scalar(key: str, kind: type) -> int | float:
            a = np.asarray(arrays[prefix + key])
            if a.shape != ():
                raise ValueError(f"{prefix + key}: expected a scalar, got shape {a.shape}")
            return kind(a)

        config = ShapeContextConfig(
            kappas=tuple(float(v) for v in np.asarray(arrays[prefix + "kappas"]).ravel()),
            n_theta=scalar("n_theta", int),
            n_r=scalar("n_r", int),
            r_in_fraction=scalar("r_in_fraction", float),
            n_points=scalar("n_points", int),
        )
        return cls(
            centers=np.asarray(arrays[prefix + "centers"]),
            sigma=np.asarray(arrays[prefix + "sigma"]),
            config=config,
            n_nearest=scalar("n_nearest", int),
        )


def fit_codebook(
    descriptors: ArrayLike | Sequence[ArrayLike],
    k: int = 100,
    rng: RngLike = 0,
    *,
    config: ShapeContextConfig | None = None,
    n_nearest: int = 3,
    max_samples: int = 100_000,
    max_iter: int = 100,
    tol: float = 1e-6,
) -> Codebook:
    """Learn a K-centre shape-context codebook per scale by k-means.

    Lloyd's algorithm with k-means++ seeding (NumPy, distances by BLAS), one
    run per scale; empty clusters are re-seeded at the worst-fit descriptors.
    Deterministic: the same descriptors and seed give the same codebook.

    Parameters
    ----------
    descriptors : (S, N, D) or (N, D) float, or a list of (S, N_i, D) float
        Pooled shape contexts of the training silhouettes: one array, or the
        :func:`sc_descriptors` outputs themselves (the same codebook as their
        concatenation along ``N``; only the sampled rows are gathered, so a
        large pool is never copied whole).
    k : int, default 100
        Codewords per scale (paper ``K = 100``); at most ``N``.
    rng : numpy.random.Generator or int, default 0
        Seed for subsampling and seeding.
    config : ShapeContextConfig, optional
        Parameters the descriptors were computed with (stored in the
        codebook). Default :class:`ShapeContextConfig()`, or, for ``(N, D)``
        input, that with ``kappas=(0.25,)``.
    n_nearest : int, default 3
        Centres each descriptor votes into when encoding.
    max_samples : int, default 100000
        At most this many descriptors (a random subset) per scale are used.
    max_iter : int, default 100
        Lloyd iterations at most; stops earlier when the relative decrease of
        the inertia is below ``tol`` (tested from the second iteration on).

    Returns
    -------
    Codebook
    """
    pool = _DescriptorPool(descriptors, "descriptors")
    s, n, dim = pool.shape
    k = positive_int(k, "k")
    if k > n:
        raise ValueError(f"k: expected at most the number of descriptors ({n}), got {k}")
    max_samples = positive_int(max_samples, "max_samples")
    max_iter = positive_int(max_iter, "max_iter")
    if config is None:
        config = ShapeContextConfig() if pool.scales_given else ShapeContextConfig(kappas=(0.25,))
    gen = as_rng(rng)
    centers = np.empty((s, k, dim))
    sigma = np.empty(s)
    for i in range(s):
        rows = np.sort(gen.choice(n, size=max_samples, replace=False)) if n > max_samples else None
        x = pool.rows(i, rows)
        centers[i] = _kmeans(x, k, gen, max_iter, float(tol))
        nearest = np.sqrt(_sq_dists(x, centers[i]).min(1))
        med = float(np.median(nearest))
        sigma[i] = med if med > 0 else max(float(nearest.mean()), 1e-6)
    return Codebook(centers=centers, sigma=sigma, config=config, n_nearest=n_nearest)


class _DescriptorPool:
    """Descriptors given as one (S, N, D) array or as blocks (S, N_i, D) pooled along N,
    read a scale's rows at a time (a training set's pool is hundreds of MB)."""

    def __init__(self, descriptors: ArrayLike | Sequence[ArrayLike], name: str) -> None:
        if (
            isinstance(descriptors, (list, tuple))
            and len(descriptors)
            and np.ndim(descriptors[0]) == 3
        ):
            blocks = [np.asarray(b, dtype=np.float64) for b in descriptors]
            if (
                any(b.ndim != 3 for b in blocks)
                or len({(b.shape[0], b.shape[2]) for b in blocks}) != 1
            ):
                raise ValueError(
                    f"{name}: expected blocks of one shape (S, N_i, D), got shapes "
                    f"{sorted({b.shape for b in blocks})[:3]}"
                )
            for b in blocks:
                if not np.all(np.isfinite(b)):
                    raise ValueError(f"{name}: contains non-finite values")
            self.blocks = blocks
            self.scales_given = True
        else:
            self.blocks = [_as_scaled_descriptors(descriptors, name)]
            self.scales_given = np.ndim(descriptors) == 3
        self.starts = np.cumsum([0] + [b.shape[1] for b in self.blocks])
        first = self.blocks[0]
        self.shape = (first.shape[0], int(self.starts[-1]), first.shape[2])
        if self.shape[1] < 1 or self.shape[2] < 1:
            raise ValueError(f"{name}: expected at least one descriptor, got shape {self.shape}")

    def rows(self, scale: int, rows: np.ndarray | None) -> NDArray[np.float64]:
        """(R, D) descriptors of one scale: ``rows`` (sorted) of the pool, or all (None)."""
        if len(self.blocks) == 1:
            d = self.blocks[0][scale]
            return d if rows is None else d[rows]
        if rows is None:
            return np.concatenate([b[scale] for b in self.blocks])
        # Sorted rows: each block's rows are one run.
        bounds = np.searchsorted(rows, self.starts)
        out = np.empty((len(rows), self.shape[2]))
        for j, block in enumerate(self.blocks):
            lo, hi = bounds[j], bounds[j + 1]
            if hi > lo:
                out[lo:hi] = block[scale, rows[lo:hi] - self.starts[j]]
        return out
