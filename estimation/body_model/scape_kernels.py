"""Compiled (numba) kernel of :meth:`bodymetry.estimation.body_model.scape.ScapeMesh.edges`.

Imported lazily by ``scape`` (only when its ``EDGES_BACKEND`` is ``"numba"``),
so importing the body model does not import numba (about 0.35 s).

One pass computes Eq. (1), ``Δy_t = R_{p_t} S_t(ν) Q_t(θ) Δx_t``, for every
(state, triangle) without the intermediate ``(B, 3, 3, T)`` and ``(B, 3, 2, T)``
arrays of the numpy reference: the posed template edge ``Q_t Δx_t = Δx_t +
Σ_f f_f P_ft`` (``f`` the six rotation-vector components of the triangle's two
joints), the shape deformation ``S_t = μ_t + Σ_k ν_k U_kt``, their product and
the part rotation. Triangles are processed in chunks of one (part, joint pair)
block, so the rotation and the pose features are constants of the inner loops,
which run over contiguous triangles through 1-D slices (LLVM vectorizes those;
2-D indexing in the loops did not vectorize, 2.5x slower); a chunk's
coefficients stay in cache across the states. A state whose features or ν
equal the previous state's reuses that state's ``Q_t Δx_t`` or ``S_t`` (the
same numbers; the contour refinement's batch of finite-difference steps changes
one coordinate per state, so most of its states reuse both). The sums over the
pose features and the shape components are written a few terms per expression,
in the same order as one pass per term (the same numbers; the loops are
bound by loads and stores of the buffers, 20-35 % faster). No ``fastmath``: no fused
multiply-adds; only the order of some sums differs from the numpy reference
(its matrix products), so the edges agree to rounding (measured: 4e-16 of the
largest edge).

numba, and its on-disk cache folder, come from :mod:`bodymetry.jit`.
"""

from __future__ import annotations

import numpy as np

from bodymetry.jit import numba

#: Triangles per chunk: the chunk's coefficients (up to ~1.2 kB per triangle with
#: 20 shape components) stay in the L2 cache while all states are computed.
CHUNK = 128


