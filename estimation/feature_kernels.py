"""Compiled (numba) kernels of the silhouette features.

The kernels of :mod:`estimation.rdf`, :mod:`estimation.shape_context` and
:mod:`estimation.codebook`.

Imported lazily, only when ``features.BACKEND`` is ``"numba"``
(``$BODYMETRY_FEATURES``); numba comes from :mod:`bodymetry.jit`, which points
numba's on-disk cache first.

- :func:`histograms_kernel`: the log-polar shape-context histograms of one
  silhouette's sampled points at every scale (``shape_context._histograms``). The
  numpy reference bins each ordered pair of points by ``floor`` of an
  ``arctan2`` and of a ``log``; here the same bins come from comparisons with
  the bin edges (a cross product with each orientation edge's direction, the
  squared distance against each radial edge's square), without a
  transcendental function per pair, and each unordered pair's distance is
  computed once. The bins are the reference's except where a pair lies within
  rounding (about 1e-15 relative) of a bin edge, where the two paths may round
  to different sides: numpy's SIMD ``arctan2`` and ``log`` differ from libm's
  in the last bit anyway. Tests compare the histograms for equality.
- :func:`encode_kernel`: soft-voted codebook encoding (``Codebook.encode``):
  squared distances to the ``K`` centres, the ``n_nearest`` nearest (ties to
  the lower index, as the reference's ``argmin`` passes), Gaussian weights
  relative to the nearest, the per-scale histogram normalized to unit length.
  Dot products are summed over a descriptor's non-zero bins, in another
  order than BLAS's, so encodings agree with the reference to about 1e-15,
  not bit for bit (a descriptor equidistant from two centres to within that
  could vote differently; tests/estimation/test_feature_kernels.py states the
  tolerance).
- :func:`ray_extents_kernel`: the RDF's ray casting (``rdf._simplify``
  and ``rdf._ray_extents`` in one pass, the same expressions; extents
  equal bit for bit on 256 rendered training views, tested to 1e-9 px).
"""

from __future__ import annotations

import math

import numpy as np

from bodymetry.jit import numba


@numba.njit(cache=True, nogil=True, inline="always")
def _orientation_bin(vx, vy, upper, lower, tol):  # pragma: no cover
    """Orientation bin of the direction ``(vx, vy)`` (not both zero), or -1 when
    it lies within ``tol`` (relative) of a bin edge.

    ``upper`` (U, 2) are the bin edges' unit directions with angles in
    ``[0, pi)``, in increasing angle; ``lower`` (n_theta - U, 2) those in
    ``[pi, 2 pi)``. Within a half-plane, ``cross(edge, v) >= 0`` exactly when
    ``v``'s angle is at or past the edge's, so the bin is the number of edges
    passed; past the last edge wraps to bin 0. An odd ``n_theta`` has an edge
    at ``pi``, between the half-planes: a direction near the horizontal is
    then undecided too.
    """
    n_upper = upper.shape[0]
    n_theta = n_upper + lower.shape[0]
    scale = tol * (abs(vx) + abs(vy))
    if n_theta % 2 == 1 and abs(vy) <= scale:
        return -1
    if vy > 0.0 or (vy == 0.0 and vx > 0.0):  # angle in [0, pi)
        edges = upper
        k = 0
    else:
        edges = lower
        k = n_upper
    for m in range(edges.shape[0]):
        cross = edges[m, 0] * vy - edges[m, 1] * vx
        if abs(cross) <= scale:
            return -1
        if cross < 0.0:
            break
        k += 1
    return k % n_theta


