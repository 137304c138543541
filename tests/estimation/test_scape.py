"""Tests for estimation.body_model.scape (Eq. 1 and the vertex solve) on tiny synthetic meshes.

The meshes are icospheres split into two "parts" by the plane z = 0, with
hand-built :class:`ScapeArrays` (no baked model).
"""

from __future__ import annotations

import importlib.util
import itertools

import numpy as np
import pytest
import trimesh

from bodymetry.estimation.body_model import scape
from bodymetry.estimation.body_model.rotations import axis_angle_to_matrix, euler_to_matrix

# --------------------------------------------------------------------------------------
# Tolerances, all in one place (absolute, metres on a unit-radius sphere).
# --------------------------------------------------------------------------------------
# Consistent edges reconstructed by the prefactored sparse least squares: the
# system is well conditioned on a 162-vertex sphere, so round-off stays tiny.
ATOL_SOLVE = 1e-9
# The factorizations against each other (cholespy vs the SuperLU reference) on the
# same right-hand sides: both are exact up to float64 round-off.
ATOL_SOLVERS = 1e-9
# Closed-form per-triangle quantities (frames, deformation gradients, Eq. 1 edges).
ATOL = 1e-12
SEED = 20240614
N_JOINTS = 5  # joints referenced by pose_joints in the synthetic model
#: Factorizations available here; the SuperLU reference always is.
SOLVERS = [s for s in scape._SOLVERS if s != "cholespy" or importlib.util.find_spec("cholespy")]
#: Implementations of Eq. (1) available here; the numpy reference always is.
EDGE_BACKENDS = [
    b for b in scape._EDGE_BACKENDS if b != "numba" or importlib.util.find_spec("numba")
]
#: The compiled edges against the numpy reference, relative to the largest edge: the same
#: products, some sums in another order (measured ~4e-16).
RTOL_EDGE_BACKENDS = 1e-12


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _sphere(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64)


def _arrays(
    rng: np.random.Generator,
    shape_mean: np.ndarray | None = None,
    shape_basis: np.ndarray | None = None,
    pose_coef: np.ndarray | None = None,
) -> scape.ScapeArrays:
    """Two parts (lower/upper hemisphere), random joint pairs, S = I and Q = I by default."""
    v, f = _sphere()
    T = len(f)
    parts = (v[f].mean(axis=1)[:, 2] > 0).astype(np.int64)
    pose_joints = rng.integers(0, N_JOINTS, size=(T, 2))
    if shape_mean is None:
        shape_mean = np.tile(np.eye(3).reshape(9), (T, 1))
    if shape_basis is None:
        shape_basis = np.zeros((2, T, 9))
    if pose_coef is None:
        pose_coef = np.zeros((T, 9, scape.N_POSE_FEATURES))
    return scape.ScapeArrays(v, f, parts, shape_mean, shape_basis, pose_joints, pose_coef)


def _deforming_arrays(rng, n_components: int):
    """The sphere's arrays with a random S (mean near I, ``n_components`` basis
    vectors) and a random Q: every factor of Eq. (1) at work."""
    T = len(_sphere()[1])
    return _arrays(
        rng,
        shape_mean=np.tile(np.eye(3).reshape(9), (T, 1)) + 0.1 * rng.normal(size=(T, 9)),
        shape_basis=0.1 * rng.normal(size=(n_components, T, 9)),
        pose_coef=0.1 * rng.normal(size=(T, 9, scape.N_POSE_FEATURES)),
    )


def _file_order(mesh: scape.ScapeMesh, arrays: scape.ScapeArrays) -> np.ndarray:
    """Index into the file's triangles of each of ``mesh``'s internally ordered triangles."""
    where = {tuple(face): t for t, face in enumerate(arrays.faces.tolist())}
    return np.array([where[tuple(face)] for face in mesh.faces.tolist()])


