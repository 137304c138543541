"""Tests for the rigging bake helpers (synthetic meshes; no MakeHuman assets)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components

from bodymetry.estimation.body_model.bake import rigging as rg
from bodymetry.estimation.body_model.skeleton import JOINTS, N_PARTS, PARTS

# --------------------------------------------------------------------------------------
# Tolerances, all in one place.
# --------------------------------------------------------------------------------------
# Sums of weights (affine regressor rows, part weights).
ATOL_SUM = 1e-12
# Keypoints that are exact affine combinations of vertices, recovered by the
# ridge-regularized fit (ridge 1e-6 relative to the data scale biases the weights
# by about that much; metres on unit-scale bodies).
ATOL_REGRESSOR = 1e-4
SEED = 20240617


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _sphere(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64)


def _components(faces: np.ndarray, labels: np.ndarray, part: int) -> int:
    idx = np.flatnonzero(labels == part)
    adj = rg.triangle_adjacency(faces)[idx][:, idx]
    return connected_components(adj, directed=False)[0]


# --- bone -> part ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bone", "part"),
    [
        ("root", "pelvis"),
        ("pelvis.L", "pelvis"),
        ("spine05", "pelvis"),
        ("spine04", "pelvis"),
        ("spine03", "torso"),
        ("spine01", "torso"),
        ("neck01", "torso"),
        ("clavicle.R", "torso"),
        ("breast.L", "torso"),
        ("shoulder01.L", "torso"),
        ("neck02", "head"),
        ("neck03", "head"),
        ("head", "head"),
        ("jaw", "head"),
        ("eye.L", "head"),
        ("orbicularis03.R", "head"),
        ("tongue02", "head"),
        ("upperarm01.L", "upper_arm_l"),
        ("upperarm02.R", "upper_arm_r"),
        ("lowerarm01.L", "lower_arm_l"),
        ("wrist.R", "hand_r"),
        ("metacarpal2.L", "hand_l"),
        ("finger3-1.R", "hand_r"),
        ("finger1-3.L", "hand_l"),
        ("upperleg01.L", "thigh_l"),
        ("upperleg02.R", "thigh_r"),
        ("lowerleg01.L", "shin_l"),
        ("foot.R", "foot_r"),
        ("toe1-2.L", "foot_l"),
    ],
)
def test_bone_part(bone, part):
    assert rg.bone_part(bone) == PARTS.index(part)


@pytest.mark.parametrize(
    "bone", ["spine06", "upperleg01.X", "upperleg01", "Root", "finger3-1", "tail", ""]
)
def test_bone_part_unknown(bone):
    with pytest.raises(ValueError, match=f"bone {bone!r}"):
        rg.bone_part(bone)


def test_joint_bones_belong_to_the_joints_part():
    # A part hangs from the joint at its proximal end: the bone whose head is the
    # joint centre is the part's first bone.
    assert set(rg.JOINT_BONE) == set(JOINTS) - {"root"}
    for joint, bone in rg.JOINT_BONE.items():
        assert rg.bone_part(bone) == JOINTS.index(joint), (joint, bone)
    for name, bone in rg.EXTRA_KEYPOINT_BONE.items():
        assert rg.bone_part(bone) == PARTS.index(f"hand_{name[-1]}")
    assert rg.KEYPOINTS[: len(JOINTS)] == JOINTS
    assert len(set(rg.KEYPOINTS)) == len(rg.KEYPOINTS)


# --- skin weights -------------------------------------------------------------------------------


def test_part_weights():
    skin = {
        "upperleg01.L": (np.array([0, 1, 2]), np.array([0.5, 1.0, 0.2])),
        "upperleg02.L": (np.array([0]), np.array([0.25])),  # same part: summed
        "lowerleg01.L": (np.array([0, 2, 99]), np.array([0.25, 0.2, 1.0])),  # 99: ignored
    }
    W = rg.part_weights(skin, n_vertices=4)
    assert W.shape == (4, N_PARTS)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=ATOL_SUM)
    thigh, shin, pelvis = (PARTS.index(p) for p in ("thigh_l", "shin_l", "pelvis"))
    np.testing.assert_allclose(W[0, [thigh, shin]], [0.75, 0.25], atol=ATOL_SUM)
    np.testing.assert_allclose(W[1, thigh], 1.0, atol=ATOL_SUM)
    np.testing.assert_allclose(W[2, [thigh, shin]], [0.5, 0.5], atol=ATOL_SUM)
    np.testing.assert_allclose(W[3, pelvis], 1.0, atol=ATOL_SUM)  # no weight: pelvis


def test_part_weights_rejects_unknown_bones():
    with pytest.raises(ValueError, match="nose_ring"):
        rg.part_weights({"nose_ring": (np.array([0]), np.array([1.0]))}, 1)


# --- segmentation ---------------------------------------------------------------------------------


def test_triangle_adjacency():
    tetra = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [0, 2, 3]])
    adj = rg.triangle_adjacency(tetra).toarray()
    np.testing.assert_array_equal(adj, ~np.eye(4, dtype=bool))
    _, f = _sphere(2)
    adj = rg.triangle_adjacency(f)
    assert (adj != adj.T).nnz == 0
    np.testing.assert_array_equal(np.asarray(adj.sum(axis=1)).ravel(), 3)  # closed mesh


def test_merge_islands_returns_stray_triangles(rng):
    v, f = _sphere()
    centroids = v[f].mean(axis=1)
    labels = np.where(centroids[:, 2] > 0, 1, 0)
    stray = rng.choice(np.flatnonzero(centroids[:, 2] < -0.5), size=3, replace=False)
    noisy = labels.copy()
    noisy[stray] = 1
    assert _components(f, noisy, 1) > 1
    merged = rg.merge_islands(f, noisy)
    np.testing.assert_array_equal(merged, labels)
    np.testing.assert_array_equal(noisy[stray], 1)  # the input is not modified


def test_merge_islands_keeps_connected_parts(rng):
    v, f = _sphere()
    centroids = v[f].mean(axis=1)
    labels = np.digitize(centroids[:, 2], [-0.5, 0.0, 0.5])  # four bands, each connected
    np.testing.assert_array_equal(rg.merge_islands(f, labels), labels)
    # An island of the top band inside the bottom band joins the bottom band.
    island = np.flatnonzero(centroids[:, 2] < -0.95)
    noisy = labels.copy()
    noisy[island] = 3
    merged = rg.merge_islands(f, noisy)
    np.testing.assert_array_equal(merged, labels)
    for part in range(4):
        assert _components(f, merged, part) == 1


def test_segment_triangles_by_weights_and_cut_plane():
    v, f = _sphere()
    W = np.zeros((len(v), N_PARTS))
    # x > 0: thigh_l by weight; the rest pelvis or torso, split by the plane z = 0.1.
    thigh, pelvis, torso = (PARTS.index(p) for p in ("thigh_l", "pelvis", "torso"))
    W[:, pelvis] = 1.0
    W[v[:, 0] > 0.3, thigh] = 2.0
    cuts = [(pelvis, torso, np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 1.0]))]
    labels = rg.segment_triangles(f, v, W, cuts)
    centroids = v[f].mean(axis=1)
    by_weight = np.argmax(W[f].sum(axis=1), axis=1)
    thighs = by_weight == thigh
    np.testing.assert_array_equal(labels[thighs], thigh)  # the cut leaves other parts alone
    above = centroids[:, 2] > 0.1
    np.testing.assert_array_equal(labels[~thighs & above], torso)
    np.testing.assert_array_equal(labels[~thighs & ~above], pelvis)


def _quad_tube(n_around: int = 24, n_up: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An open cylinder of quads, each split into two triangles; returns v, f, quad of each f."""
    a = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    z = np.linspace(0.0, 1.0, n_up + 1)
    v = np.stack(
        [np.tile(np.cos(a), n_up + 1), np.tile(np.sin(a), n_up + 1), np.repeat(z, n_around)], 1
    )
    faces, quads = [], []
    for i in range(n_up):
        for j in range(n_around):
            p0, p1 = i * n_around + j, i * n_around + (j + 1) % n_around
            p2, p3 = p1 + n_around, p0 + n_around
            faces += [[p0, p1, p2], [p0, p2, p3]]
            quads += [i * n_around + j] * 2
    return v, np.array(faces), np.array(quads)


