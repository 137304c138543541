"""Tests for estimation.body_model.skeleton: θ layout, forward kinematics, joint limits.

Synthetic skeletons only (random rest joints); the committed model's skeleton is
covered in test_body_model.py.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from bodymetry.estimation.body_model import skeleton as sk
from bodymetry.estimation.body_model.rotations import axis_rotation, euler_to_matrix

# --------------------------------------------------------------------------------------
# Tolerances, all in one place (absolute; metres for positions, entries for matrices).
# --------------------------------------------------------------------------------------
ATOL = 1e-12
#: The compiled posed_skeleton against the numpy reference: the same expressions, the
#: 3x3 products summed in order where numpy's may fuse multiply-adds (measured ~2e-16
#: on unit rotations and metre-sized joints).
ATOL_KERNEL = 1e-14
HAS_NUMBA = importlib.util.find_spec("numba") is not None
SEED = 20240613
B = 64


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _rest_joints(rng: np.random.Generator) -> np.ndarray:
    """A body-sized random skeleton: each joint 5-40 cm from its parent."""
    rest = np.zeros((sk.N_PARTS, 3))
    rest[0] = rng.normal(size=3)
    for k, parent in enumerate(sk.PART_PARENT):
        if parent >= 0:
            d = rng.normal(size=3)
            rest[k] = rest[parent] + rng.uniform(0.05, 0.4) * d / np.linalg.norm(d)
    return rest


def _hinge_axes(rng: np.random.Generator) -> np.ndarray:
    axes = np.zeros((sk.N_PARTS, 3))
    for j in sk.HINGES:
        a = rng.normal(size=3)
        axes[j] = a / np.linalg.norm(a)
    return axes


def _random_theta(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-np.pi, np.pi, (n, sk.N_POSE))


# --- layout -----------------------------------------------------------------------------------


def test_dof_names_are_37_unique():
    names = sk.dof_names()
    assert sk.N_POSE == 37
    assert len(names) == 37
    assert len(set(names)) == 37
    assert names[:3] == ("root.x", "root.y", "root.z")
    assert names[sk.JOINT_SLICES[sk.JOINTS.index("knee_l")].start] == "knee_l"


def test_joint_slices_tile_theta():
    covered = np.concatenate([np.arange(s.start, s.stop) for s in sk.JOINT_SLICES])
    np.testing.assert_array_equal(covered, np.arange(sk.N_POSE))
    assert [s.stop - s.start for s in sk.JOINT_SLICES] == list(sk.JOINT_DOFS)
    # Names follow the slices.
    names = sk.dof_names()
    for joint, sl in zip(sk.JOINTS, sk.JOINT_SLICES, strict=True):
        assert all(n.split(".")[0] == joint for n in names[sl])


def test_tree_is_topologically_ordered_and_mirrored():
    assert len(sk.PARTS) == len(sk.JOINTS) == len(sk.PART_PARENT) == sk.N_PARTS == 15
    assert sk.PART_PARENT[0] == -1
    assert all(0 <= p < k for k, p in enumerate(sk.PART_PARENT) if k > 0)
    assert {sk.JOINTS[j] for j in sk.HINGES} == {"elbow_l", "elbow_r", "knee_l", "knee_r"}
    # Left and right limbs have the same structure.
    for k, part in enumerate(sk.PARTS):
        if part.endswith("_l"):
            r = sk.PARTS.index(part[:-1] + "r")
            pl, pr = sk.PART_PARENT[k], sk.PART_PARENT[r]
            assert sk.PARTS[pl].replace("_l", "_r") == sk.PARTS[pr]
            assert sk.JOINT_DOFS[k] == sk.JOINT_DOFS[r]


# --- rotations and forward kinematics ---------------------------------------------------------


def test_local_rotations(rng):
    theta = _random_theta(rng, B)
    hinge = _hinge_axes(rng)
    local = sk.local_rotations(theta, hinge)
    assert local.shape == (B, 15, 3, 3)
    for j, sl in enumerate(sk.JOINT_SLICES):
        if sk.JOINT_DOFS[j] == 3:
            expected = euler_to_matrix(theta[:, sl])
        else:
            expected = axis_rotation(hinge[j], theta[:, sl.start])
        np.testing.assert_allclose(local[:, j], expected, atol=ATOL)


def test_local_rotations_rejects_wrong_length():
    with pytest.raises(ValueError, match="theta"):
        sk.local_rotations(np.zeros((2, 36)), np.zeros((15, 3)))


def test_forward_kinematics_rest_pose(rng):
    rest = _rest_joints(rng)
    tau = rng.normal(size=(B, 3))
    R, joints = sk.forward_kinematics(np.zeros((B, 37)), tau, rest, _hinge_axes(rng))
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), R.shape), atol=ATOL)
    np.testing.assert_allclose(joints, rest - rest[0] + tau[:, None, :], atol=ATOL)


def test_forward_kinematics_composes_along_the_chain(rng):
    rest = _rest_joints(rng)
    hinge = _hinge_axes(rng)
    theta = _random_theta(rng, B)
    R, joints = sk.forward_kinematics(theta, np.zeros(3), rest, hinge)
    local = sk.local_rotations(theta, hinge)
    for k, parent in enumerate(sk.PART_PARENT):
        if parent < 0:
            np.testing.assert_allclose(R[:, k], local[:, k], atol=ATOL)
            np.testing.assert_allclose(joints[:, k], 0.0, atol=ATOL)
        else:
            np.testing.assert_allclose(R[:, k], R[:, parent] @ local[:, k], atol=ATOL)
            # The child joint is a point of the parent part: p -> R (p - j_rest) + j.
            moved = np.einsum("bij,j->bi", R[:, parent], rest[k] - rest[parent])
            np.testing.assert_allclose(joints[:, k], joints[:, parent] + moved, atol=ATOL)


def test_global_rotations_are_rotations(rng):
    R, _ = sk.forward_kinematics(
        _random_theta(rng, B), np.zeros(3), _rest_joints(rng), _hinge_axes(rng)
    )
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-11
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-11)


def test_bone_lengths_are_preserved(rng):
    rest = _rest_joints(rng)
    _, joints = sk.forward_kinematics(
        _random_theta(rng, B), rng.normal(size=(B, 3)), rest, _hinge_axes(rng)
    )
    for k, parent in enumerate(sk.PART_PARENT):
        if parent >= 0:
            np.testing.assert_allclose(
                np.linalg.norm(joints[:, k] - joints[:, parent], axis=-1),
                np.linalg.norm(rest[k] - rest[parent]),
                atol=ATOL,
            )


def test_root_rotation_turns_the_body_rigidly_about_tau(rng):
    rest = _rest_joints(rng)
    hinge = _hinge_axes(rng)
    theta = _random_theta(rng, B)
    theta[:, sk.JOINT_SLICES[0]] = 0.0
    tau = rng.normal(size=(B, 3))
    R0, j0 = sk.forward_kinematics(theta, tau, rest, hinge)
    root = rng.uniform(-1.0, 1.0, (B, 3))
    turned = theta.copy()
    turned[:, sk.JOINT_SLICES[0]] = root
    R1, j1 = sk.forward_kinematics(turned, tau, rest, hinge)
    Rroot = euler_to_matrix(root)
    np.testing.assert_allclose(R1, Rroot[:, None] @ R0, atol=ATOL)
    expected = np.einsum("bij,bkj->bki", Rroot, j0 - tau[:, None]) + tau[:, None]
    np.testing.assert_allclose(j1, expected, atol=ATOL)


def test_forward_kinematics_batched_rest_joints(rng):
    rests = np.stack([_rest_joints(rng) for _ in range(4)])
    hinge = _hinge_axes(rng)
    theta = _random_theta(rng, 4)
    R, joints = sk.forward_kinematics(theta, np.zeros(3), rests, hinge)
    for b in range(4):
        Rb, jb = sk.forward_kinematics(theta[b], np.zeros(3), rests[b], hinge)
        np.testing.assert_allclose(R[b], Rb[0], atol=ATOL)
        np.testing.assert_allclose(joints[b], jb[0], atol=ATOL)


def test_a_joint_moves_only_its_subtree(rng):
    rest = _rest_joints(rng)
    hinge = _hinge_axes(rng)
    theta = _random_theta(rng, 1)
    _, j0 = sk.forward_kinematics(theta, np.zeros(3), rest, hinge)
    knee = sk.JOINTS.index("knee_l")
    bent = theta.copy()
    bent[0, sk.JOINT_SLICES[knee]] += 0.7
    _, j1 = sk.forward_kinematics(bent, np.zeros(3), rest, hinge)
    moved = np.linalg.norm(j1 - j0, axis=-1)[0] > 1e-9
    assert [sk.JOINTS[k] for k in np.flatnonzero(moved)] == ["ankle_l"]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("batched_rest", [False, True])
def test_posed_skeleton_is_local_rotations_and_forward_kinematics(
    rng, monkeypatch, backend, batched_rest
):
    """Both backends give the reference functions' rotations and joints (the numpy
    one bit for bit, the compiled one to rounding)."""
    if backend == "numba" and not HAS_NUMBA:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(sk, "BACKEND", backend)
    hinge = _hinge_axes(rng)
    theta = _random_theta(rng, B)
    rest = np.stack([_rest_joints(rng) for _ in range(B)]) if batched_rest else _rest_joints(rng)
    tau = rng.normal(size=(B, 3))
    local, R, joints = sk.posed_skeleton(theta, tau, rest, hinge)
    R_ref, joints_ref = sk.forward_kinematics(theta, tau, rest, hinge)
    local_ref = sk.local_rotations(theta, hinge)
    atol = 0.0 if backend == "numpy" else ATOL_KERNEL
    assert local.shape == R.shape == (B, 15, 3, 3) and joints.shape == (B, 15, 3)
    np.testing.assert_allclose(local, local_ref, rtol=0, atol=atol)
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=atol)
    np.testing.assert_allclose(joints, joints_ref, rtol=0, atol=atol)


@pytest.mark.skipif(not HAS_NUMBA, reason="numba is not installed")
def test_posed_skeleton_broadcasts_tau_and_checks_shapes(rng, monkeypatch):
    monkeypatch.setattr(sk, "BACKEND", "numba")
    hinge, rest = _hinge_axes(rng), _rest_joints(rng)
    theta = _random_theta(rng, 3)
    tau = rng.normal(size=3)
    _, R, joints = sk.posed_skeleton(theta, tau, rest, hinge)
    R_ref, joints_ref = sk.forward_kinematics(theta, tau, rest, hinge)
    np.testing.assert_allclose(joints, joints_ref, rtol=0, atol=ATOL_KERNEL)
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=ATOL_KERNEL)
    with pytest.raises(ValueError, match="theta"):
        sk.posed_skeleton(np.zeros((2, 36)), tau, rest, hinge)
    with pytest.raises(ValueError, match="hinge_axes"):
        sk.posed_skeleton(theta, tau, rest, hinge[:14])
    with pytest.raises(ValueError, match="rest_joints"):
        sk.posed_skeleton(theta, tau, rest[:, :2], hinge)


def test_skeleton_backend_choice(rng, monkeypatch):
    with pytest.raises(ValueError, match="BODYMETRY_SKELETON"):
        sk.default_backend("BODYMETRY_SKELETON", "cuda", sk._BACKENDS, "numba")
    monkeypatch.setattr(sk, "BACKEND", "cuda")
    with pytest.raises(ValueError, match=r"skeleton\.BACKEND"):
        sk.posed_skeleton(np.zeros((1, 37)), np.zeros(3), _rest_joints(rng), _hinge_axes(rng))


# --- limits -----------------------------------------------------------------------------------


def test_default_limits_are_ordered_and_mirrored():
    lim = sk.JointLimits.default()
    assert lim.lower.shape == lim.upper.shape == (37,)
    assert np.all(lim.lower < lim.upper)
    assert lim.contains(np.zeros(37))  # the rest pose is allowed
    # Mirroring x -> -x maps Euler angles (a, b, c) to (a, -b, -c) and swaps sides.
    for j, joint in enumerate(sk.JOINTS):
        if not joint.endswith("_l"):
            continue
        jr = sk.JOINTS.index(joint[:-1] + "r")
        sl, sr = sk.JOINT_SLICES[j], sk.JOINT_SLICES[jr]
        if sk.JOINT_DOFS[j] == 1:
            np.testing.assert_array_equal(lim.lower[sl], lim.lower[sr])
            np.testing.assert_array_equal(lim.upper[sl], lim.upper[sr])
        else:
            sign = np.array([1.0, -1.0, -1.0])
            lo, hi = lim.lower[sl] * sign, lim.upper[sl] * sign
            np.testing.assert_array_equal(np.minimum(lo, hi), lim.lower[sr])
            np.testing.assert_array_equal(np.maximum(lo, hi), lim.upper[sr])


def test_limits_clip_and_contains(rng):
    lim = sk.JointLimits.default()
    theta = rng.uniform(-4.0, 4.0, (200, 37))
    inside = lim.contains(theta)
    assert inside.shape == (200,)
    assert not inside.all()
    clipped = lim.clip(theta)
    assert lim.contains(clipped).all()
    # Clipping leaves in-range values alone and moves others to the nearest bound.
    keep = (theta >= lim.lower) & (theta <= lim.upper)
    np.testing.assert_array_equal(clipped[keep], theta[keep])
    np.testing.assert_array_equal(
        clipped[~keep], np.where(theta < lim.lower, lim.lower, lim.upper)[~keep]
    )
    np.testing.assert_array_equal(lim.clip(clipped), clipped)


def test_limits_contains_tolerance():
    lim = sk.JointLimits.default()
    theta = lim.upper.copy()
    assert lim.contains(theta)
    theta[5] += 1e-10
    assert lim.contains(theta)  # inside the default 1e-9 tolerance
    theta[5] += 1e-6
    assert not lim.contains(theta)
    assert lim.contains(theta, tol=1e-5)
    assert not lim.contains(lim.lower - 1e-6)


@pytest.mark.skipif(not HAS_NUMBA, reason="numba is not installed")
def test_linear_kernel_is_the_numpy_sum_bit_for_bit(rng):
    """``basis[0] + Σ ν_i basis[1 + i]`` summed per element in component order, as the
    body model's numpy path sums it: the same bits."""
    from bodymetry.estimation.body_model import skeleton_kernels as kernels

    basis = rng.normal(size=(10, 37, 3))
    nu = rng.normal(size=(6, 9))
    want = np.broadcast_to(basis[0], (6, 37, 3)).copy()
    for i in range(9):
        want += nu[:, i, None, None] * basis[1 + i]
    got = np.empty((6, 37 * 3))
    kernels.linear_kernel(basis.reshape(10, -1), nu, got)
    assert np.array_equal(got.reshape(6, 37, 3), want)


@pytest.mark.skipif(not HAS_NUMBA, reason="numba is not installed")
def test_translate_kernel_is_numpys_broadcast_add(rng):
    """The posed mesh's placement: each state's vertices moved by its shift, the same
    bits as numpy's ``vertices += shift[:, None, :]``."""
    from bodymetry.estimation.body_model import skeleton_kernels as kernels

    vertices = rng.normal(size=(5, 40, 3))
    shift = rng.normal(size=(5, 3))
    want = vertices + shift[:, None, :]
    kernels.translate_kernel(vertices, shift)
    assert np.array_equal(vertices, want)
