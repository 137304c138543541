"""SCAPE mesh deformation, Eq. (1) of the paper, and the vertex solve.

For every triangle t of a template with edge matrix ``Δx_t = [v2 - v1, v3 - v1]``
the posed, shaped edges are::

    Δy_t = R_{p_t}(θ) S_t(ν) Q_t(θ) Δx_t

with ``R`` the rigid rotation of the triangle's part, ``S_t(ν) = μ_t + Σ_i ν_i U_it``
the shape deformation (PCA) and ``Q_t = I + A_t f_t(θ)`` the pose deformation, a
linear function of the rotation vectors of the two joints nearest the
triangle (Q = I in the rest pose). The
vertices are then the least-squares fit to the predicted edges; the system
matrix depends only on the topology, so it is factorized once and every state
(or batch of states, as right-hand-side columns) costs one sparse solve.

Deformations are 3x3 because each triangle's frame includes a third, normal
vector scaled by the inverse square root of the area (deformation transfer),
which makes the per-triangle deformation gradient unique.

:data:`SOLVER` selects the factorization of the (symmetric positive definite)
normal equations, from ``$BODYMETRY_SCAPE_SOLVER`` (``cholespy`` or ``splu``);
by default cholespy's sparse Cholesky when it is installed, else SciPy's SuperLU.
Both give the same vertices to rounding (about 1e-12 m).

:data:`EDGES_BACKEND` selects how :meth:`ScapeMesh.edges` evaluates Eq. (1),
from ``$BODYMETRY_SCAPE_EDGES`` (``numba`` or ``numpy``): a fused compiled
kernel (:mod:`~bodymetry.estimation.body_model.scape_kernels`, one pass per
state and triangle) or the numpy reference (a few dense products over blocks of
triangles); by default numba when it is installed. Both give the same edges to
rounding (about 1e-15 relative).
"""

from __future__ import annotations

import itertools
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from bodymetry.estimation.backends import default_backend, module_kernels
from bodymetry.estimation.body_model.rotations import matrix_to_axis_angle

log = logging.getLogger(__name__)

_SOLVERS = ("cholespy", "splu")
_EDGE_BACKENDS = ("numba", "numpy")


def _default_solver(env: str | None) -> str:
    """``$BODYMETRY_SCAPE_SOLVER`` or, unset, cholespy when installed (without importing it)."""
    return default_backend("BODYMETRY_SCAPE_SOLVER", env, _SOLVERS, "cholespy")


#: The factorization behind :meth:`ScapeMesh.solve`: ``"cholespy"`` or ``"splu"``.
#: Read when a :class:`ScapeMesh` is built (the factorization is computed once
#: then), so tests and benchmarks may set it; the one place the choice is made.
SOLVER: str = _default_solver(os.environ.get("BODYMETRY_SCAPE_SOLVER"))


def _default_edges_backend(env: str | None) -> str:
    """``$BODYMETRY_SCAPE_EDGES`` or, unset, numba when installed (without importing it)."""
    return default_backend("BODYMETRY_SCAPE_EDGES", env, _EDGE_BACKENDS, "numba")


#: How :meth:`ScapeMesh.edges` evaluates Eq. (1): ``"numba"`` (the fused kernel)
#: or ``"numpy"`` (the reference). Read at every call, so tests and benchmarks
#: may set it.
EDGES_BACKEND: str = _default_edges_backend(os.environ.get("BODYMETRY_SCAPE_EDGES"))


def _edge_kernels() -> ModuleType | None:
    """The compiled kernel module when :data:`EDGES_BACKEND` is ``"numba"``, else None.

    Imported on first use, so that importing the body model does not import
    numba. When numba was chosen by default but fails to import (a broken
    install), the numpy path is used with a log message; an explicit
    ``BODYMETRY_SCAPE_EDGES=numba`` raises instead.
    """
    return module_kernels(
        globals(),
        "EDGES_BACKEND",
        "bodymetry.estimation.body_model.scape_kernels",
        "BODYMETRY_SCAPE_EDGES",
        "SCAPE edges",
    )


