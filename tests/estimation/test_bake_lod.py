"""Tests for the LOD bake helpers (synthetic meshes only; no MakeHuman assets)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from bodymetry.estimation.body_model.bake import lod

fast_simplification = pytest.importorskip("fast_simplification")
trimesh_creation = pytest.importorskip("trimesh.creation")


def _ellipsoid(subdivisions: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A bumpy ellipsoid (20,480 faces at 5 subdivisions), outward, watertight."""
    sphere = trimesh_creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices, dtype=float)
    f = np.asarray(sphere.faces, dtype=np.int64)
    bump = 1.0 + 0.05 * np.sin(3.0 * v[:, 0]) * np.cos(2.0 * v[:, 2])
    return v * bump[:, None] * np.array([0.3, 0.2, 0.9]), f


@pytest.fixture(scope="module")
def ellipsoid() -> tuple[np.ndarray, np.ndarray]:
    return _ellipsoid()


@pytest.fixture(scope="module")
def decimated(ellipsoid) -> tuple[np.ndarray, np.ndarray]:
    return lod.decimate_watertight(*ellipsoid, target_faces=3000)


def _brute_force_distance(v, f, points):
    n_p, n_f = points.shape[0], f.shape[0]
    p = np.repeat(points, n_f, axis=0)
    t = np.tile(f, (n_p, 1))
    _, d2 = lod._closest_on_triangles(p, v[t[:, 0]], v[t[:, 1]], v[t[:, 2]])
    return np.sqrt(d2.reshape(n_p, n_f).min(axis=1))


# ---------------------------------------------------------------- checks


def test_mesh_defects_accepts_closed_outward_mesh(ellipsoid):
    v, f = ellipsoid
    assert lod.mesh_defects(v, f) == []
    assert lod.signed_volume(v, f) > 0


def test_mesh_defects_finds_problems():
    v, f = _ellipsoid(subdivisions=1)
    assert any("opposite" in p for p in lod.mesh_defects(v, f[1:]))  # open
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert lod.mesh_defects(v, flipped)
    assert any("non-positive volume" in p for p in lod.mesh_defects(v, f[:, ::-1]))
    assert any("duplicate" in p for p in lod.mesh_defects(v, np.vstack([f, f[:1]])))
    # Two tetrahedra sharing one vertex: edge-manifold but pinched.
    tv = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tf = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    v2 = np.vstack([tv, -tv[1:]])
    f2 = np.vstack([tf, np.where(tf == 0, 0, tf + 3)[:, ::-1]])  # mirrored: flip
    assert lod.mesh_defects(tv, tf) == []
    assert any("pinched" in p for p in lod.mesh_defects(v2, f2))


# ---------------------------------------------------------------- decimation


def test_decimation_is_watertight_and_close(ellipsoid, decimated):
    v, f = ellipsoid
    lv, lf = decimated
    assert abs(lf.shape[0] - 3000) <= 60
    assert lv.dtype == np.float64 and lf.dtype == np.int64
    assert lod.mesh_defects(lv, lf) == []
    ratio = lod.signed_volume(lv, lf) / lod.signed_volume(v, f)
    assert abs(ratio - 1.0) < 0.02
    _, dist = lod.barycentric_map(v, f, lv, return_distances=True)
    assert dist.max() < 0.01  # 1 % of the longest semi-axis


def test_decimation_is_deterministic(ellipsoid, decimated):
    lv, lf = lod.decimate_watertight(*ellipsoid, target_faces=3000)
    assert lv.tobytes() == decimated[0].tobytes()
    assert lf.tobytes() == decimated[1].tobytes()


def test_decimation_retries_then_gives_up(ellipsoid, monkeypatch):
    v, f = ellipsoid
    real = fast_simplification.simplify
    calls = []

    def open_first(points, triangles, **kw):
        calls.append(kw["agg"])
        out_v, out_f = real(points, triangles, **kw)
        return (out_v, out_f[1:]) if len(calls) == 1 else (out_v, out_f)

    monkeypatch.setattr(fast_simplification, "simplify", open_first)
    lv, lf = lod.decimate_watertight(v, f, target_faces=3000)
    assert calls == [5.0, 4.0]
    assert lod.mesh_defects(lv, lf) == []

    def always_open(points, triangles, **kw):
        out_v, out_f = real(points, triangles, **kw)
        return out_v, out_f[1:]

    monkeypatch.setattr(fast_simplification, "simplify", always_open)
    with pytest.raises(RuntimeError, match="no setting gave an acceptable watertight mesh"):
        lod.decimate_watertight(v, f, target_faces=3000, target_scales=(1.0,))


