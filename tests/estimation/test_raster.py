"""Coverage rasterization (estimation.raster.coverage) against the z-buffer's inside rule,
and the compiled (numba) rasterizer against the numpy reference, bit for bit."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import trimesh

from bodymetry.estimation import raster
from bodymetry.estimation.body_model.model import THETA, BodyModel, BodyState
from bodymetry.estimation.raster import Raster, coverage, coverage_views, rasterize
from bodymetry.studio.rig import studio_rig

HAVE_NUMBA = importlib.util.find_spec("numba") is not None
#: Every implementation available here: the tests of the inside rule run on each.
BACKENDS = ["numpy", "numba"] if HAVE_NUMBA else ["numpy"]
needs_numba = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(params=BACKENDS)
def backend(request, monkeypatch):
    """Run each test with each implementation (raster.BACKEND, read at every call)."""
    monkeypatch.setattr(raster, "BACKEND", request.param)
    return request.param


def _both(monkeypatch, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` by the numpy reference and by the compiled kernels."""
    out = []
    for name in ("numpy", "numba"):
        monkeypatch.setattr(raster, "BACKEND", name)
        out.append(fn(*args, **kwargs))
    return out


def _same_bits(a: np.ndarray, b: np.ndarray) -> None:
    """Equal dtype, shape and bytes (stricter than assert_array_equal: -0.0 != 0.0)."""
    assert a.dtype == b.dtype and a.shape == b.shape
    assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()


def _same_raster(a: Raster, b: Raster) -> None:
    assert a.size == b.size
    for field in ("tri", "depth", "pixels", "bary"):
        _same_bits(getattr(a, field), getattr(b, field))


def _zbuffer_mask(xy: np.ndarray, faces: np.ndarray, size, valid=None) -> np.ndarray:
    return rasterize(xy, np.ones(len(xy)), faces, size, perspective=False, valid=valid).mask


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coverage_equals_the_zbuffer_mask_on_triangle_soup(backend, seed):
    """Random triangles, partly off the image, some on integer (pixel-centre) positions."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-20, 120, (300, 2))
    xy[::3] = np.round(xy[::3])  # vertices exactly on pixel centres: ties of the inside rule
    faces = rng.integers(0, 300, (200, 3))
    np.testing.assert_array_equal(
        coverage(xy, faces, (100, 80)), _zbuffer_mask(xy, faces, (100, 80))
    )


def test_front_faces_of_a_closed_mesh_cover_the_same_pixels(backend):
    """An outward sphere seen through a pinhole: front faces alone give the whole silhouette."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    for centre in ([0.0, 0.0, 2.0], [0.3, -0.2, 1.2], [-0.9, 0.5, 3.0]):
        v = sphere.vertices + centre
        xy = 300.0 * v[:, :2] / v[:, 2:] + [160.3, 120.6]  # OpenCV camera, no distortion
        full = _zbuffer_mask(xy, sphere.faces, (320, 240))
        assert full.sum() > 500
        np.testing.assert_array_equal(coverage(xy, sphere.faces, (320, 240), closed=True), full)
        np.testing.assert_array_equal(coverage(xy, sphere.faces, (320, 240)), full)


def test_coverage_skips_invalid_vertices_and_validates(backend):
    xy = np.array([[1.0, 1.0], [8.0, 1.0], [1.0, 8.0], [np.nan, 3.0]])
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    mask = coverage(xy, faces, (10, 10))
    np.testing.assert_array_equal(mask, _zbuffer_mask(np.nan_to_num(xy), faces[:1], (10, 10)))
    assert not coverage(xy, faces, (10, 10), valid=np.array([False, True, True, True])).any()
    assert not coverage(np.zeros((0, 2)), np.zeros((0, 3), int), (10, 10)).any()
    with pytest.raises(ValueError, match="xy must have shape"):
        coverage(np.zeros((3, 3)), faces, (10, 10))