def test_segment_triangles_cuts_face_groups_as_one():
    v, f, quads = _quad_tube()
    W = np.zeros((len(v), N_PARTS))
    W[:, 0] = 1.0
    cuts = [(0, 1, np.array([0.0, 0.0, 0.5]), np.array([0.3, 0.2, 1.0]))]
    grouped = rg.segment_triangles(f, v, W, cuts, face_groups=quads)
    np.testing.assert_array_equal(grouped[0::2], grouped[1::2])  # quads are never split
    assert set(np.unique(grouped)) == {0, 1}
    # Without the groups the tilted plane splits some quads along their diagonal.
    single = rg.segment_triangles(f, v, W, cuts)
    assert np.any(single[0::2] != single[1::2])
    # Each quad takes the side of its centre.
    centre = v[f].mean(axis=1).reshape(-1, 2, 3).mean(axis=1)
    above = (centre - [0.0, 0.0, 0.5]) @ np.array([0.3, 0.2, 1.0]) > 0
    np.testing.assert_array_equal(grouped[0::2], above.astype(int))


# --- keypoint regressor ------------------------------------------------------------------------


def test_fit_keypoint_regressor_recovers_affine_combinations(rng):
    V, N, K = 300, 60, 4
    template = rng.uniform(-1.0, 1.0, (V, 3))
    template_kp = rng.uniform(-0.5, 0.5, (K, 3))
    # True keypoints: affine combinations of each keypoint's 5 nearest template vertices.
    W = np.zeros((K, V))
    for j in range(K):
        nn = np.argsort(np.linalg.norm(template - template_kp[j], axis=1))[:5]
        w = rng.uniform(0.0, 1.0, 5)
        w[0] -= 0.3  # weights may be negative
        W[j, nn] = w / w.sum()
    bodies = template + 0.1 * rng.normal(size=(N, V, 3))
    keypoints = np.einsum("kv,nvd->nkd", W, bodies)
    reg = rg.fit_keypoint_regressor(bodies, keypoints, template, template_kp, k=24)
    assert isinstance(reg, sp.csr_matrix)
    assert reg.shape == (K, V)
    assert np.all(np.diff(reg.indptr) == 24)
    np.testing.assert_allclose(np.asarray(reg.sum(axis=1)).ravel(), 1.0, atol=ATOL_SUM)
    # Unseen bodies, shifted and scaled: the regressor follows them.
    test = 1.3 * (template + 0.1 * rng.normal(size=(5, V, 3))) + np.array([2.0, -1.0, 0.5])
    got = np.stack([reg @ b for b in test])
    np.testing.assert_allclose(got, np.einsum("kv,nvd->nkd", W, test), atol=ATOL_REGRESSOR)


def test_fit_keypoint_regressor_is_translation_exact(rng):
    V = 100
    template = rng.uniform(-1.0, 1.0, (V, 3))
    bodies = template + 0.05 * rng.normal(size=(20, V, 3))
    keypoints = bodies[:, :2].mean(axis=1, keepdims=True) + rng.normal(size=(20, 1, 3)) * 0.01
    reg = rg.fit_keypoint_regressor(bodies, keypoints, template, template[:1], k=10)
    shift = np.array([10.0, -3.0, 7.0])
    np.testing.assert_allclose(reg @ (template + shift), reg @ template + shift, atol=1e-9)
