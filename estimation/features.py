"""Silhouette features for discriminative estimation (paper §3).

Two descriptors of one view's silhouette:

* **Radial distance function** (RDF, :func:`rdf`): the silhouette centroid
  followed by the maximal extent of the outer contour in ``n`` equally spaced
  directions from it, in pixels. Deliberately *not* translation or scale
  invariant: with a calibrated, fixed camera, position and size carry the
  body's location and height.
* **Histograms of shape context** (SC, :func:`sc_features`): log-polar
  histograms (``n_theta = 12`` orientations x ``n_r = 5`` radii, outer radius
  ``r_out = kappa * h`` with ``h`` the silhouette height) at randomly sampled
  contour points, vector-quantized into a K-centre k-means :class:`Codebook`
  with soft voting and normalized to unit length. Translation and scale
  invariant by construction, but not rotation invariant (orientation is
  measured against the image axes, because the pose matters).

Conventions
-----------
* Masks are 2-D arrays ``(H, W)``; ``bool`` or any integer/float array whose
  non-zero pixels are the foreground. Only the largest blob (by enclosed area) is
  used (the capture stage cleans masks to one person blob anyway).
* Image points are ``(x, y)`` pixel-centre coordinates: ``x`` = column
  (right), ``y`` = row (down), as OpenCV.
* Angles are measured in the image frame from ``+x`` towards ``+y`` (that is
  clockwise on screen), starting at ``0``.
* Every random choice takes ``rng``: a :class:`numpy.random.Generator` or an
  integer seed. The same inputs and seed give the same output.

See ``docs/features.md`` for the definitions, the design choices and timings.
"""

from __future__ import annotations

import functools
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import ModuleType

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.backends import default_backend, module_kernels

__all__ = [
    "Codebook",
    "ShapeContextConfig",
    "draw_rdf",
    "draw_shape_context_grid",
    "fit_codebook",
    "multiscale_shape_contexts",
    "rdf",
    "rdf_batch",
    "sample_contour_points",
    "sc_descriptors",
    "sc_features",
    "shape_context_descriptors",
    "silhouette_contour",
    "silhouette_features",
]

RngLike = np.random.Generator | int | np.integer

_BACKENDS = ("numba", "numpy")

#: The implementation of the shape-context histograms, the codebook encoding and
#: the RDF's ray casting: ``"numba"`` (``feature_kernels.py``: the same
#: histograms, encodings equal to about 1e-15, extents to about 1e-12 px) or
#: ``"numpy"`` (the reference). From ``$BODYMETRY_FEATURES``; by
#: default numba when installed. Read at every call, so tests and benchmarks may
#: set it.
BACKEND: str = default_backend(
    "BODYMETRY_FEATURES", os.environ.get("BODYMETRY_FEATURES"), _BACKENDS, "numba"
)


def _kernels() -> ModuleType | None:
    """The compiled feature kernels, or None for the numpy path (see ``raster._kernels``)."""
    return module_kernels(
        globals(),
        "BACKEND",
        "bodymetry.estimation.feature_kernels",
        "BODYMETRY_FEATURES",
        "shape-context features",
    )


# Default ratio r_in / r_out of the log-polar grid. The paper uses r_in = 3 px
# with r_out = h / 4 for silhouettes roughly 400 px tall (r_out ~ 100 px), i.e.
# a ratio of about 1/32; keeping the ratio (rather than 3 px) keeps the
# descriptor scale invariant.
DEFAULT_R_IN_FRACTION = 1.0 / 32.0


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------


def _as_rng(rng: RngLike, name: str = "rng") -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, numbers.Integral) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise ValueError(f"{name}: expected a numpy.random.Generator or an int seed, got {rng!r}")


def _positive_int(value: object, name: str, minimum: int = 1) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def _positive_float(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected a positive number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
    return v


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
    return tuple(_positive_float(k, f"{name}[{i}]") for i, k in enumerate(values))


def _as_mask(mask: ArrayLike, name: str = "mask") -> NDArray[np.uint8]:
    """Validate a 2-D mask and return it as a 0/1 ``uint8`` array ``(H, W)``."""
    arr = np.asarray(mask)
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D (H, W) mask, got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name}: expected a non-empty (H, W) mask, got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr.view(np.uint8)
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name}: expected a bool or numeric mask, got dtype {arr.dtype}")
    return (arr != 0).view(np.uint8)


