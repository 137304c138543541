"""Compiled (numba) kernels of the silhouette likelihood (:mod:`estimation.generative`)
and of the contour refinement's inner loops (:mod:`estimation.refinement`).

Imported lazily, only when ``generative.BACKEND`` is ``"numba"``
(``$BODYMETRY_LIKELIHOOD``); numba comes from :mod:`bodymetry.jit`, which
points numba's on-disk cache first.

- :func:`project_kernel`: every body's vertices through every camera in one
  call, with the cameras' full OpenCV lens model (``Camera.project``'s
  expressions, term for term; pixels equal to about 1e-12);
- :func:`chamfer_kernel`: each body's bidirectional chamfer cost in each view,
  replacing the numpy path's per-body, per-view loop (rasterize, mask
  arithmetic, distance transform, masked sums). It covers the front faces
  exactly as ``raster_kernels.coverage_kernel`` does (same tiles, same
  rounding), sums the observed distance map over the covered pixels while
  covering, and takes the model's distance transform on the numpy path's crop
  with OpenCV's 3x3 chamfer algorithm (:func:`chamfer_distance_3x3`), summing
  the observed pixels' distances in its backward pass;
- :func:`project_midpoints_kernel`, :func:`contour_kernel`: the refinement's
  edge-midpoint projections and occluding contour.

The sums are accumulated in float64 where numpy sums float32 pairwise, so the
costs agree with the numpy path to about 1e-6 relative, not bit for bit
(tests/estimation/test_likelihood_kernels.py states the tolerances).
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.raster_kernels import finite_triangle, triangle_setup_inline
from bodymetry.jit import numba


@numba.njit(cache=True, nogil=True, inline="always")
def _camera(R, t, K, dist, tilt, c):  # pragma: no cover
    """Camera ``c``'s parameters as one tuple of scalars: loaded once per camera, so
    the per-point loops keep them in registers (3x faster than indexing the
    arrays per point, measured)."""
    return (
        R[c, 0, 0], R[c, 0, 1], R[c, 0, 2], R[c, 1, 0], R[c, 1, 1], R[c, 1, 2],
        R[c, 2, 0], R[c, 2, 1], R[c, 2, 2], t[c, 0], t[c, 1], t[c, 2],
        K[c, 0, 0], K[c, 0, 1], K[c, 0, 2], K[c, 1, 0], K[c, 1, 1], K[c, 1, 2],
        dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3], dist[c, 4], dist[c, 5],
        dist[c, 6], dist[c, 7], dist[c, 8], dist[c, 9], dist[c, 10], dist[c, 11],
        tilt[c, 0, 0], tilt[c, 0, 1], tilt[c, 0, 2], tilt[c, 1, 0], tilt[c, 1, 1],
        tilt[c, 1, 2], tilt[c, 2, 0], tilt[c, 2, 1], tilt[c, 2, 2],
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _project_one(px, py, pz, cam, mode):  # pragma: no cover
    """Pixel ``(u, v)`` of one world point (NaN behind the camera): ``Camera.project``'s
    expressions, term for term. ``cam`` is :func:`_camera`'s tuple."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2 = cam[:12]
    f00, f01, f02, f10, f11, f12 = cam[12:18]
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = cam[18:30]
    X = px * r00 + py * r01 + pz * r02 + t0
    Y = px * r10 + py * r11 + pz * r12 + t1
    Z = px * r20 + py * r21 + pz * r22 + t2
    x = X / Z
    y = Y / Z
    r2 = x * x + y * y
    if mode == 0:
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    else:
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + r2 * s2)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + r2 * s4)
        if mode == 2:
            m00, m01, m02, m10, m11, m12, m20, m21, m22 = cam[30:39]
            w = m20 * xd + m21 * yd + m22
            xt = (m00 * xd + m01 * yd + m02) / w
            yt = (m10 * xd + m11 * yd + m12) / w
            xd, yd = xt, yt
    u = xd * f00 + yd * f01 + f02
    v = xd * f10 + yd * f11 + f12
    if not Z > 1e-9:
        u = np.nan
        v = np.nan
    return u, v


