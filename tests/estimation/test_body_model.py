"""Tests for estimation.body_model.model: BodyState and the committed SCAPE BodyModel."""

from __future__ import annotations

import importlib.util
import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodymetry.errors import InputError
from bodymetry.estimation.body_model import geometry, scape
from bodymetry.estimation.body_model.bake.lod import closest_points
from bodymetry.estimation.body_model.model import (
    ADULT_YEARS,
    ANCHOR_CLEARANCE,
    DEFAULT_MODEL_PATH,
    DEFAULT_SHAPE_DOFS,
    BodyModel,
    BodyState,
)
from bodymetry.estimation.body_model.rotations import euler_to_matrix
from bodymetry.estimation.body_model.skeleton import (
    HINGES,
    JOINT_DOFS,
    JOINT_SLICES,
    JOINTS,
    N_POSE,
    PARTS,
    dof_names,
    forward_kinematics,
    local_rotations,
    posed_skeleton,
)

# --------------------------------------------------------------------------------------
# Tolerances, all in one place (metres unless stated).
# --------------------------------------------------------------------------------------
# Exact symmetries of the model (translation, rotation about the root, rest pose =
# translated canonical body): only float64 round-off of the sparse solve on a 1.7 m body.
ATOL_EXACT = 1e-6
# Vertices of posed bodies from each factorization of the vertex solve against the
# SuperLU reference (float64 round-off of two exact solvers, measured ~2e-12 m).
ATOL_SOLVERS = 1e-9
# ν recovered from its own canonical mesh (a well-posed linear least squares).
ATOL_NU = 1e-6
# The ~3k-triangle LOD against the full mesh of the same state: every LOD vertex
# within LOD_MAX_DISTANCE of the full surface (mean LOD_MEAN_DISTANCE), volume
# ratio LOD/full in LOD_VOLUME_RATIO. In the rest and named poses the LOD is
# close (measured: 6-9 mm, ratio 0.995-1.002); random poses bend big LOD
# triangles across joints (measured over 30 poses: 1.9 cm, mean 7 mm, 0.963-1.005).
LOD_MAX_DISTANCE = {"named": 0.012, "random": 0.025}
LOD_MEAN_DISTANCE = {"named": 0.003, "random": 0.008}
LOD_VOLUME_RATIO = {"named": (0.99, 1.005), "random": (0.95, 1.01)}
# Volume of a posed body relative to its rest body (random poses, see the test).
POSED_VOLUME = 0.12
# Mirror symmetry (x -> -x) of the mean body: the MakeHuman mesh is symmetric to
# about 0.1 mm; joints come from a fitted regressor (sub-millimetre asymmetry).
MIRROR_MESH = 1e-3
MIRROR_JOINTS = 1e-3
# Plausible heights of the prior's bodies, metres: the shape space's population runs
# from 5-year-olds (about 1.1 m) to tall adults (the 99th percentile man is 1.94 m).
HEIGHT_RANGE = (1.0, 2.1)
# The population of the bake (``phenotype.POPULATION_AGE_BANDS``): 5-90 years, three
# of its eight age bands under 18, the same number of bodies per band and sex (each
# split has one body more in each of the first n % 16 cells, which are children's:
# 100 held-out bodies are 40 % children, 600 training bodies 37.5 %).
POPULATION_YEARS = (5.0, 90.0)
CHILD_SHARE = 3.0 / 8.0
SHARE_ATOL = 0.03
# T-pose: elbow, wrist and knuckle lie along ±x from the shoulder within this many
# degrees (the pose is solved on the template's skeleton; the mean body's elbow sits
# 1.3 cm off the line, 4.2 degrees).
TPOSE_DEG = 5.0
# A-pose: arms 45 degrees below horizontal, within this many degrees.
APOSE_DEG = 3.0
# The stored prior shapes: training scores are standardized (population std vs the
# PCA's sample std differ by 1/(2n)).
PRIOR_MEAN = 1e-3
PRIOR_STD = 1e-2
SEED = 20240615
#: Factorizations available here; the SuperLU reference always is.
SOLVERS = [s for s in scape._SOLVERS if s != "cholespy" or importlib.util.find_spec("cholespy")]
#: The compiled Eq. (1) against the numpy reference, through the solve (measured ~1e-15 m).
ATOL_EDGE_BACKENDS = 1e-9

SIGN = np.array([1.0, -1.0, -1.0])  # mirror x -> -x on Euler angles (a, b, c) and hinge axes


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _random_states(model: BodyModel, rng: np.random.Generator, n: int) -> BodyState:
    theta = model.limits.clip(rng.uniform(-0.8, 0.8, (n, N_POSE)))
    return BodyState(rng.normal(scale=0.5, size=(n, 3)), theta, rng.normal(size=(n, model.n_shape)))


def _mirror_joint_index() -> list[int]:
    return [
        JOINTS.index(j[:-1] + ("r" if j.endswith("_l") else "l")) if j[-2:] in ("_l", "_r") else i
        for i, j in enumerate(JOINTS)
    ]


