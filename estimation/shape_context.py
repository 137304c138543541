"""Histograms of shape context of a silhouette's contour (paper §3).

Log-polar histograms (``n_theta = 12`` orientations x ``n_r = 5`` radii, outer
radius ``r_out = kappa * h`` with ``h`` the silhouette height) at randomly
sampled contour points, at several scales. Translation and scale invariant by
construction, but not rotation invariant (orientation is measured against the
image axes, because the pose matters). :mod:`bodymetry.estimation.codebook`
quantizes them into the feature ``X_sc``. Conventions (masks, image points,
angles, ``rng``) are :mod:`bodymetry.estimation.features`'; see
``docs/features.md``.
"""

from __future__ import annotations

import functools
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.features import (
    RngLike,
    as_rng,
    compiled_kernels,
    positive_float,
    positive_int,
    silhouette_contour,
)

__all__ = [
    "DEFAULT_R_IN_FRACTION",
    "ShapeContextConfig",
    "contour_descriptors",
    "multiscale_shape_contexts",
    "sample_contour_points",
    "sc_descriptors",
    "shape_context_descriptors",
]

# Default ratio r_in / r_out of the log-polar grid. The paper uses r_in = 3 px
# with r_out = h / 4 for silhouettes roughly 400 px tall (r_out ~ 100 px), i.e.
# a ratio of about 1/32; keeping the ratio (rather than 3 px) keeps the
# descriptor scale invariant.
DEFAULT_R_IN_FRACTION = 1.0 / 32.0


def _kappas(kappas: object, name: str = "kappas") -> tuple[float, ...]:
    if isinstance(kappas, numbers.Real):
        raise ValueError(f"{name}: expected a sequence of positive numbers, got {kappas!r}")
    try:
        values = tuple(kappas)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(
            f"{name}: expected a sequence of positive numbers, got {kappas!r}"
        ) from None
    if not values:
        raise ValueError(f"{name}: expected at least one scale, got an empty sequence")
    return tuple(positive_float(k, f"{name}[{i}]") for i, k in enumerate(values))