def test_views_in_one_pass_equal_one_call_per_view(backend):
    """Tiles do not bleed: triangles reaching past their view's bottom or top are cut
    at its edge; a NaN vertex drops its triangles in that view only."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(-30, 130, (3, 300, 2))
    xy[1, 5] = np.nan
    faces = rng.integers(0, 300, (200, 3))
    stacked = coverage_views(xy, faces, (100, 80))
    assert stacked.shape == (3, 80, 100)
    for c in range(3):
        valid = np.isfinite(xy[c]).all(axis=1)
        alone = coverage(np.nan_to_num(xy[c]), faces, (100, 80), valid=valid)
        np.testing.assert_array_equal(stacked[c], alone)
    with pytest.raises(ValueError, match="xy must have shape"):
        coverage_views(xy[0], faces, (100, 80))


# --- numba against the numpy reference ------------------------------------------------


def _soup(seed: int, n: int = 300, t: int = 400, lo: float = -30.0, hi: float = 130.0):
    """Random triangles with every special case of the inside rule: vertices on
    pixel centres and half-pixels (ties), degenerate triangles (a repeated vertex,
    collinear, sub-1e-12 area), triangles partly or wholly off the image, both
    windings, a NaN and an infinite vertex, huge coordinates."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(lo, hi, (n, 2))
    xy[::3] = np.round(xy[::3])  # on pixel centres
    xy[1::7] = np.round(xy[1::7]) + 0.5  # on pixel edges
    xy[5] = np.nan
    xy[6] = [np.inf, 3.0]
    xy[7] = [1e150, -1e150]  # finite, far off; (numpy warns when products overflow)
    xy[8] = [1e-13, 0.0]
    faces = rng.integers(0, n, (t, 3))
    faces[:10, 1] = faces[:10, 0]  # repeated vertex
    xy[9:12] = [[10.0, 10.0], [20.0, 20.0], [30.0, 30.0]]  # collinear
    faces[10] = [9, 10, 11]
    xy[12:15] = [[0.0, 0.0], [1e-7, 0.0], [0.0, 1e-7]]  # area 1e-14: dropped
    faces[11] = [12, 13, 14]
    faces[12] = [5, 20, 21]
    faces[13] = [6, 22, 23]
    faces[14] = [7, 24, 25]
    depth = rng.uniform(0.5, 5.0, n)
    depth[::11] = 2.0  # equal depths: ties of the z-buffer
    return xy, faces, depth


@needs_numba
@pytest.mark.parametrize("seed", range(6))
def test_numba_coverage_is_the_numpy_coverage_bit_for_bit(monkeypatch, seed):
    xy, faces, _ = _soup(seed)
    valid = np.random.default_rng(seed).random(len(xy)) > 0.1
    for size in ((100, 80), (37, 129), (1, 1)):
        for closed in (False, True):
            for v in (None, valid):
                ref, fast = _both(monkeypatch, coverage, xy, faces, size, closed=closed, valid=v)
                _same_bits(ref, fast)
    # One pixel, a triangle through its centre exactly on an edge (the tolerance).
    tri = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    ref, fast = _both(monkeypatch, coverage, tri, np.array([[0, 1, 2]]), (3, 3))
    _same_bits(ref, fast)
    assert ref.sum() == 6


@needs_numba
@pytest.mark.parametrize("seed", range(2))
def test_numba_views_are_the_numpy_views_bit_for_bit(monkeypatch, seed):
    """Views of one size (stacked) and of different sizes (a list), NaN vertices in
    some views, triangles past a tile's edge; the views' y offsets round alike."""
    rng = np.random.default_rng(100 + seed)
    xy = np.stack([_soup(seed + 10 * c)[0] for c in range(4)])
    faces = _soup(seed)[1]
    xy[2, 40:60] = np.nan
    xy[3] *= 2.5  # reaches far past the tile
    for size in ((100, 80), [(100, 80), (64, 48), (120, 30), (7, 90)]):
        for closed in (False, True):
            ref, fast = _both(monkeypatch, coverage_views, xy, faces, size, closed=closed)
            assert type(ref) is type(fast)
            for a, b in zip(ref, fast, strict=True):
                _same_bits(a, b)
    sizes = [tuple(int(v) for v in s) for s in rng.integers(1, 200, (4, 2))]
    ref, fast = _both(monkeypatch, coverage_views, xy, faces, sizes, closed=True)
    for a, b in zip(ref, fast, strict=True):
        _same_bits(a, b)


