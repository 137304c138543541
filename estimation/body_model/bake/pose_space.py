"""Learn SCAPE's pose deformation Q from posed meshes of one body (bake time).

SCAPE fitted Q to 70 range scans of one person in known poses. We pose the
template by linear blend skinning (LBS) with the MakeHuman skin weights summed
per part, at random joint angles, and fit per triangle the linear map from the
two nearest joints' rotation vectors to the residual ``R_p^T D_t``, where ``D_t``
is the triangle's deformation gradient and ``R_p`` its part's rigid rotation.
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.scape import N_POSE_FEATURES, deformation_gradients
from bodymetry.estimation.body_model.skeleton import (
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    N_POSE,
    PART_PARENT,
    JointLimits,
)


def sample_training_poses(
    rng: np.random.Generator,
    n: int,
    limits: JointLimits,
    max_bend: float = 1.0,
    full_range: tuple[str, ...] = (),
) -> np.ndarray:
    """Random joint angles within the limits, each DOF within ``±max_bend``.

    The root rotation is zero: Q depends only on relative joint rotations.
    The joints named in ``full_range`` (e.g. the shoulders) are drawn over
    their whole limits instead; their draws come after the others', so the
    other joints' angles do not depend on ``full_range``.

    Returns
    -------
    (n, 37) float
    """
    lo = np.maximum(limits.lower, -max_bend)
    hi = np.minimum(limits.upper, max_bend)
    theta = rng.uniform(lo, hi, size=(n, N_POSE))
    theta[:, JOINT_SLICES[0]] = 0.0
    for name in full_range:
        s = JOINT_SLICES[JOINTS.index(name)]
        theta[:, s] = rng.uniform(limits.lower[s], limits.upper[s], size=(n, s.stop - s.start))
    return theta


def adjacent_joints(part: int) -> list[int]:
    """Joints on the border of ``part``: its own (unless root) and its children's."""
    own = [] if PART_PARENT[part] < 0 else [part]
    return own + [k for k, p in enumerate(PART_PARENT) if p == part]


def nearest_joint_pairs(
    vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray, joints: np.ndarray
) -> np.ndarray:
    """The two border joints of each triangle's part nearest to the triangle.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (T, 3) int
    parts : (T,) int
    joints : (15, 3) float
        Rest joint positions.

    Returns
    -------
    (T, 2) int
        Indices into ``skeleton.JOINTS``; a part with one border joint repeats it.
    """
    centroids = vertices[faces].mean(axis=1)
    out = np.empty((len(faces), 2), dtype=np.int64)
    for part in range(N_PARTS):
        sel = parts == part
        cand = np.asarray(adjacent_joints(part))
        if len(cand) == 1:
            out[sel] = cand[0]
            continue
        d = np.linalg.norm(centroids[sel, None, :] - joints[cand][None], axis=-1)
        order = np.argsort(d, axis=1)[:, :2]
        out[sel] = cand[order]
    return out


def pose_features(local_rotvecs: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Features ``[r_j1, r_j2]`` of every triangle.

    Parameters
    ----------
    local_rotvecs : (B, 15, 3) float
    pairs : (T, 2) int

    Returns
    -------
    (B, T, 6) float
    """
    return np.concatenate([local_rotvecs[:, pairs[:, 0]], local_rotvecs[:, pairs[:, 1]]], -1)


def fit_pose_coefficients(
    rest_vertices: np.ndarray,
    faces: np.ndarray,
    parts: np.ndarray,
    pairs: np.ndarray,
    posed_vertices: np.ndarray,
    part_rotations: np.ndarray,
    local_rotvecs: np.ndarray,
    ridge: float = 1e-3,
) -> np.ndarray:
    """Least-squares Q_t coefficients from posed meshes.

    Parameters
    ----------
    rest_vertices : (V, 3) float
        The body in its rest pose (θ = 0).
    faces : (T, 3) int
    parts : (T,) int
    pairs : (T, 2) int
        From :func:`nearest_joint_pairs`.
    posed_vertices : (K, V, 3) float
    part_rotations : (K, 15, 3, 3) float
    local_rotvecs : (K, 15, 3) float
        Rotation vectors of each joint relative to its parent.
    ridge : float
        Ridge penalty, relative to the number of poses.

    Returns
    -------
    (T, 9, 6) float
    """
    K = len(posed_vertices)
    D = deformation_gradients(rest_vertices, posed_vertices, faces)  # (K, T, 3, 3)
    R = part_rotations[:, parts]  # (K, T, 3, 3)
    Q = np.swapaxes(R, -1, -2) @ D
    Y = (Q - np.eye(3)).reshape(K, len(faces), 9)
    coef = np.zeros((len(faces), 9, N_POSE_FEATURES))
    penalty = ridge * K * np.eye(N_POSE_FEATURES)
    keys = pairs[:, 0] * len(JOINTS) + pairs[:, 1]
    for key in np.unique(keys):
        sel = np.flatnonzero(keys == key)
        j1, j2 = pairs[sel[0]]
        F = np.concatenate([local_rotvecs[:, j1], local_rotvecs[:, j2]], 1)
        G = F.T @ F + penalty
        rhs = F.T @ Y[:, sel].reshape(K, -1)  # (6, n_sel * 9)
        sol = np.linalg.solve(G, rhs).reshape(N_POSE_FEATURES, len(sel), 9)
        coef[sel] = sol.transpose(1, 2, 0)
    return coef