@numba.njit(cache=True, nogil=True, error_model="numpy")
def project_kernel(verts, R, t, K, dist, tilt, mode, out):  # pragma: no cover
    """Project B bodies into C cameras.

    Parameters
    ----------
    verts : (B, V, 3) float64
        World coordinates.
    R : (C, 3, 3), t : (C, 3), K : (C, 3, 3) float64
        Each camera's ``camera_from_world`` rotation, translation and intrinsics.
    dist : (C, 14) float64
        Distortion coefficients, zero-padded (OpenCV order).
    tilt : (C, 3, 3) float64
        Tilted-sensor matrix (used when ``mode`` is 2).
    mode : (C,) int64
        0: five-coefficient lens (``k1, k2, p1, p2, k3``); 1: rational, thin
        prism; 2: as 1 with a tilted sensor.
    out : (B, C, V, 2) float64
        Pixels; NaN for points behind the camera (z <= 1e-9).
    """
    B, V, _ = verts.shape
    for c in range(R.shape[0]):
        cam = _camera(R, t, K, dist, tilt, c)
        m = mode[c]
        for b in range(B):
            for v in range(V):
                u, w = _project_one(verts[b, v, 0], verts[b, v, 1], verts[b, v, 2], cam, m)
                out[b, c, v, 0] = u
                out[b, c, v, 1] = w


@numba.njit(cache=True, nogil=True, error_model="numpy")
def project_midpoints_kernel(verts, ends, R, t, K, dist, tilt, mode, out):  # pragma: no cover
    """Project the midpoints of mesh edges of S bodies through one camera.

    Parameters
    ----------
    verts : (S, V, 3) float64
    ends : (n, 2) int64
        The edges' vertex pairs.
    R, t, K, dist, tilt, mode
        One camera's, as :func:`project_kernel` takes them (leading axis of 1).
    out : (S, n, 2) float64
        Pixels of ``0.5 * (verts[:, ends[:, 0]] + verts[:, ends[:, 1]])``.
    """
    cam = _camera(R, t, K, dist, tilt, 0)
    m = mode[0]
    for s in range(verts.shape[0]):
        for k in range(ends.shape[0]):
            i, j = ends[k, 0], ends[k, 1]
            u, w = _project_one(
                0.5 * (verts[s, i, 0] + verts[s, j, 0]),
                0.5 * (verts[s, i, 1] + verts[s, j, 1]),
                0.5 * (verts[s, i, 2] + verts[s, j, 2]),
                cam, m,
            )  # fmt: skip
            out[s, k, 0] = u
            out[s, k, 1] = w