def test_repair_drops_folded_and_duplicate_faces():
    v, f = _ellipsoid(subdivisions=1)
    extra = np.vstack([f[:2], f[3, ::-1], f[3], [[0, 0, 1]]])
    rv, rf = lod._repair(v, np.vstack([f, extra]))
    rf_set = {tuple(x) for x in rf}
    assert rv.shape == v.shape and rf.shape[0] == f.shape[0] - 1
    assert tuple(f[3]) not in rf_set and rf_set <= {tuple(x) for x in f}


def test_decimation_rejects_bad_input(ellipsoid):
    v, f = ellipsoid
    with pytest.raises(ValueError, match="not watertight"):
        lod.decimate_watertight(v, f[1:], target_faces=3000)
    with pytest.raises(ValueError, match="target_faces"):
        lod.decimate_watertight(v, f, target_faces=f.shape[0])


# ---------------------------------------------------------------- barycentric map


def test_closest_triangle_kernel_matches_dense_sampling():
    rng = np.random.default_rng(1)
    a, b, c = rng.normal(size=(3, 200, 3))
    c[:20] = a[:20] + 0.3 * (b[:20] - a[:20])  # degenerate (collinear) triangles
    p = 2.0 * rng.normal(size=(200, 3))
    bary, d2 = lod._closest_on_triangles(p, a, b, c)
    assert np.all(bary >= 0) and np.allclose(bary.sum(axis=1), 1.0)
    grid = np.vstack([lod._grid_centroids(60), np.eye(3)])  # (3600 + 3, 3)
    samples = np.einsum("sk,nkd->nsd", grid, np.stack([a, b, c], axis=1))
    dense = np.sqrt(((samples - p[:, None, :]) ** 2).sum(axis=2).min(axis=1))
    assert np.all(np.sqrt(d2) <= dense + 1e-12)


def test_closest_points_is_exact():
    v, f = _ellipsoid(subdivisions=2)
    # Make some triangles much larger than others (exercises the proxies).
    v = v * (1.0 + 2.0 * (v[:, 2:] > 0.6))
    rng = np.random.default_rng(2)
    pts = np.vstack([rng.normal(size=(150, 3)) * 0.6, v[:50] + 0.02 * rng.normal(size=(50, 3))])
    for k in (1, 4, 16):
        face, bary, dist = lod.closest_points(v, f, pts, k=k)
        np.testing.assert_allclose(dist, _brute_force_distance(v, f, pts), atol=1e-12)
        q = np.einsum("pk,pkd->pd", bary, v[f[face]])
        np.testing.assert_allclose(np.linalg.norm(pts - q, axis=1), dist, atol=1e-12)


def test_barycentric_map_reproduces_surface_points(ellipsoid):
    v, f = ellipsoid
    pts = np.vstack([v[::2], v[f[::2]].mean(axis=1)])
    M, dist = lod.barycentric_map(v, f, pts, return_distances=True)
    assert sp.issparse(M) and M.format == "csr" and M.shape == (pts.shape[0], v.shape[0])
    np.testing.assert_allclose(np.asarray(M.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert M.data.min() >= 0.0 and M.data.max() <= 1.0
    assert np.all(np.diff(M.indptr) == 3)
    np.testing.assert_allclose(M @ v, pts, rtol=0, atol=1e-9)
    assert dist.max() < 1e-9


def test_barycentric_map_is_linear_in_the_full_mesh(ellipsoid, decimated):
    v, f = ellipsoid
    rng = np.random.default_rng(3)
    pts = np.vstack([decimated[0], rng.normal(size=(100, 3))])
    M = lod.barycentric_map(v, f, pts)
    A = rng.normal(size=(3, 3))
    t = rng.normal(size=3)
    np.testing.assert_allclose(M @ (v @ A.T + t), (M @ v) @ A.T + t, rtol=0, atol=1e-12)
    # Mapped points lie on the surface: re-mapping them moves nothing.
    on = M @ v
    _, dist = lod.barycentric_map(v, f, on, return_distances=True)
    assert dist.max() < 1e-12


# ---------------------------------------------------------------- labels


def test_transfer_face_labels_by_side(ellipsoid, decimated):
    v, f = ellipsoid
    lv, lf = decimated
    labels = np.where(v[f].mean(axis=1)[:, 0] > 0, 7, 3)
    out = lod.transfer_face_labels(v, f, labels, lv, lf)
    assert out.shape == (lf.shape[0],) and out.dtype == labels.dtype
    x = lv[lf][:, :, 0]
    right, left = (x > 0.02).all(axis=1), (x < -0.02).all(axis=1)
    assert right.sum() > 1000 and left.sum() > 1000
    assert np.all(out[right] == 7) and np.all(out[left] == 3)
    names = np.where(labels == 7, "right", "left")
    assert np.array_equal(lod.transfer_face_labels(v, f, names, lv, lf) == "right", out == 7)
