"""A watertight decimated level of detail (LOD) of the body mesh (bake time only).

The image likelihoods render the body many times per frame, so they use a
~3k-triangle LOD instead of the 26,756-triangle MakeHuman body. This module
builds it once, at bake time:

* :func:`decimate_watertight` runs quadric edge-collapse decimation
  (``fast_simplification``, a maintainer-only dependency, imported lazily), then
  repairs and *verifies* the result: closed, every edge shared by exactly two
  faces with opposite orientation, no pinched (non-manifold) vertices, no
  zero-area faces, outward (positive) volume, volume close to the input's. It
  retries other settings in a fixed order and raises :class:`RuntimeError` if
  none passes. Same input -> same output bytes.
* :func:`barycentric_map` expresses points (the LOD vertices) as barycentric
  combinations of the full mesh's vertices at their exact closest points on
  the full surface, as a sparse ``(P, V)`` matrix ``M``. For any deformation of
  the full mesh with the same topology, ``M @ full_vertices`` follows the LOD
  along.
* :func:`transfer_face_labels` carries per-triangle labels (body parts) from
  the full mesh to the LOD.

Only numpy and scipy are needed at import time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bodymetry.errors import InputError

__all__ = [
    "barycentric_map",
    "closest_points",
    "decimate_watertight",
    "mesh_defects",
    "signed_volume",
    "transfer_face_labels",
]

#: Quadric-decimation aggressiveness values tried, in order. 5 gives a
#: watertight LOD of the MakeHuman body at 3000 triangles; 6-8 leave duplicate
#: (folded) face pairs there.
DEFAULT_AGGRESSIVENESS: tuple[float, ...] = (5.0, 4.0, 3.0, 6.0, 2.0, 7.0)
#: Factors on ``target_faces`` tried when no aggressiveness works at the target
#: (small changes of the target rarely change the outcome; these are a last resort).
DEFAULT_TARGET_SCALES: tuple[float, ...] = (1.0, 1.03, 0.97)


# --------------------------------------------------------------------------
# Mesh checks
# --------------------------------------------------------------------------


def _as_mesh(vertices: np.ndarray, faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"{what}: vertices must be (V, 3), got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"{what}: faces must be (F, 3), got shape {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"{what}: faces must be integer indices, got dtype {f.dtype}")
    f = f.astype(np.int64, copy=False)
    if f.shape[0] == 0:
        raise InputError(f"{what}: no faces")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise InputError(f"{what}: face indices out of range 0..{v.shape[0] - 1}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{what}: non-finite vertex coordinates")
    return v, f


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle mesh (positive when outward).

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    """
    v, f = _as_mesh(vertices, faces, "signed_volume")
    # Centre first: the sum is translation invariant for closed meshes and this
    # keeps the round-off small.
    v = v - v[np.unique(f)].mean(axis=0)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _half_edges(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed edges (3F,) ``src``, ``dst``; half-edge ``3 * face + i`` is ``f[i] -> f[i+1]``."""
    return f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)


def mesh_defects(vertices: np.ndarray, faces: np.ndarray, area_eps: float = 1e-12) -> list[str]:
    """Why a triangle mesh is not a closed, consistently and outward oriented 2-manifold.

    Checks: no repeated index within a face; no duplicate faces; every edge
    shared by exactly two faces that traverse it in opposite directions (closed
    and consistently oriented); every vertex referenced and its faces forming a
    single fan (no pinched vertices); no face with area below
    ``area_eps * diag**2`` (``diag`` the bounding-box diagonal); every connected
    component encloses a positive volume. Self-intersections are NOT checked.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    area_eps : float
        Relative area threshold for degenerate faces.

    Returns
    -------
    list of str
        Empty when the mesh passes every check.
    """
    v, f = _as_mesh(vertices, faces, "mesh_defects")
    problems = _face_defects(v, f, area_eps)
    edge_problems, twin = _edge_defects(v.shape[0], f)
    problems += edge_problems
    if problems:
        return problems
    # Edge-manifold and consistently oriented from here on: twin is well defined.
    return _fan_defects(v.shape[0], twin) + _orientation_defects(v, f, twin)


def _face_defects(v: np.ndarray, f: np.ndarray, area_eps: float) -> list[str]:
    """Faces repeating an index, duplicate faces, unreferenced vertices, zero-area faces.

    Parameters
    ----------
    v : (V, 3) float
    f : (F, 3) int
    area_eps : float
        Relative area threshold (of the bounding-box diagonal squared).
    """
    problems: list[str] = []
    n_v = v.shape[0]
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    if repeated.any():
        problems.append(f"{int(repeated.sum())} faces repeat a vertex index")
    n_dup = f.shape[0] - np.unique(np.sort(f, axis=1), axis=0).shape[0]
    if n_dup:
        problems.append(f"{n_dup} duplicate faces (same three vertices)")
    unreferenced = n_v - np.unique(f).size
    if unreferenced:
        problems.append(f"{unreferenced} unreferenced vertices")

    diag = float(np.linalg.norm(np.ptp(v[np.unique(f)], axis=0)))
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    n_tiny = int((0.5 * area2 <= area_eps * diag**2).sum())
    if n_tiny:
        problems.append(f"{n_tiny} zero-area faces")
    return problems


def _edge_defects(n_v: int, f: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Directed edges used twice and half-edges without an opposite.

    Parameters
    ----------
    n_v : int
        Vertex count.
    f : (F, 3) int

    Returns
    -------
    problems : list of str
    twin : (3F,) int
        The opposite half-edge of each half-edge (meaningful only without problems).
    """
    problems: list[str] = []
    src, dst = _half_edges(f)
    key = src * n_v + dst
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    n_repeat_he = int((np.diff(sorted_key) == 0).sum())
    if n_repeat_he:
        problems.append(
            f"{n_repeat_he} directed edges used twice (inconsistent orientation or non-manifold)"
        )
    rev = dst * n_v + src
    pos = np.clip(np.searchsorted(sorted_key, rev), 0, key.size - 1)
    has_twin = sorted_key[pos] == rev
    if not has_twin.all():
        problems.append(
            f"{int((~has_twin).sum())} half-edges without an opposite (open or flipped)"
        )
    return problems, order[pos]


def _fan_defects(n_v: int, twin: np.ndarray) -> list[str]:
    """Pinched (non-manifold) vertices of an edge-manifold, consistently oriented mesh.

    Corners (face, vertex) around the same vertex are linked across each edge
    incident to it; one fan per vertex <=> as many corner components as vertices.
    Half-edge h = (s -> d) in face F has corner s in F; its twin (d -> s) in face
    G has its *next* half-edge starting at s, so the corner at s in G is half-edge
    3*G + (j+1)%3.

    Parameters
    ----------
    n_v : int
        Vertex count.
    twin : (3F,) int
        Opposite half-edge of each half-edge.
    """
    t_face, t_local = np.divmod(twin, 3)
    nxt = 3 * t_face + (t_local + 1) % 3
    n_he = twin.size
    graph = sp.coo_matrix((np.ones(n_he), (np.arange(n_he), nxt)), shape=(n_he, n_he)).tocsr()
    n_corner_comp, _ = connected_components(graph, directed=False)
    if n_corner_comp != n_v:
        return [f"{n_corner_comp - n_v} pinched (non-manifold) vertices"]
    return []


def _orientation_defects(v: np.ndarray, f: np.ndarray, twin: np.ndarray) -> list[str]:
    """Connected components whose enclosed volume is not positive (inward or flat).

    Parameters
    ----------
    v : (V, 3) float
    f : (F, 3) int
    twin : (3F,) int
        Opposite half-edge of each half-edge.
    """
    n_he = twin.size
    he_face = np.arange(n_he) // 3
    fgraph = sp.coo_matrix(
        (np.ones(n_he), (he_face, he_face[twin])), shape=(f.shape[0], f.shape[0])
    ).tocsr()
    n_comp, comp = connected_components(fgraph, directed=False)
    centre = v[np.unique(f)].mean(axis=0)
    a, b, c = v[f[:, 0]] - centre, v[f[:, 1]] - centre, v[f[:, 2]] - centre
    vol = np.bincount(comp, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0, minlength=n_comp)
    if (vol <= 0).any():
        return [f"{int((vol <= 0).sum())} of {n_comp} components have non-positive volume"]
    return []


# --------------------------------------------------------------------------
# Decimation
# --------------------------------------------------------------------------


def _repair(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop faces repeating an index, same-orientation duplicates and opposite
    face pairs (zero-volume folds), then unreferenced vertices."""
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    # Rotate each face so its smallest index comes first (orientation kept).
    shift = np.argmin(f, axis=1)
    idx = (shift[:, None] + np.arange(3)) % 3
    canon = np.take_along_axis(f, idx, axis=1)
    _, first = np.unique(canon, axis=0, return_index=True)
    keep = np.sort(first)  # first occurrence of each oriented face, original order
    f, canon = f[keep], canon[keep]
    # A face whose reverse is also present: remove both.
    n = int(f.max()) + 1 if f.size else 1
    fwd = (canon[:, 0] * n + canon[:, 1]) * n + canon[:, 2]
    bwd = (canon[:, 0] * n + canon[:, 2]) * n + canon[:, 1]
    f = f[~np.isin(bwd, fwd)]
    used = np.unique(f)
    remap = np.full(v.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return np.ascontiguousarray(v[used]), np.ascontiguousarray(remap[f])


def decimate_watertight(
    vertices: np.ndarray,
    faces: np.ndarray,
    target_faces: int = 3000,
    aggressiveness: Sequence[float] = DEFAULT_AGGRESSIVENESS,
    target_scales: Sequence[float] = DEFAULT_TARGET_SCALES,
    face_tolerance: float = 0.1,
    volume_tolerance: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Decimate a closed triangle mesh to about ``target_faces`` faces, keeping it closed.

    Runs ``fast_simplification.simplify`` (quadric error metric edge collapses;
    the new vertices sit at quadric-optimal positions, i.e. NOT exactly on the
    input surface), repairs (duplicate, folded and index-degenerate faces,
    unreferenced vertices) and verifies the result with :func:`mesh_defects`,
    plus ``|F' - target| <= face_tolerance * target`` and
    ``|vol' / vol - 1| <= volume_tolerance``. Settings are tried in a fixed
    order -- each factor in ``target_scales`` with each value in
    ``aggressiveness`` -- and the first result passing every check is returned.
    The simplifier has no randomness, so the output is deterministic (same
    input bytes, same numpy / fast_simplification build -> same output bytes).
    Its error thresholds are absolute, so the result depends (slightly) on the
    units: decimate in the units the LOD will be used in.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Must itself pass :func:`mesh_defects` (closed, oriented outward).
    target_faces : int
        Wanted face count (4 <= target < F; a closed genus-0 mesh has an even count).
    aggressiveness : sequence of float
        ``agg`` values for ``fast_simplification`` (0..10), tried in order.
    target_scales : sequence of float
        Factors on ``target_faces`` (rounded to an even count) tried in order,
        each with every ``agg``.
    face_tolerance, volume_tolerance : float
        Relative acceptance bounds on face count and volume.

    Returns
    -------
    lod_vertices : (V', 3) float64
    lod_faces : (F', 3) int64

    Raises
    ------
    bodymetry.errors.InputError
        The input is not a closed, outward-oriented manifold, or the target is invalid.
    RuntimeError
        No setting gave a mesh passing every check.
    """
    import fast_simplification  # maintainer-only dependency

    v, f = _as_mesh(vertices, faces, "decimate_watertight")
    target_faces = _check_decimation_input(v, f, target_faces)
    vol_in = signed_volume(v, f)
    tried: list[str] = []
    counts = dict.fromkeys(2 * round(target_faces * float(x) / 2) for x in target_scales)
    for count in counts:
        if not 4 <= count < f.shape[0]:
            continue
        for agg in aggressiveness:
            out_v, out_f = fast_simplification.simplify(v, f, target_count=count, agg=float(agg))
            out_v = np.asarray(out_v, dtype=np.float64)
            out_f = np.asarray(out_f, dtype=np.int64).reshape(-1, 3)
            if out_f.shape[0] == 0:
                tried.append(f"target={count} agg={agg}: empty result")
                continue
            out_v, out_f = _repair(out_v, out_f)
            why = _decimation_defects(
                out_v, out_f, target_faces, vol_in, face_tolerance, volume_tolerance
            )
            if not why:
                return out_v, out_f
            tried.append(f"target={count} agg={agg}: " + "; ".join(why))
    raise RuntimeError(
        "decimate_watertight: no setting gave an acceptable watertight mesh; tried:\n  "
        + "\n  ".join(tried)
    )


def _check_decimation_input(v: np.ndarray, f: np.ndarray, target_faces: int) -> int:
    """The target face count as an int, after checking the input mesh and the target.

    Parameters
    ----------
    v : (V, 3) float
    f : (F, 3) int

    Raises
    ------
    bodymetry.errors.InputError
        The mesh has defects (:func:`mesh_defects`) or the target is not in 4..F-1.
    """
    defects = mesh_defects(v, f)
    if defects:
        raise InputError("decimate_watertight: input mesh is not watertight: " + "; ".join(defects))
    target_faces = int(target_faces)
    if not 4 <= target_faces < f.shape[0]:
        raise InputError(
            f"decimate_watertight: target_faces must be in 4..{f.shape[0] - 1}, got {target_faces}"
        )
    return target_faces


def _decimation_defects(
    out_v: np.ndarray,
    out_f: np.ndarray,
    target_faces: int,
    vol_in: float,
    face_tolerance: float,
    volume_tolerance: float,
) -> list[str]:
    """Why a repaired decimation is not accepted (empty list: accepted).

    Parameters
    ----------
    out_v : (V', 3) float
    out_f : (F', 3) int
    target_faces : int
    vol_in : float
        Signed volume of the input mesh.
    face_tolerance, volume_tolerance : float
        Relative bounds on the face count and the volume.
    """
    why = mesh_defects(out_v, out_f) if out_f.shape[0] else ["empty after repair"]
    if not why:
        n = out_f.shape[0]
        if abs(n - target_faces) > face_tolerance * target_faces:
            why.append(f"{n} faces, target {target_faces}")
        ratio = signed_volume(out_v, out_f) / vol_in
        if abs(ratio - 1.0) > volume_tolerance:
            why.append(f"volume ratio {ratio:.4f}")
    return why


# --------------------------------------------------------------------------
# Closest points and the barycentric map
# --------------------------------------------------------------------------


def _closest_on_triangles(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exact closest points of ``p`` (N, 3) on triangles ``a, b, c`` (N, 3) each.

    Ericson, *Real-Time Collision Detection*, 5.1.5, vectorised. Returns the
    barycentric weights (N, 3) (non-negative, summing to 1) and the squared
    distances (N,).
    """
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        out = np.zeros_like(num)
        np.divide(num, den, out=out, where=den != 0)
        return np.clip(out, 0.0, 1.0)

    # Interior (face region) first; the regions below override it in reverse
    # order of Ericson's early returns, so the first matching test wins. The
    # clipping only guards round-off (and degenerate triangles, which the edge
    # tests then handle): the weights always describe a point on the triangle.
    denom = va + vb + vc
    v = ratio(vb, denom)
    w = ratio(vc, denom)
    bary = np.stack([np.maximum(1.0 - v - w, 0.0), v, w], axis=1)
    bary /= bary.sum(axis=1, keepdims=True)  # the sum is max(1, v + w) >= 1

    def edge(mask: np.ndarray, i: int, j: int, t: np.ndarray) -> None:
        row = np.zeros((int(mask.sum()), 3))
        row[:, i] = 1.0 - t[mask]
        row[:, j] = t[mask]
        bary[mask] = row

    def corner(mask: np.ndarray, i: int) -> None:
        row = np.zeros(3)
        row[i] = 1.0
        bary[mask] = row

    d43, d56 = d4 - d3, d5 - d6
    edge((va <= 0) & (d43 >= 0) & (d56 >= 0), 1, 2, ratio(d43, d43 + d56))  # edge BC
    edge((vb <= 0) & (d2 >= 0) & (d6 <= 0), 0, 2, ratio(d2, d2 - d6))  # edge AC
    corner((d6 >= 0) & (d5 <= d6), 2)  # vertex C
    edge((vc <= 0) & (d1 >= 0) & (d3 <= 0), 0, 1, ratio(d1, d1 - d3))  # edge AB
    corner((d3 >= 0) & (d4 <= d3), 1)  # vertex B
    corner((d1 <= 0) & (d2 <= 0), 0)  # vertex A

    q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    diff = p - q
    return bary, np.einsum("ij,ij->i", diff, diff)


def _best_pairs(
    p: np.ndarray, v: np.ndarray, f: np.ndarray, pt: np.ndarray, fc: np.ndarray, n_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate (point ``pt``, face ``fc``) pairs; per point keep the nearest face
    (ties: smallest face index). Points without pairs get face -1, distance inf."""
    key = np.sort(pt * f.shape[0] + fc)  # sorted by (point, face)
    key = key[np.r_[True, key[1:] != key[:-1]]] if key.size else key  # drop repeats
    pt, fc = np.divmod(key, f.shape[0])
    bary, d2 = _closest_on_triangles(p[pt], v[f[fc, 0]], v[f[fc, 1]], v[f[fc, 2]])
    order = np.lexsort((d2, pt))  # stable: equal distances keep the face order
    pt_sorted = pt[order]
    first = order[np.r_[True, pt_sorted[1:] != pt_sorted[:-1]]] if pt.size else order
    face = np.full(n_points, -1, dtype=np.int64)
    out_bary = np.zeros((n_points, 3))
    out_d2 = np.full(n_points, np.inf)
    face[pt[first]] = fc[first]
    out_bary[pt[first]] = bary[first]
    out_d2[pt[first]] = d2[first]
    return face, out_bary, out_d2


def _grid_centroids(n: int) -> np.ndarray:
    """Barycentric centroids (n*n, 3) of the sub-triangles of an n-fold subdivision."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    i, j = i.ravel(), j.ravel()
    up = i + j <= n - 1
    down = i + j <= n - 2
    uv = (
        np.concatenate(
            [
                np.stack([i[up] + 1 / 3, j[up] + 1 / 3], 1),
                np.stack([i[down] + 2 / 3, j[down] + 2 / 3], 1),
            ]
        )
        / n
    )
    return np.column_stack([1.0 - uv.sum(axis=1), uv])


def _proxies(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Proxy points for the KD-tree: each triangle is split (conceptually) into
    congruent sub-triangles so that every point of it lies within ``radius`` of a
    proxy (a sub-triangle centroid). Returns proxies (Q, 3), their faces (Q,) and
    ``radius``."""
    tri = v[f]
    centroids = tri.mean(axis=1)
    r = np.sqrt(((tri - centroids[:, None, :]) ** 2).sum(axis=2).max(axis=1))
    radius = float(np.median(r))
    if radius <= 0.0:
        return centroids, np.arange(f.shape[0]), float(r.max())
    # An n-fold subdivision's sub-triangles are copies of the triangle scaled by 1/n.
    n_sub = np.maximum(1, np.ceil(r / radius - 1e-12)).astype(np.int64)
    points, owner = [centroids[n_sub == 1]], [np.flatnonzero(n_sub == 1)]
    for n in np.unique(n_sub[n_sub > 1]):
        sel = np.flatnonzero(n_sub == n)
        w = _grid_centroids(int(n))
        points.append(np.einsum("sk,fkd->fsd", w, tri[sel]).reshape(-1, 3))
        owner.append(np.repeat(sel, w.shape[0]))
    # The bound uses the largest actual sub-triangle radius.
    radius = float((r / n_sub).max())
    return np.concatenate(points), np.concatenate(owner), radius


def closest_points(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, k: int = 16
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact closest points on a triangle mesh's surface.

    A KD-tree holds proxy points of the triangles (their centroids; large
    triangles contribute the centroids of a uniform subdivision, so every point
    of a triangle lies within ``R`` of one of its proxies). The triangles of
    the ``k`` nearest proxies are the candidates; where they cannot be proven
    to contain the nearest triangle (no proxy of another triangle can be closer
    than ``d + R``), the triangles of every proxy within ``d + R`` are evaluated
    too. The result is therefore exact whatever ``k`` is (``k`` is speed only).

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    points : (P, 3) float
    k : int
        KD-tree candidates per point (speed only).

    Returns
    -------
    face : (P,) int64
        Index of the nearest triangle (ties: the smallest index).
    bary : (P, 3) float64
        Barycentric weights of the closest point on ``faces[face]``: >= 0, sum 1.
    distance : (P,) float64
        Euclidean distance from each point to the surface.
    """
    v, f = _as_mesh(vertices, faces, "closest_points")
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"closest_points: points must be (P, 3), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError("closest_points: non-finite points")
    n_p = p.shape[0]
    if n_p == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0)
    proxy, owner, radius = _proxies(v, f)
    tree = cKDTree(proxy)
    n_q = proxy.shape[0]
    face = np.full(n_p, -1, dtype=np.int64)
    bary = np.zeros((n_p, 3))
    d2 = np.full(n_p, np.inf)
    # Every triangle has a proxy within `radius` of its nearest point to p; a
    # proxy not among the k nearest is >= dist_k[:, -1] away, so its triangle
    # is >= dist_k[:, -1] - radius away. Points where that does not rule out a
    # closer triangle are retried with 4x more candidates, then with a ball.
    todo = np.arange(n_p)
    k = max(1, min(int(k), n_q))
    while todo.size:
        ball = k >= 256 and k < n_q
        if ball:
            lists = tree.query_ball_point(p[todo], np.sqrt(d2[todo]) + radius)
            sizes = np.array([len(b) for b in lists], dtype=np.int64)
            pt = np.repeat(todo, sizes)
            cand = np.concatenate([np.asarray(b, dtype=np.int64) for b in lists])
        else:
            dist_k, cand = tree.query(p[todo], k=k)
            dist_k, cand = dist_k.reshape(todo.size, k), cand.reshape(-1)
            pt = np.repeat(todo, k)
        face2, bary2, d22 = _best_pairs(p, v, f, pt, owner[cand], n_p)
        better = (face2 >= 0) & ((d22 < d2) | ((d22 == d2) & (face2 < face)))
        face[better], bary[better], d2[better] = face2[better], bary2[better], d22[better]
        if ball or k >= n_q:
            break
        todo = todo[dist_k[:, -1] - radius < np.sqrt(d2[todo])]
        k = min(4 * k, n_q)
    dist = np.sqrt(d2)
    return face, bary, dist


def barycentric_map(
    full_vertices: np.ndarray,
    full_faces: np.ndarray,
    points: np.ndarray,
    return_distances: bool = False,
    k: int = 16,
) -> sp.csr_matrix | tuple[sp.csr_matrix, np.ndarray]:
    """Sparse map from full-mesh vertices to the closest surface points of ``points``.

    Row ``i`` holds the barycentric weights of the point of the full surface
    nearest ``points[i]`` (see :func:`closest_points`) over the three vertices
    of its triangle. Rows sum to 1 and weights lie in [0, 1], so for any
    vertex positions ``X`` (V, 3) of the same topology (e.g. a posed or shaped
    body), ``M @ X`` are the mapped points on that surface; with
    ``points`` = LOD vertices this drives the LOD from the full model.

    Parameters
    ----------
    full_vertices : (V, 3) float
    full_faces : (F, 3) int
    points : (P, 3) float
    return_distances : bool
        Also return the point-to-surface distances (the fit residual).
    k : int
        KD-tree candidates per point (speed only; the result is exact).

    Returns
    -------
    M : scipy.sparse.csr_matrix, (P, V) float64
        Three stored entries per row (zeros kept, so the pattern is fixed).
    distances : (P,) float64, only if ``return_distances``
    """
    v, f = _as_mesh(full_vertices, full_faces, "barycentric_map")
    face, bary, dist = closest_points(v, f, points, k=k)
    n_p = face.shape[0]
    M = sp.csr_matrix(
        (bary.reshape(-1), f[face].reshape(-1), np.arange(0, 3 * n_p + 1, 3)),
        shape=(n_p, v.shape[0]),
    )
    return (M, dist) if return_distances else M


# --------------------------------------------------------------------------
# Face labels
# --------------------------------------------------------------------------

#: Barycentric sample points per LOD triangle for the label vote; the centroid
#: first (it wins ties).
_LABEL_SAMPLES = np.array(
    [
        [1 / 3, 1 / 3, 1 / 3],
        [2 / 3, 1 / 6, 1 / 6],
        [1 / 6, 2 / 3, 1 / 6],
        [1 / 6, 1 / 6, 2 / 3],
    ]
)


def transfer_face_labels(
    full_vertices: np.ndarray,
    full_faces: np.ndarray,
    full_labels: np.ndarray,
    lod_vertices: np.ndarray,
    lod_faces: np.ndarray,
) -> np.ndarray:
    """Label each LOD triangle from the full mesh's triangle labels.

    Four points of each LOD triangle (its centroid and three points halfway
    between the centroid and each corner) take the label of the full triangle
    nearest to them (:func:`closest_points`); the LOD triangle gets the most
    frequent one, ties going to the centroid's.

    Parameters
    ----------
    full_vertices : (V, 3) float
    full_faces : (F, 3) int
    full_labels : (F,) any dtype
    lod_vertices : (V', 3) float
    lod_faces : (F', 3) int

    Returns
    -------
    (F',) array of ``full_labels``' dtype
    """
    v, f = _as_mesh(full_vertices, full_faces, "transfer_face_labels(full)")
    lv, lf = _as_mesh(lod_vertices, lod_faces, "transfer_face_labels(lod)")
    labels = np.asarray(full_labels)
    if labels.shape != (f.shape[0],):
        raise InputError(
            f"transfer_face_labels: full_labels must be ({f.shape[0]},), got {labels.shape}"
        )
    samples = np.einsum("sk,fkd->fsd", _LABEL_SAMPLES, lv[lf])  # (F', S, 3)
    n_lod, n_s = samples.shape[:2]
    face, _, _ = closest_points(v, f, samples.reshape(-1, 3))
    _, code = np.unique(labels, return_inverse=True)
    votes = code.reshape(-1)[face].reshape(n_lod, n_s)
    counts = (votes[:, :, None] == votes[:, None, :]).sum(axis=2)
    winner = np.argmax(counts, axis=1)  # first maximum: the centroid on ties
    return labels[face.reshape(n_lod, n_s)[np.arange(n_lod), winner]]
