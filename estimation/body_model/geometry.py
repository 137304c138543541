"""Plain-array triangle-mesh geometry for body measurements.

Every function takes plain NumPy arrays (no mesh object) and validates them,
raising :class:`ValueError` that names the argument, the expected shape and the
shape it got.

Conventions
-----------
* Lengths are in metres, world ``z`` is up and the floor is ``z = 0``.
* ``vertices`` is a float array of shape ``(V, 3)``; functions documented as
  batched also accept ``(B, V, 3)`` (``B`` meshes sharing one ``faces``).
* ``faces`` is an integer array of shape ``(F, 3)`` of vertex indices in
  ``[0, V)``. A face ``(a, b, c)`` is *outward* when ``(b - a) x (c - a)``
  points out of the body (counter-clockwise seen from outside). Outward faces
  give a positive volume and counter-clockwise (positive-area) section loops.
* Horizontal sections treat a vertex lying exactly on the cutting plane as
  *above* it, i.e. the plane ``z = h`` cuts the mesh like ``z = h - ε`` for an
  infinitesimal ``ε``. This makes sections through vertices well defined: every
  cut face gives exactly one segment, and neighbouring faces produce
  bit-identical end points on their shared edge.

Main entry points
-----------------
:func:`mesh_volume` (weight = volume x density), :func:`girth` (tape-measure
circumference at a height), :func:`plane_section` + :func:`section_loops` (the
individual cross-section outlines), :func:`is_closed` (whether a volume is
meaningful).
"""

from __future__ import annotations

import numbers

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

__all__ = [
    "boundary_edges",
    "convex_perimeter",
    "face_normals",
    "girth",
    "is_closed",
    "loop_area",
    "loop_perimeter",
    "mesh_volume",
    "neighbour_mean",
    "plane_section",
    "section_loops",
    "surface_area",
    "triangle_areas",
    "vertex_normals",
]

# Relative size of the second singular value below which a 2-D point set is
# treated as collinear by `convex_perimeter` (Qhull cannot build a 2-D hull).
_COLLINEAR_RTOL = 1e-12


# --------------------------------------------------------------------------
# Input validation
# --------------------------------------------------------------------------


def _shape_str(shape: tuple[int, ...]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _as_real_array(x: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(x)
    if arr.dtype == np.bool_ or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ):
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def _check_vertices(vertices: ArrayLike, *, batched: bool) -> NDArray[np.float64]:
    """Return ``vertices`` as float64 of shape (V, 3) or, if ``batched``, (B, V, 3)."""
    v = _as_real_array(vertices, "vertices")
    ok = v.shape[-1:] == (3,) and (v.ndim == 2 or (batched and v.ndim == 3))
    if not ok:
        expected = "(V, 3) or (B, V, 3)" if batched else "(V, 3)"
        raise ValueError(f"vertices must have shape {expected}, got {_shape_str(v.shape)}")
    return v


def _check_faces(faces: ArrayLike, n_vertices: int | None) -> NDArray[np.intp]:
    """Return ``faces`` as intp of shape (F, 3), indices checked against ``n_vertices``."""
    f = np.asarray(faces)
    if f.shape in ((0,), (0, 0), (0, 3)):
        return np.zeros((0, 3), dtype=np.intp)  # [], np.empty((0, 3)) ...
    if f.dtype == np.bool_ or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be an integer array, got dtype {f.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {_shape_str(f.shape)}")
    if n_vertices is not None:
        lo, hi = int(f.min()), int(f.max())
        if lo < 0 or hi >= n_vertices:
            bad = lo if lo < 0 else hi
            raise ValueError(
                f"faces must index vertices in [0, {n_vertices}) (V = {n_vertices}), "
                f"got index {bad}"
            )
    return f.astype(np.intp, copy=False)


def _check_points2d(points: ArrayLike, name: str) -> NDArray[np.float64]:
    p = _as_real_array(points, name)
    if p.size == 0 and p.ndim == 1:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {_shape_str(p.shape)}")
    return p


def _check_face_mask(face_mask: ArrayLike | None, n_faces: int) -> NDArray[np.bool_] | None:
    if face_mask is None:
        return None
    m = np.asarray(face_mask)
    if m.dtype != np.bool_:
        raise ValueError(f"face_mask must be a boolean array, got dtype {m.dtype}")
    if m.shape != (n_faces,):
        raise ValueError(
            f"face_mask must have shape (F,) = ({n_faces},), got {_shape_str(m.shape)}"
        )
    return m


def _check_height(z: float) -> float:
    if not isinstance(z, numbers.Real) and not (isinstance(z, np.ndarray) and z.ndim == 0):
        raise ValueError(f"z must be a real scalar, got {type(z).__name__} {np.shape(z)}")
    zf = float(z)
    if not np.isfinite(zf):
        raise ValueError(f"z must be finite, got {zf}")
    return zf


# --------------------------------------------------------------------------
# Per-face quantities
# --------------------------------------------------------------------------


def _face_cross(v: NDArray[np.float64], f: NDArray[np.intp]) -> NDArray[np.float64]:
    """``(b - a) x (c - a)`` per face; shape (..., F, 3)."""
    tri = np.take(v, f, axis=-2)  # (..., F, 3, 3)
    return np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])


