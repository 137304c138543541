"""Tests for estimation.body_model.geometry on synthetic analytic meshes (trimesh builds them)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from bodymetry.estimation.body_model import geometry as g

# --------------------------------------------------------------------------
# Tolerances, all in one place (relative unless the name says ABS, in metres).
# --------------------------------------------------------------------------
# Closed-form results: box volume/girth, polygonal-prism volume, regular-polygon
# perimeter and area. Only float64 round-off separates us from them.
RTOL_EXACT = 1e-12
ABS_EXACT = 1e-12
# icosphere(subdivisions=SPHERE_SUBDIVISIONS) against the *smooth* sphere 4/3 π r³:
# the inscribed polyhedron is 0.054 % smaller, inside the required 0.1 %.
SPHERE_SUBDIVISIONS = 5
RTOL_SPHERE_VOLUME = 1e-3
# Girth of that icosphere against the smooth circle 2π√(r² - z²): the section lies
# inside the circle (so never above it) and at most 0.08 % short for z in
# [-0.9 r, 0.9 r]; tolerance with margin.
RTOL_SPHERE_GIRTH = 2e-3
# Cylinder with CYLINDER_SECTIONS sides against the smooth cylinder πr²h / 2πr:
# polygon corrections sin(2π/n)/(2π/n) = 0.040 % and sin(π/n)/(π/n) = 0.010 %.
CYLINDER_SECTIONS = 128
RTOL_SMOOTH_CYLINDER = 1e-3
# Invariances under rigid motion / scaling / batching of float64 meshes.
RTOL_INVARIANCE = 1e-10

SEED = 20240611


# --------------------------------------------------------------------------
# Synthetic meshes
# --------------------------------------------------------------------------


def _polygon_perimeter(r: float, n: int) -> float:
    """Perimeter of a regular n-gon inscribed in a circle of radius r."""
    return 2.0 * n * r * np.sin(np.pi / n)


def _polygon_area(r: float, n: int) -> float:
    return 0.5 * n * r * r * np.sin(2.0 * np.pi / n)


def _box(extents=(0.3, 0.2, 1.7), floor=0.0):
    """Axis-aligned box standing on z = floor, centred on x = y = 0."""
    m = trimesh.creation.box(extents=extents)
    v = m.vertices + np.array([0.0, 0.0, floor + extents[2] / 2])
    return v, m.faces


def _icosphere(radius=0.15, center=(0.0, 0.0, 0.0)):
    m = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=radius)
    return m.vertices + center, m.faces


def _cylinder(radius=0.1, height=0.8, sections=CYLINDER_SECTIONS, center=(0.0, 0.0, 0.4)):
    """Regular-prism cylinder with vertices at angles 2πk/sections (trimesh layout)."""
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    return m.vertices + center, m.faces


def _ringed_cylinder(radius, levels, sections, center_xy=(0.0, 0.0)):
    """Closed outward prism with a vertex ring at every height in ``levels`` (to cut
    exactly through vertices)."""
    levels = np.asarray(levels, dtype=float)
    n, m = sections, len(levels)
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.stack([radius * np.cos(ang), radius * np.sin(ang)], axis=1) + center_xy
    verts = [np.column_stack([ring, np.full(n, zk)]) for zk in levels]
    verts.append([[*center_xy, levels[0]], [*center_xy, levels[-1]]])
    v = np.concatenate(verts)
    idx = np.arange(m * n).reshape(m, n)
    a, b = idx[:-1], np.roll(idx, -1, axis=1)[:-1]
    c, d = np.roll(idx, -1, axis=1)[1:], idx[1:]
    side = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    bottom_c, top_c = m * n, m * n + 1
    j, j1 = np.arange(n), np.roll(np.arange(n), -1)
    bottom = np.column_stack([np.full(n, bottom_c), idx[0, j1], idx[0, j]])
    top = np.column_stack([np.full(n, top_c), idx[-1, j], idx[-1, j1]])
    return v, np.concatenate([side, bottom, top])


def _two_legs(r_left=0.07, r_right=0.06, gap=0.25, sections=48):
    """Two disjoint vertical cylinders ("legs") at x = -gap/2 and x = +gap/2."""
    vl, fl = _ringed_cylinder(r_left, [0.0, 0.4, 0.8], sections, (-gap / 2, 0.0))
    vr, fr = _ringed_cylinder(r_right, [0.0, 0.4, 0.8], sections, (gap / 2, 0.0))
    v = np.concatenate([vl, vr])
    f = np.concatenate([fl, fr + len(vl)])
    left = np.zeros(len(f), dtype=bool)
    left[: len(fl)] = True
    return v, f, left


@pytest.fixture(scope="module")
def closed_meshes():
    return {
        "box": _box(),
        "icosphere": _icosphere(),
        "cylinder": _cylinder(),
        "ringed_cylinder": _ringed_cylinder(0.1, [0.0, 0.3, 0.5, 1.0], 40),
    }


# --------------------------------------------------------------------------
# Volume
# --------------------------------------------------------------------------


def test_box_volume_exact():
    v, f = _box((0.3, 0.2, 1.7), floor=0.0)
    assert g.mesh_volume(v, f) == pytest.approx(0.3 * 0.2 * 1.7, rel=RTOL_EXACT)


def test_icosphere_volume_matches_smooth_sphere():
    r = 0.15
    v, f = _icosphere(r, center=(0.2, -0.1, 1.2))
    vol = g.mesh_volume(v, f)
    assert isinstance(vol, float)
    assert vol == pytest.approx(4.0 / 3.0 * np.pi * r**3, rel=RTOL_SPHERE_VOLUME)
    assert vol < 4.0 / 3.0 * np.pi * r**3  # inscribed polyhedron
    # and an independent implementation agrees to round-off
    assert vol == pytest.approx(trimesh.Trimesh(v, f, process=False).volume, rel=RTOL_EXACT)


def test_cylinder_volume_prism_exact_and_smooth():
    r, h = 0.1, 0.8
    v, f = _cylinder(r, h)
    vol = g.mesh_volume(v, f)
    assert vol == pytest.approx(_polygon_area(r, CYLINDER_SECTIONS) * h, rel=RTOL_EXACT)
    assert vol == pytest.approx(np.pi * r * r * h, rel=RTOL_SMOOTH_CYLINDER)
    v2, f2 = _ringed_cylinder(r, [0.0, 0.3, 0.5, h], 40)
    assert g.mesh_volume(v2, f2) == pytest.approx(_polygon_area(r, 40) * h, rel=RTOL_EXACT)


@pytest.mark.parametrize("name", ["box", "icosphere", "cylinder", "ringed_cylinder"])
def test_volume_invariances(closed_meshes, name):
    v, f = closed_meshes[name]
    rng = np.random.default_rng(SEED)
    vol = g.mesh_volume(v, f)
    assert vol > 0

    rot = Rotation.random(random_state=rng).as_matrix()
    moved = v @ rot.T + rng.uniform(-5.0, 5.0, size=3)
    assert g.mesh_volume(moved, f) == pytest.approx(vol, rel=RTOL_INVARIANCE)

    s = 1.7
    assert g.mesh_volume(s * v, f) == pytest.approx(s**3 * vol, rel=RTOL_INVARIANCE)
    assert g.mesh_volume(v, f[:, ::-1]) == pytest.approx(-vol, rel=RTOL_EXACT)


def test_volume_batched_equals_per_mesh():
    rng = np.random.default_rng(SEED)
    v, f = _icosphere()
    batch = v + rng.normal(scale=0.005, size=(4, *v.shape))  # same topology, 4 shapes
    vols = g.mesh_volume(batch, f)
    assert isinstance(vols, np.ndarray)
    assert vols.shape == (4,)
    expected = [g.mesh_volume(b, f) for b in batch]
    np.testing.assert_allclose(vols, expected, rtol=RTOL_INVARIANCE)
    assert g.mesh_volume(batch[:0], f).shape == (0,)
    # float32 input is accumulated in float64
    vol32 = g.mesh_volume(batch.astype(np.float32), f)
    np.testing.assert_allclose(vol32, expected, rtol=1e-5)


def test_volume_empty_mesh_is_zero():
    assert g.mesh_volume(np.zeros((0, 3)), np.zeros((0, 3), dtype=int)) == 0.0
    assert g.mesh_volume(np.zeros((4, 3)), []) == 0.0


# --------------------------------------------------------------------------
# Topology
# --------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["box", "icosphere", "cylinder", "ringed_cylinder"])
def test_is_closed_true_then_false_when_broken(closed_meshes, name):
    v, f = closed_meshes[name]
    assert g.is_closed(f, len(v))
    assert g.boundary_edges(f).shape == (0, 2)

    holed = np.delete(f, 3, axis=0)
    assert not g.is_closed(holed, len(v))
    a, b, c = f[3]
    assert {tuple(e) for e in g.boundary_edges(holed)} == {(b, a), (c, b), (a, c)}

    flipped = f.copy()
    flipped[3] = flipped[3, ::-1]
    assert not g.is_closed(flipped, len(v))
    assert g.boundary_edges(flipped).shape == (0, 2)  # watertight, just inconsistent


def test_is_closed_other_failures():
    v, f = _box()
    assert not g.is_closed(np.zeros((0, 3), dtype=int), len(v))  # nothing enclosed
    assert not g.is_closed(np.concatenate([f, f[:1]]), len(v))  # a duplicated face
    degenerate = f.copy()
    degenerate[0, 1] = degenerate[0, 0]
    assert not g.is_closed(degenerate, len(v))
    legs_v, legs_f, _ = _two_legs()
    assert g.is_closed(legs_f, len(legs_v))  # two disjoint closed parts


# --------------------------------------------------------------------------
# Sections and girths
# --------------------------------------------------------------------------


def test_box_section_exact():
    a, b, h = 0.3, 0.2, 1.7
    v, f = _box((a, b, h))
    for z in (0.25, 1.0, h):  # h: exactly through the top vertices (on-plane = above)
        assert g.girth(v, f, z) == pytest.approx(2 * (a + b), rel=RTOL_EXACT)
        (loop,) = g.section_loops(g.plane_section(v, f, z))
        assert g.loop_area(loop) == pytest.approx(a * b, rel=RTOL_EXACT)
        assert g.loop_perimeter(loop) == pytest.approx(2 * (a + b), rel=RTOL_EXACT)
    assert g.girth(v, f, 0.0) == 0.0  # exactly at the floor: acts as z = -ε, misses


def test_cylinder_girth_polygon_exact_and_smooth():
    r = 0.1
    v, f = _cylinder(r, 0.8, center=(0.3, -0.2, 0.4))
    for z in (0.05, 0.4, 0.79):
        gz = g.girth(v, f, z)
        assert gz == pytest.approx(_polygon_perimeter(r, CYLINDER_SECTIONS), rel=RTOL_EXACT)
        assert gz == pytest.approx(2 * np.pi * r, rel=RTOL_SMOOTH_CYLINDER)


def test_sphere_girth_within_discretization_tolerance():
    r = 0.15
    v, f = _icosphere(r, center=(0.0, 0.0, 1.0))
    for z_rel in np.linspace(-0.9, 0.9, 7):
        rho = r * np.sqrt(1 - z_rel**2)
        gz = g.girth(v, f, 1.0 + z_rel * r)
        assert 2 * np.pi * rho * (1 - RTOL_SPHERE_GIRTH) <= gz <= 2 * np.pi * rho * (1 + 1e-12)


def test_section_through_vertex_ring_is_one_closed_loop():
    r, n = 0.1, 40
    v, f = _ringed_cylinder(r, [0.0, 0.3, 0.5, 1.0], n)
    for z in (0.3, 0.5, 1.0):  # exactly at vertex rings
        segs = g.plane_section(v, f, z)
        loops = g.section_loops(segs, tol=0.0)  # on-plane points are bit-identical
        assert len(loops) == 1
        assert len(loops[0]) == n
        assert g.loop_area(loops[0]) == pytest.approx(_polygon_area(r, n), rel=RTOL_EXACT)
        assert g.loop_perimeter(loops[0]) == pytest.approx(_polygon_perimeter(r, n), rel=1e-12)
        assert g.girth(v, f, z) == pytest.approx(_polygon_perimeter(r, n), rel=RTOL_EXACT)


def test_sphere_section_through_vertices_is_continuous():
    v, f = _icosphere(1.0)
    on_plane = v[np.abs(v[:, 2]) < 1e-15]
    assert len(on_plane) > 0  # the equator of an icosphere holds vertices
    loops = g.section_loops(g.plane_section(v, f, 0.0), tol=0.0)
    assert len(loops) == 1
    below, at, above = (g.girth(v, f, z) for z in (-1e-9, 0.0, 1e-9))
    assert min(below, above) - 1e-6 <= at <= max(below, above) + 1e-6


def test_section_orientation_follows_faces():
    v, f = _icosphere(0.15, center=(0.0, 0.0, 1.0))
    (loop,) = g.section_loops(g.plane_section(v, f, 1.05))
    assert g.loop_area(loop) > 0  # outward faces: counter-clockwise seen from above
    (loop_in,) = g.section_loops(g.plane_section(v, f[:, ::-1], 1.05))
    assert g.loop_area(loop_in) == pytest.approx(-g.loop_area(loop), rel=RTOL_EXACT)


def test_plane_missing_mesh_gives_empty_section_and_zero_girth():
    v, f = _cylinder()
    for z in (-1.0, 0.0, 0.8 + 1e-9, 5.0):
        segs = g.plane_section(v, f, z)
        assert segs.shape == (0, 2, 2)
        assert g.girth(v, f, z) == 0.0
        assert g.section_loops(segs) == []


def test_face_mask_restricts_section():
    r, gap, n = 0.07, 0.25, 48
    v, f, left = _two_legs(r, r, gap, n)
    z = 0.2
    one = _polygon_perimeter(r, n)
    assert g.girth(v, f, z, face_mask=left) == pytest.approx(one, rel=RTOL_EXACT)
    assert g.girth(v, f, z, face_mask=~left) == pytest.approx(one, rel=RTOL_EXACT)
    assert len(g.plane_section(v, f, z, face_mask=left)) == 2 * n  # 2 triangles per side
    assert g.girth(v, f, z, face_mask=np.zeros(len(f), dtype=bool)) == 0.0
    # A tape around both legs: the hull of a convex K and K + d is the Minkowski
    # sum K + [0, d], whose perimeter is per(K) + 2|d|.
    assert g.girth(v, f, z) == pytest.approx(one + 2 * gap, rel=RTOL_EXACT)


def test_two_legs_give_two_loops_sorted_by_area():
    r_left, r_right, gap, n = 0.07, 0.06, 0.25, 48
    v, f, _ = _two_legs(r_left, r_right, gap, n)
    loops = g.section_loops(g.plane_section(v, f, 0.2))
    assert len(loops) == 2
    big, small = loops
    assert g.loop_area(big) == pytest.approx(_polygon_area(r_left, n), rel=RTOL_EXACT)
    assert g.loop_area(small) == pytest.approx(_polygon_area(r_right, n), rel=RTOL_EXACT)
    np.testing.assert_allclose(big.mean(axis=0), [-gap / 2, 0.0], atol=ABS_EXACT)
    np.testing.assert_allclose(small.mean(axis=0), [gap / 2, 0.0], atol=ABS_EXACT)
    for loop, r in ((big, r_left), (small, r_right)):
        assert loop.shape == (2 * n, 2)  # corners + a point on each side's diagonal
        assert g.loop_perimeter(loop) == pytest.approx(_polygon_perimeter(r, n), rel=1e-12)


def test_loops_touching_at_a_point_are_split():
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    other = cube.copy()
    other.apply_translation((1.0, 1.0, 0.0))  # shares one vertical edge with `cube`
    m = trimesh.util.concatenate([cube, other])
    m.merge_vertices()
    v, f = m.vertices, m.faces
    assert not g.is_closed(f, len(v))  # the shared edge has four faces
    assert g.mesh_volume(v, f) == pytest.approx(2.0, rel=RTOL_EXACT)
    for z in (-0.2, 0.0, 0.5):
        loops = g.section_loops(g.plane_section(v, f, z))
        assert [g.loop_area(loop) for loop in loops] == pytest.approx([1.0, 1.0], rel=RTOL_EXACT)
        assert g.girth(v, f, z) == pytest.approx(4.0 + 2.0 * np.sqrt(2.0), rel=RTOL_EXACT)


def test_section_loops_open_chains_raise_or_drop():
    v, f = _cylinder()
    half = g.face_normals(v, f)[:, 0] > 0.1  # side faces facing +x only
    segs = g.plane_section(v, f, 0.4, face_mask=half)
    assert len(segs) > 0
    with pytest.raises(ValueError, match=r"open chain.*drop_open=True"):
        g.section_loops(segs)
    assert g.section_loops(segs, drop_open=True) == []


def test_section_loops_joins_within_tol():
    rng = np.random.default_rng(SEED)
    v, f = _cylinder(0.1, 0.8, sections=32)
    segs = g.plane_section(v, f, 0.4)
    noisy = segs + rng.uniform(-1e-12, 1e-12, size=segs.shape)
    (loop,) = g.section_loops(noisy, tol=1e-9)
    assert len(loop) == 64  # corners + a point on each side's diagonal
    with pytest.raises(ValueError, match="open chain"):
        g.section_loops(noisy, tol=0.0)
    # zero-length segments are ignored
    stub = np.concatenate([segs, [[[0.1, 0.0], [0.1, 0.0]]]])
    assert len(g.section_loops(stub)) == 1


# --------------------------------------------------------------------------
# 2-D helpers
# --------------------------------------------------------------------------


def test_convex_perimeter_regular_and_degenerate():
    rng = np.random.default_rng(SEED)
    square = np.array([[0.0, 0.0], [0.3, 0.0], [0.3, 0.3], [0.0, 0.3]])
    inner = rng.uniform(0.01, 0.29, size=(50, 2))
    pts = np.concatenate([square, inner])[rng.permutation(54)]
    assert g.convex_perimeter(pts) == pytest.approx(1.2, rel=RTOL_EXACT)

    ang = rng.uniform(0, 2 * np.pi, 200)
    circle = np.column_stack([np.cos(ang), np.sin(ang)])
    assert g.convex_perimeter(circle) < 2 * np.pi
    assert g.convex_perimeter(circle) > 2 * np.pi * 0.99

    assert g.convex_perimeter(np.zeros((0, 2))) == 0.0
    assert g.convex_perimeter([]) == 0.0
    assert g.convex_perimeter([[1.0, 2.0]]) == 0.0
    assert g.convex_perimeter([[1.0, 2.0]] * 5) == 0.0  # coincident
    assert g.convex_perimeter([[0.0, 0.0], [3.0, 4.0]]) == pytest.approx(10.0, rel=RTOL_EXACT)
    t = rng.uniform(-1.0, 2.0, 20)
    collinear = np.column_stack([1.0 + 0.6 * t, 2.0 + 0.8 * t])
    expected = 2 * (t.max() - t.min())
    assert g.convex_perimeter(collinear) == pytest.approx(expected, rel=1e-9)


def test_loop_area_and_perimeter():
    ccw = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert g.loop_area(ccw) == pytest.approx(1.0, rel=RTOL_EXACT)
    assert g.loop_area(ccw[::-1]) == pytest.approx(-1.0, rel=RTOL_EXACT)
    assert g.loop_area(ccw + 1e6) == pytest.approx(1.0, rel=1e-9)  # far from the origin
    assert g.loop_perimeter(ccw) == pytest.approx(4.0, rel=RTOL_EXACT)
    assert g.loop_perimeter(ccw, closed=False) == pytest.approx(3.0, rel=RTOL_EXACT)
    assert g.loop_area(ccw[:2]) == 0.0
    assert g.loop_perimeter(ccw[:1]) == 0.0


def test_areas_and_normals():
    a, b, c = 0.3, 0.2, 1.7
    v, f = _box((a, b, c))
    areas = g.triangle_areas(v, f)
    assert areas.shape == (12,)
    assert g.surface_area(v, f) == pytest.approx(2 * (a * b + b * c + c * a), rel=RTOL_EXACT)
    batch = np.stack([v, 2 * v])
    np.testing.assert_allclose(g.surface_area(batch, f), np.array([1, 4]) * g.surface_area(v, f))
    fn = g.face_normals(v, f)
    np.testing.assert_allclose(np.abs(fn).sum(axis=1), 1.0)  # axis-aligned unit normals

    r = 0.15
    sv, sf = _icosphere(r, center=(0.0, 0.0, 1.0))
    sv = np.concatenate([sv, [[9.0, 9.0, 9.0]]])  # an unused vertex
    vn = g.vertex_normals(sv, sf)
    radial = (sv[:-1] - [0.0, 0.0, 1.0]) / r
    assert np.min(np.sum(vn[:-1] * radial, axis=1)) > 0.999
    np.testing.assert_array_equal(vn[-1], 0.0)
    vn_batch = g.vertex_normals(np.stack([sv, sv + 1.0]), sf)
    np.testing.assert_allclose(vn_batch, np.stack([vn, vn]), atol=1e-12)


# --------------------------------------------------------------------------
# Input validation
# --------------------------------------------------------------------------


def test_bad_shapes_raise_clear_value_errors():
    v, f = _box()
    with pytest.raises(ValueError, match=r"faces must have shape \(F, 3\), got \(12, 4\)"):
        g.mesh_volume(v, np.column_stack([f, f[:, :1]]))
    with pytest.raises(ValueError, match=r"vertices must have shape .*got \(8, 2\)"):
        g.mesh_volume(v[:, :2], f)
    with pytest.raises(ValueError, match=r"vertices must have shape \(V, 3\), got \(2, 8, 3\)"):
        g.plane_section(np.stack([v, v]), f, 0.5)
    with pytest.raises(ValueError, match=r"faces must index vertices in \[0, 8\).*got index 8"):
        g.mesh_volume(v, np.where(f == 7, 8, f))
    with pytest.raises(ValueError, match=r"got index -1"):
        g.is_closed(np.where(f == 0, -1, f), len(v))
    with pytest.raises(ValueError, match="faces must be an integer array, got dtype float64"):
        g.triangle_areas(v, f.astype(float))
    with pytest.raises(ValueError, match="vertices must be a real numeric array"):
        g.mesh_volume(v.astype(complex), f)
    with pytest.raises(
        ValueError, match=r"face_mask must have shape \(F,\) = \(12,\), got \(11,\)"
    ):
        g.plane_section(v, f, 0.5, face_mask=np.ones(11, dtype=bool))
    with pytest.raises(ValueError, match="face_mask must be a boolean array"):
        g.girth(v, f, 0.5, face_mask=np.ones(12))
    with pytest.raises(ValueError, match="z must be finite"):
        g.plane_section(v, f, float("nan"))
    with pytest.raises(ValueError, match="z must be a real scalar"):
        g.girth(v, f, np.array([0.5, 0.6]))
    with pytest.raises(ValueError, match=r"segments must have shape \(S, 2, 2\), got \(5, 4\)"):
        g.section_loops(np.zeros((5, 4)))
    with pytest.raises(ValueError, match="tol must be a non-negative"):
        g.section_loops(np.zeros((1, 2, 2)), tol=-1.0)
    with pytest.raises(ValueError, match=r"points must have shape \(N, 2\), got \(4, 3\)"):
        g.convex_perimeter(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="points must be finite"):
        g.convex_perimeter([[0.0, 0.0], [1.0, np.nan], [0.0, 1.0]])
    with pytest.raises(ValueError, match=r"loop must have shape \(N, 2\), got \(3,\)"):
        g.loop_area(np.zeros(3))
    with pytest.raises(ValueError, match="n_vertices must be >= 0"):
        g.is_closed(f, -1)
    with pytest.raises(ValueError, match="n_vertices must be an int"):
        g.is_closed(f, 8.0)


def test_neighbour_mean_known_answer_and_constants():
    """On a tetrahedron each vertex's neighbours are the other three; constants are kept."""
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    m = g.neighbour_mean(faces, 5).toarray()  # vertex 4 is unused
    expected = (np.ones((4, 4)) - np.eye(4)) / 3.0
    np.testing.assert_allclose(m[:4, :4], expected, atol=1e-15)
    assert not m[4].any() and not m[:, 4].any()
    np.testing.assert_allclose(m[:4] @ np.ones(5), 1.0, atol=1e-15)
    with pytest.raises(ValueError, match="n_vertices"):
        g.neighbour_mean(faces, -1)