@numba.njit(cache=True, nogil=True)
def _chamfer_passes(zero, y0, x0, h, w, tmp, weight, out):  # pragma: no cover
    """OpenCV's two-pass 3x3 chamfer transform of a crop, and a sum over it.

    The distance of each pixel of ``zero[y0:y0 + h, x0:x0 + w]`` to the nearest
    True pixel (0.955 along rows and columns, 1.3693 diagonally, float32 steps
    as in :func:`chamfer_distance_3x3`). Each distance is written to ``out``
    when ``out`` is not empty, and summed (float64) over the pixels where
    ``weight`` is True as it becomes final in the backward pass.

    Parameters
    ----------
    zero : (H, W) bool
        The pixels at distance 0.
    y0, x0, h, w : int
        The crop.
    tmp : (>= h + 2, >= w + 2) float32
        Scratch (distances with a one-pixel border).
    weight : (H, W) bool
        The pixels whose distances are summed (same frame as ``zero``).
    out : (h, w) or (0, 0) float32
        The distances, or nothing.

    Returns
    -------
    float
        The sum over the ``weight`` pixels.
    """
    a = np.float32(0.955)
    d = np.float32(1.3693)
    far = np.float32(1e30)
    write = out.shape[0] > 0
    for j in range(w + 2):
        tmp[0, j] = far
        tmp[h + 1, j] = far
    for i in range(h):
        r = i + 1
        tmp[r, 0] = far
        tmp[r, w + 1] = far
        for j in range(w):
            if zero[y0 + i, x0 + j]:
                tmp[r, j + 1] = 0
            else:
                t0 = tmp[r - 1, j] + d
                t = tmp[r - 1, j + 1] + a
                if t0 > t:
                    t0 = t
                t = tmp[r - 1, j + 2] + d
                if t0 > t:
                    t0 = t
                t = tmp[r, j] + a
                if t0 > t:
                    t0 = t
                tmp[r, j + 1] = t0
    total = 0.0
    for i in range(h - 1, -1, -1):
        r = i + 1
        for j in range(w - 1, -1, -1):
            t0 = tmp[r, j + 1]
            if t0 > a:
                t = tmp[r + 1, j + 2] + d
                if t0 > t:
                    t0 = t
                t = tmp[r + 1, j + 1] + a
                if t0 > t:
                    t0 = t
                t = tmp[r + 1, j] + d
                if t0 > t:
                    t0 = t
                t = tmp[r, j + 2] + a
                if t0 > t:
                    t0 = t
                tmp[r, j + 1] = t0
            if write:
                out[i, j] = t0
            if weight[y0 + i, x0 + j]:
                total += t0
    return total


@numba.njit(cache=True, nogil=True)
def chamfer_distance_3x3(src, tmp, out):  # pragma: no cover
    """OpenCV's ``distanceTransform(src, DIST_L2, 3)``: two passes of the 3x3
    chamfer mask (0.955 along rows and columns, 1.3693 diagonally), in float32.

    OpenCV's own C code works in 16.16 fixed point; the build on PyPI calls
    Intel IPP, which adds float32 steps. This follows the latter: the values
    match ``cv2.distanceTransform`` to one float32 rounding (about 1e-7
    relative), tested.

    Parameters
    ----------
    src : (h, w) bool
        Non-zero pixels get their distance to the nearest zero pixel.
    tmp : (>= h + 2, >= w + 2) float32
        Scratch (distances with a one-pixel border).
    out : (h, w) float32
        The distances.
    """
    h, w = src.shape
    _chamfer_passes(~src, 0, 0, h, w, tmp, np.zeros((h, w), np.bool_), out)


@numba.njit(cache=True, nogil=True)
def _observed_distance_sum(model, observed, y0, x0, h, w, tmp):  # pragma: no cover
    """Sum over the observed pixels of a crop of their distance to the model.

    :func:`chamfer_distance_3x3` of ``~model[y0:y0 + h, x0:x0 + w]``, the sum
    taken in the backward pass as each distance becomes final (no distance
    image, no separate passes to fill the source and to sum).
    """
    return _chamfer_passes(model, y0, x0, h, w, tmp, observed, np.empty((0, 0), np.float32))