def _mirror_theta(theta: np.ndarray) -> np.ndarray:
    out = np.empty_like(theta)
    swap = _mirror_joint_index()
    for j, sl in enumerate(JOINT_SLICES):
        src = theta[..., JOINT_SLICES[swap[j]]]
        out[..., sl] = src * SIGN if JOINT_DOFS[j] == 3 else src
    return out


# --- BodyState -------------------------------------------------------------------------------


def test_body_state_rest_and_vector_round_trip(rng):
    rest = BodyState.rest(DEFAULT_SHAPE_DOFS, batch=3)
    assert len(rest) == 3
    assert rest.vector().shape == (3, 3 + N_POSE + DEFAULT_SHAPE_DOFS)
    np.testing.assert_array_equal(rest.vector(), 0.0)
    y = rng.normal(size=(5, 3 + N_POSE + 4))
    state = BodyState.from_vector(y)
    assert state.nu.shape == (5, 4)
    np.testing.assert_array_equal(state.vector(), y)
    np.testing.assert_array_equal(BodyState.from_vector(y[0]).vector(), y[:1])


def test_body_state_broadcasts_a_batch_of_one(rng):
    state = BodyState(np.zeros(3), rng.normal(size=(4, N_POSE)), np.ones(9))
    assert state.tau.shape == (4, 3) and state.nu.shape == (4, 9)
    np.testing.assert_array_equal(state.nu, 1.0)
    sub = state[1:3]
    assert len(sub) == 2
    np.testing.assert_array_equal(sub.theta, state.theta[1:3])


@pytest.mark.parametrize(
    ("tau", "theta", "nu", "message"),
    [
        (np.zeros(2), np.zeros(37), np.zeros(9), "tau"),
        (np.zeros(3), np.zeros(36), np.zeros(9), "theta"),
        (np.zeros((2, 3)), np.zeros((3, 37)), np.zeros(9), "batch size"),
        (np.zeros(3), np.zeros(37), np.array([np.zeros(9), np.full(9, np.nan)]), "nu.*NaN"),
        (np.full(3, np.inf), np.zeros(37), np.zeros(9), "tau.*infinity"),
        (np.zeros(3), np.full(37, np.nan), np.zeros(9), "theta.*NaN"),
    ],
)
def test_body_state_validation(tau, theta, nu, message):
    with pytest.raises(ValueError, match=message):
        BodyState(tau, theta, nu)


def test_body_state_is_a_copy():
    theta = np.zeros((1, N_POSE))
    state = BodyState(np.zeros(3), theta, np.zeros(DEFAULT_SHAPE_DOFS))
    theta[0, 0] = 1.0
    assert state.theta[0, 0] == 0.0


# --- the file ------------------------------------------------------------------------------------


def test_model_contents(model):
    assert model.n_shape == DEFAULT_SHAPE_DOFS
    assert model.full.n_vertices == 13380
    assert model.faces().shape == (26756, 3)
    assert 2500 <= len(model.faces(lod=True)) <= 3500
    assert geometry.is_closed(model.faces(), model.full.n_vertices)
    assert geometry.is_closed(model.faces(lod=True), model.lod.n_vertices)
    for mesh in (model.full, model.lod):
        np.testing.assert_array_equal(np.unique(mesh.arrays.parts), np.arange(len(PARTS)))
    assert model.keypoint_names[: len(JOINTS)] == JOINTS
    assert {"knuckle_l", "knuckle_r"} <= set(model.keypoint_names)
    assert model.keypoint_regressor.shape == (len(model.keypoint_names), model.full.n_vertices)
    np.testing.assert_allclose(model.keypoint_regressor.sum(axis=1), 1.0, atol=1e-9)
    assert model.lod_map.shape == (model.lod.n_vertices, model.full.n_vertices)
    np.testing.assert_allclose(model.lod_map.sum(axis=1), 1.0, atol=1e-9)
    assert re.fullmatch(r"[0-9a-f]{64}", model.provenance["wheel_sha256"])
    assert model.n_shape_stored >= DEFAULT_SHAPE_DOFS


def test_hinge_axes_are_unit_and_mirrored(model):
    axes = model.hinge_axes
    np.testing.assert_allclose(np.linalg.norm(axes[list(HINGES)], axis=1), 1.0, atol=1e-9)
    for left in ("elbow_l", "knee_l"):
        right = left[:-1] + "r"
        np.testing.assert_allclose(
            axes[JOINTS.index(right)], SIGN * axes[JOINTS.index(left)], atol=1e-6
        )


def test_limits_contain_rest_tpose_and_apose_and_are_mirrored(model):
    lim = model.limits
    assert np.all(lim.lower < lim.upper)
    assert lim.contains(np.zeros(N_POSE))
    for name in ("tpose", "apose"):
        theta = model.poses[name]
        assert theta.shape == (N_POSE,)
        assert lim.contains(theta), name
        np.testing.assert_allclose(_mirror_theta(theta), theta, atol=1e-6)
    lo, hi = _mirror_theta(lim.lower), _mirror_theta(lim.upper)
    np.testing.assert_array_equal(np.minimum(lo, hi), lim.lower)
    np.testing.assert_array_equal(np.maximum(lo, hi), lim.upper)


