"""Compiled (numba) kernels of :mod:`bodymetry.estimation.raster`.

Imported lazily by ``raster`` (only when its ``BACKEND`` is ``"numba"``), so
importing the rasterizer does not import numba (about 0.35 s).

The kernels loop over triangles and the pixel centres of their bounding
boxes, and evaluate the *same* floating-point expressions, in the same order,
as the numpy reference (``raster._covered``): the affine barycentric functions
``l_i = a_i x + b_i y + c_i`` from the same coefficients, ``l2 = 1 - l0 - l1``,
and the inside test ``l_i >= -INSIDE_EPS``. Without ``fastmath`` LLVM neither
reassociates nor fuses multiply-adds, so both paths decide every pixel
identically (tests/estimation/test_raster.py compares them bit for bit).

numba, and its on-disk cache, come from :mod:`bodymetry.jit`.
"""

from __future__ import annotations

import numpy as np

from bodymetry.jit import inline_copy, numba

#: Codes of ``raster``'s ``cull`` ("none", "back", "front") inside the kernels.
_CULL_NONE, _CULL_BACK, _CULL_FRONT = 0, 1, 2


@numba.njit(cache=True, nogil=True, inline="always")
def finite_triangle(x0, y0, x1, y1, x2, y2):  # pragma: no cover
    """Whether a projected triangle's corners are all finite.

    A vertex behind a camera or outside the lens model's range projects to NaN.

    Parameters
    ----------
    x0, y0, x1, y1, x2, y2 : float
        Pixel coordinates of the triangle's three corners.

    Returns
    -------
    bool
        True when all six coordinates are finite.
    """
    return (
        np.isfinite(x0)
        and np.isfinite(x1)
        and np.isfinite(x2)
        and np.isfinite(y0)
        and np.isfinite(y1)
        and np.isfinite(y2)
    )