@numba.njit(cache=True, nogil=True)
def edges_kernel(
    template, pose_coef, shape_mean, shape_basis, blocks, rotvec, nu, part_rot, out
):  # pragma: no cover
    """Eq. (1) for a batch of states, in the mesh's internal triangle order.

    One function, not named steps: it is one compiled loop over the triangle
    runs, whose buffers and reuse of the previous state's products would
    otherwise pass between jitted calls in the innermost loop.

    Parameters
    ----------
    template : (6, T) float
        Template edges ``Δx_t``, rows ``(xyz, edge)``.
    pose_coef : (6, 6, T) float
        ``P[f, (xyz, edge), t]``: the pose deformation's coefficients with the
        template edges folded in, ``(Q_t - I) Δx_t = Σ_f feature_f P[f, :, t]``.
    shape_mean : (9, T) float
        μ_t, rows ``(i, j)`` of ``S_t``.
    shape_basis : (K, 9, T) float
        U_kt (K may be 0).
    blocks : (N, 5) int
        ``(start, stop, part, j1, j2)`` of each run of triangles sharing a part
        and a joint pair.
    rotvec : (B, J, 3) float
        Rotation vector of each joint relative to its parent (zeros: Q = I).
    nu : (B, K) float
        Shape coefficients.
    part_rot : (B, P, 3, 3) float
        Global rotation of each part.
    out : (B, 6, T) float
        Written: ``Δy_t``, rows ``(xyz, edge)``.
    """
    B = out.shape[0]
    K = shape_basis.shape[0]
    x = np.empty((6, CHUNK))
    s = np.empty((9, CHUNK))
    for blk in range(blocks.shape[0]):
        start, stop, part = blocks[blk, 0], blocks[blk, 1], blocks[blk, 2]
        j1, j2 = blocks[blk, 3], blocks[blk, 4]
        for c0 in range(start, stop, CHUNK):
            n = min(CHUNK, stop - c0)
            c1 = c0 + n
            for b in range(B):
                # The buffers hold the previous state's Q_t Δx_t and S_t for this
                # chunk: a state with the same features or the same ν (a batch of
                # finite-difference steps moves one coordinate) reuses them, the
                # same numbers without the arithmetic.
                same_pose = b > 0
                same_shape = b > 0
                if b > 0:
                    for f in range(3):
                        if rotvec[b, j1, f] != rotvec[b - 1, j1, f]:
                            same_pose = False
                        if rotvec[b, j2, f] != rotvec[b - 1, j2, f]:
                            same_pose = False
                    for q in range(K):
                        if nu[b, q] != nu[b - 1, q]:
                            same_shape = False
                if same_pose and same_shape:
                    # The part's rotation too: then the chunk's edges are the previous
                    # state's (a finite-difference step of τ, or of a joint outside
                    # this part's chain), copied rather than computed again.
                    same_rot = True
                    for i in range(3):
                        for j in range(3):
                            if part_rot[b, part, i, j] != part_rot[b - 1, part, i, j]:
                                same_rot = False
                    if same_rot:
                        for r in range(6):
                            out[b, r, c0:c1] = out[b - 1, r, c0:c1]
                        continue
                if not same_pose:
                    # Q_t Δx_t: the six features times their coefficients, then the template.
                    # The six terms in one expression, in the order of separate passes
                    # over the features (the same sums), one load and store of x.
                    f0, f1, f2 = rotvec[b, j1, 0], rotvec[b, j1, 1], rotvec[b, j1, 2]
                    f3, f4, f5 = rotvec[b, j2, 0], rotvec[b, j2, 1], rotvec[b, j2, 2]
                    for r in range(6):
                        xr = x[r, :n]
                        p0 = pose_coef[0, r, c0:c1]
                        p1 = pose_coef[1, r, c0:c1]
                        p2 = pose_coef[2, r, c0:c1]
                        p3 = pose_coef[3, r, c0:c1]
                        p4 = pose_coef[4, r, c0:c1]
                        p5 = pose_coef[5, r, c0:c1]
                        tr = template[r, c0:c1]
                        for k in range(n):
                            xr[k] = (
                                (
                                    ((((0.0 + f0 * p0[k]) + f1 * p1[k]) + f2 * p2[k]) + f3 * p3[k])
                                    + f4 * p4[k]
                                )
                                + f5 * p5[k]
                            ) + tr[k]
                if not same_shape and K == 9:
                    # The default nine components: the same sums in one pass over S
                    # (the nine terms in order from 0.0, then μ_t), one store of S
                    # instead of three loads and stores per three components.
                    w0, w1, w2 = nu[b, 0], nu[b, 1], nu[b, 2]
                    w3, w4, w5 = nu[b, 3], nu[b, 4], nu[b, 5]
                    w6, w7, w8 = nu[b, 6], nu[b, 7], nu[b, 8]
                    for r in range(9):
                        sr = s[r, :n]
                        u0 = shape_basis[0, r, c0:c1]
                        u1 = shape_basis[1, r, c0:c1]
                        u2 = shape_basis[2, r, c0:c1]
                        u3 = shape_basis[3, r, c0:c1]
                        u4 = shape_basis[4, r, c0:c1]
                        u5 = shape_basis[5, r, c0:c1]
                        u6 = shape_basis[6, r, c0:c1]
                        u7 = shape_basis[7, r, c0:c1]
                        u8 = shape_basis[8, r, c0:c1]
                        mr = shape_mean[r, c0:c1]
                        for k in range(n):
                            a = ((0.0 + w0 * u0[k]) + w1 * u1[k]) + w2 * u2[k]
                            a = ((a + w3 * u3[k]) + w4 * u4[k]) + w5 * u5[k]
                            a = ((a + w6 * u6[k]) + w7 * u7[k]) + w8 * u8[k]
                            sr[k] = a + mr[k]
                elif not same_shape:
                    # S_t(ν) = Σ_k ν_k U_kt, then μ_t.
                    for r in range(9):
                        s[r, :n] = 0.0
                    # Three components per pass over S, the sums still in component
                    # order: a third of the loads and stores of S (load-bound).
                    q = 0
                    while q + 3 <= K:
                        w0, w1, w2 = nu[b, q], nu[b, q + 1], nu[b, q + 2]
                        for r in range(9):
                            sr = s[r, :n]
                            u0 = shape_basis[q, r, c0:c1]
                            u1 = shape_basis[q + 1, r, c0:c1]
                            u2 = shape_basis[q + 2, r, c0:c1]
                            for k in range(n):
                                sr[k] = ((sr[k] + w0 * u0[k]) + w1 * u1[k]) + w2 * u2[k]
                        q += 3
                    while q < K:
                        w = nu[b, q]
                        for r in range(9):
                            sr = s[r, :n]
                            ub = shape_basis[q, r, c0:c1]
                            for k in range(n):
                                sr[k] += w * ub[k]
                        q += 1
                    for r in range(9):
                        sr = s[r, :n]
                        mr = shape_mean[r, c0:c1]
                        for k in range(n):
                            sr[k] += mr[k]
                # R_p S_t (Q_t Δx_t), per edge e.
                R = part_rot[b, part]
                r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
                r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
                r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
                s0, s1, s2, s3, s4, s5, s6, s7, s8 = (
                    s[0],
                    s[1],
                    s[2],
                    s[3],
                    s[4],
                    s[5],
                    s[6],
                    s[7],
                    s[8],
                )
                for e in range(2):
                    xa, xb, xc = x[e], x[2 + e], x[4 + e]
                    o0 = out[b, e, c0:c1]
                    o1 = out[b, 2 + e, c0:c1]
                    o2 = out[b, 4 + e, c0:c1]
                    for k in range(n):
                        x0, x1, x2 = xa[k], xb[k], xc[k]
                        y0 = s0[k] * x0 + s1[k] * x1 + s2[k] * x2
                        y1 = s3[k] * x0 + s4[k] * x1 + s5[k] * x2
                        y2 = s6[k] * x0 + s7[k] * x1 + s8[k] * x2
                        o0[k] = r00 * y0 + r01 * y1 + r02 * y2
                        o1[k] = r10 * y0 + r11 * y1 + r12 * y2
                        o2[k] = r20 * y0 + r21 * y1 + r22 * y2