def test_load_missing_file(tmp_path):
    path = tmp_path / "nope.npz"
    with pytest.raises(InputError, match=re.escape(str(path))):
        BodyModel.load(path)


def test_load_corrupt_file(tmp_path):
    path = tmp_path / "corrupt.npz"
    path.write_bytes(b"PK\x03\x04 this is not a zip archive")
    with pytest.raises(InputError, match=re.escape(str(path))):
        BodyModel.load(path)
    # A truncated copy of the real file.
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(DEFAULT_MODEL_PATH.read_bytes()[:100_000])
    with pytest.raises(InputError, match=re.escape(str(truncated))):
        BodyModel.load(truncated)


def test_load_rejects_other_npz_files(tmp_path):
    # A model file of another format version.
    path = tmp_path / "future.npz"
    np.savez(path, format=np.array(999), full_shape_basis=np.zeros((20, 1, 9)))
    with pytest.raises(InputError, match=re.escape(f"{path}: body model format 999")):
        BodyModel.load(path)
    # Some other .npz file altogether.
    other = tmp_path / "other.npz"
    np.savez(other, a=np.arange(3))
    with pytest.raises(InputError, match=re.escape(f"{other}: not a bodymetry body model")):
        BodyModel.load(other)


@pytest.mark.parametrize("n_shape", [0, -1, 10_000])
def test_load_n_shape_out_of_range(n_shape):
    with pytest.raises(InputError, match=rf"n_shape must be 1\.\.\d+, got {n_shape}") as info:
        BodyModel.load(n_shape=n_shape)
    assert str(DEFAULT_MODEL_PATH) in str(info.value)


def test_fewer_shape_components(model):
    small = BodyModel(model.data, n_shape=3)
    nu = np.array([[0.5, -1.0, 0.3]])
    padded = np.pad(nu, ((0, 0), (0, model.n_shape - 3)))
    np.testing.assert_allclose(
        small.canonical_vertices(nu), model.canonical_vertices(padded), atol=ATOL_EXACT
    )
    with pytest.raises(ValueError, match=r"nu: expected shape \(B, 3\)"):
        small.canonical_vertices(padded)
    with pytest.raises(ValueError, match="nu"):
        small.pose(BodyState(np.zeros(3), np.zeros(N_POSE), padded))


# --- the canonical body --------------------------------------------------------------------------


def test_canonical_body_stands_on_the_floor_over_the_origin(model, rng):
    nu = np.vstack([np.zeros(model.n_shape), rng.uniform(-2.0, 2.0, (6, model.n_shape))])
    v = model.canonical_vertices(nu)
    assert v.shape == (7, model.full.n_vertices, 3)
    np.testing.assert_allclose(v[..., 2].min(axis=1), 0.0, atol=1e-12)
    kp = model.rest_keypoints(nu)
    np.testing.assert_allclose(kp[:, 0, :2], 0.0, atol=1e-12)  # root above the origin
    height = v[..., 2].max(axis=1)
    assert np.all((HEIGHT_RANGE[0] < height) & (height < HEIGHT_RANGE[1])), height
    # The root (mid-hips) is at about half the height.
    ratio = kp[:, 0, 2] / height
    assert np.all((ratio > 0.4) & (ratio < 0.62)), ratio
    assert np.all(geometry.mesh_volume(v, model.faces()) > 0)


@pytest.mark.parametrize("i", range(DEFAULT_SHAPE_DOFS))
def test_heights_along_each_shape_axis(model, i):
    nu = np.zeros((2, model.n_shape))
    nu[:, i] = [-2.0, 2.0]
    height = model.canonical_vertices(nu)[..., 2].max(axis=1)
    assert np.all((HEIGHT_RANGE[0] < height) & (height < HEIGHT_RANGE[1])), height


def test_canonical_shape_is_linear_in_nu(model, rng):
    # Up to the floor/origin placement, which moves with the lowest vertex.
    nu = rng.normal(size=(2, model.n_shape))
    v = model.canonical_vertices(np.vstack([nu, nu.mean(axis=0)]))
    mid = 0.5 * (v[0] + v[1])
    np.testing.assert_allclose(mid - mid.mean(axis=0), v[2] - v[2].mean(axis=0), atol=1e-9)


def test_shape_from_vertices_round_trip(model, rng):
    nu = rng.normal(size=(4, model.n_shape))
    v = model.canonical_vertices(nu)
    np.testing.assert_allclose(model.shape_from_vertices(v), nu, atol=ATOL_NU)
    # Any translation, and a single mesh.
    np.testing.assert_allclose(
        model.shape_from_vertices(v[1] + np.array([1.0, -2.0, 0.5])), nu[1:2], atol=ATOL_NU
    )
    with pytest.raises(ValueError, match="vertices"):
        model.shape_from_vertices(v[:, :100])


