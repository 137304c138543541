"""Tests for estimation.body_model.rotations: Euler angles, axis-angle and back."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model import rotations as rot

# --------------------------------------------------------------------------------------
# Tolerances, all in one place (absolute, on matrix entries or radians).
# --------------------------------------------------------------------------------------
# Round trips and identities of float64 rotation matrices (entries are O(1)).
ATOL = 1e-12
# Euler round trip away from gimbal lock (|b| <= pi/2 - 1e-3): arcsin/arctan2 round-off.
ATOL_EULER = 1e-10
SEED = 20240612
N = 500


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    return rot.axis_rotation(_unit(rng, n), rng.uniform(0.0, np.pi, n))


def _assert_rotations(R: np.ndarray) -> None:
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), eye, atol=ATOL)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=ATOL)


# --- axis_rotation / euler_to_matrix -------------------------------------------------------


def test_axis_rotation_is_rodrigues(rng):
    axes = _unit(rng, N)
    angles = rng.uniform(-4.0, 4.0, N)
    R = rot.axis_rotation(axes, angles)
    _assert_rotations(R)
    # The axis is fixed, and a perpendicular vector turns by the angle (right hand rule).
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, axes), axes, atol=ATOL)
    perp = np.cross(axes, _unit(rng, N))
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    turned = np.einsum("nij,nj->ni", R, perp)
    np.testing.assert_allclose(np.einsum("ni,ni->n", perp, turned), np.cos(angles), atol=ATOL)
    np.testing.assert_allclose(
        np.einsum("ni,ni->n", np.cross(perp, turned), axes), np.sin(angles), atol=ATOL
    )


def test_axis_rotation_broadcasts_one_axis_over_angles():
    angles = np.linspace(-1.0, 1.0, 7)
    R = rot.axis_rotation(np.array([0.0, 0.0, 1.0]), angles)
    assert R.shape == (7, 3, 3)
    np.testing.assert_allclose(R[:, 0, 0], np.cos(angles), atol=ATOL)
    np.testing.assert_allclose(R[:, 1, 0], np.sin(angles), atol=ATOL)


def test_euler_is_rz_ry_rx(rng):
    angles = rng.uniform(-np.pi, np.pi, (N, 3))
    ex, ey, ez = np.eye(3)
    expected = (
        rot.axis_rotation(ez, angles[:, 2])
        @ rot.axis_rotation(ey, angles[:, 1])
        @ rot.axis_rotation(ex, angles[:, 0])
    )
    R = rot.euler_to_matrix(angles)
    np.testing.assert_allclose(R, expected, atol=ATOL)
    _assert_rotations(R)


def test_euler_batch_shapes():
    assert rot.euler_to_matrix(np.zeros(3)).shape == (3, 3)
    assert rot.euler_to_matrix(np.zeros((2, 4, 3))).shape == (2, 4, 3, 3)
    np.testing.assert_array_equal(rot.euler_to_matrix(np.zeros(3)), np.eye(3))


def test_euler_round_trip(rng):
    a = rng.uniform(-np.pi, np.pi, N)
    b = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, N)
    c = rng.uniform(-np.pi, np.pi, N)
    angles = np.stack([a, b, c], axis=1)
    back = rot.matrix_to_euler(rot.euler_to_matrix(angles))
    # Compare angles on the circle (pi and -pi are the same angle).
    np.testing.assert_allclose(np.angle(np.exp(1j * (back - angles))), 0.0, atol=ATOL_EULER)


def test_matrix_to_euler_inverts_any_rotation(rng):
    R = _random_rotations(rng, N)
    e = rot.matrix_to_euler(R)
    assert np.all(np.abs(e[:, 1]) <= np.pi / 2)
    np.testing.assert_allclose(rot.euler_to_matrix(e), R, atol=ATOL_EULER)


@pytest.mark.parametrize("b", [np.pi / 2, -np.pi / 2])
def test_matrix_to_euler_at_gimbal_lock(rng, b):
    angles = np.stack([rng.uniform(-3, 3, 50), np.full(50, b), rng.uniform(-3, 3, 50)], axis=1)
    R = rot.euler_to_matrix(angles)
    e = rot.matrix_to_euler(R)
    np.testing.assert_array_equal(e[:, 2], 0.0)  # documented: c = 0 at the lock
    np.testing.assert_allclose(rot.euler_to_matrix(e), R, atol=ATOL)


# --- axis-angle -------------------------------------------------------------------------------


#: Angles of the axis-angle round trip: near 0, generic, and approaching pi.
ROUND_TRIP_ANGLES = (
    *(0.0, 1e-14, 1e-9, 1e-6, 1e-3, 0.5, 2.0),
    *(np.pi - d for d in (0.1, 1e-3, 1e-5, 1e-6, 1e-7, 1e-9, 1e-12, 0.0)),
)


@pytest.mark.parametrize("angle", ROUND_TRIP_ANGLES)
def test_axis_angle_round_trip(rng, angle):
    axes = _unit(rng, N)
    rotvec = axes * angle
    R = rot.axis_angle_to_matrix(rotvec)
    _assert_rotations(R)
    back = rot.matrix_to_axis_angle(R)
    np.testing.assert_allclose(rot.axis_angle_to_matrix(back), R, atol=ATOL)
    # Angles in [0, pi]: the vector itself comes back (at exactly pi, up to its sign).
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), angle, atol=ATOL)
    if angle < np.pi:
        np.testing.assert_allclose(back, rotvec, atol=ATOL)
    else:
        np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", back, axes)), np.pi, atol=ATOL)


def test_matrix_to_axis_angle_of_random_rotations(rng):
    R = _random_rotations(rng, N).reshape(5, 100, 3, 3)  # any leading shape
    v = rot.matrix_to_axis_angle(R)
    assert v.shape == (5, 100, 3)
    assert np.all(np.linalg.norm(v, axis=-1) <= np.pi + ATOL)
    np.testing.assert_allclose(rot.axis_angle_to_matrix(v), R, atol=ATOL)


def test_axis_angle_of_identity_is_zero():
    np.testing.assert_array_equal(rot.matrix_to_axis_angle(np.eye(3)), np.zeros(3))
    np.testing.assert_array_equal(rot.axis_angle_to_matrix(np.zeros(3)), np.eye(3))


# --- rotation_between --------------------------------------------------------------------------


def test_rotation_between_maps_u_to_v(rng):
    for _ in range(200):
        u, v = rng.normal(size=(2, 3)) * rng.uniform(0.1, 10.0, (2, 1))
        R = rot.rotation_between(u, v)
        _assert_rotations(R)
        np.testing.assert_allclose(R @ (u / np.linalg.norm(u)), v / np.linalg.norm(v), atol=ATOL)
        # Smallest rotation: about u x v, by the angle between them.
        angle = np.arccos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1))
        np.testing.assert_allclose(np.linalg.norm(rot.matrix_to_axis_angle(R)), angle, atol=1e-9)


@pytest.mark.parametrize(
    "u", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [0.3, -0.2, 0.9], [-1.0, 0.0, 0.0]]
)
def test_rotation_between_parallel_and_opposite(u):
    u = np.asarray(u)
    np.testing.assert_allclose(rot.rotation_between(u, 3.0 * u), np.eye(3), atol=ATOL)
    R = rot.rotation_between(u, -u)
    _assert_rotations(R)
    n = u / np.linalg.norm(u)
    np.testing.assert_allclose(R @ n, -n, atol=ATOL)
    np.testing.assert_allclose(np.linalg.norm(rot.matrix_to_axis_angle(R)), np.pi, atol=ATOL)