@numba.njit(cache=True, nogil=True)
def chamfer_kernel(
    xs, ys, faces, sizes, h_canvas, observed, dist, boxes, area, scale, eps, out
):  # pragma: no cover
    """Bidirectional chamfer cost of B bodies in C views (``generative._view_cost``).

    One function, not named steps: it is one compiled loop over bodies and views
    (cull, cover while summing distances, then the observed side) that reuses
    one model image and its dirty box from body to body.

    Parameters
    ----------
    xs, ys : (B, C, V) float64
        Projected vertices per body and view (NaN: behind the camera).
    faces : (T, 3) int64
        A closed mesh; only front faces are drawn.
    sizes : (C, 2) int64
        ``(width, height)`` of each view.
    h_canvas : int
        The largest height: view ``k`` is covered as tile ``k`` of a tall
        canvas (``y + k * h_canvas``), the rounding of ``raster.coverage_views``.
    observed : (C, H, W) bool
        Observed silhouettes (each view's own size in the top-left corner).
    dist : (C, H, W) float32
        Distance (full-resolution pixels) to the observed silhouette.
    boxes : (C, 4) int64
        Bounding box ``x0, y0, x1, y1`` of each observed silhouette.
    area : (C,) float64
        Observed area (full-resolution pixels).
    scale : float
        Comparison scale.
    eps : float
        The rasterizer's inside tolerance.
    out : (B, C) float64
        The costs; inf where the body covers no pixel of a view.

    Returns
    -------
    int
        0, or -1 when a face index is outside ``0 .. V - 1``.
    """
    B, C, V = xs.shape
    T = faces.shape[0]
    H, W = observed.shape[1], observed.shape[2]
    for t in range(T):
        for k in range(3):
            if faces[t, k] < 0 or faces[t, k] >= V:
                return -1
    model = np.zeros((H, W), np.bool_)
    tmp = np.empty((H + 2, W + 2), np.float32)
    kept = np.empty(T, np.int64)  # the triangles that may cover a pixel
    # Rows [0, 1) and columns [2, 3) of ``model`` that may hold True.
    dirty = np.zeros(4, np.int64)
    for b in range(B):
        for c in range(C):
            w_img = sizes[c, 0]
            h_img = sizes[c, 1]
            row_lo = c * h_canvas
            row_hi = row_lo + h_img - 1
            off = float(row_lo)
            # Clear only the box the previous body drew in (the image starts empty):
            # a body covers a tenth of a view.
            for r in range(dirty[0], dirty[1]):
                for q in range(dirty[2], dirty[3]):
                    model[r, q] = False
            dirty[0], dirty[1], dirty[2], dirty[3] = H, 0, W, 0
            extra = 0.0
            covered = 0
            xb = xs[b, c]
            yb = ys[b, c]
            # Two passes keep, in index order, the triangles that can cover a pixel,
            # each without branches (an index is written, the count moves by 0 or 1):
            # the front faces by the winding test alone (NaN fails it, as numpy's
            # comparison), then those whose box holds a pixel centre in the view,
            # ``triangle_setup``'s test. Which triangle passes is a coin toss for the branch
            # predictor; the passes made the kernel 14 % faster (measured). The
            # covering loop below runs ``triangle_setup`` on the kept ones as before.
            n_front = 0
            for tri in range(T):
                i0, i1, i2 = faces[tri, 0], faces[tri, 1], faces[tri, 2]
                x0, x1, x2 = xb[i0], xb[i1], xb[i2]
                y0, y1, y2 = yb[i0] + off, yb[i1] + off, yb[i2] + off
                area2 = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
                kept[n_front] = tri
                n_front += area2 < -1e-12
            n_kept = 0
            for q in range(n_front):
                tri = kept[q]
                i0, i1, i2 = faces[tri, 0], faces[tri, 1], faces[tri, 2]
                x0, x1, x2 = xb[i0], xb[i1], xb[i2]
                y0, y1, y2 = yb[i0] + off, yb[i1] + off, yb[i2] + off
                xmin = np.ceil(min(min(x0, x1), x2))
                xmax = np.floor(max(max(x0, x1), x2))
                ymin = np.ceil(min(min(y0, y1), y2))
                ymax = np.floor(max(max(y0, y1), y2))
                box = (xmax >= 0) & (ymax >= row_lo) & (xmin <= w_img - 1) & (ymin <= row_hi)
                kept[n_kept] = tri
                n_kept += box & (xmin <= xmax) & (ymin <= ymax)
            for q in range(n_kept):
                tri = kept[q]
                i0, i1, i2 = faces[tri, 0], faces[tri, 1], faces[tri, 2]
                x0, x1, x2 = xb[i0], xb[i1], xb[i2]
                y0, y1, y2 = yb[i0] + off, yb[i1] + off, yb[i2] + off
                if not finite_triangle(x0, y0, x1, y1, x2, y2):
                    continue
                ok, box = triangle_setup_inline(x0, y0, x1, y1, x2, y2, 1, w_img, row_lo, row_hi)
                if not ok:
                    continue
                bx0, bx1, by0, by1, a0, b0, c0, a1, b1, c1 = box
                dirty[0] = min(dirty[0], by0 - row_lo)
                dirty[1] = max(dirty[1], by1 - row_lo + 1)
                dirty[2] = min(dirty[2], bx0)
                dirty[3] = max(dirty[3], bx1 + 1)
                for py in range(by0, by1 + 1):
                    fy = float(py)
                    r = py - row_lo
                    for px in range(bx0, bx1 + 1):
                        # Without branches (selects): whether a 1-3 pixel box's pixels
                        # are inside or already covered is a coin toss for the branch
                        # predictor (16 % of the kernel, measured). A pixel adds its
                        # distance once, when first covered; adding +0.0 to the
                        # non-negative sum leaves it unchanged, so the sum is the same.
                        fx = float(px)
                        l0 = a0 * fx + b0 * fy + c0
                        l1 = a1 * fx + b1 * fy + c1
                        l2 = 1.0 - l0 - l1
                        inside = (l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps)
                        was = model[r, px]
                        new = inside & (not was)
                        model[r, px] = was | inside
                        covered += new
                        d_px = dist[c, r, px]
                        extra += d_px if new else 0.0
            cost = extra
            if covered == 0:
                # No model pixel in this view (off the image, behind the camera):
                # no distance to it exists, and a usable view has observed pixels.
                out[b, c] = np.inf
                continue
            # Observed pixels outside the model: their distance to the model, on the
            # crop of the numpy path (both boxes, from the vertices' extent).
            ox0, oy0, ox1, oy1 = boxes[c, 0], boxes[c, 1], boxes[c, 2], boxes[c, 3]
            lox = np.inf
            loy = np.inf
            hix = -np.inf
            hiy = -np.inf
            for v in range(V):
                xv, yv = xs[b, c, v], ys[b, c, v]
                if xv == xv:
                    lox = min(lox, xv)
                    hix = max(hix, xv)
                if yv == yv:
                    loy = min(loy, yv)
                    hiy = max(hiy, yv)
            if lox == np.inf:
                lox, hix = 0.0, 0.0
            if loy == np.inf:
                loy, hiy = 0.0, 0.0
            cx0 = int(max(0.0, min(float(ox0), np.floor(lox))))
            cy0 = int(max(0.0, min(float(oy0), np.floor(loy))))
            cx1 = int(min(float(w_img), max(float(ox1), np.ceil(hix) + 1)))
            cy1 = int(min(float(h_img), max(float(oy1), np.ceil(hiy) + 1)))
            far = _observed_distance_sum(model, observed[c], cy0, cx0, cy1 - cy0, cx1 - cx0, tmp)
            cost += far / scale
            out[b, c] = cost / scale**2 / area[c]
    return 0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def contour_kernel(
    verts, faces, center, edges, edge_faces, mask, R, t, K, dist, tilt, mode, out
):  # pragma: no cover
    """The visible occluding contour of a mesh in one view (``contours.occluding_contour``).

    One function, not named steps: it is one compiled pass over the edges
    (face orientation, projection and visibility test fused per edge).

    An edge is a contour generator when one of its faces turns towards the
    camera and the other away; it is kept when the midpoint of its projected
    ends, rounded to a pixel (half to even, as ``np.round``), lies in the image
    within one pixel of the mask's outside (the pixel or one of its four
    neighbours is outside; the image border is not outside).

    Parameters
    ----------
    verts : (V, 3) float64
    faces : (T, 3) int64
        A face faces the camera when its normal ``(v1 - v0) x (v2 - v0)`` points
        towards the camera from its centroid ``(v0 + v1 + v2) / 3``
        (``contours.face_frames``, the same expressions).
    center : (3,) float64
        Camera centre.
    edges, edge_faces : (E, 2) int64
        ``contours.mesh_edges`` of the mesh.
    mask : (H, W) bool
        The silhouette deciding visibility, at the camera's size.
    R, t, K, dist, tilt, mode
        One camera, as :func:`project_kernel` takes them.
    out : (E,) int64
        Receives the kept edges' indices, in increasing order.

    Returns
    -------
    int
        How many were kept (the first entries of ``out``).
    """
    T = faces.shape[0]
    h, w = mask.shape
    facing = np.empty(T, np.bool_)
    cx, cy, cz = center[0], center[1], center[2]
    for f in range(T):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ax = verts[i1, 0] - verts[i0, 0]
        ay = verts[i1, 1] - verts[i0, 1]
        az = verts[i1, 2] - verts[i0, 2]
        bx = verts[i2, 0] - verts[i0, 0]
        by = verts[i2, 1] - verts[i0, 1]
        bz = verts[i2, 2] - verts[i0, 2]
        nx = ay * bz - az * by
        ny = az * bx - ax * bz
        nz = ax * by - ay * bx
        mx = (verts[i0, 0] + verts[i1, 0] + verts[i2, 0]) / 3.0
        my = (verts[i0, 1] + verts[i1, 1] + verts[i2, 1]) / 3.0
        mz = (verts[i0, 2] + verts[i1, 2] + verts[i2, 2]) / 3.0
        facing[f] = nx * (mx - cx) + ny * (my - cy) + nz * (mz - cz) < 0
    cam = _camera(R, t, K, dist, tilt, 0)
    m = mode[0]
    count = 0
    for e in range(edges.shape[0]):
        if facing[edge_faces[e, 0]] == facing[edge_faces[e, 1]]:
            continue
        i, j = edges[e, 0], edges[e, 1]
        u0, v0 = _project_one(verts[i, 0], verts[i, 1], verts[i, 2], cam, m)
        u1, v1 = _project_one(verts[j, 0], verts[j, 1], verts[j, 2], cam, m)
        mx = 0.5 * (u0 + u1)
        my = 0.5 * (v0 + v1)
        if not (mx == mx and my == my):
            continue  # behind the camera: NaN, never in the image
        fx = np.rint(mx)
        fy = np.rint(my)
        if not (fx >= 0 and fx < w and fy >= 0 and fy < h):
            continue
        x = int(fx)
        y = int(fy)
        near = not mask[y, x]
        if not near and x + 1 < w:
            near = not mask[y, x + 1]
        if not near and x > 0:
            near = not mask[y, x - 1]
        if not near and y + 1 < h:
            near = not mask[y + 1, x]
        if not near and y > 0:
            near = not mask[y - 1, x]
        if near:
            out[count] = e
            count += 1
    return count


