"""Compiled (numba) kernel of :func:`bodymetry.estimation.body_model.skeleton.posed_skeleton`.

Imported lazily by ``skeleton`` (only when its ``BACKEND`` is ``"numba"``), so
importing the body model does not import numba.

The numpy path builds each joint's rotation with a few array operations and
walks the 15-part tree with stacked 3x3 products: about 25 numpy calls of a
few microseconds each, 0.7 ms per pose of one state, which the fit pays some
130 times per frame. The kernel does the same arithmetic in one pass per
state: the Euler and hinge matrices with ``rotations``' expressions, term for
term, then the tree. The 3x3 products are written out as sums of three
products, in order; numpy's matmul and einsum may fuse multiply-adds (BLAS),
so the rotations and joints agree with the numpy path to rounding (a few
1e-16), not bit for bit (tests/estimation/test_skeleton.py states the
tolerance).

numba, and its on-disk cache folder, come from :mod:`bodymetry.jit`.
"""

from __future__ import annotations

import math

import numpy as np

from bodymetry.jit import numba


@numba.njit(cache=True, nogil=True)
def posed_skeleton_kernel(
    theta, hinge_axes, dofs, starts, parents, rest, tau, local, rot, joints
):  # pragma: no cover
    """Local and global part rotations and joint positions of B states.

    Parameters
    ----------
    theta : (B, 37) float64
    hinge_axes : (J, 3) float64
        Unit axes of the hinge joints (other rows unused).
    dofs, starts, parents : (J,) int64
        Each joint's degrees of freedom (3 or 1), its first entry in θ and its
        parent part (-1 for the root); parents precede their children.
    rest : (B, J, 3) float64
        Rest-pose joint positions.
    tau : (B, 3) float64
        World position of the root joint.
    local, rot : (B, J, 3, 3) float64
        Written: rotation of each part relative to its parent, and global.
    joints : (B, J, 3) float64
        Written: world joint positions.
    """
    B = theta.shape[0]
    J = dofs.shape[0]
    for b in range(B):
        for j in range(J):
            L = local[b, j]
            s0 = starts[j]
            if dofs[j] == 3:
                # rotations.euler_to_matrix: Rz(c) Ry(b) Rx(a).
                ca = math.cos(theta[b, s0])
                cb = math.cos(theta[b, s0 + 1])
                cc = math.cos(theta[b, s0 + 2])
                sa = math.sin(theta[b, s0])
                sb = math.sin(theta[b, s0 + 1])
                sc = math.sin(theta[b, s0 + 2])
                L[0, 0] = cc * cb
                L[0, 1] = cc * sb * sa - sc * ca
                L[0, 2] = cc * sb * ca + sc * sa
                L[1, 0] = sc * cb
                L[1, 1] = sc * sb * sa + cc * ca
                L[1, 2] = sc * sb * ca - cc * sa
                L[2, 0] = -sb
                L[2, 1] = cb * sa
                L[2, 2] = cb * ca
            else:
                # rotations.axis_rotation (Rodrigues) about the hinge's axis.
                x, y, z = hinge_axes[j, 0], hinge_axes[j, 1], hinge_axes[j, 2]
                c = math.cos(theta[b, s0])
                s = math.sin(theta[b, s0])
                C = 1.0 - c
                L[0, 0] = c + x * x * C
                L[0, 1] = x * y * C - z * s
                L[0, 2] = x * z * C + y * s
                L[1, 0] = y * x * C + z * s
                L[1, 1] = c + y * y * C
                L[1, 2] = y * z * C - x * s
                L[2, 0] = z * x * C - y * s
                L[2, 1] = z * y * C + x * s
                L[2, 2] = c + z * z * C
            p = parents[j]
            G = rot[b, j]
            if p < 0:
                for r in range(3):
                    for q in range(3):
                        G[r, q] = L[r, q]
                    joints[b, j, r] = tau[b, r]
                continue
            P = rot[b, p]
            o0 = rest[b, j, 0] - rest[b, p, 0]
            o1 = rest[b, j, 1] - rest[b, p, 1]
            o2 = rest[b, j, 2] - rest[b, p, 2]
            for r in range(3):
                for q in range(3):
                    G[r, q] = P[r, 0] * L[0, q] + P[r, 1] * L[1, q] + P[r, 2] * L[2, q]
                joints[b, j, r] = joints[b, p, r] + (P[r, 0] * o0 + P[r, 1] * o1 + P[r, 2] * o2)