#: Features per triangle for Q: two joints' rotation vectors. No constant term:
#: Q must be the identity in the rest pose, where the body is the template.
N_POSE_FEATURES = 6


def triangle_frames(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-triangle frames ``[e1, e2, n / sqrt(|n|)]`` as columns.

    Parameters
    ----------
    vertices : (..., V, 3) float
    faces : (T, 3) int

    Returns
    -------
    (..., T, 3, 3) float
    """
    tri = vertices[..., faces, :]
    e1 = tri[..., 1, :] - tri[..., 0, :]
    e2 = tri[..., 2, :] - tri[..., 0, :]
    n = np.cross(e1, e2)
    n = n / np.sqrt(np.linalg.norm(n, axis=-1, keepdims=True) + 1e-300)
    return np.stack([e1, e2, n], axis=-1)


def deformation_gradients(rest: np.ndarray, deformed: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-triangle linear maps taking ``rest`` triangle frames to ``deformed`` ones.

    Parameters
    ----------
    rest : (V, 3) float
    deformed : (..., V, 3) float
    faces : (T, 3) int

    Returns
    -------
    (..., T, 3, 3) float
        ``D`` with ``D @ [e1, e2] = [e1', e2']`` for every triangle.
    """
    inv_rest = np.linalg.inv(triangle_frames(rest, faces))
    return triangle_frames(deformed, faces) @ inv_rest


@dataclass(frozen=True)
class ScapeArrays:
    """The learned SCAPE model at one resolution (what the model file stores).

    Attributes
    ----------
    template : (V, 3) float
        Rest-pose template vertices (world frame, metres).
    faces : (T, 3) int
        Outward-oriented triangles.
    parts : (T,) int
        Part index of each triangle (see ``skeleton.PARTS``).
    shape_mean : (T, 9) float
        Row-major mean shape deformation μ_t.
    shape_basis : (K, T, 9) float
        Shape components, scaled so ν ~ N(0, I) over the training bodies.
    pose_joints : (T, 2) int
        The two joints (indices into ``skeleton.JOINTS``) whose rotations drive Q_t.
    pose_coef : (T, 9, 6) float
        ``vec(Q_t) - vec(I) = pose_coef[t] @ [r_j1, r_j2]``.
    """

    template: np.ndarray
    faces: np.ndarray
    parts: np.ndarray
    shape_mean: np.ndarray
    shape_basis: np.ndarray
    pose_joints: np.ndarray
    pose_coef: np.ndarray


class ScapeMesh:
    """Eq. (1) and the prefactored vertex solve for one mesh resolution.

    Internally triangles are sorted by (part, joint pair) so that the part
    rotations and the pose deformations become a few dense matrix products over
    contiguous blocks, and edge arrays are laid out ``(B, xyz, edge, T)``.

    Parameters
    ----------
    arrays : ScapeArrays
    n_shape : int
        Shape components to use (at most ``arrays.shape_basis.shape[0]``).
    solver : {"cholespy", "splu"}, optional
        Factorization of the vertex solve; default :data:`SOLVER`.
    """

    def __init__(self, arrays: ScapeArrays, n_shape: int, solver: str | None = None) -> None:
        n_max = arrays.shape_basis.shape[0]
        if not 0 < n_shape <= n_max:
            raise ValueError(f"n_shape: expected 1..{n_max}, got {n_shape}")
        self.arrays = arrays
        self.n_shape = n_shape
        self.n_vertices = len(arrays.template)
        T = len(arrays.faces)
        n_joints = int(arrays.pose_joints.max()) + 1
        key = (arrays.parts * n_joints + arrays.pose_joints[:, 0]) * n_joints + arrays.pose_joints[
            :, 1
        ]
        order = np.argsort(key, kind="stable")
        self._order = order
        self.faces = arrays.faces[order]
        self.parts = arrays.parts[order]
        pairs = arrays.pose_joints[order]
        tri = arrays.template[self.faces]
        edges = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]], axis=-1)  # (T, 3, 2)
        #: (3, 2, T) template edges Δx_t
        self.template_edges = np.ascontiguousarray(edges.transpose(1, 2, 0))
        # Shape: S = mean + ν @ basis, rows (i, j) of S_t, triangles last.
        self._shape_mean = np.ascontiguousarray(arrays.shape_mean[order].reshape(T, 9).T).reshape(
            -1
        )
        basis = arrays.shape_basis[:n_shape][:, order].reshape(n_shape, T, 9)
        self._shape_basis = np.ascontiguousarray(basis.transpose(0, 2, 1).reshape(n_shape, -1))
        # Pose: (Q - I) Δx is linear in the features, so fold Δx into the coefficients:
        # P[t, f] = C_f[t] @ Δx_t, (T, 6, 3, 2).
        # Laid out (feature, (xyz, edge), T) for the compiled kernel; the numpy
        # path takes each (part, joint pair) block as one (6, 6 * n) matrix.
        C = arrays.pose_coef[order].reshape(T, 3, 3, N_POSE_FEATURES)
        self._pose_coef = np.ascontiguousarray(
            np.einsum("tijf,tje->fiet", C, edges).reshape(N_POSE_FEATURES, 6, T)
        )
        self._part_blocks = _blocks(self.parts)
        self._pose_blocks = []
        for start, stop in _blocks(key[order]):
            j1, j2 = pairs[start]
            block = self._pose_coef[:, :, start:stop].reshape(N_POSE_FEATURES, -1)
            self._pose_blocks.append((start, stop, int(j1), int(j2), block))
        #: (N, 5) ``(start, stop, part, j1, j2)`` of the blocks, for the kernel.
        self._kernel_blocks = np.array(
            [(a, b, self.parts[a], j1, j2) for a, b, j1, j2, _ in self._pose_blocks],
            dtype=np.int64,
        ).reshape(-1, 5)
        self._build_solver(SOLVER if solver is None else solver)

    def _edge_matrix(self) -> sp.csr_matrix:
        """(2T, V) ``A``: row ``e * T + t`` maps the vertices to edge e of triangle t
        (matching the (xyz, edge, T) layout of :meth:`edges`)."""
        T, V = len(self.faces), self.n_vertices
        f = self.faces
        rows = np.concatenate([np.arange(T), np.arange(T), T + np.arange(T), T + np.arange(T)])
        cols = np.concatenate([f[:, 1], f[:, 0], f[:, 2], f[:, 0]])
        vals = np.concatenate([np.ones(T), -np.ones(T), np.ones(T), -np.ones(T)])
        return sp.csr_matrix((vals, (rows, cols)), shape=(2 * T, V))

    def _build_solver(self, solver: str) -> None:
        # Vertex 0 is pinned at the origin: the edges fix the mesh up to a translation.
        A = self._edge_matrix()[:, 1:].tocsc()
        self._At = A.T.tocsr()
        self._faces64 = np.ascontiguousarray(self.faces, dtype=np.int64)
        self._factor = _factorize((self._At @ A).tocsr(), solver)
        self.solver = solver
        self._anchors: tuple[np.ndarray, float, Callable[[np.ndarray], np.ndarray]] | None = None

    def set_anchors(self, vertices: np.ndarray, weight: float) -> None:
        """Soft anchors for :meth:`solve` with ``targets``: factorize once.

        The anchored solve minimizes ``‖A x - E‖² + weight² Σ_a ‖x_a - target_a‖²``
        over all vertices (no pinned vertex: the anchors place the mesh).

        Parameters
        ----------
        vertices : (Na,) int
            Anchored vertices (file order, as :attr:`arrays`).
        weight : float
            Weight of an anchor against one edge equation (> 0).
        """
        idx = np.asarray(vertices, dtype=np.int64)
        if not weight > 0 or idx.ndim != 1 or len(idx) == 0:
            raise ValueError(f"anchors: expected vertices and a weight > 0, got {weight}")
        if idx.min() < 0 or idx.max() >= self.n_vertices:
            raise ValueError(f"anchors: vertex indices must lie in 0..{self.n_vertices - 1}")
        A = self._edge_matrix()
        V = self.n_vertices
        W = sp.csr_matrix((np.full(len(idx), weight**2), (idx, idx)), shape=(V, V))
        self._anchors = (idx, float(weight**2), _factorize((A.T @ A + W).tocsr(), self.solver))
        # For the compiled right-hand sides: each vertex's anchor. With a vertex listed
        # twice, the last listing's target is added, as numpy's ``rhs[idx] +=``.
        self._anchor_of = np.full(V, -1, dtype=np.int64)
        self._anchor_of[idx] = np.arange(len(idx))

    # --- Eq. (1) -------------------------------------------------------------
    def shape_deformations(self, nu: np.ndarray) -> np.ndarray:
        """S_t(ν) for a batch of shapes, in internal triangle order.

        Parameters
        ----------
        nu : (B, n_shape) float

        Returns
        -------
        (B, 3, 3, T) float
        """
        nu = np.atleast_2d(np.asarray(nu, dtype=float))
        if nu.shape[-1] != self.n_shape:
            raise ValueError(f"nu: expected shape (B, {self.n_shape}), got {nu.shape}")
        S = self._shape_mean + nu @ self._shape_basis
        return S.reshape(len(nu), 3, 3, -1)

    def posed_template_edges(self, local_rotations: np.ndarray) -> np.ndarray:
        """``Q_t(θ) Δx_t`` for a batch of poses.

        Parameters
        ----------
        local_rotations : (B, 15, 3, 3) float
            Each part's rotation relative to its parent.

        Returns
        -------
        (B, 3, 2, T) float
        """
        rotvec = matrix_to_axis_angle(local_rotations)  # (B, 15, 3)
        B = len(rotvec)
        out = np.empty((B, 3, 2, len(self.faces)))
        feats = np.empty((B, N_POSE_FEATURES))
        for start, stop, j1, j2, block in self._pose_blocks:
            feats[:, 0:3] = rotvec[:, j1]
            feats[:, 3:6] = rotvec[:, j2]
            out[..., start:stop] = (feats @ block).reshape(B, 3, 2, stop - start)
        out += self.template_edges
        return out

    def edges(
        self,
        part_rotations: np.ndarray | None,
        local_rotations: np.ndarray | None,
        nu: np.ndarray | None,
    ) -> np.ndarray:
        """Predicted triangle edges Δy_t of Eq. (1), in internal triangle order.

        Parameters
        ----------
        part_rotations : (B, 15, 3, 3) float or None
            Global rotation of each part; None for the rest pose (identity).
        local_rotations : (B, 15, 3, 3) float or None
            Rotation of each part relative to its parent; None for no pose
            deformation (Q = I).
        nu : (B, n_shape) float or None
            None keeps the template's own shape (S = I), the body Q was fitted on.

        Returns
        -------
        (B, 3, 2, T) float
        """
        kernels = _edge_kernels()
        if kernels is not None:
            return self._edges_numba(kernels, part_rotations, local_rotations, nu)
        if nu is None:
            sizes = [len(r) for r in (part_rotations, local_rotations) if r is not None]
            B = sizes[0] if sizes else 1
        else:
            S = self.shape_deformations(nu)
            B = len(S)
        if local_rotations is None:
            x = np.broadcast_to(self.template_edges, (B, *self.template_edges.shape))
        else:
            x = self.posed_template_edges(local_rotations)
        if nu is None:
            y = np.array(x)
        else:
            # y_i = sum_j S_ij x_j, elementwise over (state, edge, triangle).
            y = np.empty((B, 3, 2, len(self.faces)))
            for i in range(3):
                y[:, i] = (
                    S[:, i, 0, None] * x[:, 0]
                    + S[:, i, 1, None] * x[:, 1]
                    + S[:, i, 2, None] * x[:, 2]
                )
        if part_rotations is None:
            return y
        out = np.empty_like(y)
        for part, (start, stop) in zip(np.unique(self.parts), self._part_blocks, strict=True):
            block = y[..., start:stop].reshape(B, 3, -1)
            out[..., start:stop] = (part_rotations[:, part] @ block).reshape(B, 3, 2, -1)
        return out

    def _edges_numba(
        self,
        kernels: ModuleType,
        part_rotations: np.ndarray | None,
        local_rotations: np.ndarray | None,
        nu: np.ndarray | None,
    ) -> np.ndarray:
        """:meth:`edges` by the fused kernel (same arguments and result).

        The missing factors become their identities (zero rotation vectors,
        S = I with no components, identity part rotations), which the kernel
        applies exactly: adding zeros and multiplying by ones and zeros does not
        round.
        """
        T = len(self.faces)
        if nu is None:
            sizes = [len(r) for r in (part_rotations, local_rotations) if r is not None]
            B = sizes[0] if sizes else 1
            nu = np.zeros((B, 0))
            mean = np.ascontiguousarray(np.broadcast_to(np.eye(3).reshape(9, 1), (9, T)))
            basis = np.zeros((0, 9, T))
        else:
            nu = np.atleast_2d(np.asarray(nu, dtype=float))
            if nu.shape[-1] != self.n_shape:
                raise ValueError(f"nu: expected shape (B, {self.n_shape}), got {nu.shape}")
            B = len(nu)
            mean = self._shape_mean.reshape(9, T)
            basis = self._shape_basis.reshape(self.n_shape, 9, T)
        if local_rotations is None:
            rotvec = np.zeros((B, int(self._kernel_blocks[:, 3:].max()) + 1, 3))
        else:
            rotvec = matrix_to_axis_angle(local_rotations)
        if part_rotations is None:
            part_rotations = np.broadcast_to(np.eye(3), (B, int(self.parts.max()) + 1, 3, 3))
        out = np.empty((B, 3, 2, T))
        kernels.edges_kernel(
            self.template_edges.reshape(6, T),
            self._pose_coef,
            mean,
            basis,
            self._kernel_blocks,
            _kernel_arg(rotvec),
            _kernel_arg(nu),
            _kernel_arg(part_rotations),
            out.reshape(B, 6, T),
        )
        return out

    def solve(self, edges: np.ndarray, targets: np.ndarray | None = None) -> np.ndarray:
        """Vertices whose triangle edges best fit ``edges`` (least squares).

        Parameters
        ----------
        edges : (B, 3, 2, T) float
            As returned by :meth:`edges`.
        targets : (B, Na, 3) float, optional
            Where the anchors of :meth:`set_anchors` should be: the anchored
            solve, in the targets' frame.

        Returns
        -------
        (B, V, 3) float
            Without targets, vertex 0 at the origin (callers place the mesh).
        """
        if targets is not None:
            return self._solve_anchored(edges, targets)
        # Columns (state, xyz): the 3 coordinates of all states share one factorization.
        X = self._factor(np.ascontiguousarray(self._pinned_rhs(edges)))  # (V-1, 3B)
        return self._vertex_arrays(X, edges.shape[0])

    def _solve_anchored(self, edges: np.ndarray, targets: np.ndarray) -> np.ndarray:
        if self._anchors is None:
            raise ValueError("solve with targets: call set_anchors first")
        idx, w2, factor = self._anchors
        B = edges.shape[0]
        targets = np.asarray(targets, dtype=float)
        if targets.shape != (B, len(idx), 3):
            raise ValueError(f"targets: expected shape {(B, len(idx), 3)}, got {targets.shape}")
        rhs = np.empty((self.n_vertices, 3 * B))
        kernels = _edge_kernels()
        if kernels is not None:
            # One pass, the same numbers (scape_kernels.anchored_rhs_kernel).
            kernels.anchored_rhs_kernel(
                self._faces64, _kernel_arg(edges), self._anchor_of, w2, _kernel_arg(targets), rhs
            )
            return self._vertex_arrays(factor(rhs), B)
        rhs[1:] = self._pinned_rhs(edges)
        # Every edge adds +E to one end and -E to the other, so the rows of AᵀE sum
        # to zero: vertex 0's row (left out of the pinned system) is minus the rest.
        rhs[0] = -rhs[1:].sum(axis=0)
        rhs[idx] += w2 * targets.transpose(1, 0, 2).reshape(len(idx), 3 * B)
        return self._vertex_arrays(factor(rhs), B)  # (V, 3B) solved

    def _pinned_rhs(self, edges: np.ndarray) -> np.ndarray:
        """(V-1, 3B) ``Aᵀ E`` of the pinned system, columns (state, xyz); may be a view."""
        B = edges.shape[0]
        kernels = _edge_kernels()
        if kernels is not None:
            # Aᵀ E without the transposed copy of the edges scipy's product makes
            # (most of the solve's time for a batch): the same sums, in the same order.
            rhs_t = np.empty((3 * B, self.n_vertices - 1))
            kernels.normal_rhs_kernel(self._faces64, _kernel_arg(edges), rhs_t)
            return rhs_t.T
        E = np.ascontiguousarray(edges).reshape(B * 3, -1).T  # (2T, 3B)
        return np.asarray(self._At @ E)

    def _vertex_arrays(self, X: np.ndarray, B: int) -> np.ndarray:
        """(B, V, 3) vertices from a solve's columns (state, xyz): ``X`` (V-1, 3B)
        of the pinned solve (vertex 0 at the origin) or (V, 3B) of the anchored one."""
        kernels = _edge_kernels()
        if kernels is not None:
            out = np.empty((B, self.n_vertices, 3))
            kernels.vertices_kernel(_kernel_arg(X), out)  # the same copy, one pass
            return out
        out = np.zeros((B, self.n_vertices, 3))
        out[:, self.n_vertices - len(X) :] = X.reshape(-1, B, 3).transpose(1, 0, 2)
        return out