def triangle_areas(vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.float64]:
    """Area of every triangle.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) array of float
        Vertex positions, optionally batched.
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    areas : (F,) or (B, F) ndarray of float64
        Non-negative triangle areas (0 for degenerate triangles).
    """
    v = _check_vertices(vertices, batched=True)
    f = _check_faces(faces, v.shape[-2])
    return 0.5 * np.linalg.norm(_face_cross(v, f), axis=-1)


def surface_area(vertices: ArrayLike, faces: ArrayLike) -> float | NDArray[np.float64]:
    """Total surface area (e.g. body surface area, BSA).

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) array of float
        Vertex positions, optionally batched.
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    area : float or (B,) ndarray of float64
        Sum of the triangle areas; a Python ``float`` for unbatched input.
    """
    areas = triangle_areas(vertices, faces).sum(axis=-1)
    return float(areas) if np.ndim(areas) == 0 else areas


def face_normals(vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.float64]:
    """Unit normal of every triangle, following the right-hand rule.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) array of float
        Vertex positions, optionally batched.
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    normals : (F, 3) or (B, F, 3) ndarray of float64
        Unit vectors along ``(b - a) x (c - a)``; the zero vector for
        degenerate (zero-area) triangles.
    """
    v = _check_vertices(vertices, batched=True)
    f = _check_faces(faces, v.shape[-2])
    return _normalize(_face_cross(v, f))


def vertex_normals(vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.float64]:
    """Area-weighted unit vertex normals.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) array of float
        Vertex positions, optionally batched.
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    normals : (V, 3) or (B, V, 3) ndarray of float64
        Normalized sum of the (area-weighted) normals of the faces around each
        vertex; the zero vector for vertices used by no face (or only by
        degenerate faces).
    """
    v = _check_vertices(vertices, batched=True)
    f = _check_faces(faces, v.shape[-2])
    n_v, n_f = v.shape[-2], f.shape[0]
    cross = _face_cross(v, f)  # (..., F, 3)
    # Vertex-face incidence (V, F): each face adds its cross product to its 3 corners.
    incidence = sparse.csr_array(
        (np.ones(3 * n_f), (f.T.ravel(), np.tile(np.arange(n_f), 3))), shape=(n_v, n_f)
    )
    flat = np.moveaxis(cross, -2, 0).reshape(n_f, -1)  # (F, B*3)
    summed = np.asarray(incidence @ flat).reshape((n_v, *cross.shape[:-2], 3))
    return _normalize(np.moveaxis(summed, 0, -2))


def _normalize(x: NDArray[np.float64]) -> NDArray[np.float64]:
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, norm, out=np.zeros_like(x), where=norm > 0)


# --------------------------------------------------------------------------
# Volume and topology
# --------------------------------------------------------------------------