def _largest_blob(
    mask: ArrayLike, name: str = "mask"
) -> tuple[NDArray[np.uint8], int, int, NDArray[np.float64]]:
    """The largest blob of a mask: its pixels and its outer contour.

    The largest blob is the external contour enclosing the largest area
    (``cv2.contourArea``; ties go to the longer contour, then the first found).

    Returns
    -------
    roi : (h, w) uint8
        0/1 pixels of the blob alone (holes kept) inside its bounding box.
    x0, y0 : int
        Image coordinates of ``roi[0, 0]``.
    contour : (P, 2) float64
        Its boundary pixel centres ``(x, y)``, ``CHAIN_APPROX_NONE``, oriented
        clockwise on screen, starting at the top-most, then left-most pixel.
    """
    m = _as_mask(mask, name)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ValueError(f"{name}: the mask is empty (no foreground pixel), shape {m.shape}")
    if len(contours) == 1:
        best = contours[0]
    else:
        best = max(contours, key=lambda c: (cv2.contourArea(c), len(c)))
    x0, y0, w, h = cv2.boundingRect(best)
    roi = m[y0 : y0 + h, x0 : x0 + w]
    if len(contours) > 1:  # keep only this blob's pixels (and its holes)
        fill = np.zeros((h, w), np.uint8)
        cv2.drawContours(fill, [best], -1, 1, cv2.FILLED, offset=(-x0, -y0))
        roi = roi & fill
    c = best.reshape(-1, 2).astype(np.float64)
    # consistent orientation: positive shoelace area in (x right, y down),
    # i.e. clockwise on screen (OpenCV returns outer contours the other way).
    x, y = c[:, 0], c[:, 1]
    if np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)) < 0:
        c = np.concatenate([c[:1], c[:0:-1]])  # same start point, reversed
    return roi, x0, y0, c


def _simplify(contour: NDArray[np.float64]) -> NDArray[np.float64]:
    """Drop points whose incoming and outgoing steps are equal (collinear runs).

    Same polygon as the input, like ``CHAIN_APPROX_SIMPLE``; ``(P', 2)``.
    """
    if contour.shape[0] < 3:
        return contour
    d_in = contour - np.roll(contour, 1, axis=0)
    d_out = np.roll(contour, -1, axis=0) - contour
    keep = np.any(d_in != d_out, axis=1)
    return contour[keep] if keep.any() else contour[:1]


