"""Tests for the pose-space bake helpers: LBS, training poses and the Q regression.

Synthetic data only: random skeletons, icospheres and "triangle soups" (every
triangle with its own three vertices, so any per-triangle deformation is realizable).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from bodymetry.estimation.body_model.bake import pose_space as ps
from bodymetry.estimation.body_model.bake.bake import _skinned_errors
from bodymetry.estimation.body_model.model import BodyState, shipped_model
from bodymetry.estimation.body_model.rotations import matrix_to_axis_angle
from bodymetry.estimation.body_model.scape import N_POSE_FEATURES
from bodymetry.estimation.body_model.skeleton import (
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    N_POSE,
    PART_PARENT,
    PARTS,
    JointLimits,
    forward_kinematics,
    local_rotations,
)
from bodymetry.estimation.body_model.skinning import lbs

# --------------------------------------------------------------------------------------
# Tolerances, all in one place (absolute; metres on unit-scale meshes, or entries of Q).
# --------------------------------------------------------------------------------------
ATOL = 1e-12
# Least-squares fits of exactly linear (or exactly zero) data with a negligible ridge
# (RIDGE_TINY; some ridge is needed: a part with one border joint repeats its features).
ATOL_FIT = 1e-9
RIDGE_TINY = 1e-12
SEED = 20240618


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _rest_joints(rng: np.random.Generator) -> np.ndarray:
    rest = np.zeros((N_PARTS, 3))
    for k, parent in enumerate(PART_PARENT):
        if parent >= 0:
            d = rng.normal(size=3)
            rest[k] = rest[parent] + rng.uniform(0.1, 0.4) * d / np.linalg.norm(d)
    return rest


def _hinge_axes() -> np.ndarray:
    axes = np.zeros((N_PARTS, 3))
    axes[[JOINTS.index(j) for j in ("elbow_l", "elbow_r", "knee_l", "knee_r")]] = [1.0, 0, 0]
    return axes


def _posed(rng: np.random.Generator, n: int, rest: np.ndarray):
    """Random poses: global part rotations, joints, local rotation vectors."""
    theta = rng.uniform(-1.0, 1.0, (n, N_POSE))
    hinge = _hinge_axes()
    R, joints = forward_kinematics(theta, rng.normal(size=(n, 3)), rest, hinge)
    rotvec = matrix_to_axis_angle(local_rotations(theta, hinge))
    return R, joints, rotvec


def _sphere() -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64)


def _soup(rng: np.random.Generator, T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T separate, well-shaped triangles: vertices (3T, 3), faces (T, 3), parts (T,)."""
    centres = rng.uniform(-1.0, 1.0, (T, 1, 3))
    corners = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0]])
    frames = np.linalg.qr(rng.normal(size=(T, 3, 3)))[0]
    v = (centres + np.einsum("tij,cj->tci", frames, corners)).reshape(-1, 3)
    faces = np.arange(3 * T).reshape(T, 3)
    parts = rng.integers(0, N_PARTS, T)
    return v, faces, parts


