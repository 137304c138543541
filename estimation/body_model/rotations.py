"""Batched rotation helpers: Euler angles, axis-angle, and back.

Conventions: matrices act on column vectors (``x' = R @ x``). The Euler
triple ``(a, b, c)`` of a 3-DOF joint means ``R = Rz(c) @ Ry(b) @ Rx(a)``:
first about x, then y, then z, all about the parent's rest-frame axes.
"""

from __future__ import annotations

import numpy as np


def axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation about a unit axis (Rodrigues).

    Parameters
    ----------
    axis : (..., 3) float
        Unit rotation axes.
    angle : (...) float
        Angles in radians (broadcast against ``axis[..., 0]``).

    Returns
    -------
    (..., 3, 3) float
    """
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    shape = np.broadcast_shapes(axis.shape[:-1], angle.shape)
    axis = np.broadcast_to(axis, (*shape, 3))
    angle = np.broadcast_to(angle, shape)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    C = 1.0 - c
    out = np.empty((*shape, 3, 3))
    out[..., 0, 0] = c + x * x * C
    out[..., 0, 1] = x * y * C - z * s
    out[..., 0, 2] = x * z * C + y * s
    out[..., 1, 0] = y * x * C + z * s
    out[..., 1, 1] = c + y * y * C
    out[..., 1, 2] = y * z * C - x * s
    out[..., 2, 0] = z * x * C - y * s
    out[..., 2, 1] = z * y * C + x * s
    out[..., 2, 2] = c + z * z * C
    return out


def euler_to_matrix(angles: np.ndarray) -> np.ndarray:
    """``Rz(c) @ Ry(b) @ Rx(a)`` for Euler triples ``(a, b, c)``.

    Parameters
    ----------
    angles : (..., 3) float
        Radians.

    Returns
    -------
    (..., 3, 3) float
    """
    angles = np.asarray(angles, dtype=float)
    ca, cb, cc = np.cos(angles[..., 0]), np.cos(angles[..., 1]), np.cos(angles[..., 2])
    sa, sb, sc = np.sin(angles[..., 0]), np.sin(angles[..., 1]), np.sin(angles[..., 2])
    out = np.empty((*angles.shape[:-1], 3, 3))
    out[..., 0, 0] = cc * cb
    out[..., 0, 1] = cc * sb * sa - sc * ca
    out[..., 0, 2] = cc * sb * ca + sc * sa
    out[..., 1, 0] = sc * cb
    out[..., 1, 1] = sc * sb * sa + cc * ca
    out[..., 1, 2] = sc * sb * ca - cc * sa
    out[..., 2, 0] = -sb
    out[..., 2, 1] = cb * sa
    out[..., 2, 2] = cb * ca
    return out


def matrix_to_euler(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix`, with ``b`` in ``[-pi/2, pi/2]``.

    Parameters
    ----------
    R : (..., 3, 3) float
        Rotation matrices.

    Returns
    -------
    (..., 3) float
        ``(a, b, c)``. At gimbal lock (``|b| = pi/2``) ``c`` is set to 0.
    """
    R = np.asarray(R, dtype=float)
    b = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    cb = np.cos(b)
    locked = cb < 1e-9
    a = np.where(
        locked, np.arctan2(-R[..., 1, 2], R[..., 1, 1]), np.arctan2(R[..., 2, 1], R[..., 2, 2])
    )
    c = np.where(locked, 0.0, np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([a, b, c], axis=-1)


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis times angle, angle in ``[0, pi]``).

    Parameters
    ----------
    R : (..., 3, 3) float

    Returns
    -------
    (..., 3) float
    """
    R = np.asarray(R, dtype=float)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    w = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    # w = 2 sin(angle) axis. Take the angle from atan2, not arccos(cos): near pi,
    # arccos loses digits that angle / sin(angle) then amplifies (1e-3 rad at pi - 1e-6).
    sin = 0.5 * np.linalg.norm(w, axis=-1)
    angle = np.arctan2(sin, cos)
    small = sin < 1e-6
    # Near 0 the vector w/2 is the rotation vector to first order; near pi use the
    # symmetric part (the antisymmetric one vanishes, its direction is lost in round-off).
    scale = np.where(small, 0.5, angle / (2.0 * np.where(small, 1.0, sin)))
    out = w * scale[..., None]
    near_pi = (sin < 1e-3) & (cos < 0)
    if np.any(near_pi):
        # (R + R^T) / 2 - cos I = (1 - cos) axis axis^T: its largest column is along the axis.
        Rp = R[near_pi]
        B = 0.5 * (Rp + np.swapaxes(Rp, -1, -2)) - cos[near_pi][:, None, None] * np.eye(3)
        k = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        axis = B[np.arange(len(Rp)), :, k]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        # Orient it like w (which still carries the sign unless the angle is exactly pi).
        sign = np.where(np.einsum("ni,ni->n", axis, w[near_pi]) < 0, -1.0, 1.0)
        out[near_pi] = axis * (sign * angle[near_pi])[:, None]
    return out


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Inverse of :func:`matrix_to_axis_angle`.

    Parameters
    ----------
    rotvec : (..., 3) float

    Returns
    -------
    (..., 3, 3) float
    """
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1)
    safe = np.where(angle < 1e-12, 1.0, angle)
    axis = rotvec / safe[..., None]
    axis = np.where((angle < 1e-12)[..., None], np.array([1.0, 0.0, 0.0]), axis)
    return axis_rotation(axis, angle)


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smallest rotation taking direction ``u`` onto direction ``v``.

    Parameters
    ----------
    u, v : (3,) float
        Non-zero vectors (normalized here).

    Returns
    -------
    (3, 3) float
    """
    u = np.asarray(u, dtype=float) / np.linalg.norm(u)
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    axis = np.cross(u, v)
    s = np.linalg.norm(axis)
    c = float(np.dot(u, v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite directions: any axis perpendicular to u.
        perp = np.cross(u, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(u, [0.0, 1.0, 0.0])
        return axis_rotation(perp / np.linalg.norm(perp), np.pi)
    return axis_rotation(axis / s, np.arctan2(s, c))