def test_prior_shapes(model):
    train = model.prior_shapes()
    assert train.shape[1] == model.n_shape and len(train) >= 100
    # PCA scores in standard deviations of the training bodies, the origin at the
    # training adults' mean body (the population's mean is a child's shape away).
    adults = model.prior_ages() >= ADULT_YEARS
    np.testing.assert_allclose(train[adults].mean(axis=0), 0.0, atol=PRIOR_MEAN)
    np.testing.assert_allclose(train.std(axis=0), 1.0, atol=PRIOR_STD)
    assert train[~adults, 0].mean() < -1.0  # children: smaller along the first component
    heldout = model.prior_shapes("heldout")
    assert heldout.shape[1] == model.n_shape
    assert not np.allclose(heldout[: len(train)], train[: len(heldout)])
    height = model.canonical_vertices(heldout)[..., 2].max(axis=1)
    assert np.all((HEIGHT_RANGE[0] < height) & (height < HEIGHT_RANGE[1]))
    with pytest.raises(ValueError, match="split"):
        model.prior_shapes("test")


@pytest.mark.parametrize("split", ["train", "heldout"])
def test_prior_population_spans_children_and_adults(model, split):
    ages = model.prior_ages(split)
    female = model.data[f"{split}_is_female"]
    assert len(ages) == len(female) == len(model.prior_shapes(split))
    low, high = POPULATION_YEARS
    assert np.all((ages >= low) & (ages <= high))
    # Stratified: the youngest and oldest bands are reached, not left to chance.
    assert ages.min() < low + 1.0 and ages.max() > high - 3.0
    assert abs(np.mean(ages < 18.0) - CHILD_SHARE) <= SHARE_ATOL
    assert abs(np.mean(female) - 0.5) <= SHARE_ATOL
    with pytest.raises(ValueError, match="split"):
        model.prior_ages("test")
    # The provenance says how the population was drawn and where ν = 0 is.
    assert "sample_population" in model.provenance["population"]
    assert model.provenance["bake_config"]["age_bands"][0] == [low, 9.0]
    assert str(int(ADULT_YEARS)) in model.provenance["shape_origin"]
    # Children are shorter than adults in the space itself, not only in the labels.
    height = np.ptp(model.canonical_vertices(model.prior_shapes(split))[..., 2], axis=1)
    assert np.median(height[ages < 9.0]) < 1.35 < np.median(height[ages >= 18.0])


def test_mean_body_is_mirror_symmetric(model):
    v = model.canonical_vertices(np.zeros((1, model.n_shape)))[0]
    d, _ = cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))
    assert d.max() < MIRROR_MESH
    kp = model.rest_keypoints(np.zeros((1, model.n_shape)))[0, : len(JOINTS)]
    mirrored = kp[_mirror_joint_index()] * np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(mirrored, kp, atol=MIRROR_JOINTS)


# --- posing -----------------------------------------------------------------------------------


def test_rest_pose_is_the_translated_canonical_body(model, rng):
    nu = rng.normal(size=(3, model.n_shape))
    tau = rng.normal(size=(3, 3))
    body = model.pose(BodyState(tau, np.zeros((3, N_POSE)), nu))
    canon = model.canonical_vertices(nu)
    root = model.rest_keypoints(nu)[:, 0]
    # Q = I and R = I at θ = 0: the canonical body with its root joint moved to τ.
    np.testing.assert_allclose(body.vertices, canon - root[:, None] + tau[:, None], atol=ATOL_EXACT)
    np.testing.assert_allclose(
        body.keypoints, model.rest_keypoints(nu) - root[:, None] + tau[:, None], atol=ATOL_EXACT
    )
    np.testing.assert_allclose(body.joints[:, 0], tau, atol=1e-12)


def test_pose_outputs(model, rng):
    state = _random_states(model, rng, 3)
    body = model.pose(state)
    V, K = model.full.n_vertices, len(model.keypoint_names)
    assert body.vertices.shape == (3, V, 3)
    assert body.joints.shape == (3, len(JOINTS), 3)
    assert body.keypoints.shape == (3, K, 3)
    np.testing.assert_array_equal(body.faces, model.faces())
    np.testing.assert_array_equal(body.keypoints[:, : len(JOINTS)], body.joints)
    np.testing.assert_allclose(body.joints[:, 0], state.tau, atol=1e-12)
    # Joints are forward kinematics of the shaped rest skeleton.
    rest = model.rest_keypoints(state.nu)[:, : len(JOINTS)]
    _, joints = forward_kinematics(state.theta, state.tau, rest, model.hinge_axes)
    np.testing.assert_allclose(body.joints, joints, atol=1e-12)
    # Knuckles ride rigidly on the hands.
    for s in "lr":
        k, w = model.keypoint_names.index(f"knuckle_{s}"), JOINTS.index(f"wrist_{s}")
        np.testing.assert_allclose(
            np.linalg.norm(body.keypoints[:, k] - body.joints[:, w], axis=-1),
            np.linalg.norm(rest[:, w] - model.rest_keypoints(state.nu)[:, k], axis=-1),
            atol=1e-12,
        )


