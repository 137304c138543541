"""Skinning: how a rest surface follows the 15 parts' rigid motions.

Two blends of the parts' motions, both with skin weights summed per part:

* **linear blend skinning** (:func:`lbs`) averages the parts' rotation
  *matrices*. The average of two rotations far apart is no rotation at all but
  a projection that shrinks the skin towards the joint: with the arms overhead
  (the shoulders turned about 150 degrees from the rest pose) it hollowed the
  upper chest and back of the studio's heaviest woman by up to 8 cm and took
  3 L of her 104 L, a silhouette no person shows.
* **dual quaternion skinning** (:func:`dual_quaternion_skin`; Kavan, Collins,
  Žára & O'Sullivan, "Geometric skinning with approximate dual quaternion
  blending", ACM TOG 2008) blends the parts' rigid motions as unit dual
  quaternions instead, so every skin point moves rigidly (rotation and
  translation, no scaling): the same body keeps its volume within half a litre
  in every frame of the same motion. It is linear blend skinning's usual
  replacement in animation rigs.

The bake poses the template with one of them to learn SCAPE's pose deformation
Q (:mod:`.bake.pose_space`), and the studio poses its independent subjects with
one of them (``studio/independent.py``). Our model's own posing is neither
(per-triangle rotations, Q, least-squares stitching).

Quaternions are ``(w, x, y, z)`` here.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["SKINNINGS", "dual_quaternion_skin", "lbs", "skin"]

#: The skinnings by name: ``dual_quaternion`` (:func:`dual_quaternion_skin`) and
#: ``linear_blend`` (:func:`lbs`).
SKINNINGS = ("dual_quaternion", "linear_blend")


def lbs(
    rest_vertices: np.ndarray,
    weights: np.ndarray,
    rest_joints: np.ndarray,
    rotations: np.ndarray,
    joints: np.ndarray,
) -> np.ndarray:
    """Linear blend skinning over the 15 parts.

    Parameters
    ----------
    rest_vertices : (V, 3) float
    weights : (V, 15) float
        Rows sum to 1.
    rest_joints : (15, 3) float
    rotations : (B, 15, 3, 3) float
        Global part rotations.
    joints : (B, 15, 3) float
        Posed joint positions.

    Returns
    -------
    (B, V, 3) float
    """
    # Each part's affine map x -> R (x - j_rest) + j.
    t = joints - np.einsum("bkij,kj->bki", rotations, rest_joints)  # (B, 15, 3)
    blended_R = np.einsum("vk,bkij->bvij", weights, rotations)
    blended_t = np.einsum("vk,bki->bvi", weights, t)
    return np.einsum("bvij,vj->bvi", blended_R, rest_vertices) + blended_t


def _quaternions(rotations: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices as (..., 4) unit quaternions (w, x, y, z)."""
    shape = rotations.shape[:-2]
    xyzw = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat()
    return xyzw[:, [3, 0, 1, 2]].reshape(*shape, 4)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions (w, x, y, z)."""
    w1, v1 = a[..., :1], a[..., 1:]
    w2, v2 = b[..., :1], b[..., 1:]
    w = w1 * w2 - np.sum(v1 * v2, axis=-1, keepdims=True)
    v = w1 * v2 + w2 * v1 + np.cross(v1, v2)
    return np.concatenate([w, v], axis=-1)


def dual_quaternion_skin(
    rest_vertices: np.ndarray,
    weights: np.ndarray,
    rest_joints: np.ndarray,
    rotations: np.ndarray,
    joints: np.ndarray,
) -> np.ndarray:
    """Dual quaternion skinning: each point moved by the blend of the parts' rigid motions.

    The arguments are those of the bake's linear blend skinning
    (:func:`lbs`). Each part's
    motion ``x -> R (x - j_rest) + j``, i.e. ``x -> R x + t``, becomes a unit dual quaternion
    ``q + ε ½ (0, t) q``; a point blends its parts' dual quaternions with its skin
    weights, each flipped to the hemisphere of the point's heaviest part (``q``
    and ``-q`` are the same rotation, and a blend of opposite signs would cancel),
    normalizes the blend by its real part's norm and applies the rigid motion it
    stands for. A point with one part moves exactly as that part does.

    Parameters
    ----------
    rest_vertices : (V, 3) float
    weights : (V, K) float
        Skin weights, rows summing to 1.
    rest_joints : (K, 3) float
        Each part's pivot in the rest pose.
    rotations : (B, K, 3, 3) float
        Each part's global rotation.
    joints : (B, K, 3) float
        Each part's posed pivot.

    Returns
    -------
    (B, V, 3) float
    """
    weights = np.asarray(weights, dtype=float)
    rest = np.asarray(rest_vertices, dtype=float)
    rotations = np.asarray(rotations, dtype=float)
    real = _quaternions(rotations)  # (B, K, 4)
    t = np.asarray(joints, dtype=float) - np.einsum("bkij,kj->bki", rotations, rest_joints)
    dual = 0.5 * _qmul(np.concatenate([np.zeros(t.shape[:-1] + (1,)), t], axis=-1), real)
    heaviest = np.argmax(weights, axis=1)  # (V,)
    out = np.empty((len(real), len(rest), 3))
    for b, (qr, qd) in enumerate(zip(real, dual, strict=True)):
        # Antipodality: the sign of each part's quaternion as seen from the point's
        # heaviest part (V, K).
        sign = np.where(qr[heaviest] @ qr.T < 0.0, -1.0, 1.0)
        signed = weights * sign
        r, d = signed @ qr, signed @ qd  # (V, 4) each
        norm = np.linalg.norm(r, axis=1, keepdims=True)
        r, d = r / norm, d / norm
        w, v = r[:, :1], r[:, 1:]
        d0, dv = d[:, :1], d[:, 1:]
        rotated = rest + 2.0 * np.cross(v, np.cross(v, rest) + w * rest)
        out[b] = rotated + 2.0 * (w * dv - d0 * v + np.cross(v, dv))
    return out


def skin(
    kind: str,
    rest_vertices: np.ndarray,
    weights: np.ndarray,
    rest_joints: np.ndarray,
    rotations: np.ndarray,
    joints: np.ndarray,
) -> np.ndarray:
    """Pose ``rest_vertices`` by the skinning named ``kind`` (one of :data:`SKINNINGS`).

    The other arguments and the result are those of :func:`lbs`.

    Raises
    ------
    ValueError
        ``kind`` is not one of :data:`SKINNINGS`.
    """
    if kind not in SKINNINGS:
        raise ValueError(f"skinning: expected one of {SKINNINGS}, got {kind!r}")
    blend = dual_quaternion_skin if kind == "dual_quaternion" else lbs
    return blend(rest_vertices, weights, rest_joints, rotations, joints)