@needs_numba
@pytest.mark.parametrize("seed", range(4))
def test_numba_zbuffer_is_the_numpy_zbuffer_bit_for_bit(monkeypatch, seed):
    """Triangle, depth and barycentrics per pixel; equal depths tie the same way
    (the last triangle wins), every cull mode, perspective and orthographic."""
    xy, faces, depth = _soup(seed)
    valid = np.random.default_rng(seed).random(len(xy)) > 0.05
    for perspective in (True, False):
        for cull in ("none", "back", "front"):
            for v in (None, valid):
                ref, fast = _both(
                    monkeypatch,
                    rasterize,
                    xy,
                    depth,
                    faces,
                    (100, 80),
                    perspective=perspective,
                    cull=cull,
                    valid=v,
                )
                _same_raster(ref, fast)
    flat = np.ones(len(xy))  # every candidate ties: the last triangle wins in both
    ref, fast = _both(monkeypatch, rasterize, xy, flat, faces, (100, 80), perspective=False)
    _same_raster(ref, fast)
    huge = depth * 1e30  # orthographic depths of both signs, far apart
    huge[1::2] *= -1
    ref, fast = _both(monkeypatch, rasterize, xy, huge, faces, (100, 80), perspective=False)
    _same_raster(ref, fast)


@pytest.fixture(scope="module")
def body():
    """The body's level of detail in a few poses, and the studio rig at two sizes."""
    model = BodyModel.load()
    rng = np.random.default_rng(3)
    state = BodyState.rest(batch=4)
    Y = state.vector()
    Y[:, :3] = [0.0, 0.0, 0.93]
    Y[1:, THETA] += rng.normal(0.0, 0.4, (3, THETA.stop - THETA.start))
    Y[3, :3] += [1.9, 0.5, 0.0]  # partly outside some images
    posed = model.pose(BodyState.from_vector(Y), lod=True).vertices
    return posed, model.faces(lod=True)


@needs_numba
@pytest.mark.parametrize("size", [(160, 120), (640, 480)])
def test_numba_is_numpy_on_the_body_level_of_detail(monkeypatch, body, size):
    """The likelihood's case: front faces of the closed body in 4 views, per view
    and in one pass, with views of different sizes; and the studio's z-buffer."""
    verts, faces = body
    cams = studio_rig(4, size, seed=5)
    for v in verts:
        xy = np.stack([c.project(v) for c in cams])
        ref, fast = _both(monkeypatch, coverage_views, xy, faces, size, closed=True)
        _same_bits(ref, fast)
        assert ref.any()
        mixed = [size, (size[0] // 2, size[1]), (size[0], size[1] // 3), (size[0] - 7, 11)]
        ref, fast = _both(monkeypatch, coverage_views, xy, faces, mixed, closed=True)
        for a, b in zip(ref, fast, strict=True):
            _same_bits(a, b)
        for c, cam in enumerate(cams):
            ref, fast = _both(monkeypatch, coverage, xy[c], faces, size, closed=True)
            _same_bits(ref, fast)
            z = cam.to_camera(v)[:, 2]
            ref, fast = _both(monkeypatch, rasterize, xy[c], z, faces, size, cull="back")
            _same_raster(ref, fast)


@needs_numba
def test_numba_takes_read_only_and_int32_inputs(monkeypatch, body):
    """Shared, read-only meshes (BodyModel.faces) and int32 faces give the same pixels
    (the arguments are normalized, so no second kernel version is compiled); face
    indices outside 0 .. N - 1, negative ones included, raise."""
    verts, faces = body
    xy = studio_rig(1, (160, 120), seed=5)[0].project(verts[0])
    ro = faces.astype(np.int32)
    ro.flags.writeable = False
    ref, fast = _both(monkeypatch, coverage, xy, ro, (160, 120), closed=True)
    _same_bits(ref, fast)
    kernels = raster._kernels()
    assert len(kernels.coverage_kernel.signatures) == 1
    with pytest.raises(IndexError, match="out of range"):
        coverage(xy, faces + len(xy), (160, 120))
    with pytest.raises(IndexError, match="out of range"):
        rasterize(xy, np.ones(len(xy)), faces + len(xy), (160, 120))
    with pytest.raises(IndexError, match="out of range"):  # numpy would wrap them
        coverage_views(xy[None], faces - len(xy), (160, 120))


def test_the_backend_is_chosen_in_one_place():
    assert raster._default_backend("numpy") == "numpy"
    assert raster._default_backend("numba") == "numba"
    assert raster._default_backend(None) == ("numba" if HAVE_NUMBA else "numpy")
    with pytest.raises(ValueError, match="BODYMETRY_RASTER"):
        raster._default_backend("cuda")