@numba.njit(cache=True, nogil=True)
def normal_rhs_kernel(faces, edges, out):  # pragma: no cover
    """``Aᵀ E``, the vertex solve's right-hand sides, transposed: ``out[(b, x), v - 1]``.

    ``A`` maps vertices to the edges ``v1 - v0`` (rows ``t``) and ``v2 - v0``
    (rows ``T + t``) of each triangle, vertex 0 pinned. Each vertex gathers
    ``+E`` where it is a triangle's ``v1`` or ``v2`` and ``-E`` where it is its
    ``v0``, in the order of the rows of ``A`` (edge 1 of every triangle, then
    edge 2), which is the order scipy's CSR product of ``ScapeMesh._At`` adds
    them: the same numbers, written one contiguous row per state and
    coordinate instead of through a transposed copy of the edges.

    Parameters
    ----------
    faces : (T, 3) int64
        In the mesh's internal order.
    edges : (B, 3, 2, T) float64
    out : (3B, V - 1) float64
        Written.
    """
    B = edges.shape[0]
    T = faces.shape[0]
    for b in range(B):
        for x in range(3):
            row = out[3 * b + x]
            row[:] = 0.0
            for e in range(2):
                ee = edges[b, x, e]
                for t in range(T):
                    v0 = faces[t, 0]
                    v = faces[t, e + 1]
                    if v > 0:
                        row[v - 1] += ee[t]
                    if v0 > 0:
                        row[v0 - 1] -= ee[t]