def mesh_volume(vertices: ArrayLike, faces: ArrayLike) -> float | NDArray[np.float64]:
    """Enclosed volume of a closed, consistently oriented triangle mesh.

    Divergence theorem: the sum of the signed volumes of the tetrahedra formed
    by each face and a reference point. The reference point is the mean vertex
    of each mesh (not the origin) so that a mesh far from the origin loses no
    precision; for a closed mesh the result does not depend on it.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) array of float
        Vertex positions, optionally a batch of ``B`` meshes sharing ``faces``.
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    volume : float or (B,) ndarray of float64
        Positive for outward-oriented faces, negative for inward ones; a Python
        ``float`` for unbatched input. Units are those of ``vertices`` cubed.

    Notes
    -----
    The mesh must be closed and consistently oriented (see :func:`is_closed`);
    for an open mesh the value depends on the reference point and means little.
    Self-intersections are not detected; overlapping regions count twice.
    Batched input uses ``B * F * 9`` float64 values of temporary memory.
    """
    v = _check_vertices(vertices, batched=True)
    f = _check_faces(faces, v.shape[-2])
    if v.shape[-2] == 0 or f.shape[0] == 0:
        vol = np.zeros(v.shape[:-2])
    else:
        centred = v - v.mean(axis=-2, keepdims=True)
        tri = np.take(centred, f, axis=-2)  # (..., F, 3, 3)
        triple = np.einsum(
            "...i,...i->...", tri[..., 0, :], np.cross(tri[..., 1, :], tri[..., 2, :])
        )
        vol = triple.sum(axis=-1) / 6.0
    return float(vol) if vol.ndim == 0 else vol


