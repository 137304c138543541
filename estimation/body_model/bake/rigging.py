"""From the MakeHuman rig to our 15-part skeleton (bake time only).

* Each MakeHuman bone is assigned to one of our parts (:data:`BONE_PART`).
* Per-vertex part weights are the summed skin weights of the part's bones;
  they drive the linear-blend skinning used to pose training meshes.
* Each triangle gets the part with the largest summed weight over its three
  vertices, then the torso/pelvis and head/torso borders are cut by planes
  through the spine and neck joints (skin weights leave ragged borders there)
  and small islands are merged into their neighbours.
* Joint centres come from the rig's bone heads (which average helper "joint
  cube" vertices); :func:`fit_keypoint_regressor` expresses them as sparse
  affine combinations of body vertices so they follow any body shape.
"""

from __future__ import annotations

import re

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bodymetry.estimation.body_model.skeleton import JOINTS, N_PARTS, PARTS

_HEAD_BONES = (
    r"(neck0[23]|head|jaw|eye\..|levator.*|oculi.*|orbicularis.*|oris.*|risorius.*"
    r"|special.*|temporalis.*|tongue.*)"
)
_BONE_RULES: tuple[tuple[str, str], ...] = (
    (r"root|pelvis\.[LR]|spine0[45]", "pelvis"),
    (r"spine0[123]|neck01|clavicle\.[LR]|breast\.[LR]|shoulder01\.[LR]", "torso"),
    (_HEAD_BONES, "head"),
    (r"upperarm0[12]\.(?P<s>[LR])", "upper_arm"),
    (r"lowerarm0[12]\.(?P<s>[LR])", "lower_arm"),
    (r"(wrist|metacarpal\d|finger\d-\d)\.(?P<s>[LR])", "hand"),
    (r"upperleg0[12]\.(?P<s>[LR])", "thigh"),
    (r"lowerleg0[12]\.(?P<s>[LR])", "shin"),
    (r"(foot|toe\d-\d)\.(?P<s>[LR])", "foot"),
)

#: Bone whose head is each joint's centre ("root" is the mid-point of the hips).
JOINT_BONE: dict[str, str] = {
    "spine": "spine03",
    "neck": "neck02",
    "shoulder_l": "upperarm01.L",
    "elbow_l": "lowerarm01.L",
    "wrist_l": "wrist.L",
    "shoulder_r": "upperarm01.R",
    "elbow_r": "lowerarm01.R",
    "wrist_r": "wrist.R",
    "hip_l": "upperleg01.L",
    "knee_l": "lowerleg01.L",
    "ankle_l": "foot.L",
    "hip_r": "upperleg01.R",
    "knee_r": "lowerleg01.R",
    "ankle_r": "foot.R",
}
#: Extra keypoints: the middle-finger knuckles (arm span) and the skull top.
EXTRA_KEYPOINT_BONE: dict[str, str] = {"knuckle_l": "finger3-1.L", "knuckle_r": "finger3-1.R"}
KEYPOINTS: tuple[str, ...] = (*JOINTS, *EXTRA_KEYPOINT_BONE)


def bone_part(bone: str) -> int:
    """Index into :data:`PARTS` of the part that MakeHuman bone ``bone`` belongs to."""
    for pattern, part in _BONE_RULES:
        m = re.fullmatch(pattern, bone)
        if m:
            side = m.groupdict().get("s")
            name = part if side is None else f"{part}_{side.lower()}"
            return PARTS.index(name)
    raise ValueError(f"MakeHuman bone {bone!r} has no part assignment")


def part_weights(
    skin_weights: dict[str, tuple[np.ndarray, np.ndarray]], n_vertices: int
) -> np.ndarray:
    """Per-vertex part weights from MakeHuman skin weights.

    Returns
    -------
    (V, 15) float
        Rows sum to 1 (vertices with no weight are given to the pelvis).
    """
    W = np.zeros((n_vertices, N_PARTS))
    for bone, (idx, w) in skin_weights.items():
        keep = idx < n_vertices
        np.add.at(W[:, bone_part(bone)], idx[keep], w[keep])
    total = W.sum(axis=1)
    W[total == 0, PARTS.index("pelvis")] = 1.0
    return W / W.sum(axis=1, keepdims=True)