@numba.njit(cache=True, nogil=True)
def histogram_counts_kernel(
    x, y, radial_edges, upper, lower, symmetric, tol, counts, pairs
):  # pragma: no cover
    """Log-polar shape-context counts of ``N`` points at ``S`` scales, but for the
    pairs near a bin edge.

    One function, not named steps: it is one compiled loop over the point pairs,
    each pair binned once for both of its points at every scale.

    Each unordered pair of points is binned once for both of its points: the
    squared distance against the radial edges, the direction by
    :func:`_orientation_bin`. A pair within ``tol`` (relative) of an
    orientation or radial edge is not counted but listed in ``pairs``: there
    the reference's rounding decides, and the caller bins it with the
    reference's own expressions (:func:`histogram_add_kernel`).

    Parameters
    ----------
    x, y : (N,) float64
        Point coordinates.
    radial_edges : (S, n_r) float64
        Per scale, the squared outer radii of the radial bins, increasing: a
        pair at squared distance ``d2`` falls into bin ``r``, the number of
        edges ``<= d2`` (bin 0 includes points closer than ``r_in``); ``r =
        n_r`` (at or beyond ``r_out``) is not counted.
    upper, lower : (U, 2), (n_theta - U, 2) float64
        Orientation bin edges (see :func:`_orientation_bin`).
    symmetric : bool
        Whether ``lower`` is exactly ``-upper`` (an even ``n_theta``): then the
        reverse pair's orientation bin is the opposite one, exactly
        (``cross(-e, v) = cross(e, -v)``), and is not searched again.
    tol : float
        Relative distance to an edge under which a pair is left to the caller.
    counts : (S, N, n_r * n_theta) int64
        Zeroed; receives the counts, bin ``r * n_theta + theta``.
    pairs : (N (N - 1) / 2, 2) int64
        Receives the undecided pairs ``(i, j)``, ``i < j``.

    Returns
    -------
    int
        The number of undecided pairs (rows of ``pairs`` filled).
    """
    n = x.shape[0]
    n_scales, n_r = radial_edges.shape
    n_theta = upper.shape[0] + lower.shape[0]
    half = n_theta // 2
    rs = np.empty(n_scales, np.int64)
    log_edge0 = np.log(radial_edges[:, 0])
    inv_log_step = 1.0 / math.log(radial_edges[0, 1] / radial_edges[0, 0]) if n_r > 1 else 0.0
    n_pairs = 0
    for i in range(n):
        for j in range(i + 1, n):
            # other - self for i; j's vector is its exact negation
            dx = x[j] - x[i]
            dy = y[j] - y[i]
            d2 = dx * dx + dy * dy
            if d2 == 0.0:  # duplicate points: the reference's arctan2(0, 0) = 0
                ti = 0
                tj = 0
            else:
                ti = _orientation_bin(dx, dy, upper, lower, tol)
                if ti < 0:
                    tj = -1
                elif symmetric:
                    tj = ti + half if ti < half else ti - half
                else:
                    tj = _orientation_bin(-dx, -dy, upper, lower, tol)
            if tj < 0:
                pairs[n_pairs, 0] = i
                pairs[n_pairs, 1] = j
                n_pairs += 1
                continue
            undecided = False
            # first guess of each scale's radial bin from one log (edges are
            # geometric: bin r from r_in^2 g^(2r)), then the exact test against
            # the edges on either side of d2, which alone can be within tol of it
            log_d2 = math.log(d2) if d2 > 0.0 else -math.inf
            for s in range(n_scales):
                g = (log_d2 - log_edge0[s]) * inv_log_step
                if g < 0.0:
                    r = 0
                elif g >= n_r:
                    r = n_r
                else:
                    r = int(g) + 1
                if r > 0 and d2 < radial_edges[s, r - 1]:
                    r -= 1
                elif r < n_r and d2 >= radial_edges[s, r]:
                    r += 1
                if r > 0 and d2 - radial_edges[s, r - 1] <= tol * radial_edges[s, r - 1]:
                    undecided = True
                if r < n_r and radial_edges[s, r] - d2 <= tol * radial_edges[s, r]:
                    undecided = True
                rs[s] = r
            if undecided:
                pairs[n_pairs, 0] = i
                pairs[n_pairs, 1] = j
                n_pairs += 1
                continue
            for s in range(n_scales):
                r = rs[s]
                if r < n_r:
                    counts[s, i, r * n_theta + ti] += 1
                    counts[s, j, r * n_theta + tj] += 1
    return n_pairs


