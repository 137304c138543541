"""Compiled likelihood kernels against their numpy references (projection, distance
transform, chamfer cost) and a chamfer cost known in closed form."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.calibration.camera import Camera
from bodymetry.estimation.projection import camera_arrays
from bodymetry.estimation.raster import INSIDE_EPS, signed_area2

lk = pytest.importorskip("bodymetry.estimation.likelihood_kernels")

#: Pixels: the kernel and numpy evaluate the same expressions, but numpy's matrix
#: products may round differently (BLAS); on a 160-640 pixel image this is ~1e-13.
ATOL_PIXELS = 1e-9

#: One float32 rounding of a distance of up to ~100 pixels.
RTOL_DISTANCE = 2.5e-7


def _camera(dist: list[float]) -> Camera:
    rng = np.random.default_rng(len(dist))
    angle = rng.normal(0.0, 0.2, 3)
    R, _ = cv2.Rodrigues(angle)
    K = np.array([[300.0, 0.5, 81.0], [0.0, 310.0, 59.0], [0.0, 0.0, 1.0]])
    return Camera("cam", (160, 120), K, np.asarray(dist), R, np.array([0.1, -0.2, 3.0]))


LENSES = {
    "4": [0.1, -0.05, 0.001, -0.002],
    "5": [0.1, -0.05, 0.001, -0.002, 0.01],
    "8": [0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005],
    "12": [0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005, 1e-3, -2e-3, 5e-4, 1e-3],
    "14 (tilt)": [0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005]
    + [1e-3, -2e-3, 5e-4, 1e-3, 0.01, -0.02],
}


@pytest.mark.parametrize("lens", LENSES)
def test_projection_kernel_matches_the_camera_model(lens):
    """Every lens model the cameras accept, and points behind the camera (NaN)."""
    cam = _camera(LENSES[lens])
    rng = np.random.default_rng(0)
    pts = rng.normal(0.0, 0.5, (2, 300, 3))
    pts[0, :5, 2] = -10.0  # behind the camera
    out = np.empty((2, 1, 300, 2))
    lk.project_kernel(pts, *camera_arrays([cam]), out)
    want = cam.project(pts)
    assert np.array_equal(np.isnan(out[:, 0]), np.isnan(want))
    assert np.isnan(out[0, 0, :5]).all()
    np.testing.assert_allclose(out[:, 0], want, rtol=0, atol=ATOL_PIXELS)


def test_midpoint_projection_kernel_matches_numpy():
    cam = _camera(LENSES["5"])
    rng = np.random.default_rng(1)
    verts = rng.normal(0.0, 0.5, (3, 50, 3))
    ends = rng.integers(0, 50, (40, 2))
    out = np.empty((3, 40, 2))
    lk.project_midpoints_kernel(verts, ends, *camera_arrays([cam]), out)
    want = cam.project(0.5 * (verts[:, ends[:, 0]] + verts[:, ends[:, 1]]))
    np.testing.assert_allclose(out, want, rtol=0, atol=ATOL_PIXELS)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_distance_transform_is_opencvs(seed):
    """cv2.distanceTransform(DIST_L2, 3) of random masks with blobs, lines and holes."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(20, 90, 2)
    src = np.ones((h, w), np.uint8)
    src[rng.random((h, w)) < 0.01] = 0
    y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
    src[y0 : y0 + h // 3, x0 : x0 + w // 4] = 0
    want = cv2.distanceTransform(src, cv2.DIST_L2, 3)
    got = np.empty((h, w), np.float32)
    lk.chamfer_distance_3x3(src.astype(bool), np.empty((h + 2, w + 2), np.float32), got)
    np.testing.assert_allclose(got, want, rtol=RTOL_DISTANCE, atol=0)
    assert np.array_equal(got == 0, want == 0)


def _quad(x0: float, y0: float, x1: float, y1: float) -> tuple[np.ndarray, np.ndarray]:
    """Two front-facing triangles (negative signed area) covering the pixel centres
    ``x0 < x < x1``, ``y0 < y < y1`` (corners at half pixels)."""
    xy = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if signed_area2(xy, faces)[0] > 0:
        faces = faces[:, ::-1].copy()
    return xy, faces


def _kernel_cost(xy, faces, observed, scale=1.0, status=0):
    h, w = observed.shape
    d = cv2.distanceTransform((~observed).astype(np.uint8), cv2.DIST_L2, 3) / scale
    x, y, bw, bh = cv2.boundingRect(observed.astype(np.uint8))
    out = np.empty((1, 1))
    got = lk.chamfer_kernel(
        np.ascontiguousarray(xy[None, None, :, 0]),
        np.ascontiguousarray(xy[None, None, :, 1]),
        faces.astype(np.int64),
        np.array([[w, h]], np.int64),
        h,
        observed[None],
        d[None].astype(np.float32),
        np.array([[x, y, x + bw, y + bh]], np.int64),
        np.array([max(observed.sum(), 1) / scale**2]),
        scale,
        INSIDE_EPS,
        out,
    )
    assert got == status
    return out[0, 0]


def test_chamfer_of_a_rectangle_shifted_by_one_pixel():
    """Model and observed 20 x 30 rectangles one column apart: one column of 30 pixels
    on each side, each 0.955 (the 3x3 mask's step) from the other silhouette."""
    observed = np.zeros((60, 50), bool)
    observed[10:40, 10:30] = True
    xy, faces = _quad(10.5, 9.5, 30.5, 39.5)  # columns 11..30, rows 10..39
    cost = _kernel_cost(xy, faces, observed)
    assert cost == pytest.approx(2 * 30 * np.float32(0.955) / (20 * 30), rel=1e-7)
    same, faces = _quad(9.5, 9.5, 29.5, 39.5)
    assert _kernel_cost(same, faces, observed) == 0.0


def test_chamfer_is_infinite_for_a_body_off_the_image():
    observed = np.zeros((60, 50), bool)
    observed[10:40, 10:30] = True
    xy, faces = _quad(100.5, 9.5, 130.5, 39.5)
    assert _kernel_cost(xy, faces, observed) == np.inf


def test_chamfer_kernel_rejects_bad_faces():
    observed = np.zeros((10, 10), bool)
    observed[2:5, 2:5] = True
    xy, faces = _quad(1.5, 1.5, 5.5, 5.5)
    _kernel_cost(xy, faces + 10, observed, status=-1)


def test_chamfer_of_a_batch_is_each_bodys_own_cost():
    """The kernel reuses one model image for every body and view, clearing only the
    box the previous one drew: a batch of bodies in views of different sizes costs
    exactly what each body costs alone."""
    rng = np.random.default_rng(7)
    sizes = np.array([[50, 60], [40, 30]], np.int64)  # (width, height)
    H, W = 60, 50
    observed = np.zeros((2, H, W), bool)
    observed[0, 10:40, 10:30] = True
    observed[1, 5:20, 8:25] = True
    dist = np.zeros((2, H, W), np.float32)
    boxes = np.zeros((2, 4), np.int64)
    for c, (w, h) in enumerate(sizes):
        obs_c = observed[c, :h, :w]
        dist[c, :h, :w] = cv2.distanceTransform((~obs_c).astype(np.uint8), cv2.DIST_L2, 3)
        x, y, bw, bh = cv2.boundingRect(obs_c.astype(np.uint8))
        boxes[c] = (x, y, x + bw, y + bh)
    area = observed.sum(axis=(1, 2)).astype(float)
    # Three bodies: quads of random corners, the first large (it draws over most of
    # the views), so a stale pixel of it would change the later costs.
    bodies = [(2.5, 3.5, 45.5, 55.5)] + [
        tuple(np.sort(rng.uniform(0, 40, 2))) + tuple(np.sort(rng.uniform(0, 28, 2)))
        for _ in range(2)
    ]
    xs, ys = np.empty((3, 2, 4)), np.empty((3, 2, 4))
    faces = None
    for b, (x0, y0, x1, y1) in enumerate(bodies):
        xy, faces = _quad(x0, y0, x1, y1)
        xs[b], ys[b] = xy[:, 0], xy[:, 1]

    def costs(xs, ys):
        out = np.empty((len(xs), 2))
        status = lk.chamfer_kernel(
            xs, ys, faces.astype(np.int64), sizes, H, observed, dist, boxes, area, 1.0,
            INSIDE_EPS, out,
        )  # fmt: skip
        assert status == 0
        return out

    batch = costs(xs, ys)
    for b in range(3):
        assert np.array_equal(batch[b], costs(xs[b : b + 1], ys[b : b + 1])[0])
    assert np.all(np.isfinite(batch)) and batch[0, 0] > 0


def test_nearest_pairs_are_the_kd_trees():
    """Both directions of nearest neighbours by one pass over all pairs: the k-d tree's
    indices (continuous model points against observed points on a quarter-pixel grid,
    as the refinement has them: no exact ties)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    for n, m in ((1, 1), (37, 400), (1100, 400)):
        observed = np.round(rng.uniform(0, 300, (m, 2)) * 4) / 4
        model = rng.uniform(0, 300, (n, 2))
        j, k = np.empty(n, np.int64), np.empty(m, np.int64)
        lk.nearest_pairs_kernel(model, observed, j, k)
        assert np.array_equal(j, cKDTree(observed).query(model)[1])
        assert np.array_equal(k, cKDTree(model).query(observed)[1])