def triangle_adjacency(faces: np.ndarray) -> sp.csr_matrix:
    """(F, F) boolean adjacency of triangles sharing an edge."""
    F = len(faces)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(F), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    e, o = edges[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    a, b = o[:-1][same], o[1:][same]
    adj = sp.coo_matrix((np.ones(len(a), bool), (a, b)), shape=(F, F))
    return (adj + adj.T).tocsr()


def segment_triangles(
    faces: np.ndarray,
    vertices: np.ndarray,
    weights: np.ndarray,
    cuts: list[tuple[int, int, np.ndarray, np.ndarray]],
    face_groups: np.ndarray | None = None,
) -> np.ndarray:
    """Part label per triangle.

    Parameters
    ----------
    faces : (F, 3) int
    vertices : (V, 3) float
        World coordinates of the template.
    weights : (V, 15) float
        Part weights (:func:`part_weights`).
    cuts : list of (lower_part, upper_part, point (3,), normal (3,))
        Triangles labelled ``lower_part`` or ``upper_part`` are re-labelled by the
        side of the plane through ``point`` with ``normal`` (pointing to ``upper_part``).
    face_groups : (F,) int, optional
        Triangles of one group (the two halves of a source quad) are cut as one,
        by the group's centroid, so cut borders do not zig-zag across quads.

    Returns
    -------
    (F,) int
    """
    labels = np.argmax(weights[faces].sum(axis=1), axis=1)
    centroids = vertices[faces].mean(axis=1)
    if face_groups is not None:
        counts = np.bincount(face_groups)[:, None]
        group_centroid = np.stack(
            [np.bincount(face_groups, weights=centroids[:, d]) for d in range(3)], axis=1
        )
        centroids = (group_centroid / np.maximum(counts, 1))[face_groups]
    for lower, upper, point, normal in cuts:
        sel = (labels == lower) | (labels == upper)
        above = (centroids - point) @ normal > 0
        labels[sel] = np.where(above[sel], upper, lower)
    return merge_islands(faces, labels)


def merge_islands(faces: np.ndarray, labels: np.ndarray, max_iter: int = 10) -> np.ndarray:
    """Give every connected piece of a part but its largest to the neighbouring part.

    Parameters
    ----------
    faces : (F, 3) int
    labels : (F,) int

    Returns
    -------
    (F,) int
        Each part is one edge-connected patch.
    """
    adj = triangle_adjacency(faces)
    labels = labels.copy()
    for _ in range(max_iter):
        changed = False
        for part in np.unique(labels):
            idx = np.flatnonzero(labels == part)
            sub = adj[idx][:, idx]
            n, comp = connected_components(sub, directed=False)
            if n <= 1:
                continue
            keep = np.argmax(np.bincount(comp))
            for c in range(n):
                if c == keep:
                    continue
                members = idx[comp == c]
                neigh = adj[members].indices
                neigh_labels = labels[neigh]
                neigh_labels = neigh_labels[neigh_labels != part]
                if len(neigh_labels):
                    labels[members] = np.bincount(neigh_labels).argmax()
                    changed = True
        if not changed:
            break
    return labels


def fit_keypoint_regressor(
    body_vertices: np.ndarray,
    keypoints: np.ndarray,
    template: np.ndarray,
    template_keypoints: np.ndarray,
    k: int = 48,
    ridge: float = 1e-6,
) -> sp.csr_matrix:
    """Sparse affine regressor from body vertices to keypoints, fitted over many bodies.

    Each keypoint is written as ``sum_i w_i v_i`` over its ``k`` nearest template
    vertices with ``sum_i w_i = 1`` (so it moves with translations exactly), the
    weights fitted by ridge-regularized least squares over the bodies.

    Parameters
    ----------
    body_vertices : (N, V, 3) float
        Bodies in full correspondence.
    keypoints : (N, K, 3) float
        Target keypoints of each body.
    template : (V, 3) float
        Where nearest vertices are looked up.
    template_keypoints : (K, 3) float
        The keypoints on ``template``.
    k : int
        Vertices per keypoint.
    ridge : float
        Regularization towards equal weights, relative to the data scale.

    Returns
    -------
    (K, V) scipy.sparse.csr_matrix
    """
    N, V, _ = body_vertices.shape
    K = keypoints.shape[1]
    tree = cKDTree(template)
    rows, cols, vals = [], [], []
    for j in range(K):
        _, nn = tree.query(template_keypoints[j], k=k)
        X = body_vertices[:, nn, :]  # (N, k, 3)
        y = keypoints[:, j, :]  # (N, 3)
        # Eliminate the sum-to-one constraint: w = w0 + Z c with w0 = 1/k.
        w0 = np.full(k, 1.0 / k)
        Z = np.vstack([np.eye(k - 1), -np.ones((1, k - 1))])  # (k, k-1), columns sum to 0
        A = np.einsum("nkd,kc->ndc", X, Z).reshape(N * 3, k - 1)
        b = (y - np.einsum("nkd,k->nd", X, w0)).reshape(N * 3)
        scale = np.trace(A.T @ A) / (k - 1)
        c = np.linalg.solve(A.T @ A + ridge * scale * np.eye(k - 1), A.T @ b)
        w = w0 + Z @ c
        rows.extend([j] * k)
        cols.extend(nn.tolist())
        vals.extend(w.tolist())
    return sp.csr_matrix((vals, (rows, cols)), shape=(K, V))