@numba.njit(cache=True, nogil=True)
def histogram_add_kernel(counts, pairs, t_ij, t_ji, radial, n_theta, out):  # pragma: no cover
    """Add the caller's bins of the undecided pairs to ``counts``; normalize into ``out``.

    Parameters
    ----------
    counts : (S, N, n_r * n_theta) int64
        From :func:`histogram_counts_kernel` (updated).
    pairs : (A, 2) int64
        The undecided pairs ``(i, j)``.
    t_ij, t_ji : (A,) int64
        Orientation bin of ``j`` seen from ``i`` and of ``i`` seen from ``j``.
    radial : (S, A) int64
        Radial bin per scale, ``n_r`` for none.
    n_theta : int
    out : (S, N, n_r * n_theta) float64
        Receives each point's histogram divided by its sum (all zero for a
        point with no neighbour within ``r_out``).
    """
    n_scales, n, n_bins = counts.shape
    n_r = n_bins // n_theta
    for a in range(pairs.shape[0]):
        i, j = pairs[a, 0], pairs[a, 1]
        for s in range(n_scales):
            r = radial[s, a]
            if r < n_r:
                counts[s, i, r * n_theta + t_ij[a]] += 1
                counts[s, j, r * n_theta + t_ji[a]] += 1
    for s in range(n_scales):
        for i in range(n):
            total = 0
            for b in range(n_bins):
                total += counts[s, i, b]
            denom = float(total) if total > 0 else 1.0
            for b in range(n_bins):
                out[s, i, b] = float(counts[s, i, b]) / denom


@numba.njit(cache=True, nogil=True)
def encode_kernel(d, centers_t, centers_sq, sigma, n_nearest, out):  # pragma: no cover
    """Soft-voted bag-of-words histograms of one silhouette's descriptors.

    Parameters
    ----------
    d : (S, N, D) float64
        Descriptors per scale.
    centers_t : (S, D, K) float64
        The codebook's centres, transposed: a descriptor's dot products with
        all centres are accumulated over its non-zero bins only (shape contexts
        are about 2/3 zeros), the loop over centres innermost, where it
        vectorizes without reassociating any sum.
    centers_sq : (S, K) float64
        Their squared norms.
    sigma : (S,) float64
        Voting bandwidths.
    n_nearest : int
        Centres each descriptor votes into, ``1 <= n_nearest <= K``.
    out : (S, K) float64
        Receives each scale's histogram, normalized to unit length (the caller
        divides by ``sqrt(S)``).
    """
    n_scales, n, dim = d.shape
    k = centers_t.shape[2]
    d2 = np.empty(k)
    nonzero = np.empty(dim, np.int64)
    idx = np.empty(n_nearest, np.int64)
    near = np.empty(n_nearest)
    for s in range(n_scales):
        c_t = centers_t[s]
        c_sq = centers_sq[s]
        for c in range(k):
            out[s, c] = 0.0
        scale = 2.0 * sigma[s] ** 2
        for p in range(n):
            x = d[s, p]
            x_sq = 0.0
            m = 0
            for a in range(dim):
                x_sq += x[a] * x[a]
                nonzero[m] = a
                m += x[a] != 0.0  # branch-free: zeros are unpredictable
            for c in range(k):
                d2[c] = 0.0
            for q in range(m):
                xa = x[nonzero[q]]
                row = c_t[nonzero[q]]
                for c in range(k):
                    d2[c] += xa * row[c]
            # squared distances as the reference expands them; the n_nearest
            # smallest by insertion, ordered by (distance, index) as the
            # reference's argmin passes order them
            filled = 0
            for c in range(k):
                v = x_sq - 2.0 * d2[c] + c_sq[c]
                v = v if v > 0.0 else 0.0
                if filled == n_nearest and not v < near[n_nearest - 1]:
                    continue
                q = filled if filled < n_nearest else n_nearest - 1
                while q > 0 and v < near[q - 1]:
                    near[q] = near[q - 1]
                    idx[q] = idx[q - 1]
                    q -= 1
                near[q] = v
                idx[q] = c
                if filled < n_nearest:
                    filled += 1
            lo = near[0]
            total = 0.0
            for q in range(n_nearest):
                near[q] = math.exp(-(near[q] - lo) / scale)
                total += near[q]
            for q in range(n_nearest):
                out[s, idx[q]] += near[q] / total
        norm = 0.0
        for c in range(k):
            norm += out[s, c] * out[s, c]
        norm = math.sqrt(norm)
        for c in range(k):
            out[s, c] /= norm