def _check_contour(contour: ArrayLike, name: str = "contour") -> NDArray[np.float64]:
    c = np.asarray(contour, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 2:
        raise ValueError(f"{name}: expected a (P, 2) array of (x, y) points, got shape {c.shape}")
    if c.shape[0] < 1:
        raise ValueError(f"{name}: expected at least one point, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name}: contains non-finite coordinates")
    return c


@dataclass(frozen=True)
class ShapeContextConfig:
    """Parameters of the multi-scale shape-context descriptor.

    Attributes
    ----------
    kappas : tuple of float
        Scales: ``r_out = kappa * h`` with ``h`` the silhouette height in
        pixels; one 60-bin block per scale. Default ``(0.25, 0.5, 1.0)``
        (paper: ``1/4`` "roughly the limb size", more scales help shape).
    n_theta : int
        Orientation bins (paper ``phi = 12``).
    n_r : int
        Log-radial bins (paper ``r = 5``).
    r_in_fraction : float
        ``r_in = r_in_fraction * r_out`` (default 1/32, the paper's 3 px at
        ``r_out`` ~ 100 px), relative so that scale invariance holds.
    n_points : int
        Contour points sampled per silhouette (default 300).
    """

    kappas: tuple[float, ...] = (0.25, 0.5, 1.0)
    n_theta: int = 12
    n_r: int = 5
    r_in_fraction: float = DEFAULT_R_IN_FRACTION
    n_points: int = 300

    def __post_init__(self) -> None:
        object.__setattr__(self, "kappas", _kappas(self.kappas, "kappas"))
        object.__setattr__(self, "n_theta", positive_int(self.n_theta, "n_theta"))
        object.__setattr__(self, "n_r", positive_int(self.n_r, "n_r"))
        object.__setattr__(self, "n_points", positive_int(self.n_points, "n_points"))
        frac = positive_float(self.r_in_fraction, "r_in_fraction")
        if frac >= 1.0:
            raise ValueError(f"r_in_fraction: expected a value in (0, 1), got {frac!r}")
        object.__setattr__(self, "r_in_fraction", frac)

    @property
    def n_bins(self) -> int:
        """Bins per descriptor block, ``n_theta * n_r``."""
        return self.n_theta * self.n_r


def _sample_points(
    contour: NDArray[np.float64], n_points: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """``n_points`` points evenly spaced in arc length, at a random phase.

    The closed polyline through ``contour`` is cut at arc lengths
    ``(u + k) L / n_points``, ``k = 0 .. n_points - 1``, with one random
    ``u ~ U[0, 1)`` (stratified sampling), and the points are interpolated
    linearly between contour vertices. Returns ``(n_points, 2)`` positions
    relative to ``contour[0]`` (the histograms only use differences).
    """
    # relative to the first point: shapes that differ by a translation give
    # bit-identical samples (and so identical histograms)
    origin = contour[0]
    closed = np.concatenate([contour, contour[:1]]) - origin
    seg = np.hypot(*np.diff(closed, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    length = cum[-1]
    u = rng.random()
    if length <= 0.0:  # a single pixel
        return np.zeros((n_points, 2))
    t = (u + np.arange(n_points)) * (length / n_points)
    j = np.clip(np.searchsorted(cum, t, side="right") - 1, 0, seg.size - 1)
    frac = ((t - cum[j]) / np.where(seg[j] > 0, seg[j], 1.0))[:, None]
    return closed[j] + frac * (closed[j + 1] - closed[j])


def sample_contour_points(contour: ArrayLike, n_points: int, rng: RngLike) -> NDArray[np.float64]:
    """The points the shape context samples on a contour (for plots and overlays).

    Parameters
    ----------
    contour : (P, 2) float
        Boundary points ``(x, y)`` in order along the closed outline.
    n_points : int
        Number of points ``N``.
    rng : numpy.random.Generator or int
        The same generator state as given to :func:`multiscale_shape_contexts`
        gives the same points.

    Returns
    -------
    points : (N, 2) float64
        Image coordinates, evenly spaced in arc length at a random phase.
    """
    c = _check_contour(contour)
    return _sample_points(c, positive_int(n_points, "n_points"), as_rng(rng)) + c[0]


def _histograms(
    points: NDArray[np.float64],
    height: float,
    kappas: tuple[float, ...],
    n_theta: int,
    n_r: int,
    r_in_fraction: float,
) -> NDArray[np.float64]:
    """Log-polar histograms ``(S, N, n_theta * n_r)`` of ``points`` ``(N, 2)``.

    By :data:`BACKEND`: the compiled kernel (``feature_kernels.histograms_kernel``)
    or the numpy reference (:func:`_histograms_numpy`); the same histograms.
    """
    kernels = compiled_kernels()
    if kernels is None:
        return _histograms_numpy(points, height, kappas, n_theta, n_r, r_in_fraction)
    n = points.shape[0]
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    upper, lower = _orientation_edges(n_theta)
    counts = np.zeros((len(kappas), n, n_theta * n_r), np.int64)
    pairs = np.empty((n * (n - 1) // 2, 2), np.int64)
    n_pairs = kernels.histogram_counts_kernel(
        x,
        y,
        _radial_edges(height, kappas, n_r, r_in_fraction),
        upper,
        lower,
        lower.shape[0] == upper.shape[0],
        _EDGE_TOL,
        counts,
        pairs,
    )
    pairs = pairs[:n_pairs]
    t_ij, t_ji, radial = _reference_bins(x, y, pairs, height, kappas, n_theta, n_r, r_in_fraction)
    out = np.empty((len(kappas), n, n_theta * n_r))
    kernels.histogram_add_kernel(counts, pairs, t_ij, t_ji, radial, n_theta, out)
    return out


#: Relative distance from a bin edge under which the compiled histograms leave a
#: pair to the reference's expressions. Their rounding decides pairs within about
#: 1e-15 of an edge (numpy's arctan2 and log differ from libm's in the last bit,
#: and adding ``0.5 + n_theta`` rounds the bin coordinate to about 2e-15), and
#: such pairs are common: contour points on one diagonal pixel run lie at
#: exactly 45 degrees, an orientation edge, up to rounding.
_EDGE_TOL = 1e-10


def _reference_bins(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    pairs: NDArray[np.int64],
    height: float,
    kappas: tuple[float, ...],
    n_theta: int,
    n_r: int,
    r_in_fraction: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Bins of point pairs ``(A, 2)`` by :func:`_histograms_numpy`'s expressions, bit for bit.

    Returns the orientation bins ``(A,)`` of ``j`` from ``i`` and of ``i`` from
    ``j``, and the radial bins ``(S, A)`` (``n_r``: beyond ``r_out``).
    """
    i, j = pairs[:, 0], pairs[:, 1]
    a = len(pairs)
    # Both directions in one call (elementwise, the same values): j from i, then i
    # from j as x[i] - x[j], like the reference (+0.0 where equal, not -0.0:
    # arctan2 tells them apart on the horizontal).
    dx = np.concatenate([x[j] - x[i], x[i] - x[j]])
    dy = np.concatenate([y[j] - y[i], y[i] - y[j]])
    t = np.arctan2(dy, dx)
    t *= n_theta / (2.0 * np.pi)
    t += 0.5 + n_theta
    theta = np.floor(t).astype(np.int64) % n_theta
    log_d2 = dx[:a] * dx[:a]
    log_d2 += dy[:a] * dy[:a]
    with np.errstate(divide="ignore"):
        np.log(log_d2, out=log_d2)
    gain = n_r / (2.0 * np.log(1.0 / r_in_fraction))
    # 2 log r_in per scale by scalar calls, as the reference computes it
    log_r_in2 = np.array([2.0 * np.log(r_in_fraction * kappa * height) for kappa in kappas])
    q = log_d2[None, :] - log_r_in2[:, None]
    q *= gain
    radial = np.clip(np.floor(q), 0, n_r).astype(np.int64)
    return theta[:a], theta[a:], radial


@functools.lru_cache(maxsize=8)
def _orientation_edges(n_theta: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit directions of the orientation bin edges, for the compiled histograms.

    Edge ``m`` is at the angle ``(m + 1/2) 2 pi / n_theta`` (bins centred on the
    image axes). Returns those with angles in ``[0, pi)`` (U, 2) and in
    ``[pi, 2 pi)`` (n_theta - U, 2), each in increasing angle. For an even
    ``n_theta`` the second are the exact negations of the first, so a pair of
    points and its reverse fall into exactly opposite bins.
    """
    angles = (np.arange(n_theta) + 0.5) * (2.0 * np.pi / n_theta)
    edges = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    if n_theta % 2 == 0:
        upper = edges[: n_theta // 2]
        lower = -upper
    else:
        upper, lower = edges[angles < np.pi], edges[angles >= np.pi]
    upper, lower = np.ascontiguousarray(upper), np.ascontiguousarray(lower)
    upper.setflags(write=False)
    lower.setflags(write=False)
    return upper, lower


def _radial_edges(
    height: float, kappas: tuple[float, ...], n_r: int, r_in_fraction: float
) -> NDArray[np.float64]:
    """Squared outer radii ``(S, n_r)`` of the radial bins, for the compiled histograms.

    The reference's bin is ``floor((log d^2 - 2 log r_in) * gain)`` with
    ``gain = n_r / (2 log(1 / r_in_fraction))``: it reaches ``k`` at
    ``d^2 = exp(2 log r_in + k / gain)``, computed here from the same ``log r_in``
    and ``gain``; the last edge is ``r_out^2``.
    """
    gain = n_r / (2.0 * np.log(1.0 / r_in_fraction))
    log_r_in2 = 2.0 * np.log(r_in_fraction * np.asarray(kappas, dtype=np.float64) * height)
    return np.exp(log_r_in2[:, None] + np.arange(1, n_r + 1) / gain)


def _histograms_numpy(
    points: NDArray[np.float64],
    height: float,
    kappas: tuple[float, ...],
    n_theta: int,
    n_r: int,
    r_in_fraction: float,
) -> NDArray[np.float64]:
    """The numpy reference of :func:`_histograms`: every ordered pair's bins by
    ``floor`` of an ``arctan2`` and of a ``log``."""
    n = points.shape[0]
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    # (N, N) work arrays, updated in place (fewer large temporaries)
    dx = x[None, :] - x[:, None]  # other - self
    dy = y[None, :] - y[:, None]
    # orientation bins centred on the image axes: bin k covers
    # [(k - 1/2), (k + 1/2)) * 2 pi / n_theta, so the frequent horizontal and
    # vertical pixel-grid directions never sit on a bin edge.
    # Orientation bin + n_theta, in [n_theta/2, 3 n_theta/2]: bins k and
    # k + n_theta are the same bin and are merged after counting (cheaper
    # than a modulo over N^2 floats).
    base = np.arctan2(dy, dx)
    base *= n_theta / (2.0 * np.pi)
    base += 0.5 + n_theta
    np.floor(base, out=base)
    # n_theta = 1 puts the one bin edge at pi: arctan2 = pi lands on 2 n_theta,
    # which is bin n_theta (= bin 0) again, not the next radial row's first bin.
    base[base >= 2 * n_theta] -= n_theta
    # flat bin index (kept in float64, exact for integers) into an
    # (N, n_r + 1, 2 n_theta) array whose last radial row collects the points
    # at r >= r_out (and the point itself), dropped below
    width = (n_r + 1) * 2 * n_theta
    base += (np.arange(n, dtype=np.float64) * width)[:, None]
    log_d2 = dx
    log_d2 *= dx
    dy *= dy
    log_d2 += dy
    np.fill_diagonal(log_d2, np.inf)  # a point is not its own neighbour
    with np.errstate(divide="ignore"):
        np.log(log_d2, out=log_d2)  # log r^2 (-inf for a duplicate point)
    q = dy
    gain = n_r / (2.0 * np.log(1.0 / r_in_fraction))
    out = np.empty((len(kappas), n, n_theta * n_r))
    for s, kappa in enumerate(kappas):
        r_in = r_in_fraction * kappa * height
        # radial bin k covers [r_in g^k, r_in g^(k+1)), g = (r_out / r_in)^(1/n_r);
        # points closer than r_in fall into the innermost bin (as in
        # Belongie et al.'s reference code); points at r >= r_out are ignored.
        np.subtract(log_d2, 2.0 * np.log(r_in), out=q)
        q *= gain
        np.floor(q, out=q)
        np.clip(q, 0, n_r, out=q)
        q *= 2 * n_theta
        q += base
        counts = np.bincount(q.astype(np.intp).ravel(), minlength=n * width)
        counts = counts.reshape(n, n_r + 1, 2, n_theta)[:, :n_r].sum(axis=2)
        counts = counts.reshape(n, n_r * n_theta).astype(np.float64)
        total = counts.sum(axis=1, keepdims=True)
        out[s] = counts / np.where(total > 0, total, 1.0)
    return out


def _contour_height(contour: NDArray[np.float64]) -> float:
    return float(contour[:, 1].max() - contour[:, 1].min() + 1.0)


def multiscale_shape_contexts(
    contour: ArrayLike,
    n_points: int,
    rng: RngLike,
    *,
    kappas: Sequence[float] = (0.25, 0.5, 1.0),
    n_theta: int = 12,
    n_r: int = 5,
    r_in_fraction: float = DEFAULT_R_IN_FRACTION,
    height: float | None = None,
) -> NDArray[np.float64]:
    """Shape-context histograms at several scales, at the same sampled points.

    ``n_points`` points are sampled on the closed polyline through ``contour``
    at random but evenly spaced in arc length: at ``(u + k) L / n_points`` for
    ``k = 0 .. n_points - 1`` with one random phase ``u ~ U[0, 1)`` (``L`` the
    perimeter). This stratified sampling is as unbiased as drawing contour
    points independently but far less noisy: the same shape at two scales or
    offsets gives nearly the same descriptor set.

    At each sampled point, the other sampled points within
    ``r_out = kappa * h`` are counted in a log-polar grid: ``n_theta``
    orientation bins, bin ``k`` centred on the angle ``2 pi k / n_theta`` from
    ``+x`` towards ``+y`` (image axes, so not rotation invariant), and ``n_r``
    radial bins spaced logarithmically from ``r_in = r_in_fraction * r_out`` to
    ``r_out`` (points closer than ``r_in`` count in the innermost bin). Each
    histogram is divided by its sum, so it sums to 1 (a point with no neighbour
    within ``r_out`` keeps an all-zero histogram). Since all radii are
    proportional to ``h``, the descriptor is translation and scale invariant.

    Parameters
    ----------
    contour : (P, 2) float
        Boundary points ``(x, y)`` in order along the closed outline, e.g.
        from :func:`silhouette_contour`.
    n_points : int
        Number of points to sample, ``N``.
    rng : numpy.random.Generator or int
        Sampling randomness.
    kappas : sequence of float, default (0.25, 0.5, 1.0)
        Scales, ``S`` of them.
    n_theta, n_r : int, default 12, 5
        Orientation and log-radial bins.
    r_in_fraction : float, default 1/32
        ``r_in / r_out``.
    height : float, optional
        Silhouette height ``h`` in pixels; default the contour's row extent
        ``max(y) - min(y) + 1``.

    Returns
    -------
    descriptors : (S, N, n_theta * n_r) float64
        Bin index ``r_bin * n_theta + theta_bin``.

    Raises
    ------
    ValueError
        On a malformed contour or parameter (the message names it).
    """
    c = _check_contour(contour)
    n_points = positive_int(n_points, "n_points")
    gen = as_rng(rng)
    cfg = ShapeContextConfig(
        kappas=kappas,  # type: ignore[arg-type]
        n_theta=n_theta,
        n_r=n_r,
        r_in_fraction=r_in_fraction,
        n_points=n_points,
    )
    h = _contour_height(c) if height is None else positive_float(height, "height")
    pts = _sample_points(c, n_points, gen)
    return _histograms(pts, h, cfg.kappas, cfg.n_theta, cfg.n_r, cfg.r_in_fraction)


def shape_context_descriptors(
    contour: ArrayLike,
    n_points: int,
    rng: RngLike,
    *,
    n_theta: int = 12,
    n_r: int = 5,
    kappa: float = 0.25,
    r_in_fraction: float = DEFAULT_R_IN_FRACTION,
    height: float | None = None,
) -> NDArray[np.float64]:
    """Shape-context histograms at one scale ``r_out = kappa * h``.

    Same as :func:`multiscale_shape_contexts` with ``kappas=(kappa,)``.

    Returns
    -------
    descriptors : (n_points, n_theta * n_r) float64
        Each row sums to 1 (or is all zero for an isolated point).
    """
    kappa = positive_float(kappa, "kappa")
    return multiscale_shape_contexts(
        contour,
        n_points,
        rng,
        kappas=(kappa,),
        n_theta=n_theta,
        n_r=n_r,
        r_in_fraction=r_in_fraction,
        height=height,
    )[0]


def contour_descriptors(
    contour: NDArray[np.float64], rng: RngLike, config: ShapeContextConfig
) -> NDArray[np.float64]:
    """Multi-scale shape contexts at ``config.n_points`` points sampled on a contour.

    Parameters
    ----------
    contour : (P, 2) float64
        A silhouette's outer contour (:func:`~bodymetry.estimation.features.
        silhouette_contour`); its height sets the scales.
    rng : numpy.random.Generator or int
        Sampling randomness.
    config : ShapeContextConfig
        Descriptor parameters.

    Returns
    -------
    descriptors : (S, config.n_points, config.n_bins) float64
    """
    return _histograms(
        _sample_points(contour, config.n_points, as_rng(rng)),
        _contour_height(contour),
        config.kappas,
        config.n_theta,
        config.n_r,
        config.r_in_fraction,
    )


def sc_descriptors(
    mask: ArrayLike, rng: RngLike, config: ShapeContextConfig | None = None
) -> NDArray[np.float64]:
    """Multi-scale shape contexts of a silhouette mask (input to :func:`fit_codebook`).

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette.
    rng : numpy.random.Generator or int
        Sampling randomness.
    config : ShapeContextConfig, optional
        Descriptor parameters (default :class:`ShapeContextConfig()`).

    Returns
    -------
    descriptors : (S, config.n_points, config.n_bins) float64
    """
    cfg = ShapeContextConfig() if config is None else config
    if not isinstance(cfg, ShapeContextConfig):
        raise ValueError(f"config: expected a ShapeContextConfig, got {type(cfg).__name__}")
    return contour_descriptors(silhouette_contour(mask), rng, cfg)