@numba.njit(cache=True, nogil=True)
def triangle_setup(x0, y0, x1, y1, x2, y2, cull, w_img, row_lo, row_hi):  # pragma: no cover
    """Cull test, clipped pixel box and barycentric coefficients of one triangle.

    The expressions are ``raster._covered``'s, term for term.

    Parameters
    ----------
    x0, y0, x1, y1, x2, y2 : float
        Pixel coordinates of the triangle's three corners.
    cull : int
        ``_CULL_NONE``, ``_CULL_BACK`` or ``_CULL_FRONT``.
    w_img : int
        Image width: columns are ``0 .. w_img - 1``.
    row_lo, row_hi : int
        First and last row to test (the view's tile).

    Returns
    -------
    ok : bool
        False when there is no pixel centre to test.
    box : tuple
        ``(bx0, bx1, by0, by1, a0, b0, c0, a1, b1, c1)``: the clipped pixel box
        (inclusive) and the coefficients of ``l0`` and ``l1``.
    """
    area2 = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if cull == _CULL_BACK:
        keep = area2 < -1e-12
    elif cull == _CULL_FRONT:
        keep = area2 > 1e-12
    else:
        keep = abs(area2) > 1e-12  # False for NaN, as numpy's comparison
    xmin = np.ceil(min(min(x0, x1), x2))
    xmax = np.floor(max(max(x0, x1), x2))
    ymin = np.ceil(min(min(y0, y1), y2))
    ymax = np.floor(max(max(y0, y1), y2))
    if keep:
        # Boxes off the image (tile) or holding no pixel centre: nothing to test.
        keep = xmax >= 0 and ymax >= row_lo and xmin <= w_img - 1 and ymin <= row_hi
        keep = keep and xmin <= xmax and ymin <= ymax
    if not keep:
        return False, (0, -1, 0, -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    bx0 = int(max(xmin, 0.0))
    bx1 = int(min(xmax, float(w_img - 1)))
    by0 = int(max(ymin, float(row_lo)))
    by1 = int(min(ymax, float(row_hi)))
    inv = 1.0 / area2
    a0 = (y1 - y2) * inv
    b0 = (x2 - x1) * inv
    c0 = (x1 * y2 - x2 * y1) * inv
    a1 = (y2 - y0) * inv
    b1 = (x0 - x2) * inv
    c1 = (x2 * y0 - x0 * y2) * inv
    return True, (bx0, bx1, by0, by1, a0, b0, c0, a1, b1, c1)


#: :func:`triangle_setup` inlined into the triangle loops of the coverage and chamfer kernels
#: (the same function, so the same expressions; a call per triangle cost ~10 %).
triangle_setup_inline = inline_copy(triangle_setup)


@numba.njit(cache=True, nogil=True)
def _faces_in_range(faces, n):  # pragma: no cover
    """Whether every index of ``faces`` (T, 3) lies in ``0 .. n - 1``."""
    for t in range(faces.shape[0]):
        for k in range(3):
            i = faces[t, k]
            if i < 0 or i >= n:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def coverage_kernel(xs, ys, valid, faces, sizes, h_canvas, cull, eps, out):  # pragma: no cover
    """Front-face (or all-face) coverage of one mesh in C views, as tiles.

    View ``c``'s vertices are shifted down by ``c * h_canvas`` rows, as numpy's
    ``coverage_views`` stacks its tiles (the same rounding of ``y + offset``),
    and its pixels are tested up to its own width and height only (the rest of
    its tile is cropped away anyway).

    Parameters
    ----------
    xs, ys : (C, N) float64
        Vertex pixel coordinates per view (not offset).
    valid : (C, N) bool
        Vertices that may be drawn (finiteness is checked here too).
    faces : (T, 3) int64
        Indices into ``0 .. N - 1``. (No negative ones: numpy would wrap them,
        and ``coverage_views``'s numpy path into another view's vertices.)
    sizes : (C, 2) int64
        ``(width, height)`` of each view, at most ``out``'s.
    h_canvas : int
        Tile height (the offset between views).
    cull : int
        0 none, 1 keep back-culled (negative area, the front faces of a closed
        mesh), 2 keep positive area.
    eps : float
        Tolerance of the inside test.
    out : (C, H, W) bool
        Zeroed; covered pixels are set True.

    Returns
    -------
    int
        0, or -1 when a face index is outside ``0 .. N - 1`` (nothing drawn).
    """
    C, N = xs.shape
    T = faces.shape[0]
    if not _faces_in_range(faces, N):
        return -1
    for c in range(C):
        w_img = sizes[c, 0]
        row_lo = c * h_canvas
        row_hi = row_lo + sizes[c, 1] - 1
        off = float(row_lo)
        for t in range(T):
            i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
            if not (valid[c, i0] and valid[c, i1] and valid[c, i2]):
                continue
            x0, x1, x2 = xs[c, i0], xs[c, i1], xs[c, i2]
            y0, y1, y2 = ys[c, i0] + off, ys[c, i1] + off, ys[c, i2] + off
            if not finite_triangle(x0, y0, x1, y1, x2, y2):
                continue
            ok, box = triangle_setup_inline(x0, y0, x1, y1, x2, y2, cull, w_img, row_lo, row_hi)
            if not ok:
                continue
            bx0, bx1, by0, by1, a0, b0, c0, a1, b1, c1 = box
            for py in range(by0, by1 + 1):
                fy = float(py)
                r = py - row_lo
                row = out[c, r]
                for px in range(bx0, bx1 + 1):
                    # The inside test or'ed in without branches: whether a pixel of a
                    # small box is inside, or already covered, is a coin toss for the
                    # branch predictor (with the inlined setup: 1.7x faster on a
                    # 640x480 body, measured). The same pixels come out True.
                    fx = float(px)
                    l0 = a0 * fx + b0 * fy + c0
                    l1 = a1 * fx + b1 * fy + c1
                    l2 = 1.0 - l0 - l1
                    row[px] = row[px] | ((l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps))
    return 0


@numba.njit(cache=True, nogil=True)
def zbuffer_kernel(
    xs, ys, depth, valid, faces, w_img, h_img, cull, perspective, eps, zbuf, tri, bary
):  # pragma: no cover
    """The z-buffer of ``raster.rasterize``: nearest covering triangle per pixel.

    Triangles are visited in index order and pixels take a candidate whose key
    is <= the stored one, so among equal keys the last triangle wins, as the
    numpy path's "last written wins". A NaN key poisons its pixel (numpy's
    ``minimum.at`` propagates NaN, so no candidate equals the minimum there):
    the caller clears pixels whose ``zbuf`` is NaN.

    Parameters
    ----------
    xs, ys, depth : (N,) float64
    valid : (N,) bool
        Vertices that may be drawn (finite, in front of the camera, ...).
    faces : (T, 3) int64
    w_img, h_img : int
    cull : int
        As in :func:`coverage_kernel`.
    perspective : bool
        Key ``-(l0/d0 + l1/d1 + l2/d2)`` (nearest has the largest 1/z), else
        ``l0 d0 + l1 d1 + l2 d2``.
    eps : float
    zbuf : (H*W,) float64
        Filled with inf; receives the winning keys.
    tri : (H*W,) int64
        Filled with -1; receives the winning triangle indices.
    bary : (H*W, 3) float64
        Receives the winner's affine barycentrics ``l0, l1, l2``.

    Returns
    -------
    int
        0, or -1 when a face index is outside ``0 .. N - 1``.
    """
    N = xs.shape[0]
    T = faces.shape[0]
    if not _faces_in_range(faces, N):
        return -1
    for t in range(T):
        i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
        if not (valid[i0] and valid[i1] and valid[i2]):
            continue
        x0, x1, x2 = xs[i0], xs[i1], xs[i2]
        y0, y1, y2 = ys[i0], ys[i1], ys[i2]
        ok, box = triangle_setup(x0, y0, x1, y1, x2, y2, cull, w_img, 0, h_img - 1)
        if not ok:
            continue
        bx0, bx1, by0, by1, a0, b0, c0, a1, b1, c1 = box
        d0, d1, d2 = depth[i0], depth[i1], depth[i2]
        for py in range(by0, by1 + 1):
            fy = float(py)
            for px in range(bx0, bx1 + 1):
                fx = float(px)
                l0 = a0 * fx + b0 * fy + c0
                l1 = a1 * fx + b1 * fy + c1
                l2 = 1.0 - l0 - l1
                if not (l0 >= -eps and l1 >= -eps and l2 >= -eps):
                    continue
                key = -(l0 / d0 + l1 / d1 + l2 / d2) if perspective else l0 * d0 + l1 * d1 + l2 * d2
                p = py * w_img + px
                if key != key:
                    zbuf[p] = key
                elif key <= zbuf[p]:
                    zbuf[p] = key
                    tri[p] = t
                    bary[p, 0] = l0
                    bary[p, 1] = l1
                    bary[p, 2] = l2
    return 0