@numba.njit(cache=True, nogil=True)
def ray_extents_kernel(contour, cx, cy, n, out):  # pragma: no cover
    """Farthest intersection of ``n`` rays from ``(cx, cy)`` with a contour polygon.

    One function, not named steps: it is one compiled pass over the contour's
    edges (simplification and ray casting fused, with no intermediate polygon).

    ``rdf._simplify`` and ``rdf._ray_extents`` in one pass, term for
    term: collinear runs dropped (the same polygon), each edge intersected only
    with the rays inside the angle it subtends at the centre (widened by 1e-9
    rad), ray ``k`` at the angle ``k 2 pi / n``. ``arctan2``, ``cos`` and
    ``sin`` are libm's rather than numpy's (which may differ in the last bit),
    so the extents agree with the reference to about 1e-12 px.

    Parameters
    ----------
    contour : (P, 2) float64
        Closed outline ``(x, y)``, ``P >= 1``.
    cx, cy : float
        The centre.
    n : int
        Number of rays.
    out : (n,) float64
        Receives the extents (0 for a ray that meets no edge).
    """
    p_all = contour.shape[0]
    # collinear points dropped (rdf._simplify): a point whose incoming and
    # outgoing steps are equal
    keep = np.ones(p_all, np.bool_)
    if p_all >= 3:
        any_kept = False
        for m in range(p_all):
            prev = m - 1 if m > 0 else p_all - 1
            nxt = m + 1 if m < p_all - 1 else 0
            same = (
                contour[m, 0] - contour[prev, 0] == contour[nxt, 0] - contour[m, 0]
                and contour[m, 1] - contour[prev, 1] == contour[nxt, 1] - contour[m, 1]
            )
            keep[m] = not same
            any_kept = any_kept or keep[m]
        if not any_kept:
            keep[:] = False
            keep[0] = True
    m_kept = 0
    for m in range(p_all):
        m_kept += keep[m]
    ax = np.empty(m_kept)
    ay = np.empty(m_kept)
    q = 0
    for m in range(p_all):
        if keep[m]:
            ax[q] = contour[m, 0] - cx
            ay[q] = contour[m, 1] - cy
            q += 1
    for k in range(n):
        out[k] = 0.0
    if m_kept == 1:
        r = math.hypot(ax[0], ay[0])
        for k in range(n):
            out[k] = r
        return
    step = 2.0 * np.pi / n
    two_pi = 2.0 * np.pi
    for m in range(m_kept):
        nb = m + 1 if m < m_kept - 1 else 0
        a0, a1 = ax[m], ay[m]
        b0, b1 = ax[nb], ay[nb]
        e0, e1 = b0 - a0, b1 - a1
        phi = math.atan2(a1, a0)
        dphi = math.atan2(b1, b0) - phi
        dphi -= two_pi * np.round(dphi / two_pi)
        lo = min(phi, phi + dphi) - 1e-9
        hi = max(phi, phi + dphi) + 1e-9
        k_lo = math.ceil(lo / step)
        k_hi = math.floor(hi / step)
        e_len = math.hypot(e0, e1)
        far = max(math.hypot(a0, a1), math.hypot(b0, b1))
        for k in range(k_lo, k_hi + 1):
            ang = k * step
            d0 = math.cos(ang)
            d1 = math.sin(ang)
            denom = d0 * e1 - d1 * e0
            if abs(denom) <= 1e-12 * (1.0 + e_len):
                dist = far  # an edge along the ray: its farther end
            else:
                u = (a0 * d1 - a1 * d0) / denom
                u = min(max(u, 0.0), 1.0)
                dist = math.hypot(a0 + u * e0, a1 + u * e1)
            j = k % n
            if dist > out[j]:
                out[j] = dist