@numba.njit(cache=True, nogil=True)
def nearest_pairs_kernel(model, observed, model_to_observed, observed_to_model):  # pragma: no cover
    """Nearest neighbours in both directions between two small 2-D point sets.

    The contour refinement's correspondences (``refinement.ContourCost.pairs``):
    a few hundred model contour points against at most a few hundred observed
    boundary points. One pass over all pairs finds both directions, 2-4x faster
    than building a k-d tree and querying it twice (measured: 0.13 vs 0.46 ms
    for 250 x 400 points, 0.8 vs 1.5 ms for 1,100 x 400). The squared
    distance is ``dx * dx + dy * dy``, the k-d tree's sum; of equally near
    points the first is taken.

    Parameters
    ----------
    model : (n, 2) float64
    observed : (m, 2) float64
    model_to_observed : (n,) int64
        Written: index of the observed point nearest each model point.
    observed_to_model : (m,) int64
        Written: index of the model point nearest each observed point.
    """
    m = observed.shape[0]
    best_obs = np.full(m, np.inf)
    for j in range(m):
        observed_to_model[j] = 0
    for i in range(model.shape[0]):
        mx, my = model[i, 0], model[i, 1]
        best = np.inf
        arg = 0
        for j in range(m):
            dx = mx - observed[j, 0]
            dy = my - observed[j, 1]
            d = dx * dx + dy * dy
            if d < best:
                best = d
                arg = j
            if d < best_obs[j]:
                best_obs[j] = d
                observed_to_model[j] = i
        model_to_observed[i] = arg


