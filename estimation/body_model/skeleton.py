"""The 15-part kinematic tree and the 37-DOF joint-angle vector θ (paper §2).

Parts (paper: torso, pelvis, head; upper arm, lower arm, hand; thigh, shin,
foot per side) each hang from one joint at their proximal end. The root joint
(pelvis) carries the global rotation; τ is the root joint's world position.

θ layout (radians), in part order::

    root 3 | spine 3 | neck 3 | shoulder_l 3, elbow_l 1, wrist_l 3 |
    shoulder_r 3, elbow_r 1, wrist_r 3 | hip_l 3, knee_l 1, ankle_l 3 |
    hip_r 3, knee_r 1, ankle_r 3                                  = 37

A 3-DOF joint's angles ``(a, b, c)`` give ``R = Rz(c) Ry(b) Rx(a)`` about the
axes of the canonical body frame (x to the subject's left, y backwards, z up;
the body faces -y). A hinge (elbow, knee) rotates about an axis stored in the
model, positive = flexion. θ = 0 is the rest pose of the model (MakeHuman's
A-pose with the elbows bent about 47°).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from bodymetry.estimation.backends import default_backend, module_kernels
from bodymetry.estimation.body_model.rotations import axis_rotation, euler_to_matrix

PARTS: tuple[str, ...] = (
    "pelvis",
    "torso",
    "head",
    "upper_arm_l",
    "lower_arm_l",
    "hand_l",
    "upper_arm_r",
    "lower_arm_r",
    "hand_r",
    "thigh_l",
    "shin_l",
    "foot_l",
    "thigh_r",
    "shin_r",
    "foot_r",
)
#: Parent part of each part (-1 for the root).
PART_PARENT: tuple[int, ...] = (-1, 0, 1, 1, 3, 4, 1, 6, 7, 0, 9, 10, 0, 12, 13)
#: The joint at each part's proximal end.
JOINTS: tuple[str, ...] = (
    "root",
    "spine",
    "neck",
    "shoulder_l",
    "elbow_l",
    "wrist_l",
    "shoulder_r",
    "elbow_r",
    "wrist_r",
    "hip_l",
    "knee_l",
    "ankle_l",
    "hip_r",
    "knee_r",
    "ankle_r",
)
JOINT_DOFS: tuple[int, ...] = (3, 3, 3, 3, 1, 3, 3, 1, 3, 3, 1, 3, 3, 1, 3)
N_PARTS = len(PARTS)
N_POSE = sum(JOINT_DOFS)  # 37
#: Slice of θ belonging to each joint.
JOINT_SLICES: tuple[slice, ...] = tuple(
    slice(int(s), int(s) + d)
    for s, d in zip(np.cumsum((0, *JOINT_DOFS[:-1])), JOINT_DOFS, strict=True)
)
#: Index in θ of the global heading (rotation of the root about the vertical z axis).
YAW: int = JOINT_SLICES[0].start + 2
HINGES: tuple[int, ...] = tuple(i for i, d in enumerate(JOINT_DOFS) if d == 1)

_BACKENDS = ("numba", "numpy")

#: How :func:`posed_skeleton` (the body model's pose) runs: ``"numba"`` (one
#: compiled pass, :mod:`~bodymetry.estimation.body_model.skeleton_kernels`) or
#: ``"numpy"`` (:func:`local_rotations` and :func:`forward_kinematics`, the
#: reference). From ``$BODYMETRY_SKELETON``; unset, numba when it is installed.
#: Read at every call, so tests and benchmarks may set it.
BACKEND: str = default_backend(
    "BODYMETRY_SKELETON", os.environ.get("BODYMETRY_SKELETON"), _BACKENDS, "numba"
)
#: The tree as arrays for the kernel: degrees of freedom, first θ entry, parent.
_DOFS = np.array(JOINT_DOFS, dtype=np.int64)
_STARTS = np.array([s.start for s in JOINT_SLICES], dtype=np.int64)
_PARENTS = np.array(PART_PARENT, dtype=np.int64)


def dof_names() -> tuple[str, ...]:
    """Names of the 37 entries of θ, e.g. ``"hip_l.x"`` or ``"knee_l"``."""
    names: list[str] = []
    for joint, dofs in zip(JOINTS, JOINT_DOFS, strict=True):
        names.extend([joint] if dofs == 1 else [f"{joint}.{ax}" for ax in "xyz"])
    return tuple(names)


def _default_limits() -> tuple[np.ndarray, np.ndarray]:
    # Anatomical ranges in this file's axis conventions. Signs: +x rotation tips
    # an upward segment forward (trunk flexion) and a downward one backward (hip
    # extension, knee flexion); +y rotation swings a downward segment towards -x,
    # which is adduction on the left side and abduction on the right.
    table = {
        "root": ((-1.3, -0.7, -np.pi), (0.7, 0.7, np.pi)),
        "spine": ((-0.4, -0.5, -0.6), (1.1, 0.5, 0.6)),
        "neck": ((-0.7, -0.6, -1.2), (0.8, 0.6, 1.2)),
        "shoulder_l": ((-2.8, -2.6, -1.6), (1.0, 0.9, 1.6)),
        "elbow_l": ((-0.6,), (2.5,)),
        "wrist_l": ((-1.0, -0.5, -1.4), (1.0, 0.5, 1.4)),
        "shoulder_r": ((-2.8, -0.9, -1.6), (1.0, 2.6, 1.6)),
        "elbow_r": ((-0.6,), (2.5,)),
        "wrist_r": ((-1.0, -0.5, -1.4), (1.0, 0.5, 1.4)),
        "hip_l": ((-2.0, -0.8, -0.7), (0.5, 0.5, 0.7)),
        "knee_l": ((-0.05,), (2.4,)),
        "ankle_l": ((-0.4, -0.35, -0.4), (0.8, 0.35, 0.4)),
        "hip_r": ((-2.0, -0.5, -0.7), (0.5, 0.8, 0.7)),
        "knee_r": ((-0.05,), (2.4,)),
        "ankle_r": ((-0.4, -0.35, -0.4), (0.8, 0.35, 0.4)),
    }
    lo = np.concatenate([np.asarray(table[j][0], dtype=float) for j in JOINTS])
    hi = np.concatenate([np.asarray(table[j][1], dtype=float) for j in JOINTS])
    return lo, hi


@dataclass(frozen=True)
class JointLimits:
    """Per-DOF bounds on θ.

    Attributes
    ----------
    lower, upper : (37,) float
        Radians; ``lower <= upper``.
    """

    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def default(cls) -> JointLimits:
        lo, hi = _default_limits()
        return cls(lo, hi)

    def clip(self, theta: np.ndarray) -> np.ndarray:
        """Clip ``theta`` (..., 37) into the limits."""
        return np.clip(theta, self.lower, self.upper)

    def contains(self, theta: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Whether each θ in ``theta`` (..., 37) lies inside the limits -> (...) bool."""
        return np.all((theta >= self.lower - tol) & (theta <= self.upper + tol), axis=-1)