def _factorize(K: sp.csr_matrix, solver: str) -> Callable[[np.ndarray], np.ndarray]:
    """Factorize the SPD matrix ``K`` once; return ``solve(rhs) -> x``.

    Parameters
    ----------
    K : (N, N) sparse, symmetric positive definite
    solver : {"cholespy", "splu"}

    Returns
    -------
    callable
        Takes rhs (N, k) float and returns x (N, k) float with ``K @ x = rhs``.
    """
    if solver == "cholespy":
        # Supernodal sparse Cholesky: on the level of detail, 80 states (240
        # right-hand sides) solve in 5 ms, SuperLU 10-12 ms; 80 full meshes in
        # 66 vs 350-490 ms (measured, one thread). Same values to about 1e-12 m.
        # (A dense inverse of the 1.5k-vertex LOD system was slower still: 26 ms
        # for 80 states, 3.8 ms for one.)
        from cholespy import CholeskySolverD, MatrixType

        coo = K.tocoo()
        chol = CholeskySolverD(
            K.shape[0],
            coo.row.astype(np.int32),
            coo.col.astype(np.int32),
            coo.data.astype(np.float64),
            MatrixType.COO,
        )

        def solve(rhs: np.ndarray) -> np.ndarray:
            # cholespy wants C-ordered (N, k) float64 arrays and writes into x.
            rhs = np.ascontiguousarray(rhs, dtype=np.float64)
            x = np.empty_like(rhs)
            chol.solve(rhs, x)
            return x

        return solve
    if solver == "splu":
        # No pivoting is needed on an SPD matrix, and SuperLU's symmetric mode keeps
        # the fill-reducing ordering on both sides. Measured: solves 2x faster than
        # with partial pivoting (192 right-hand sides on the level of detail 13 vs
        # 25 ms; 3 on the full mesh 4 vs 9 ms), same values to rounding.
        lu = spla.splu(
            K.tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        return lu.solve
    raise ValueError(f"solver: expected one of {_SOLVERS}, got {solver!r}")


def _kernel_arg(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous, writable float64 array: numba compiles (and caches)
    one version per layout and per read-only flag, so every call passes the same kind."""
    return np.require(a, dtype=np.float64, requirements=["C", "W"])


def _blocks(sorted_keys: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of equal values in a sorted array."""
    cuts = np.flatnonzero(np.diff(sorted_keys)) + 1
    bounds = np.concatenate([[0], cuts, [len(sorted_keys)]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]