def test_posed_meshes_are_closed_with_plausible_volume(model, rng):
    state = _random_states(model, rng, 3)
    for lod in (False, True):
        body = model.pose(state, lod=lod)
        assert geometry.is_closed(body.faces, body.vertices.shape[1])
        volume = geometry.mesh_volume(body.vertices, body.faces)
        canon = geometry.mesh_volume(model.canonical_vertices(state.nu), model.faces())
        assert np.all(volume > 0)
        # Posing bends the body; it does not create or destroy much of it. The
        # second state (every DOF up to ±0.8 rad) folds hips and spine into the
        # body: measured over 30 random ν at its pose, 0.906-0.957 of the volume
        # with the adult-only shape space, 0.900-0.942 with the 5-90-year one
        # (over 40 random states: 0.92-1.08 with either).
        np.testing.assert_allclose(volume / canon, 1.0, atol=POSED_VOLUME)


def test_batched_pose_equals_single_poses(model, rng):
    state = _random_states(model, rng, 3)
    batch = model.pose(state)
    lod = model.pose(state, lod=True)
    for b in range(3):
        one = model.pose(state[b : b + 1])
        np.testing.assert_allclose(batch.vertices[b], one.vertices[0], atol=1e-9)
        np.testing.assert_allclose(batch.keypoints[b], one.keypoints[0], atol=1e-12)
        np.testing.assert_allclose(
            lod.vertices[b], model.pose(state[b : b + 1], lod=True).vertices[0], atol=1e-9
        )


@pytest.fixture(scope="module")
def models_by_solver(model) -> dict[str, BodyModel]:
    """The committed model built with each available factorization (everything,
    including the cached unposed bases, goes through that solver)."""
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        for solver in SOLVERS:
            mp.setattr(scape, "SOLVER", solver)
            out[solver] = BodyModel(model.data, model.n_shape)
    return out


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("lod", [False, True])
@pytest.mark.parametrize("B", [1, 17])
def test_solvers_pose_the_same_vertices(models_by_solver, rng, solver, lod, B):
    candidate, ref = models_by_solver[solver], models_by_solver["splu"]
    assert candidate.full.solver == candidate.lod.solver == solver
    states = _random_states(ref, rng, B)
    got = candidate.pose(states, lod=lod).vertices
    want = ref.pose(states, lod=lod).vertices
    assert got.shape == (B, ref._mesh(lod).n_vertices, 3)
    np.testing.assert_allclose(got, want, rtol=0, atol=ATOL_SOLVERS)


def test_translating_tau_translates_everything(model, rng):
    state = _random_states(model, rng, 2)
    shift = np.array([0.7, -1.3, 0.25])
    moved = BodyState(state.tau + shift, state.theta, state.nu)
    for lod in (False, True):
        a, b = model.pose(state, lod=lod), model.pose(moved, lod=lod)
        np.testing.assert_allclose(b.vertices, a.vertices + shift, atol=1e-9)
        np.testing.assert_allclose(b.keypoints, a.keypoints + shift, atol=1e-12)


def test_turning_about_the_vertical_turns_about_tau(model, rng):
    state = _random_states(model, rng, 2)
    theta = state.theta.copy()
    theta[:, :3] = 0.0
    phi = np.array([0.9, -2.5])
    turned = theta.copy()
    turned[:, 2] = phi
    a = model.pose(BodyState(state.tau, theta, state.nu))
    b = model.pose(BodyState(state.tau, turned, state.nu))
    Rz = euler_to_matrix(np.stack([np.zeros(2), np.zeros(2), phi], axis=1))
    tau = state.tau[:, None]
    expected = np.einsum("bij,bvj->bvi", Rz, a.vertices - tau) + tau
    np.testing.assert_allclose(b.vertices, expected, atol=ATOL_EXACT)
    # Heights do not change when turning about z.
    np.testing.assert_allclose(b.vertices[..., 2], a.vertices[..., 2], atol=ATOL_EXACT)


def test_any_root_rotation_is_rigid(model, rng):
    # The pose deformation Q depends on the other joints only, so the root's
    # rotation turns the whole body rigidly about τ.
    state = _random_states(model, rng, 2)
    theta = state.theta.copy()
    theta[:, :3] = 0.0
    turned = theta.copy()
    turned[:, :3] = rng.uniform(-0.7, 0.7, (2, 3))
    for lod in (False, True):
        a = model.pose(BodyState(state.tau, theta, state.nu), lod=lod)
        b = model.pose(BodyState(state.tau, turned, state.nu), lod=lod)
        R = euler_to_matrix(turned[:, :3])
        tau = state.tau[:, None]
        expected = np.einsum("bij,bvj->bvi", R, a.vertices - tau) + tau
        np.testing.assert_allclose(b.vertices, expected, atol=ATOL_EXACT)


