"""Skinning: rigid where one part rules, and no collapse where parts turn apart."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodymetry.estimation.body_model.geometry import mesh_volume
from bodymetry.estimation.body_model.skinning import dual_quaternion_skin, lbs, skin

#: Round-off of the quaternion conversions and the blend (metres, on unit-size inputs).
EXACT = 1e-9


def _cylinder(n_rings: int = 41, n_around: int = 32, length: float = 1.0, radius: float = 0.1):
    """A closed cylinder along x from -length/2 to +length/2: (V, 3) points and (F, 3) faces,
    outward-facing, and the ring index of each side vertex (-1 for the two cap centres)."""
    xs = np.linspace(-length / 2, length / 2, n_rings)
    phi = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    ring = np.stack(
        [np.repeat(xs, n_around), radius * np.tile(np.cos(phi), n_rings),
         radius * np.tile(np.sin(phi), n_rings)], axis=1)  # fmt: skip
    points = np.vstack([ring, [[-length / 2, 0, 0], [length / 2, 0, 0]]])
    faces = []
    for i in range(n_rings - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            c, d = a + n_around, b + n_around
            faces += [(a, b, d), (a, d, c)]
    first, last = len(ring), len(ring) + 1
    top = (n_rings - 1) * n_around
    for j in range(n_around):
        faces.append((first, (j + 1) % n_around, j))
        faces.append((last, top + j, top + (j + 1) % n_around))
    faces = np.array(faces)
    if mesh_volume(points, faces) < 0:
        faces = faces[:, ::-1]
    rings = np.r_[np.repeat(np.arange(n_rings), n_around), -1, -1]
    return points, faces, rings


def _two_part_weights(points: np.ndarray, blend: float = 0.2) -> np.ndarray:
    """(V, 2) weights: part 0 for x < -blend/2, part 1 for x > blend/2, linear between."""
    w1 = np.clip((points[:, 0] + blend / 2) / blend, 0.0, 1.0)
    return np.stack([1.0 - w1, w1], axis=1)


def _motion(rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Part 0 fixed, part 1 turned by ``rotation`` about the origin: the rest joints
    (2, 3), rotations (1, 2, 3, 3) and posed joints (1, 2, 3)."""
    return np.zeros((2, 3)), np.stack([np.eye(3), rotation])[None], np.zeros((1, 2, 3))


def test_one_part_per_point_moves_rigidly():
    rng = np.random.default_rng(5)
    rest = rng.normal(size=(200, 3))
    rest_joints = rng.normal(size=(4, 3))
    rot = Rotation.random(3 * 4, random_state=6).as_matrix().reshape(3, 4, 3, 3)
    joints = rng.normal(size=(3, 4, 3))
    part = rng.integers(0, 4, size=200)
    weights = np.eye(4)[part]
    out = dual_quaternion_skin(rest, weights, rest_joints, rot, joints)
    expected = np.einsum("bvij,vj->bvi", rot[:, part], rest - rest_joints[part]) + joints[:, part]
    np.testing.assert_allclose(out, expected, atol=EXACT)
    np.testing.assert_allclose(lbs(rest, weights, rest_joints, rot, joints), expected, atol=EXACT)


def test_parts_moving_together_move_every_point_rigidly():
    rng = np.random.default_rng(7)
    rest = rng.normal(size=(100, 3))
    weights = rng.dirichlet(np.ones(3), size=100)
    r = Rotation.from_rotvec([0.3, -2.9, 0.4]).as_matrix()  # near a half turn: the sign test
    rest_joints = rng.normal(size=(3, 3))
    rot = np.broadcast_to(r, (1, 3, 3, 3))
    shift = np.array([0.5, -1.0, 2.0])
    joints = (rest_joints @ r.T + shift)[None]
    out = dual_quaternion_skin(rest, weights, rest_joints, rot, joints)
    np.testing.assert_allclose(out[0], rest @ r.T + shift, atol=EXACT)


def test_a_twisted_limb_keeps_its_girth_where_linear_blending_pinches_it():
    # The candy wrapper: the far half of a limb twisted 170 degrees about its own axis.
    points, faces, rings = _cylinder()
    weights = _two_part_weights(points)
    motion = _motion(Rotation.from_rotvec([np.radians(170.0), 0, 0]).as_matrix())
    middle = rings == 20
    rest_volume = mesh_volume(points, faces)
    linear = lbs(points, weights, *motion)[0]
    dqs = dual_quaternion_skin(points, weights, *motion)[0]
    radius = lambda v: np.linalg.norm(v[middle][:, 1:], axis=1)  # noqa: E731
    # Linear blending of two rotations 170 degrees apart shrinks the middle ring to
    # cos(85 degrees) of its radius; rigid blending keeps every ring round.
    assert radius(linear).max() < 0.1 * 0.1
    np.testing.assert_allclose(radius(dqs), 0.1, rtol=1e-9)
    assert mesh_volume(linear, faces) < 0.9 * rest_volume
    # (the straight edges between rings turned ~20 degrees against each other cut
    # their chords: the polyhedron loses under 1 %, the smooth limb nothing)
    assert mesh_volume(dqs, faces) == pytest.approx(rest_volume, rel=0.01)


@pytest.mark.parametrize("degrees", [60.0, 120.0, 150.0])
def test_a_bent_limb_loses_less_volume_than_with_linear_blending(degrees):
    points, faces, _ = _cylinder()
    weights = _two_part_weights(points)
    motion = _motion(Rotation.from_rotvec([0, 0, np.radians(degrees)]).as_matrix())
    rest_volume = mesh_volume(points, faces)
    lbs_loss = rest_volume - mesh_volume(lbs(points, weights, *motion)[0], faces)
    dqs_change = mesh_volume(dual_quaternion_skin(points, weights, *motion)[0], faces) - rest_volume
    assert lbs_loss > 0.0
    assert abs(dqs_change) < 0.5 * lbs_loss


def test_skin_dispatches_by_name_and_rejects_others():
    points, _, _ = _cylinder(n_rings=5, n_around=8)
    weights = _two_part_weights(points)
    motion = _motion(Rotation.from_rotvec([0, 0, 1.0]).as_matrix())
    np.testing.assert_array_equal(
        skin("dual_quaternion", points, weights, *motion),
        dual_quaternion_skin(points, weights, *motion),
    )
    np.testing.assert_array_equal(
        skin("linear_blend", points, weights, *motion), lbs(points, weights, *motion)
    )
    with pytest.raises(ValueError, match="skinning: expected one of"):
        skin("rigid", points, weights, *motion)