def _edge_codes(f: NDArray[np.intp], n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Directed half-edges a->b of every face encoded as ``a * n + b``, and their reverses."""
    a = f.astype(np.int64)
    b = np.roll(a, -1, axis=1)
    return (a * n + b).ravel(), (b * n + a).ravel()


def is_closed(faces: ArrayLike, n_vertices: int) -> bool:
    """Whether a triangle mesh is watertight and consistently oriented.

    True when every edge is shared by exactly two faces that traverse it in
    opposite directions, no face repeats a vertex and there is at least one face.

    Parameters
    ----------
    faces : (F, 3) array of int
        Vertex indices of each triangle.
    n_vertices : int
        Number of vertices ``V``; indices must lie in ``[0, V)``.

    Returns
    -------
    closed : bool
        False for an empty mesh, a boundary (hole), an edge with three or more
        faces, or a flipped face.

    Notes
    -----
    This is an edge test: two closed surfaces touching at a single vertex still
    count as closed (their volume is still correct), and self-intersections are
    not detected. Orientation *consistency* is checked, not whether the normals
    point outward; use the sign of :func:`mesh_volume` for that.
    """
    n = _check_n_vertices(n_vertices)
    f = _check_faces(faces, n)
    if f.shape[0] == 0:
        return False
    if np.any((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])):
        return False
    fwd, rev = _edge_codes(f, n)
    fwd = np.sort(fwd)
    if np.any(fwd[1:] == fwd[:-1]):  # a half-edge used twice: flipped face or >2 faces
        return False
    return bool(np.array_equal(fwd, np.sort(rev)))


def _check_n_vertices(n_vertices: int) -> int:
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, numbers.Integral):
        raise ValueError(f"n_vertices must be an int, got {type(n_vertices).__name__}")
    if n_vertices < 0:
        raise ValueError(f"n_vertices must be >= 0, got {n_vertices}")
    return int(n_vertices)


def boundary_edges(faces: ArrayLike) -> NDArray[np.intp]:
    """Edges used by exactly one face (the rims of holes).

    Parameters
    ----------
    faces : (F, 3) array of int
        Vertex indices of each triangle.

    Returns
    -------
    edges : (E, 2) ndarray of intp
        Each boundary edge ``(a, b)`` oriented as in its face, sorted by
        ``(min(a, b), max(a, b))``. Empty for a closed mesh. Edges shared by two
        faces with the *same* orientation are not boundary edges (see
        :func:`is_closed`).
    """
    f = _check_faces(faces, None)
    if f.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.intp)
    if f.min() < 0:
        raise ValueError(f"faces must hold non-negative vertex indices, got {int(f.min())}")
    directed = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    edges = directed[once]
    order = np.lexsort((undirected[once, 1], undirected[once, 0]))
    return edges[order]


# --------------------------------------------------------------------------
# Horizontal sections
# --------------------------------------------------------------------------


def plane_section(
    vertices: ArrayLike,
    faces: ArrayLike,
    z: float,
    face_mask: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Segments where the horizontal plane at height ``z`` cuts the mesh.

    Parameters
    ----------
    vertices : (V, 3) array of float
        Vertex positions (not batched).
    faces : (F, 3) array of int
        Vertex indices of each triangle.
    z : float
        Height of the cutting plane.
    face_mask : (F,) array of bool, optional
        Only faces where this is True are cut (e.g. the torso, without arms).

    Returns
    -------
    segments : (S, 2, 2) ndarray of float64
        ``segments[i] = [[x0, y0], [x1, y1]]``, one per cut face (``S = 0`` when
        the plane misses the selected faces). For an outward-oriented mesh each
        segment runs counter-clockwise (seen from above) around the material, so
        the outline of a solid section has positive :func:`loop_area`.

    Notes
    -----
    A vertex exactly at height ``z`` counts as above the plane (the plane acts
    as ``z - ε``). Every cut face thus has exactly one vertex on one side and
    two on the other and yields one segment; the end point on an edge is
    computed from that edge's (below, above) vertex pair only, so faces sharing
    an edge produce bit-identical end points, which :func:`section_loops` joins
    exactly. Faces touching the plane only at a vertex give zero-length
    segments (kept here, dropped by :func:`section_loops`). A plane at exactly
    the lowest vertex height misses the mesh; one at exactly the highest gives
    the outline of the top rim.
    """
    v = _check_vertices(vertices, batched=False)
    f = _check_faces(faces, v.shape[0])
    zf = _check_height(z)
    mask = _check_face_mask(face_mask, f.shape[0])
    if mask is not None:
        f = f[mask]

    above = v[:, 2] >= zf  # on-plane counts as above
    fa = above[f]  # (F, 3)
    n_above = fa.sum(axis=1)
    cut = (n_above == 1) | (n_above == 2)
    f, fa = f[cut], fa[cut]
    if f.shape[0] == 0:
        return np.zeros((0, 2, 2))

    # Half-edge k of a face runs from corner k to corner k + 1.
    f_next, fa_next = np.roll(f, -1, axis=1), np.roll(fa, -1, axis=1)
    going_down = fa & ~fa_next  # above -> below: the segment starts here
    going_up = ~fa & fa_next  # below -> above: the segment ends here
    rows = np.arange(f.shape[0])
    k_start, k_end = going_down.argmax(axis=1), going_up.argmax(axis=1)
    start = _edge_point(v, zf, lo=f_next[rows, k_start], hi=f[rows, k_start])
    end = _edge_point(v, zf, lo=f[rows, k_end], hi=f_next[rows, k_end])
    return np.stack([start, end], axis=1)


def _edge_point(
    v: NDArray[np.float64], z: float, lo: NDArray[np.intp], hi: NDArray[np.intp]
) -> NDArray[np.float64]:
    """(x, y) where edge lo -> hi crosses height z, given z_lo < z <= z_hi."""
    z_lo, z_hi = v[lo, 2], v[hi, 2]
    t = ((z - z_lo) / (z_hi - z_lo))[:, None]  # in (0, 1]; exactly 1 when z == z_hi
    return (1.0 - t) * v[lo, :2] + t * v[hi, :2]  # exact at t == 1


def section_loops(
    segments: ArrayLike, tol: float = 1e-9, *, drop_open: bool = False
) -> list[NDArray[np.float64]]:
    """Chain section segments into closed polylines.

    Parameters
    ----------
    segments : (S, 2, 2) array of float
        Directed segments, as returned by :func:`plane_section`.
    tol : float, optional
        End points closer than ``tol`` (same units as the coordinates, metres)
        are joined. Points from :func:`plane_section` on a shared edge are
        identical, so the default only absorbs round-off from near-duplicate
        vertices.
    drop_open : bool, optional
        What to do with chains that do not close (a mesh with holes, or a
        ``face_mask`` boundary crossing the plane): raise ``ValueError`` when
        False (the default), silently leave them out when True.

    Returns
    -------
    loops : list of (n, 2) ndarray of float64
        One array per closed loop, first point not repeated at the end, in the
        direction of the segments (counter-clockwise for the outer outline of an
        outward-oriented mesh). Sorted by decreasing absolute
        :func:`loop_area`, so ``loops[0]`` is the largest outline.

    Notes
    -----
    Zero-length segments are ignored. Where several loops meet at one point
    (e.g. the plane passes exactly through a saddle vertex) the split into
    loops at that point is arbitrary but deterministic.
    """
    seg = _as_real_array(segments, "segments")
    if seg.size == 0 and seg.ndim == 1:
        seg = np.zeros((0, 2, 2))
    if seg.ndim != 3 or seg.shape[1:] != (2, 2):
        raise ValueError(f"segments must have shape (S, 2, 2), got {_shape_str(seg.shape)}")
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not tol >= 0:
        raise ValueError(f"tol must be a non-negative real number, got {tol!r}")
    if seg.shape[0] == 0:
        return []

    nodes, labels = _merge_points(seg.reshape(-1, 2), float(tol))
    starts, ends = labels[0::2], labels[1::2]
    keep = starts != ends
    starts, ends = starts[keep], ends[keep]
    chains = _walk(starts, ends, len(nodes))

    loops, n_open = [], 0
    for chain, closed in chains:
        if closed:
            loops.append(nodes[chain[:-1]])
        else:
            n_open += 1
    if n_open and not drop_open:
        raise ValueError(
            f"segments do not form closed loops: {n_open} open chain(s) "
            f"(a hole in the mesh or a face_mask boundary crossing the plane); "
            f"pass drop_open=True to ignore them"
        )
    loops.sort(key=lambda loop: -abs(loop_area(loop)))
    return loops


def _merge_points(
    points: NDArray[np.float64], tol: float
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Cluster points closer than tol; return one point per cluster and each point's label."""
    if not np.all(np.isfinite(points)):
        raise ValueError("segments must be finite, got NaN or inf")
    uniq, inverse = np.unique(points, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    if tol > 0 and len(uniq) > 1:
        pairs = cKDTree(uniq).query_pairs(tol, output_type="ndarray")
        if len(pairs):
            graph = sparse.coo_array(
                (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(uniq),) * 2
            )
            _, cluster = connected_components(graph, directed=False)
            first = np.unique(cluster, return_index=True)[1]  # representative point
            return uniq[first], cluster[inverse]
    return uniq, inverse


def _walk(
    starts: NDArray[np.intp], ends: NDArray[np.intp], n_nodes: int
) -> list[tuple[list[int], bool]]:
    """Split directed edges into node chains (chain, closed); closed: chain[-1] == chain[0]."""
    order = np.argsort(starts, kind="stable")
    offsets = np.searchsorted(starts[order], np.arange(n_nodes + 1))
    nxt = offsets[:-1].copy()  # next unused outgoing edge of each node
    stop = offsets[1:]
    out_deg = np.bincount(starts, minlength=n_nodes)
    in_deg = np.bincount(ends, minlength=n_nodes)
    ends_l, order_l = ends.tolist(), order.tolist()
    nxt_l, stop_l = nxt.tolist(), stop.tolist()

    def take(node: int) -> int:
        if nxt_l[node] >= stop_l[node]:
            return -1
        nxt_l[node] += 1
        return ends_l[order_l[nxt_l[node] - 1]]

    chains: list[tuple[list[int], bool]] = []
    # Open chains first, from nodes with surplus outgoing edges; then closed loops.
    # Closed loops start at branching nodes first, so that loops touching at a
    # point are split there rather than merged into a figure eight.
    open_starts = np.flatnonzero(out_deg > in_deg).tolist()
    open_set = set(open_starts)
    sorted_starts = starts[order]
    loop_starts = sorted_starts[np.argsort(-out_deg[sorted_starts], kind="stable")].tolist()
    for first in [*open_starts, *loop_starts]:
        while nxt_l[first] < stop_l[first]:
            chain = [first]
            node = take(first)
            while node != -1:
                chain.append(node)
                if node == first:
                    break
                node = take(node)
            chains.append((chain, chain[-1] == first and len(chain) > 1))
            if first not in open_set:
                break
    return chains


def loop_perimeter(loop: ArrayLike, closed: bool = True) -> float:
    """Length of a polyline.

    Parameters
    ----------
    loop : (n, 2) array of float
        Polyline vertices.
    closed : bool, optional
        Include the edge from the last point back to the first (default).

    Returns
    -------
    perimeter : float
        0.0 for fewer than two points.
    """
    p = _check_points2d(loop, "loop")
    if len(p) < 2:
        return 0.0
    if closed:
        p = np.concatenate([p, p[:1]])
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def loop_area(loop: ArrayLike) -> float:
    """Signed area enclosed by a closed polyline (shoelace formula).

    Parameters
    ----------
    loop : (n, 2) array of float
        Polygon vertices, first point not repeated.

    Returns
    -------
    area : float
        Positive for counter-clockwise loops (seen from above, x right, y up),
        negative for clockwise ones; 0.0 for fewer than three points.
    """
    p = _check_points2d(loop, "loop")
    if len(p) < 3:
        return 0.0
    p = p - p.mean(axis=0)  # for precision far from the origin
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))


def convex_perimeter(points: ArrayLike) -> float:
    """Perimeter of the convex hull of 2-D points: how a tape measure reads a girth.

    Parameters
    ----------
    points : (N, 2) array of float
        Points in the plane, e.g. ``segments.reshape(-1, 2)``.

    Returns
    -------
    perimeter : float
        Hull perimeter. Degenerate inputs get the limit of a flattening convex
        set: 0.0 for no points or coincident points, and twice the extent
        (a tape pulled around a flat strip) for two or collinear points.

    Raises
    ------
    ValueError
        If ``points`` has the wrong shape or holds NaN or inf.
    """
    p = _check_points2d(points, "points")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite, got NaN or inf")
    if len(p) < 2:
        return 0.0
    centred = p - p.mean(axis=0)
    _, sing, vt = np.linalg.svd(centred, full_matrices=False)
    if sing[0] == 0.0:
        return 0.0
    if len(p) >= 3 and sing[1] > _COLLINEAR_RTOL * sing[0]:
        try:
            hull = ConvexHull(centred)
        except QhullError:
            pass  # numerically flat: fall through to the collinear case
        else:
            ring = centred[hull.vertices]  # counter-clockwise in 2-D
            return float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
    along = centred @ vt[0]
    return float(2.0 * (along.max() - along.min()))


def girth(
    vertices: ArrayLike,
    faces: ArrayLike,
    z: float,
    face_mask: ArrayLike | None = None,
) -> float:
    """Tape-measure circumference of the mesh at height ``z``.

    The perimeter of the convex hull of the horizontal section, i.e. a tape
    pulled taut around everything the plane cuts (both thighs at hip height,
    arms at chest height unless ``face_mask`` leaves them out).

    Parameters
    ----------
    vertices : (V, 3) array of float
        Vertex positions (not batched).
    faces : (F, 3) array of int
        Vertex indices of each triangle.
    z : float
        Height of the horizontal plane.
    face_mask : (F,) array of bool, optional
        Only faces where this is True are measured.

    Returns
    -------
    girth : float
        Convex-hull perimeter of the section; 0.0 when the plane misses the
        selected faces. See :func:`plane_section` for vertices on the plane.
    """
    segments = plane_section(vertices, faces, z, face_mask)
    if segments.shape[0] == 0:
        return 0.0
    return convex_perimeter(segments.reshape(-1, 2))


def neighbour_mean(faces: ArrayLike, n_vertices: int) -> sparse.csr_matrix:
    """The (V, V) operator that replaces each vertex's value by its neighbours' mean.

    Row-normalised vertex adjacency of a triangle mesh (an isolated vertex's
    row is zero); ``M @ values`` smooths per-vertex values, ``(V,)`` or ``(V, k)``.

    Parameters
    ----------
    faces : (F, 3) int
    n_vertices : int
    """
    n = _check_n_vertices(n_vertices)
    f = _check_faces(faces, n)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    adj = sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    adj.data[:] = 1.0  # an edge shared by two faces counts once
    deg = np.asarray(adj.sum(axis=1)).reshape(-1)
    return (sparse.diags(1.0 / np.maximum(deg, 1.0)) @ adj).tocsr()