def test_pose_deformation_switch(model, rng):
    rest = BodyState.rest(model.n_shape)
    np.testing.assert_allclose(
        model.pose(rest, pose_deformation=False).vertices,
        model.pose(rest).vertices,
        atol=ATOL_EXACT,
    )
    theta = np.zeros(N_POSE)
    theta[JOINT_SLICES[JOINTS.index("knee_l")]] = 1.2
    bent = BodyState(np.zeros(3), theta, np.zeros(model.n_shape))
    with_q = model.pose(bent).vertices[0]
    without = model.pose(bent, pose_deformation=False).vertices[0]
    moved = with_q - without
    # Q reshapes the bent knee (mm to cm); head and arms only move rigidly with the
    # pelvis anchor (by a few mm at most). (The least-squares solve spreads Q's
    # mismatch at the hip into the pelvis and lower torso: up to 1 cm there.)
    far = ["head"] + [f"{p}_{s}" for p in ("upper_arm", "lower_arm", "hand") for s in "lr"]
    upper = np.isin(model.vertex_parts, [PARTS.index(p) for p in far])
    shift = np.median(moved[upper], axis=0)
    assert np.linalg.norm(shift) < 0.005
    assert np.abs(moved[upper] - shift).max() < 1e-3
    leg = np.isin(model.vertex_parts, [PARTS.index(p) for p in ("thigh_l", "shin_l")])
    assert 0.005 < np.linalg.norm(moved[leg] - shift, axis=1).max() < 0.05


@pytest.mark.parametrize("kind", ["named", "random"])
def test_lod_follows_the_full_mesh(model, rng, kind):
    if kind == "named":
        theta = np.stack([np.zeros(N_POSE), model.poses["tpose"], model.poses["apose"]])
        state = BodyState(np.zeros(3), theta, np.zeros(model.n_shape))
    else:
        state = _random_states(model, rng, 3)
    full = model.pose(state)
    lod = model.pose(state, lod=True)
    np.testing.assert_array_equal(lod.joints, full.joints)
    np.testing.assert_array_equal(lod.keypoints, full.keypoints)
    ratio = geometry.mesh_volume(lod.vertices, lod.faces) / geometry.mesh_volume(
        full.vertices, full.faces
    )
    lo, hi = LOD_VOLUME_RATIO[kind]
    assert np.all((lo < ratio) & (ratio < hi)), ratio
    for b in range(len(state)):
        _, _, dist = closest_points(full.vertices[b], full.faces, lod.vertices[b])
        assert dist.max() < LOD_MAX_DISTANCE[kind], dist.max()
        assert dist.mean() < LOD_MEAN_DISTANCE[kind], dist.mean()


def test_mirrored_pose_mirrors_the_joints(model, rng):
    theta = model.limits.clip(rng.uniform(-0.8, 0.8, (2, N_POSE)))
    nu = np.zeros((2, model.n_shape))
    a = model.pose(BodyState(np.zeros(3), theta, nu))
    b = model.pose(BodyState(np.zeros(3), _mirror_theta(theta), nu))
    mirrored = a.joints[:, _mirror_joint_index()] * np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(b.joints, mirrored, atol=MIRROR_JOINTS)


# --- named poses and joint sign conventions (skeleton module docstring) ------------------------


def test_tpose_arms_are_straight_and_horizontal(model):
    body = model.pose(BodyState(np.zeros(3), model.poses["tpose"], np.zeros(model.n_shape)))
    kp = body.keypoints[0]
    names = model.keypoint_names
    for s, sx in (("l", 1.0), ("r", -1.0)):
        shoulder = kp[names.index(f"shoulder_{s}")]
        for j in ("elbow", "wrist", "knuckle"):
            d = kp[names.index(f"{j}_{s}")] - shoulder
            off = np.degrees(np.arccos(sx * d[0] / np.linalg.norm(d)))
            assert off < TPOSE_DEG, (s, j, off)


def test_apose_arms_are_45_degrees_down(model):
    body = model.pose(BodyState(np.zeros(3), model.poses["apose"], np.zeros(model.n_shape)))
    kp = body.keypoints[0]
    names = model.keypoint_names
    for s in "lr":
        d = kp[names.index(f"wrist_{s}")] - kp[names.index(f"shoulder_{s}")]
        below = np.degrees(np.arcsin(-d[2] / np.linalg.norm(d)))
        assert abs(below - 45.0) < APOSE_DEG, below


def _joint_moves(model: BodyModel, dof: str, value: float) -> np.ndarray:
    """Displacement (15, 3) of every joint of the mean body when one DOF is set."""
    rest = model.rest_keypoints(np.zeros((1, model.n_shape)))[:, : len(JOINTS)]
    theta = np.zeros((2, N_POSE))
    theta[1, dof_names().index(dof)] = value
    _, joints = forward_kinematics(theta, np.zeros(3), rest, model.hinge_axes)
    return joints[1] - joints[0]