def _edges(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(..., T, 3, 2) triangle edges as columns."""
    tri = v[..., faces, :]
    return np.stack([tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]], axis=-1)


# --- LBS ------------------------------------------------------------------------------------------


def test_lbs_rest_pose_returns_the_rest_mesh(rng):
    v, _ = _sphere()
    rest = _rest_joints(rng)
    W = rng.dirichlet(np.ones(N_PARTS), size=len(v))
    R = np.broadcast_to(np.eye(3), (2, N_PARTS, 3, 3))
    out = lbs(v, W, rest, R, np.broadcast_to(rest, (2, N_PARTS, 3)))
    np.testing.assert_allclose(out, np.broadcast_to(v, out.shape), atol=ATOL)


def test_lbs_one_rigid_motion_for_all_parts_moves_the_mesh_rigidly(rng):
    v, _ = _sphere()
    rest = _rest_joints(rng)
    W = rng.dirichlet(np.ones(N_PARTS), size=len(v))
    R, joints, _ = _posed(rng, 3, rest)
    Rg = R[:, :1].repeat(N_PARTS, axis=1)  # every part turns like the root
    t = rng.normal(size=(3, 1, 3))
    joints = np.einsum("bij,kj->bki", Rg[:, 0], rest) + t
    out = lbs(v, W, rest, Rg, joints)
    np.testing.assert_allclose(out, np.einsum("bij,vj->bvi", Rg[:, 0], v) + t, atol=ATOL)


def test_lbs_one_hot_weights_move_each_part_rigidly(rng):
    v, _ = _sphere()
    rest = _rest_joints(rng)
    owner = rng.integers(0, N_PARTS, len(v))
    W = np.eye(N_PARTS)[owner]
    R, joints, _ = _posed(rng, 2, rest)
    out = lbs(v, W, rest, R, joints)
    expected = np.einsum("bvij,vj->bvi", R[:, owner], v - rest[owner]) + joints[:, owner]
    np.testing.assert_allclose(out, expected, atol=ATOL)


def test_lbs_blends_linearly(rng):
    v = rng.normal(size=(5, 3))
    rest = _rest_joints(rng)
    R, joints, _ = _posed(rng, 1, rest)
    a, b = PARTS.index("thigh_l"), PARTS.index("shin_l")
    W = np.zeros((5, N_PARTS))
    W[:, a], W[:, b] = 0.3, 0.7
    out = lbs(v, W, rest, R, joints)[0]
    ya = (v - rest[a]) @ R[0, a].T + joints[0, a]
    yb = (v - rest[b]) @ R[0, b].T + joints[0, b]
    np.testing.assert_allclose(out, 0.3 * ya + 0.7 * yb, atol=ATOL)


# --- training poses and joint pairs ----------------------------------------------------------


def test_sample_training_poses(rng):
    limits = JointLimits.default()
    theta = ps.sample_training_poses(np.random.default_rng(3), 200, limits, max_bend=0.6)
    again = ps.sample_training_poses(np.random.default_rng(3), 200, limits, max_bend=0.6)
    np.testing.assert_array_equal(theta, again)  # seeded
    assert theta.shape == (200, N_POSE)
    assert limits.contains(theta).all()
    assert np.abs(theta).max() <= 0.6
    np.testing.assert_array_equal(theta[:, JOINT_SLICES[0]], 0.0)  # no root rotation
    assert np.all(theta[:, 3:].std(axis=0) > 0.05)  # every other DOF varies


def test_adjacent_joints():
    J = JOINTS.index
    assert ps.adjacent_joints(PARTS.index("pelvis")) == [J("spine"), J("hip_l"), J("hip_r")]
    assert ps.adjacent_joints(PARTS.index("torso")) == [
        J("spine"),
        J("neck"),
        J("shoulder_l"),
        J("shoulder_r"),
    ]
    assert ps.adjacent_joints(PARTS.index("head")) == [J("neck")]
    assert ps.adjacent_joints(PARTS.index("shin_r")) == [J("knee_r"), J("ankle_r")]
    assert ps.adjacent_joints(PARTS.index("hand_l")) == [J("wrist_l")]


def test_nearest_joint_pairs(rng):
    v, f, parts = _soup(rng, 300)
    rest = _rest_joints(rng)
    pairs = ps.nearest_joint_pairs(v, f, parts, rest)
    assert pairs.shape == (300, 2)
    centroids = v[f].mean(axis=1)
    for t in range(300):
        cand = ps.adjacent_joints(parts[t])
        assert set(pairs[t]) <= set(cand)
        if len(cand) == 1:
            assert pairs[t, 0] == pairs[t, 1] == cand[0]
        else:
            d = np.linalg.norm(rest[cand] - centroids[t], axis=1)
            np.testing.assert_array_equal(pairs[t], np.asarray(cand)[np.argsort(d)[:2]])


def test_pose_features(rng):
    rotvec = rng.normal(size=(4, N_PARTS, 3))
    pairs = np.array([[1, 2], [9, 10], [5, 5]])
    F = ps.pose_features(rotvec, pairs)
    assert F.shape == (4, 3, N_POSE_FEATURES)
    np.testing.assert_array_equal(F[:, 1, :3], rotvec[:, 9])
    np.testing.assert_array_equal(F[:, 1, 3:], rotvec[:, 10])


# --- fitting Q ------------------------------------------------------------------------------------


def test_rigid_parts_need_no_pose_deformation(rng):
    # Every triangle follows its part rigidly (one-hot LBS): Q = I, coefficients 0.
    v, f, parts = _soup(rng, 200)
    rest = _rest_joints(rng)
    owner = np.repeat(parts, 3)  # each soup vertex belongs to its triangle's part
    R, joints, rotvec = _posed(rng, 30, rest)
    posed = lbs(v, np.eye(N_PARTS)[owner], rest, R, joints)
    pairs = ps.nearest_joint_pairs(v, f, parts, rest)
    coef = ps.fit_pose_coefficients(v, f, parts, pairs, posed, R, rotvec)
    assert coef.shape == (200, 9, N_POSE_FEATURES)
    np.testing.assert_allclose(coef, 0.0, atol=ATOL_FIT)


def test_fit_recovers_a_linear_pose_deformation(rng):
    """Posed triangles R_p Q_t Δx with Q_t = I + A_t f_t exactly linear in the features.

    D's third (normal) column is not linear in f, but it does not act on the edges:
    the fitted Q must reproduce the posed edges of new poses exactly (negligible ridge).
    """
    T = 120
    v, f, parts = _soup(rng, T)
    rest = _rest_joints(rng)
    pairs = ps.nearest_joint_pairs(v, f, parts, rest)
    A = 0.2 * rng.normal(size=(T, 9, N_POSE_FEATURES))
    x = _edges(v, f)  # (T, 3, 2)

    def pose_soup(n: int):
        R, _, rotvec = _posed(rng, n, rest)
        feats = ps.pose_features(rotvec, pairs)  # (n, T, 6)
        Q = np.eye(3) + np.einsum("tkf,ntf->ntk", A, feats).reshape(n, T, 3, 3)
        y = R[:, parts] @ Q @ x  # (n, T, 3, 2)
        origin = rng.normal(size=(n, T, 1, 3))
        tri = np.concatenate([origin, origin + np.swapaxes(y, -1, -2)], axis=2)  # (n, T, 3, 3)
        return tri.reshape(n, 3 * T, 3), R, rotvec, feats, Q

    posed, R, rotvec, _, _ = pose_soup(40)
    coef = ps.fit_pose_coefficients(v, f, parts, pairs, posed, R, rotvec, ridge=RIDGE_TINY)
    # Unseen poses are predicted exactly. (The coefficients themselves are not all
    # identifiable: a hinge's rotation vector stays on its axis, and a part with one
    # border joint repeats its features; the ridge sets the free directions to 0.)
    _, _, _, feats, Q = pose_soup(5)
    Qfit = np.eye(3) + np.einsum("tkf,ntf->ntk", coef, feats).reshape(5, T, 3, 3)
    np.testing.assert_allclose(Qfit @ x, Q @ x, atol=ATOL_FIT)


def test_ridge_shrinks_the_coefficients(rng):
    T = 40
    v, f, parts = _soup(rng, T)
    rest = _rest_joints(rng)
    pairs = ps.nearest_joint_pairs(v, f, parts, rest)
    R, joints, rotvec = _posed(rng, 20, rest)
    W = rng.dirichlet(np.ones(N_PARTS), size=len(v))  # blended LBS: non-rigid
    posed = lbs(v, W, rest, R, joints)
    loose = ps.fit_pose_coefficients(v, f, parts, pairs, posed, R, rotvec, ridge=RIDGE_TINY)
    tight = ps.fit_pose_coefficients(v, f, parts, pairs, posed, R, rotvec, ridge=10.0)
    assert np.linalg.norm(tight) < 0.5 * np.linalg.norm(loose)


def test_validation_reports_the_posed_volume_of_skinned_bodies_and_of_the_model():
    model = shipped_model()
    nu = np.zeros((1, model.n_shape))
    nu[0, 0] = 1.0
    body = model.canonical_vertices(nu)
    rest = BodyState.rest(model.n_shape, batch=1)
    joints = model.pose(BodyState(rest.tau, rest.theta, nu)).keypoints[:, : len(JOINTS)]
    weights = np.eye(N_PARTS)[model.parts_of_vertices()]
    bent = np.zeros((1, N_POSE))
    bent[0, JOINT_SLICES[JOINTS.index("knee_l")]] = 1.2
    poses = {"rest": np.zeros((1, N_POSE)), "bent": bent}
    errors, volume = _skinned_errors(model, body, joints, weights, poses, "dual_quaternion")
    # At rest both bodies are the canonical one: ratio 1 (round-off of the solve).
    assert volume["rest"]["skinned"]["mean"] == pytest.approx(1.0, abs=1e-9)
    assert volume["rest"]["model"]["mean"] == pytest.approx(1.0, abs=1e-3)
    assert errors["rest_anchored"]["mean_mm"] < 1.0
    # A bent knee: one-hot weights move the shin rigidly (the mesh overlaps itself a
    # little behind the knee), and the model stays within a few per cent.
    for which in ("skinned", "model"):
        assert volume["bent"][which]["mean"] == pytest.approx(1.0, abs=0.05)
    assert volume["skinning"] == "dual_quaternion"
