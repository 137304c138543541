"""Inverse kinematics from 3D landmarks: round trips through the body model's own
joints, invariance to where the subject stands, and what is refused."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyState
from bodymetry.estimation.body_model.skeleton import JOINTS, forward_kinematics
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.landmark_pose import LANDMARK_JOINTS, pose_from_landmarks

#: Joint positions are recovered to this (metres): the weak pull of the spine, neck, wrists
#: and ankles towards the neutral pose leaves up to ~9 mm on random poses (the landmarks
#: of a real subject scatter by ~30 mm).
TOL_JOINT = 0.01


@pytest.fixture(scope="module")
def body():
    return shared_body_model()


def _landmarks(body, theta, tau, nu) -> np.ndarray:
    """(33, 3) landmarks at the body's own joints (others NaN)."""
    rest = body.rest_keypoints(nu[None])[0, : len(JOINTS)]
    _, joints = forward_kinematics(theta[None], tau[None], rest, body.hinge_axes)
    out = np.full((33, 3), np.nan)
    for lm, name in LANDMARK_JOINTS.items():
        out[lm] = joints[0, JOINTS.index(name)]
    return out


def _joints(body, theta, tau, nu) -> np.ndarray:
    rest = body.rest_keypoints(nu[None])[0, : len(JOINTS)]
    return forward_kinematics(theta[None], tau[None], rest, body.hinge_axes)[1][0]


def _random_pose(body, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = body.limits.lower, body.limits.upper
    theta = np.clip(rng.normal(0, 0.35, 37), lo, hi)
    theta[:3] = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-np.pi, np.pi)]
    theta = np.clip(theta, lo, hi)
    tau = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), 0.95])
    return theta, tau


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_joints_are_recovered(body, seed):
    nu = np.zeros(body.n_shape)
    theta, tau = _random_pose(body, seed)
    landmarks = _landmarks(body, theta, tau, nu)
    pose = pose_from_landmarks(body, landmarks, nu)
    assert pose is not None and pose.n_landmarks == len(LANDMARK_JOINTS)
    got = _joints(body, pose.theta, pose.tau, nu)
    ids = [JOINTS.index(n) for n in LANDMARK_JOINTS.values()]
    err = np.linalg.norm(got[ids] - _joints(body, theta, tau, nu)[ids], axis=1)
    assert err.max() < TOL_JOINT, err
    assert pose.rms < TOL_JOINT
    assert body.limits.contains(pose.theta)


def test_moving_the_subject_moves_only_tau(body):
    nu = np.zeros(body.n_shape)
    theta, tau = _random_pose(body, 4)
    a = pose_from_landmarks(body, _landmarks(body, theta, tau, nu), nu)
    shift = np.array([1.5, -0.7, 0.0])
    b = pose_from_landmarks(body, _landmarks(body, theta, tau, nu) + shift, nu)
    np.testing.assert_allclose(b.tau - a.tau, shift, atol=2e-3)
    np.testing.assert_allclose(
        _joints(body, b.theta, b.tau, nu) - shift, _joints(body, a.theta, a.tau, nu), atol=3e-3
    )


def test_a_pose_state_round_trips_through_the_model(body):
    # The joints that pose() reports are the ones the solver matches.
    nu = body.prior_shapes("heldout")[0][: body.n_shape]
    theta, tau = _random_pose(body, 5)
    posed = body.pose(BodyState(tau=tau[None], theta=theta[None], nu=nu[None]))
    landmarks = np.full((33, 3), np.nan)
    for lm, name in LANDMARK_JOINTS.items():
        landmarks[lm] = posed.joints[0, JOINTS.index(name)]
    pose = pose_from_landmarks(body, landmarks, nu)
    assert pose.rms < TOL_JOINT


def test_missing_trunk_landmarks_give_no_pose(body):
    nu = np.zeros(body.n_shape)
    theta, tau = _random_pose(body, 6)
    landmarks = _landmarks(body, theta, tau, nu)
    landmarks[24] = np.nan  # right hip
    assert pose_from_landmarks(body, landmarks, nu) is None
    with pytest.raises(ValueError, match=r"\(33, 3\)"):
        pose_from_landmarks(body, landmarks[:20], nu)