def test_sign_conventions(model):
    J = JOINTS.index
    # Knee flexion (positive) takes the ankle backwards (+y; the body faces -y) and up.
    d = _joint_moves(model, "knee_l", 1.0)[J("ankle_l")]
    assert d[1] > 0.1 and d[2] > 0.05
    # Elbow flexion brings the wrist towards the shoulder.
    rest = model.rest_keypoints(np.zeros((1, model.n_shape)))[0]
    for s in "lr":
        d = _joint_moves(model, f"elbow_{s}", 1.0)[J(f"wrist_{s}")]
        before = np.linalg.norm(rest[J(f"wrist_{s}")] - rest[J(f"shoulder_{s}")])
        after = np.linalg.norm(rest[J(f"wrist_{s}")] + d - rest[J(f"shoulder_{s}")])
        assert after < before - 0.05
    # +x tips an upward segment forward (trunk flexion) and a downward one backward
    # (hip extension).
    assert _joint_moves(model, "spine.x", 0.5)[J("neck"), 1] < -0.1
    assert _joint_moves(model, "hip_l.x", 0.5)[J("knee_l"), 1] > 0.1
    # +y swings a downward segment towards -x: adduction left, abduction right.
    assert _joint_moves(model, "hip_l.y", 0.3)[J("knee_l"), 0] < -0.05
    assert _joint_moves(model, "hip_r.y", 0.3)[J("knee_r"), 0] < -0.05
    # +z turns the body to its left (counter-clockwise seen from above).
    d = _joint_moves(model, "root.z", 0.5)
    assert d[J("shoulder_l"), 1] > 0.05 and d[J("shoulder_r"), 1] < -0.05


@pytest.mark.skipif(not importlib.util.find_spec("numba"), reason="numba is not installed")
@pytest.mark.parametrize("lod", [True, False])
# A batch of 8 states runs the kernel's batch loop as 80 would (it has no
# size-dependent path), at a tenth of the numpy reference's cost on the full mesh.
@pytest.mark.parametrize("B", [1, 8])
@pytest.mark.parametrize("case", ["random", "rest pose", "mean shape", "no pose deformation"])
def test_numba_edges_pose_the_numpy_vertices(model, rng, monkeypatch, lod, B, case):
    """BodyModel.pose with the fused Eq. (1) kernel and with the numpy reference."""
    state = _random_states(model, rng, B)
    if case == "rest pose":
        state = BodyState(state.tau, np.zeros_like(state.theta), state.nu)
    elif case == "mean shape":
        state = BodyState(state.tau, state.theta, np.zeros_like(state.nu))
    deform = case != "no pose deformation"
    got = {}
    for backend in ("numpy", "numba"):
        monkeypatch.setattr(scape, "EDGES_BACKEND", backend)
        got[backend] = model.pose(state, lod=lod, pose_deformation=deform).vertices
    np.testing.assert_allclose(got["numba"], got["numpy"], rtol=0, atol=ATOL_EDGE_BACKENDS)


# --- skeleton anchors of the posed solve ---------------------------------------------------------

#: With both arms raised overhead (nothing else moving), the head may move this much
#: relative to the pelvis (metres). Without the anchors the least-squares solve let
#: the shoulders' deformations sink it 4 cm.
HEAD_STILL = 0.01


@pytest.mark.parametrize("lod", [False, True])
def test_anchors_are_inside_their_part_away_from_the_others(model, lod):
    idx, parts = model.skeleton_anchors(lod)
    mesh = model.lod if lod else model.full
    rest = mesh.arrays.template
    assert len(np.unique(idx)) == len(idx) and np.all(np.diff(parts) >= 0)
    assert set(parts.tolist()) == set(range(len(PARTS)))  # every part has some
    faces, face_parts = mesh.arrays.faces, mesh.arrays.parts
    for p in range(len(PARTS)):
        mine = idx[parts == p]
        other = np.unique(faces[face_parts != p])
        # Only triangles of their own part touch them, and no other part is near.
        assert not np.isin(mine, other).any()
        gap = cKDTree(rest[other]).query(rest[mine])[0]
        assert gap.min() >= ANCHOR_CLEARANCE - 1e-12


def test_raising_both_arms_leaves_the_head_where_it_was(model):
    theta = np.zeros(N_POSE)
    for side, sign in (("l", -1.0), ("r", -1.0)):
        theta[JOINT_SLICES[JOINTS.index(f"shoulder_{side}")].start] = sign * 2.4
    theta = model.limits.clip(theta)
    nu = np.zeros(model.n_shape)
    states = BodyState(np.zeros((2, 3)), np.stack([np.zeros(N_POSE), theta]), np.stack([nu, nu]))
    for lod in (False, True):
        v = model.pose(states, lod=lod).vertices
        parts = model.parts_of_vertices(lod)
        head, pelvis = parts == PARTS.index("head"), parts == PARTS.index("pelvis")
        rel = v[:, head].mean(axis=1) - v[:, pelvis].mean(axis=1)
        assert np.linalg.norm(rel[1] - rel[0]) < HEAD_STILL, rel[1] - rel[0]
        # and the hands went up, above the head
        hands = np.isin(parts, [PARTS.index("hand_l"), PARTS.index("hand_r")])
        assert v[1, hands, 2].mean() > v[1, head, 2].max()