def _check_contour(contour: ArrayLike, name: str = "contour") -> NDArray[np.float64]:
    c = np.asarray(contour, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 2:
        raise ValueError(f"{name}: expected a (P, 2) array of (x, y) points, got shape {c.shape}")
    if c.shape[0] < 1:
        raise ValueError(f"{name}: expected at least one point, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name}: contains non-finite coordinates")
    return c


# --------------------------------------------------------------------------
# contour and radial distance function
# --------------------------------------------------------------------------


def silhouette_contour(mask: ArrayLike) -> NDArray[np.float64]:
    """External boundary of the largest blob of a silhouette mask.

    The largest blob is the external contour enclosing the largest area.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette; any numeric array is accepted with non-zero = foreground.

    Returns
    -------
    contour : (P, 2) float64
        Every boundary pixel centre ``(x, y)`` of the largest blob
        (``cv2.findContours``, ``RETR_EXTERNAL``, ``CHAIN_APPROX_NONE``), in
        order along the boundary, starting at the top-most (then left-most)
        pixel and oriented clockwise on screen (positive shoelace area in image
        coordinates). Consecutive points are 8-neighbours; holes are ignored.
        A single-pixel blob gives ``P = 1``.

    Raises
    ------
    ValueError
        If ``mask`` is not 2-D, not numeric, or has no foreground pixel.
    """
    return _largest_blob(mask)[3]


def _ray_extents(
    polygon: NDArray[np.float64], center: NDArray[np.float64], n: int
) -> NDArray[np.float64]:
    """Farthest intersection of ``n`` rays from ``center`` with a closed polygon.

    ``polygon`` is ``(P, 2)``, implicitly closed. Returns ``(n,)`` distances;
    a ray that meets no edge (possible only if ``center`` lies outside the
    polygon) gets 0.

    O(P + n * winding): each edge is intersected only with the rays inside the
    angle it subtends at the centre (an edge never subtends pi or more unless
    it passes through the centre, which is then handled as a zero distance).
    """
    step = 2.0 * np.pi / n
    a = polygon - center  # (P, 2) vertices relative to the centre
    if a.shape[0] == 1:
        return np.full(n, float(np.hypot(a[0, 0], a[0, 1])))
    b = np.roll(a, -1, axis=0)
    e = b - a  # edge vectors
    phi = np.arctan2(a[:, 1], a[:, 0])  # vertex angles in (-pi, pi]
    dphi = np.roll(phi, -1) - phi
    dphi -= 2.0 * np.pi * np.round(dphi / (2.0 * np.pi))  # signed, in [-pi, pi]
    lo = np.minimum(phi, phi + dphi) - 1e-9  # widened: no ray slips between edges
    hi = np.maximum(phi, phi + dphi) + 1e-9
    k_lo = np.ceil(lo / step).astype(np.int64)
    k_hi = np.floor(hi / step).astype(np.int64)
    count = np.maximum(k_hi - k_lo + 1, 0)
    edge = np.repeat(np.arange(a.shape[0]), count)  # one (edge, ray) pair per row
    first = np.repeat(np.cumsum(count) - count, count)
    k = np.repeat(k_lo, count) + (np.arange(edge.size) - first)
    ang = k * step
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    ae, ee = a[edge], e[edge]
    denom = d[:, 0] * ee[:, 1] - d[:, 1] * ee[:, 0]  # d x e
    a_x_d = ae[:, 0] * d[:, 1] - ae[:, 1] * d[:, 0]  # a x d
    radial = np.abs(denom) <= 1e-12 * (1.0 + np.hypot(ee[:, 0], ee[:, 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip(np.where(radial, 0.0, a_x_d / denom), 0.0, 1.0)
    p = ae + u[:, None] * ee
    dist = np.hypot(p[:, 0], p[:, 1])
    # an edge along the ray: its farther end
    far = np.maximum(np.hypot(ae[:, 0], ae[:, 1]), np.hypot(*b[edge].T))
    dist = np.where(radial, far, dist)
    ext = np.zeros(n)
    np.maximum.at(ext, k % n, dist)
    return ext


def rdf(mask: ArrayLike, n: int = 100) -> NDArray[np.float64]:
    """Radial distance function of a silhouette (paper §3).

    ``X_rdf = (p_c, ||p_1 - p_c||, ..., ||p_n - p_c||)``: the centroid ``p_c`` of
    the largest blob, followed by the maximal extent of its outer contour in
    ``n`` equally spaced directions from the centroid.

    The extent in direction ``i`` (angle ``2 pi i / n`` from ``+x`` towards
    ``+y``) is found by ray casting: the distance from ``p_c`` to the farthest
    intersection of the ray with the outer-contour polygon (through boundary
    pixel centres, with collinear points dropped as ``CHAIN_APPROX_SIMPLE``
    does, which leaves the polygon unchanged). Unlike the farthest contour point
    in an angular bin, this is continuous in the shape, defined in every
    direction (no empty bins) and exact for thin limbs. If the centroid lies
    outside the silhouette (possible for strongly bent shapes), a direction
    whose ray misses the contour gets extent 0.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette (non-zero = foreground).
    n : int, default 100
        Number of directions.

    Returns
    -------
    x_rdf : (n + 2,) float64
        ``[cx, cy, r_0, ..., r_{n-1}]`` in pixels: the centroid (mean of the
        blob's pixel centres, holes excluded) then the extents. Not translation
        or scale invariant, as the paper says: a translation moves ``p_c`` by
        the same amount and leaves the extents unchanged; scaling the
        silhouette by ``s`` scales the extents by ``s``. Extents are measured
        to boundary pixel centres, i.e. about half a pixel inside the edge of
        the silhouette's pixel area.

    Raises
    ------
    ValueError
        If ``mask`` is not a 2-D numeric array, is empty, or ``n < 1``.
    """
    n = _positive_int(n, "n")
    return _rdf_of_blob(*_largest_blob(mask), n)


def _rdf_of_blob(
    roi: NDArray[np.uint8], x0: int, y0: int, contour: NDArray[np.float64], n: int
) -> NDArray[np.float64]:
    """:func:`rdf` of a blob from :func:`_largest_blob`, (n + 2,)."""
    mom = cv2.moments(roi, binaryImage=True)
    center = np.array([mom["m10"] / mom["m00"] + x0, mom["m01"] / mom["m00"] + y0])
    out = np.empty(n + 2)
    out[:2] = center
    kernels = _kernels()
    if kernels is None:
        out[2:] = _ray_extents(_simplify(contour), center, n)
    else:
        kernels.ray_extents_kernel(contour, float(center[0]), float(center[1]), n, out[2:])
    return out


def rdf_batch(masks: ArrayLike | Sequence[ArrayLike], n: int = 100) -> NDArray[np.float64]:
    """:func:`rdf` of several masks, e.g. one per camera.

    Parameters
    ----------
    masks : (B, H, W) bool, or sequence of B (H_b, W_b) bool
        Silhouettes; as a sequence they may differ in size (cameras of a rig
        with different image sizes). Each RDF is in its own mask's pixels.
    n : int, default 100
        Number of directions.

    Returns
    -------
    x_rdf : (B, n + 2) float64
        One RDF per mask. Contours differ in length, so this is a loop over
        masks (each :func:`rdf` is already vectorized over directions).

    Raises
    ------
    ValueError
        If ``masks`` is neither a 3-D stack nor a sequence of 2-D masks, or any
        mask is empty (the message names the index).
    """
    if isinstance(masks, np.ndarray) or not isinstance(masks, Sequence):
        arr = np.asarray(masks)
        if arr.ndim != 3:
            raise ValueError(f"masks: expected a 3-D (B, H, W) stack, got shape {arr.shape}")
        items: Sequence[ArrayLike] = list(arr)
    else:
        items = masks
        for i, m in enumerate(items):
            if np.ndim(m) != 2:
                raise ValueError(f"masks[{i}]: expected a 2-D (H, W) mask, got shape {np.shape(m)}")
    n = _positive_int(n, "n")
    out = np.empty((len(items), n + 2))
    for i, mask in enumerate(items):
        try:
            out[i] = rdf(mask, n)
        except ValueError as exc:
            raise ValueError(f"masks[{i}]: {exc}") from None
    return out


# --------------------------------------------------------------------------
# shape context
# --------------------------------------------------------------------------


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
        object.__setattr__(self, "n_theta", _positive_int(self.n_theta, "n_theta"))
        object.__setattr__(self, "n_r", _positive_int(self.n_r, "n_r"))
        object.__setattr__(self, "n_points", _positive_int(self.n_points, "n_points"))
        frac = _positive_float(self.r_in_fraction, "r_in_fraction")
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
    return _sample_points(c, _positive_int(n_points, "n_points"), _as_rng(rng)) + c[0]


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
    kernels = _kernels()
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
    n_points = _positive_int(n_points, "n_points")
    gen = _as_rng(rng)
    cfg = ShapeContextConfig(
        kappas=kappas,  # type: ignore[arg-type]
        n_theta=n_theta,
        n_r=n_r,
        r_in_fraction=r_in_fraction,
        n_points=n_points,
    )
    h = _contour_height(c) if height is None else _positive_float(height, "height")
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
    kappa = _positive_float(kappa, "kappa")
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


def silhouette_features(
    mask: ArrayLike, rng: RngLike, config: ShapeContextConfig, n: int = 100
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`rdf` and :func:`sc_descriptors` of one silhouette, its contour traced once.

    The same values as the two calls (``rng`` drawn from as by
    :func:`sc_descriptors`); training computes both for every rendered view.

    Returns
    -------
    x_rdf : (n + 2,) float64
    descriptors : (S, config.n_points, config.n_bins) float64
    """
    if not isinstance(config, ShapeContextConfig):
        raise ValueError(f"config: expected a ShapeContextConfig, got {type(config).__name__}")
    blob = _largest_blob(mask)
    contour = blob[3]
    descriptors = _histograms(
        _sample_points(contour, config.n_points, _as_rng(rng)),
        _contour_height(contour),
        config.kappas,
        config.n_theta,
        config.n_r,
        config.r_in_fraction,
    )
    return _rdf_of_blob(*blob, _positive_int(n, "n")), descriptors


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
    contour = silhouette_contour(mask)
    return _histograms(
        _sample_points(contour, cfg.n_points, _as_rng(rng)),
        _contour_height(contour),
        cfg.kappas,
        cfg.n_theta,
        cfg.n_r,
        cfg.r_in_fraction,
    )


# --------------------------------------------------------------------------
# codebook
# --------------------------------------------------------------------------


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
        nn = _positive_int(self.n_nearest, "n_nearest")
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
        kernels = _kernels()
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
    k = _positive_int(k, "k")
    if k > n:
        raise ValueError(f"k: expected at most the number of descriptors ({n}), got {k}")
    max_samples = _positive_int(max_samples, "max_samples")
    max_iter = _positive_int(max_iter, "max_iter")
    if config is None:
        config = ShapeContextConfig() if pool.scales_given else ShapeContextConfig(kappas=(0.25,))
    gen = _as_rng(rng)
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


def sc_features(mask: ArrayLike, codebook: Codebook, rng: RngLike) -> NDArray[np.float64]:
    """Codebook shape-context feature ``X_sc`` of a silhouette.

    Samples ``codebook.config.n_points`` contour points, computes their
    multi-scale shape contexts and encodes them with ``codebook``.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette.
    codebook : Codebook
        From :func:`fit_codebook`.
    rng : numpy.random.Generator or int
        Sampling randomness.

    Returns
    -------
    x_sc : (S * K,) float64
        Non-negative, unit length.
    """
    if not isinstance(codebook, Codebook):
        raise ValueError(f"codebook: expected a Codebook, got {type(codebook).__name__}")
    return codebook.encode(sc_descriptors(mask, rng, codebook.config))


# --------------------------------------------------------------------------
# drawing (docs figure, review overlays)
# --------------------------------------------------------------------------


def draw_rdf(
    image: NDArray[np.uint8],
    x_rdf: ArrayLike,
    color: tuple[int, int, int] = (0, 90, 255),
    thickness: int = 1,
) -> NDArray[np.uint8]:
    """Draw an RDF (rays from the centroid to the extents) on a BGR image, in place.

    Parameters
    ----------
    image : (H, W, 3) uint8
        BGR image (modified and returned).
    x_rdf : (n + 2,) float
        From :func:`rdf`.
    """
    x = np.asarray(x_rdf, dtype=np.float64)
    if x.ndim != 1 or x.size < 3:
        raise ValueError(f"x_rdf: expected an (n + 2,) vector, got shape {x.shape}")
    c, r = x[:2], x[2:]
    ang = np.arange(r.size) * (2.0 * np.pi / r.size)
    ends = c + r[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    s = 1 << 4
    c_i = tuple(int(v) for v in np.round(c * s))
    for e in np.round(ends * s).astype(np.int64):
        cv2.line(image, c_i, (int(e[0]), int(e[1])), color, thickness, cv2.LINE_AA, 4)
        cv2.circle(image, (int(e[0]), int(e[1])), 2 * s, color, -1, cv2.LINE_AA, 4)
    cv2.circle(image, c_i, 4 * s, (0, 0, 0), -1, cv2.LINE_AA, 4)
    return image


def draw_shape_context_grid(
    image: NDArray[np.uint8],
    point: ArrayLike,
    r_out: float,
    n_theta: int = 12,
    n_r: int = 5,
    r_in_fraction: float = DEFAULT_R_IN_FRACTION,
    color: tuple[int, int, int] = (200, 120, 0),
    thickness: int = 1,
) -> NDArray[np.uint8]:
    """Draw the log-polar shape-context grid around ``point`` on a BGR image, in place.

    Circles at the radial bin edges ``r_in g^k`` (``k = 0 .. n_r``) and the
    orientation bin edges (``(k + 1/2) 2 pi / n_theta``, bins centred on the
    image axes) between ``r_in`` and ``r_out``.
    """
    p = np.asarray(point, dtype=np.float64).reshape(2)
    r_in = r_in_fraction * r_out
    radii = r_in * (r_out / r_in) ** (np.arange(n_r + 1) / n_r)
    s = 1 << 4
    c_i = tuple(int(v) for v in np.round(p * s))
    for r in radii:
        cv2.circle(image, c_i, round(r * s), color, thickness, cv2.LINE_AA, 4)
    for k in range(n_theta):
        a = (k + 0.5) * 2.0 * np.pi / n_theta
        d = np.array([np.cos(a), np.sin(a)])
        p0, p1 = np.round((p + r_in * d) * s), np.round((p + r_out * d) * s)
        cv2.line(
            image,
            (int(p0[0]), int(p0[1])),
            (int(p1[0]), int(p1[1])),
            color,
            thickness,
            cv2.LINE_AA,
            4,
        )
    return image