@numba.njit(cache=True, nogil=True)
def linear_kernel(basis, nu, out):  # pragma: no cover
    """``basis[0] + Σ_i ν_i basis[1 + i]`` for a batch (``BodyModel._linear``).

    numpy's path adds one component per pass over the whole batch, in order;
    this is the same sums per element, in the same order (the same bits), in
    one pass without the temporaries.

    Parameters
    ----------
    basis : (1 + n, M) float64
    nu : (B, n) float64
    out : (B, M) float64
        Written.
    """
    n = nu.shape[1]
    for b in range(nu.shape[0]):
        row = out[b]
        for m in range(basis.shape[1]):
            row[m] = basis[0, m]
        for i in range(n):
            w = nu[b, i]
            comp = basis[1 + i]
            for m in range(basis.shape[1]):
                row[m] = row[m] + w * comp[m]


@numba.njit(cache=True, nogil=True)
def anchor_targets_kernel(basis, nu, parts, rest_joints, rot, joints, out):  # pragma: no cover
    """Where each part's rigid motion carries its skeleton anchors
    (``BodyModel._anchor_targets``).

    The anchors' rest positions ``basis[0] + Σ_i ν_i basis[1 + i]`` (summed as
    :func:`linear_kernel` sums them), then ``joints[p] + R_p (rest - rest_joints[p])``
    for each anchor's part ``p``, the 3x3 product summed in order (numpy's
    ``rel @ R.T`` may fuse multiply-adds: equal to rounding).

    Parameters
    ----------
    basis : (1 + n, Na, 3) float64
    nu : (B, n) float64
    parts : (Na,) int64
    rest_joints : (B, J, 3) float64
    rot : (B, J, 3, 3) float64
    joints : (B, J, 3) float64
    out : (B, Na, 3) float64
        Written.
    """
    n = nu.shape[1]
    # The previous state's rest positions: a state with the same ν (the refinement's
    # finite-difference batches move ν in 9 of their 50 states) reuses them, the same
    # numbers without the 1 + n passes over the basis.
    rest = np.empty((basis.shape[1], 3))
    for b in range(nu.shape[0]):
        same = b > 0
        if b > 0:
            for i in range(n):
                if nu[b, i] != nu[b - 1, i]:
                    same = False
        if not same:
            for a in range(basis.shape[1]):
                r0 = basis[0, a, 0]
                r1 = basis[0, a, 1]
                r2 = basis[0, a, 2]
                for i in range(n):
                    w = nu[b, i]
                    r0 = r0 + w * basis[1 + i, a, 0]
                    r1 = r1 + w * basis[1 + i, a, 1]
                    r2 = r2 + w * basis[1 + i, a, 2]
                rest[a, 0] = r0
                rest[a, 1] = r1
                rest[a, 2] = r2
        for a in range(basis.shape[1]):
            p = parts[a]
            r0 = rest[a, 0]
            r1 = rest[a, 1]
            r2 = rest[a, 2]
            q0 = r0 - rest_joints[b, p, 0]
            q1 = r1 - rest_joints[b, p, 1]
            q2 = r2 - rest_joints[b, p, 2]
            R = rot[b, p]
            for x in range(3):
                out[b, a, x] = joints[b, p, x] + (q0 * R[x, 0] + q1 * R[x, 1] + q2 * R[x, 2])


@numba.njit(cache=True, nogil=True)
def translate_kernel(vertices, shift):  # pragma: no cover
    """``vertices += shift[:, None, :]`` in place (``BodyModel.pose``'s placement).

    numpy broadcasts the shift over an innermost axis of 3, a slow loop (0.6 ms
    for 50 LOD states); this is the same additions in one pass (the same bits).

    Parameters
    ----------
    vertices : (B, V, 3) float64
        Moved in place.
    shift : (B, 3) float64
    """
    for b in range(vertices.shape[0]):
        s0, s1, s2 = shift[b, 0], shift[b, 1], shift[b, 2]
        for i in range(vertices.shape[1]):
            vertices[b, i, 0] += s0
            vertices[b, i, 1] += s1
            vertices[b, i, 2] += s2