@pytest.mark.parametrize("lod", [False, True])
def test_anchored_solve_of_consistent_targets_is_the_plain_solve(model, rng, lod):
    """Where the edges and the anchors agree (targets taken from the plain solve),
    the anchored least squares has that mesh as its exact optimum."""
    mesh = model.lod if lod else model.full
    model.skeleton_anchors(lod)  # sets the mesh's anchors
    state = _random_states(model, rng, 3)
    rest_kp = model.rest_keypoints(state.nu)  # any frame: the solve is translation-free
    rest = rest_kp[:, : len(JOINTS)]
    rot, _ = forward_kinematics(state.theta, state.tau, rest, model.hinge_axes)
    edges = mesh.edges(rot, local_rotations(state.theta, model.hinge_axes), state.nu)
    plain = mesh.solve(edges) + rng.normal(0.0, 1.0, (3, 1, 3))  # placed anywhere
    idx, _ = model.skeleton_anchors(lod)
    anchored = mesh.solve(edges, plain[:, idx])
    np.testing.assert_allclose(anchored, plain, atol=ATOL_SOLVERS)


def test_anchored_solve_checks_its_inputs(model):
    mesh = scape.ScapeMesh(model.lod.arrays, model.n_shape)
    edges = mesh.edges(None, None, None)
    with pytest.raises(ValueError, match="set_anchors first"):
        mesh.solve(edges, np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="weight > 0"):
        mesh.set_anchors(np.array([1, 2]), 0.0)
    with pytest.raises(ValueError, match="vertex indices"):
        mesh.set_anchors(np.array([1, mesh.n_vertices]), 0.3)
    mesh.set_anchors(np.array([1, 2, 3]), 0.3)
    with pytest.raises(ValueError, match="targets: expected shape"):
        mesh.solve(edges, np.zeros((1, 2, 3)))


@pytest.mark.parametrize("lod", [False, True])
def test_anchored_solve_numba_equals_numpy(model, rng, monkeypatch, lod):
    mesh = model.lod if lod else model.full
    idx, _ = model.skeleton_anchors(lod)
    state = _random_states(model, rng, 2)
    rest = np.zeros((2, len(JOINTS), 3))
    rot, _ = forward_kinematics(state.theta, state.tau, rest, model.hinge_axes)
    edges = mesh.edges(rot, local_rotations(state.theta, model.hinge_axes), state.nu)
    targets = rng.normal(0.0, 0.5, (2, len(idx), 3))
    got = mesh.solve(edges, targets)
    monkeypatch.setattr(scape, "_edge_kernels", lambda: None)
    np.testing.assert_allclose(mesh.solve(edges, targets), got, atol=ATOL_SOLVERS)


@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed")
@pytest.mark.parametrize("lod", [False, True])
def test_compiled_skeleton_poses_the_numpy_vertices(model, rng, monkeypatch, lod):
    """``skeleton.BACKEND`` numba (forward kinematics, shape sums, anchor targets in
    kernels) against numpy: the same bodies to rounding (measured ~3e-15 m)."""
    from bodymetry.estimation.body_model import skeleton

    theta = rng.uniform(-0.4, 0.4, (5, 37))
    state = BodyState(rng.normal(0, 0.3, (5, 3)), theta, rng.normal(0, 1, (5, model.n_shape)))
    got = {}
    for backend in ("numpy", "numba"):
        monkeypatch.setattr(skeleton, "BACKEND", backend)
        got[backend] = model.pose(state, lod=lod)
    np.testing.assert_allclose(got["numba"].vertices, got["numpy"].vertices, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["numba"].joints, got["numpy"].joints, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["numba"].keypoints, got["numpy"].keypoints, rtol=0, atol=1e-12)


@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed")
@pytest.mark.parametrize("lod", [False, True])
def test_batched_targets_of_repeated_shapes_are_each_states_own(model, rng, lod):
    """The compiled anchor targets reuse the rest positions of a state whose ν equals
    the previous state's (a finite-difference batch): every state's targets are the
    ones it gets alone, bit for bit."""
    state = _random_states(model, rng, 6)
    nu = state.nu.copy()
    nu[1] = nu[0]  # same shape, another pose
    nu[3] = nu[2]
    nu[4] = nu[3]
    nu[5, 2] += 1e-6  # one coefficient moved, as a finite-difference step
    state = BodyState(state.tau, state.theta, nu)
    rest_kp = model._linear(model._keypoint_basis, state.nu)
    rest_joints = rest_kp[:, : len(JOINTS)]
    _, rot, joints = posed_skeleton(state.theta, state.tau, rest_joints, model.hinge_axes)
    batch = model._anchor_targets(lod, state.nu, rest_joints, rot, joints)
    for b in range(len(state)):
        one = slice(b, b + 1)
        alone = model._anchor_targets(lod, state.nu[one], rest_joints[one], rot[one], joints[one])
        assert np.array_equal(batch[b], alone[0])