def local_rotations(theta: np.ndarray, hinge_axes: np.ndarray) -> np.ndarray:
    """Rotation of each part relative to its parent.

    Parameters
    ----------
    theta : (B, 37) float
    hinge_axes : (15, 3) float
        Unit axis for hinge joints (rows of 3-DOF joints are ignored).

    Returns
    -------
    (B, 15, 3, 3) float
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    if theta.shape[-1] != N_POSE:
        raise ValueError(f"theta: expected shape (B, {N_POSE}), got {theta.shape}")
    out = np.empty((theta.shape[0], N_PARTS, 3, 3))
    for j, sl in enumerate(JOINT_SLICES):
        if JOINT_DOFS[j] == 3:
            out[:, j] = euler_to_matrix(theta[:, sl])
        else:
            out[:, j] = axis_rotation(hinge_axes[j], theta[:, sl.start])
    return out


def forward_kinematics(
    theta: np.ndarray, tau: np.ndarray, rest_joints: np.ndarray, hinge_axes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Global part rotations and world joint positions.

    A point ``p`` of part ``k`` in the rest pose goes to
    ``R[k] @ (p - rest_joints[k]) + joints[k]``.

    Parameters
    ----------
    theta : (B, 37) float
    tau : (B, 3) float
        World position of the root joint.
    rest_joints : (B, 15, 3) or (15, 3) float
        Joint positions of the body in its rest pose.
    hinge_axes : (15, 3) float

    Returns
    -------
    rotations : (B, 15, 3, 3) float
    joints : (B, 15, 3) float
    """
    return _chain(local_rotations(theta, hinge_axes), tau, rest_joints)