@numba.njit(cache=True, nogil=True)
def moved_rows_kernel(indptr, indices, data, rows, lod, base, out):  # pragma: no cover
    """Full-mesh vertices moved by level-of-detail displacements (``refinement``'s
    ``_ContourCost._moved_rows``).

    ``out[0] = base[rows]`` and ``out[s] = base[rows] + M[rows] @ (lod[s] - lod[0])``
    for ``s >= 1``, with ``M`` the sparse map from the level of detail to the
    full mesh. scipy's CSR product sums each row's terms in their stored order
    from zero, as here; numpy's and scipy's route goes through transposed copies
    with a 3-wide innermost axis (slow strided copies), this is one pass.

    Parameters
    ----------
    indptr, indices : int32 or int64, data : float64
        ``M`` in CSR form, (V_full, V_lod).
    rows : (R,) int64
        The full-mesh vertices wanted.
    lod : (1 + n, V_lod, 3) float64
        The level of detail at the state and at each perturbed state.
    base : (V_full, 3) float64
        The full mesh at the state.
    out : (1 + n, R, 3) float64
        Written.
    """
    S = lod.shape[0]
    for r in range(rows.shape[0]):
        v = rows[r]
        b0, b1, b2 = base[v, 0], base[v, 1], base[v, 2]
        out[0, r, 0] = b0
        out[0, r, 1] = b1
        out[0, r, 2] = b2
        lo, hi = indptr[v], indptr[v + 1]
        for s in range(1, S):
            m0 = 0.0
            m1 = 0.0
            m2 = 0.0
            for jj in range(lo, hi):
                j = indices[jj]
                a = data[jj]
                m0 += a * (lod[s, j, 0] - lod[0, j, 0])
                m1 += a * (lod[s, j, 1] - lod[0, j, 1])
                m2 += a * (lod[s, j, 2] - lod[0, j, 2])
            out[s, r, 0] = b0 + m0
            out[s, r, 1] = b1 + m1
            out[s, r, 2] = b2 + m2