@numba.njit(cache=True, nogil=True)
def vertices_kernel(solution, out):  # pragma: no cover
    """The solve's columns ``(state, xyz)`` as vertex arrays.

    numpy's ``X.reshape(-1, B, 3).transpose(1, 0, 2)`` copied into ``(B, V, 3)``
    goes through a view whose innermost axis has 3 entries, a slow strided copy
    (2 ms for 50 states of the level of detail); this is the same copy in one
    pass over the rows of ``X``.

    Parameters
    ----------
    solution : (V - 1, 3B) or (V, 3B) float64
        The vertex solve's result, columns ``(state, xyz)``: without vertex 0
        (the pinned solve; vertex 0 is then at the origin) or with every vertex
        (the anchored solve).
    out : (B, V, 3) float64
        Written.
    """
    B = out.shape[0]
    V = out.shape[1]
    first = V - solution.shape[0]  # 1: vertex 0 pinned at the origin, 0: all solved
    for b in range(B):
        for v in range(first):
            for x in range(3):
                out[b, v, x] = 0.0
    for v in range(solution.shape[0]):
        row = solution[v]
        for b in range(B):
            for x in range(3):
                out[b, v + first, x] = row[3 * b + x]


@numba.njit(cache=True, nogil=True)
def anchored_rhs_kernel(faces, edges, anchor_of, weight2, targets, out):  # pragma: no cover
    """The anchored solve's right-hand sides ``Aᵀ E + w² Pᵀ targets``, columns ``(state, xyz)``.

    ``ScapeMesh._solve_anchored``'s numpy path builds them in four passes and
    three copies: the pinned system's ``Aᵀ E`` (:func:`normal_rhs_kernel`),
    transposed into place, vertex 0's row as minus the sum of the others, and
    the transposed targets added to the anchored rows. This is one pass per
    state with the same numbers: each state's ``Aᵀ E`` is scattered into a
    small (V, 3) buffer in the order of the rows of ``A`` (the order of
    :func:`normal_rhs_kernel` and scipy's product; the buffer stays in the L1
    cache, and the edges are read in order, which made it faster than
    gathering each vertex's edges), then copied into the state's columns,
    vertex 0's row being minus the running sum of the rows after it, taken row
    by row as numpy's ``sum(axis=0)`` adds them, and an anchored row then adding
    ``w² · target``.

    Parameters
    ----------
    faces : (T, 3) int64
        In the mesh's internal order.
    edges : (B, 3, 2, T) float64
        Predicted edges (:meth:`ScapeMesh.edges`).
    anchor_of : (V,) int64
        The anchor of each vertex (index into ``targets``' second axis), -1 for none.
    weight2 : float
        The anchors' squared weight.
    targets : (B, Na, 3) float64
    out : (V, 3B) float64
        Written.
    """
    B = edges.shape[0]
    T = faces.shape[0]
    V = out.shape[0]
    acc = np.empty((V, 3))
    for b in range(B):
        acc[:, :] = 0.0
        for e in range(2):
            ex, ey, ez = edges[b, 0, e], edges[b, 1, e], edges[b, 2, e]
            for t in range(T):
                v0 = faces[t, 0]
                v = faces[t, e + 1]
                # Vertex 0's own sums are not used (its row is minus the others').
                acc[v, 0] += ex[t]
                acc[v, 1] += ey[t]
                acc[v, 2] += ez[t]
                acc[v0, 0] -= ex[t]
                acc[v0, 1] -= ey[t]
                acc[v0, 2] -= ez[t]
        c = 3 * b
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for v in range(1, V):
            g0 = acc[v, 0]
            g1 = acc[v, 1]
            g2 = acc[v, 2]
            if v == 1:
                s0, s1, s2 = g0, g1, g2
            else:
                s0 += g0
                s1 += g1
                s2 += g2
            a = anchor_of[v]
            if a >= 0:
                g0 += weight2 * targets[b, a, 0]
                g1 += weight2 * targets[b, a, 1]
                g2 += weight2 * targets[b, a, 2]
            out[v, c] = g0
            out[v, c + 1] = g1
            out[v, c + 2] = g2
        g0, g1, g2 = -s0, -s1, -s2
        a = anchor_of[0]
        if a >= 0:
            g0 += weight2 * targets[b, a, 0]
            g1 += weight2 * targets[b, a, 1]
            g2 += weight2 * targets[b, a, 2]
        out[0, c] = g0
        out[0, c + 1] = g1
        out[0, c + 2] = g2