def _chain(
    local: np.ndarray, tau: np.ndarray, rest_joints: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`forward_kinematics` from the local rotations (B, 15, 3, 3): the tree
    walked from the root."""
    B = local.shape[0]
    tau = np.broadcast_to(np.asarray(tau, dtype=float), (B, 3))
    rest = np.broadcast_to(np.asarray(rest_joints, dtype=float), (B, N_PARTS, 3))
    rot = np.empty_like(local)
    joints = np.empty((B, N_PARTS, 3))
    for k, parent in enumerate(PART_PARENT):
        if parent < 0:
            rot[:, k] = local[:, k]
            joints[:, k] = tau
        else:
            rot[:, k] = rot[:, parent] @ local[:, k]
            offset = rest[:, k] - rest[:, parent]
            joints[:, k] = joints[:, parent] + np.einsum("bij,bj->bi", rot[:, parent], offset)
    return rot, joints


def skeleton_kernels() -> ModuleType | None:
    """The compiled kernel module when :data:`BACKEND` is ``"numba"``, else None
    (numba chosen by default but failing to import: the numpy path, logged).
    Also used by ``model.BodyModel`` for its shape-linear sums and anchors."""
    return module_kernels(
        globals(),
        "BACKEND",
        "bodymetry.estimation.body_model.skeleton_kernels",
        "BODYMETRY_SKELETON",
        "forward kinematics",
    )


def posed_skeleton(
    theta: np.ndarray, tau: np.ndarray, rest_joints: np.ndarray, hinge_axes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local rotations and forward kinematics of a batch in one call (what a pose needs).

    :func:`local_rotations` and :func:`forward_kinematics` together, the local
    rotations built once; with :data:`BACKEND` ``"numba"`` one
    compiled pass (the same expressions; equal to the numpy path to rounding,
    a few 1e-16).

    Parameters
    ----------
    theta : (B, 37) float
    tau : (B, 3) float
    rest_joints : (B, 15, 3) or (15, 3) float
    hinge_axes : (15, 3) float

    Returns
    -------
    local : (B, 15, 3, 3) float
        Rotation of each part relative to its parent.
    rotations : (B, 15, 3, 3) float
        Global rotation of each part.
    joints : (B, 15, 3) float
        World joint positions.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    if theta.shape[-1] != N_POSE:
        raise ValueError(f"theta: expected shape (B, {N_POSE}), got {theta.shape}")
    kernels = skeleton_kernels()
    if kernels is None:
        local = local_rotations(theta, hinge_axes)
        return (local, *_chain(local, tau, rest_joints))
    B = theta.shape[0]
    axes = np.asarray(hinge_axes, dtype=float)
    if axes.shape != (N_PARTS, 3):
        raise ValueError(f"hinge_axes: expected shape ({N_PARTS}, 3), got {axes.shape}")
    rest = np.asarray(rest_joints, dtype=float)
    if rest.shape[-2:] != (N_PARTS, 3) or rest.ndim not in (2, 3):
        raise ValueError(f"rest_joints: expected shape (B, {N_PARTS}, 3), got {rest.shape}")
    local = np.empty((B, N_PARTS, 3, 3))
    rot = np.empty((B, N_PARTS, 3, 3))
    joints = np.empty((B, N_PARTS, 3))
    kernels.posed_skeleton_kernel(
        np.ascontiguousarray(theta),
        np.ascontiguousarray(axes),
        _DOFS,
        _STARTS,
        _PARENTS,
        np.ascontiguousarray(np.broadcast_to(rest, (B, N_PARTS, 3))),
        np.ascontiguousarray(np.broadcast_to(np.asarray(tau, dtype=float), (B, 3))),
        local,
        rot,
        joints,
    )
    return local, rot, joints