@numba.njit(cache=True, nogil=True)
def line_residuals_kernel(q, index, targets, normals, scale, out, col0, first):  # pragma: no cover
    """Point-to-line residuals of projected contour points (``refinement``'s
    ``_ContourCost.residuals``), written into their columns of the residual array.

    ``d = (q[s, index[i], 0] - targets[i, 0]) * normals[i, 0]
    + (q[s, index[i], 1] - targets[i, 1]) * normals[i, 1]``, numpy's expression
    term for term, without its temporaries over strided views.

    Parameters
    ----------
    q : (S, n_q, 2) float64
        Projected points of S states.
    index : (n,) int64
        The point of ``q`` each residual uses.
    targets, normals : (n, 2) float64
    scale : float
        Each residual's weight (the square root of the pair's weight).
    out : (S, R) float64
        Written: ``out[s, col0 + i] = d * scale``.
    col0 : int
    first : (n,) float64
        Written: ``d`` of the first state (for the robust weights).
    """
    for s in range(q.shape[0]):
        for i in range(index.shape[0]):
            k = index[i]
            dx = q[s, k, 0] - targets[i, 0]
            dy = q[s, k, 1] - targets[i, 1]
            d = dx * normals[i, 0] + dy * normals[i, 1]
            out[s, col0 + i] = d * scale
            if s == 0:
                first[i] = d