def _template_edges(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(T, 3, 2) edges [v1 - v0, v2 - v0] as columns."""
    tri = v[f]
    return np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]], axis=-1)


def _random_rotations(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return euler_to_matrix(rng.uniform(-np.pi, np.pi, (*shape, 3)))


def _assert_same_up_to_translation(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    shift = (b - a).mean(axis=-2, keepdims=True)
    np.testing.assert_allclose(a + shift, b, atol=atol)


# --- triangle frames and deformation gradients ------------------------------------------------


def test_triangle_frames(rng):
    v, f = _sphere()
    v = v * rng.uniform(0.5, 2.0, 3)
    F = scape.triangle_frames(v, f)
    e = _template_edges(v, f)
    np.testing.assert_array_equal(F[..., :2], e)
    n = F[..., 2]
    area2 = np.linalg.norm(np.cross(e[..., 0], e[..., 1]), axis=-1)
    np.testing.assert_allclose(np.einsum("ti,tie->te", n, e), 0.0, atol=ATOL)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), np.sqrt(area2), rtol=1e-12)
    assert np.all(np.linalg.det(F) > 0)  # right-handed


def test_deformation_gradients_of_identity_is_identity():
    v, f = _sphere()
    D = scape.deformation_gradients(v, v, f)
    np.testing.assert_allclose(D, np.broadcast_to(np.eye(3), D.shape), atol=ATOL)


def test_deformation_gradients_map_edges(rng):
    v, f = _sphere()
    deformed = v + 0.1 * np.sin(3.0 * v[:, [1, 2, 0]]) + rng.normal(scale=0.01, size=v.shape)
    batch = np.stack([deformed, 2.0 * deformed])
    D = scape.deformation_gradients(v, batch, f)
    assert D.shape == (2, len(f), 3, 3)
    for b in range(2):
        np.testing.assert_allclose(
            D[b] @ _template_edges(v, f), _template_edges(batch[b], f), atol=ATOL
        )


def test_deformation_gradients_of_a_similarity(rng):
    # The normal column scales with the square root of the area, so a similarity
    # x -> s R x + t has the deformation gradient s R on every triangle (the normal too).
    v, f = _sphere()
    R = _random_rotations(rng, ())
    s = 1.7
    D = scape.deformation_gradients(v, s * v @ R.T + rng.normal(size=3), f)
    np.testing.assert_allclose(D, np.broadcast_to(s * R, D.shape), atol=ATOL)


# --- construction -------------------------------------------------------------------------------


def test_n_shape_out_of_range(rng):
    arrays = _arrays(rng)
    for bad in (0, 3, -1):
        with pytest.raises(ValueError, match="n_shape"):
            scape.ScapeMesh(arrays, bad)


def test_internal_order_is_a_permutation(rng):
    arrays = _arrays(rng)
    mesh = scape.ScapeMesh(arrays, 2)
    order = _file_order(mesh, arrays)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(arrays.faces)))
    np.testing.assert_array_equal(mesh.parts, arrays.parts[order])
    np.testing.assert_array_equal(
        mesh.template_edges, _template_edges(arrays.template, mesh.faces).transpose(1, 2, 0)
    )


# --- the solve ----------------------------------------------------------------------------------


def test_solve_reproduces_the_template(rng):
    arrays = _arrays(rng)
    mesh = scape.ScapeMesh(arrays, 2)
    out = mesh.solve(mesh.edges(None, None, None))
    assert out.shape == (1, len(arrays.template), 3)
    np.testing.assert_array_equal(out[0, 0], 0.0)  # vertex 0 pinned at the origin
    _assert_same_up_to_translation(out[0], arrays.template, ATOL_SOLVE)
    # S = I (mean shape, ν = 0) and Q = I (identity local rotations) change nothing.
    local = np.broadcast_to(np.eye(3), (1, N_JOINTS, 3, 3))
    out2 = mesh.solve(mesh.edges(None, local, np.zeros((1, 2))))
    _assert_same_up_to_translation(out2[0], arrays.template, ATOL_SOLVE)


def test_global_rotation_rotates_the_mesh(rng):
    arrays = _arrays(rng)
    mesh = scape.ScapeMesh(arrays, 2)
    R = _random_rotations(rng, (4,))
    part_rot = np.repeat(R[:, None], 2, axis=1)  # the same rotation for both parts
    out = mesh.solve(mesh.edges(part_rot, None, None))
    for b in range(4):
        _assert_same_up_to_translation(out[b], arrays.template @ R[b].T, ATOL_SOLVE)


def test_shape_basis_stretches_x_exactly(rng):
    T = len(_sphere()[1])
    basis = np.zeros((2, T, 9))
    basis[0, :, 0] = 1.0  # S = diag(1 + ν0, 1, 1)
    basis[1] = rng.normal(size=(T, 9))  # unused when ν1 = 0
    arrays = _arrays(rng, shape_basis=basis)
    mesh = scape.ScapeMesh(arrays, 2)
    nu = np.array([[0.3, 0.0], [-0.25, 0.0]])
    S = mesh.shape_deformations(nu)
    assert S.shape == (2, 3, 3, T)
    np.testing.assert_allclose(S[0, :, :, 0], np.diag([1.3, 1.0, 1.0]), atol=ATOL)
    out = mesh.solve(mesh.edges(None, None, nu))
    for b, s in enumerate(nu[:, 0]):
        _assert_same_up_to_translation(
            out[b], arrays.template * np.array([1.0 + s, 1.0, 1.0]), ATOL_SOLVE
        )


def test_only_the_first_n_shape_components_are_used(rng):
    T = len(_sphere()[1])
    arrays = _arrays(rng, shape_basis=rng.normal(size=(2, T, 9)))
    one = scape.ScapeMesh(arrays, 1)
    two = scape.ScapeMesh(arrays, 2)
    np.testing.assert_allclose(
        one.shape_deformations(np.array([[0.4]])),
        two.shape_deformations(np.array([[0.4, 0.0]])),
        atol=ATOL,
    )
    with pytest.raises(ValueError, match="nu"):
        one.shape_deformations(np.zeros((1, 2)))


def test_solve_reconstructs_a_mesh_from_its_deformation_gradients(rng):
    # Deformation transfer: S_t = D_t (the template -> body gradients) gives the body back.
    v, f = _sphere()
    body = v * np.array([0.3, 0.2, 0.9]) + 0.05 * np.sin(4.0 * v[:, [2, 0, 1]])
    D = scape.deformation_gradients(v, body, f)
    arrays = _arrays(rng, shape_mean=D.reshape(len(f), 9))
    mesh = scape.ScapeMesh(arrays, 1)
    out = mesh.solve(mesh.edges(None, None, np.zeros((1, 1))))
    _assert_same_up_to_translation(out[0], body, ATOL_SOLVE)


def test_batched_solve_equals_per_state_solve(rng):
    T = len(_sphere()[1])
    arrays = _arrays(
        rng,
        shape_basis=0.05 * rng.normal(size=(2, T, 9)),
        pose_coef=0.05 * rng.normal(size=(T, 9, scape.N_POSE_FEATURES)),
    )
    mesh = scape.ScapeMesh(arrays, 2)
    B = 6
    part_rot = _random_rotations(rng, (B, 2))
    local = _random_rotations(rng, (B, N_JOINTS))
    nu = rng.normal(size=(B, 2))
    batch = mesh.solve(mesh.edges(part_rot, local, nu))
    for b in range(B):
        single = mesh.solve(mesh.edges(part_rot[b : b + 1], local[b : b + 1], nu[b : b + 1]))
        np.testing.assert_allclose(batch[b], single[0], atol=ATOL_SOLVE)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("B", [1, 17])
def test_solvers_give_the_reference_vertices(rng, solver, B):
    # Random (inconsistent) edges: a genuine least-squares fit, not an exact one.
    arrays = _arrays(rng)
    ref = scape.ScapeMesh(arrays, 2, solver="splu")
    mesh = scape.ScapeMesh(arrays, 2, solver=solver)
    assert mesh.solver == solver
    edges = rng.normal(size=(B, 3, 2, len(arrays.faces)))
    out = mesh.solve(edges)
    assert out.shape == (B, len(arrays.template), 3)
    np.testing.assert_allclose(out, ref.solve(edges), rtol=0, atol=ATOL_SOLVERS)
    # The residual is orthogonal to the edge space (normal equations hold).
    A = ref._At.T
    E = edges.reshape(B * 3, -1).T
    X = out[:, 1:].transpose(1, 0, 2).reshape(-1, B * 3)
    np.testing.assert_allclose(ref._At @ (A @ X - E), 0.0, atol=ATOL_SOLVERS)


def test_solver_choice(rng, monkeypatch):
    assert scape._default_solver("splu") == "splu"
    assert scape._default_solver("cholespy") == "cholespy"
    default = "cholespy" if importlib.util.find_spec("cholespy") else "splu"
    assert scape._default_solver(None) == default
    assert scape._default_solver("") == default
    with pytest.raises(ValueError, match="BODYMETRY_SCAPE_SOLVER"):
        scape._default_solver("umfpack")
    with pytest.raises(ValueError, match="solver"):
        scape.ScapeMesh(_arrays(rng), 2, solver="umfpack")
    # The module switch is read when a mesh is built.
    monkeypatch.setattr(scape, "SOLVER", "splu")
    assert scape.ScapeMesh(_arrays(rng), 2).solver == "splu"


# --- Eq. (1) --------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", EDGE_BACKENDS)
def test_edges_follow_equation_1(rng, monkeypatch, backend):
    """Δy_t = R_{p_t} S_t(ν) Q_t(θ) Δx_t, triangle by triangle, in the file's order."""
    monkeypatch.setattr(scape, "EDGES_BACKEND", backend)
    v, f = _sphere()
    T = len(f)
    arrays = _deforming_arrays(rng, n_components=2)
    mesh = scape.ScapeMesh(arrays, 2)
    B = 3
    part_rot = _random_rotations(rng, (B, 2))
    local = _random_rotations(rng, (B, N_JOINTS))
    nu = rng.normal(size=(B, 2))
    got = mesh.edges(part_rot, local, nu)  # (B, 3, 2, T), internal order
    assert got.shape == (B, 3, 2, T)
    order = _file_order(mesh, arrays)
    got_file = np.empty_like(got)
    got_file[..., order] = got

    rotvec = np.stack(
        [[_rotvec_of(local[b, j]) for j in range(N_JOINTS)] for b in range(B)]
    )  # (B, J, 3)
    x = _template_edges(v, f)  # (T, 3, 2)
    for b in range(B):
        feats = np.concatenate(
            [rotvec[b, arrays.pose_joints[:, 0]], rotvec[b, arrays.pose_joints[:, 1]]], axis=1
        )  # (T, 6)
        Q = np.eye(3) + np.einsum("tkf,tf->tk", arrays.pose_coef, feats).reshape(T, 3, 3)
        S = (arrays.shape_mean + np.einsum("k,ktn->tn", nu[b], arrays.shape_basis)).reshape(T, 3, 3)
        R = part_rot[b, arrays.parts]
        expected = R @ S @ Q @ x  # (T, 3, 2)
        np.testing.assert_allclose(got_file[b], expected.transpose(1, 2, 0), atol=ATOL)


def _rotvec_of(R: np.ndarray) -> np.ndarray:
    """Rotation vector of one matrix by a route independent of scape (eigenvector + angle)."""
    w, vecs = np.linalg.eig(R)
    axis = np.real(vecs[:, np.argmin(np.abs(w - 1.0))])
    angle = np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    # Orient the axis so that rotating by +angle about it gives R.
    if np.abs(axis_angle_to_matrix(axis * angle) - R).max() > 1e-9:
        axis = -axis
    return axis * angle


def test_q_is_identity_in_the_rest_pose(rng):
    T = len(_sphere()[1])
    arrays = _arrays(rng, pose_coef=rng.normal(size=(T, 9, scape.N_POSE_FEATURES)))
    mesh = scape.ScapeMesh(arrays, 2)
    rest = np.broadcast_to(np.eye(3), (2, N_JOINTS, 3, 3))
    np.testing.assert_allclose(
        mesh.posed_template_edges(rest),
        np.broadcast_to(mesh.template_edges, (2, 3, 2, T)),
        atol=ATOL,
    )
    # And bending a joint that no triangle uses changes nothing.
    unused = N_JOINTS  # one more joint than pose_joints refers to
    local = np.broadcast_to(np.eye(3), (1, unused + 1, 3, 3)).copy()
    local[0, unused] = _random_rotations(rng, ())
    np.testing.assert_allclose(mesh.posed_template_edges(local)[0], mesh.template_edges, atol=ATOL)


def test_edges_backend_choice(rng, monkeypatch):
    default = "numba" if importlib.util.find_spec("numba") else "numpy"
    assert scape._default_edges_backend(None) == default
    assert scape._default_edges_backend("") == default
    assert scape._default_edges_backend("numpy") == "numpy"
    with pytest.raises(ValueError, match="BODYMETRY_SCAPE_EDGES"):
        scape._default_edges_backend("cuda")
    monkeypatch.setattr(scape, "EDGES_BACKEND", "cuda")
    with pytest.raises(ValueError, match="EDGES_BACKEND"):
        scape.ScapeMesh(_arrays(rng), 2).edges(None, None, None)


@pytest.mark.skipif("numba" not in EDGE_BACKENDS, reason="numba is not installed")
@pytest.mark.parametrize("B", [1, 7])
@pytest.mark.parametrize("factors", list(itertools.product([False, True], repeat=3)))
def test_numba_edges_are_the_numpy_edges(rng, monkeypatch, B, factors):
    """Every combination of the optional factors (part rotations, Q, S), both paths."""
    T = len(_sphere()[1])
    arrays = _deforming_arrays(rng, n_components=3)
    mesh = scape.ScapeMesh(arrays, 2)
    with_rot, with_local, with_nu = factors
    args = (
        _random_rotations(rng, (B, 2)) if with_rot else None,
        _random_rotations(rng, (B, N_JOINTS)) if with_local else None,
        rng.normal(size=(B, 2)) if with_nu else None,
    )
    got = {}
    for backend in ("numpy", "numba"):
        monkeypatch.setattr(scape, "EDGES_BACKEND", backend)
        got[backend] = mesh.edges(*args)
    B_out = B if any(factors) else 1
    assert got["numba"].shape == got["numpy"].shape == (B_out, 3, 2, T)
    scale = np.abs(got["numpy"]).max()
    np.testing.assert_allclose(got["numba"], got["numpy"], rtol=0, atol=RTOL_EDGE_BACKENDS * scale)


@pytest.mark.skipif("numba" not in EDGE_BACKENDS, reason="numba is not installed")
def test_numba_edges_of_repeated_shapes_and_poses_are_each_states_own(rng, monkeypatch):
    """A batch of finite-difference steps (each state moves one pose or shape value from
    the first; the kernel reuses the previous state's Q Δx or S, and copies a chunk's
    edges when its pose, shape and part rotation are all the previous state's: states
    1 and 4, and part 1 of state 5) gives, bit for bit, the edges each state gets alone."""
    monkeypatch.setattr(scape, "EDGES_BACKEND", "numba")
    mesh = scape.ScapeMesh(_deforming_arrays(rng, n_components=3), 2)
    part_rot = np.repeat(_random_rotations(rng, (1, 2)), 6, axis=0)
    local = np.repeat(_random_rotations(rng, (1, N_JOINTS)), 6, axis=0)
    nu = np.repeat(rng.normal(size=(1, 2)), 6, axis=0)
    local[2, 1] = _random_rotations(rng, ())  # one joint bent
    local[3, 1] = local[2, 1]  # same pose as the previous state, other shape below
    nu[3, 0] += 1e-2
    nu[4, 1] -= 0.0  # -0.0 is the same number
    part_rot[5, 0] = _random_rotations(rng, ())
    batch = mesh.edges(part_rot, local, nu)
    for b in range(6):
        alone = mesh.edges(part_rot[b : b + 1], local[b : b + 1], nu[b : b + 1])
        assert np.array_equal(batch[b], alone[0])


@pytest.mark.skipif("numba" not in EDGE_BACKENDS, reason="numba is not installed")
def test_numba_right_hand_sides_are_scipys(rng, monkeypatch):
    """The solve's Aᵀ E by the compiled scatter is scipy's sparse product, bit for bit,
    and the compiled copy of the solution into vertex arrays is numpy's, so both
    backends give the same vertices."""
    mesh = scape.ScapeMesh(_deforming_arrays(rng, n_components=2), 2)
    edges = rng.normal(size=(4, 3, 2, len(mesh.faces)))
    got = {}
    for backend in ("numpy", "numba"):
        monkeypatch.setattr(scape, "EDGES_BACKEND", backend)
        got[backend] = mesh.solve(edges)
    assert np.array_equal(got["numba"], got["numpy"])


@pytest.mark.skipif("numba" not in EDGE_BACKENDS, reason="numba is not installed")
def test_numba_anchored_solve_is_numpys(rng, monkeypatch):
    """The anchored solve (every vertex solved) by both backends: the same vertices,
    bit for bit (the compiled copy of the solution is numpy's)."""
    mesh = scape.ScapeMesh(_deforming_arrays(rng, n_components=2), 2)
    anchors = np.arange(0, mesh.n_vertices, 7)
    mesh.set_anchors(anchors, 0.3)
    edges = rng.normal(size=(4, 3, 2, len(mesh.faces)))
    targets = rng.normal(size=(4, len(anchors), 3))
    got = {}
    for backend in ("numpy", "numba"):
        monkeypatch.setattr(scape, "EDGES_BACKEND", backend)
        got[backend] = mesh.solve(edges, targets)
    assert got["numba"].shape == (4, mesh.n_vertices, 3)
    assert np.array_equal(got["numba"], got["numpy"])


@pytest.mark.skipif("numba" not in EDGE_BACKENDS, reason="numba is not installed")
@pytest.mark.parametrize("K", [8, 9, 10])
def test_numba_shape_sums_of_nine_components_are_the_general_ones(rng, monkeypatch, K):
    """The kernel sums nine shape components (the default ν) in one pass, other counts
    three per pass: the same sums in the same order, so S = I + Σ ν_k U_k built from
    nine of ten components equals the ten-component sum with ν_10 = 0 bit for bit
    (adding 0 · U leaves every sum unchanged), and both paths agree to rounding."""
    monkeypatch.setattr(scape, "EDGES_BACKEND", "numba")
    mesh = scape.ScapeMesh(_deforming_arrays(rng, n_components=10), K)
    part_rot = _random_rotations(rng, (4, 2))
    local = _random_rotations(rng, (4, N_JOINTS))
    nu = rng.normal(size=(4, K))
    got = mesh.edges(part_rot, local, nu)
    wider = scape.ScapeMesh(mesh.arrays, 10)
    padded = np.hstack([nu, np.zeros((4, 10 - K))])
    assert np.array_equal(got, wider.edges(part_rot, local, padded))
    monkeypatch.setattr(scape, "EDGES_BACKEND", "numpy")
    scale = np.abs(got).max()
    np.testing.assert_allclose(
        got, mesh.edges(part_rot, local, nu), rtol=0, atol=RTOL_EDGE_BACKENDS * scale
    )
