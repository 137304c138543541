"""What motion generation knows about the body: rest pose, left-right mirror, limits.

:class:`RestPoseInfo` holds a subject's rest joint centres, hinge axes, foot contact
points and named poses; :meth:`RestPoseInfo.default` is the committed model's mean
body without loading the model. :func:`mirror_pose` and :func:`symmetric` swap or
copy sides of θ (37,); :func:`default_limits` are the committed model's joint limits.
``DOF_INDEX`` maps DOF names (``skeleton.dof_names()``) to θ indices.

The mirror tables are derived from ``skeleton``; the mean-body numbers are copied
from the baked model (see the comment above ``_DEFAULT_JOINTS`` for why).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from bodymetry.estimation.body_model.skeleton import (
    JOINT_DOFS,
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    N_POSE,
    JointLimits,
    dof_names,
)

if TYPE_CHECKING:  # pragma: no cover - typing only; keeps this module numpy-only at run time
    from bodymetry.estimation.body_model.model import BodyModel

#: DOF name (``skeleton.dof_names()``, e.g. "elbow_l", "spine.x") -> index into θ (37,).
DOF_INDEX: dict[str, int] = {name: i for i, name in enumerate(dof_names())}


@dataclass(frozen=True)
class RestPoseInfo:
    """What motion generation needs to know about the body, scaled to one subject.

    Attributes
    ----------
    joints : (15, 3) float
        Rest-pose (θ = 0) joint centres in the canonical frame: root above the origin,
        lowest vertex on z = 0 (``BodyModel.rest_keypoints``).
    hinge_axes : (15, 3) float
        Elbow and knee axes (``BodyModel.hinge_axes``).
    soles : (2, 4, 3) float
        Floor-contact points of the left and right foot in the rest pose (heel, toe,
        inner and outer edge of the ball of the foot, on z = 0).
    tpose, apose : (37,) float
        The model's named poses (``BodyModel.poses``).
    """

    joints: np.ndarray
    hinge_axes: np.ndarray
    soles: np.ndarray
    tpose: np.ndarray
    apose: np.ndarray

    @property
    def root_height(self) -> float:
        """Standing (rest-pose) height of the root joint above the floor, metres."""
        return float(self.joints[0, 2])

    @classmethod
    def default(cls) -> RestPoseInfo:
        """The mean body of the committed model (ν = 0), without loading the model."""
        return cls(
            _DEFAULT_JOINTS.copy(),
            _DEFAULT_HINGES.copy(),
            _DEFAULT_SOLES.copy(),
            _DEFAULT_TPOSE.copy(),
            _DEFAULT_APOSE.copy(),
        )

    @classmethod
    def from_model(cls, model: BodyModel, nu: np.ndarray | None = None) -> RestPoseInfo:
        """Read the proportions of the body with shape ``nu`` (default mean) from ``model``."""
        nu = np.zeros((1, model.n_shape)) if nu is None else np.atleast_2d(nu)
        joints = model.rest_keypoints(nu)[0, :N_PARTS]
        verts = model.canonical_vertices(nu)[0]
        soles = np.zeros((2, 4, 3))
        for k, side in enumerate("lr"):
            foot = verts[model.vertex_parts == model.parts.index(f"foot_{side}")]
            low = foot[foot[:, 2] < foot[:, 2].min() + 0.015]
            ball = low[low[:, 1] < np.quantile(low[:, 1], 0.4)]
            ball_out = ball[:, 0] * (1.0 if side == "l" else -1.0)
            soles[k, 0] = low[np.argmax(low[:, 1])]  # heel
            soles[k, 1] = low[np.argmin(low[:, 1])]  # toe
            soles[k, 2] = ball[np.argmin(ball_out)]  # inner edge of the ball
            soles[k, 3] = ball[np.argmax(ball_out)]  # outer edge
        soles[..., 2] = 0.0
        return cls(
            joints.copy(),
            np.asarray(model.hinge_axes, dtype=float).copy(),
            soles,
            np.asarray(model.poses["tpose"], dtype=float).copy(),
            np.asarray(model.poses["apose"], dtype=float).copy(),
        )

    def scaled(self, root_height: float) -> RestPoseInfo:
        """The same proportions scaled so that the standing root height is ``root_height``."""
        s = float(root_height) / self.root_height
        return replace(self, joints=self.joints * s, soles=self.soles * s)


# The committed model's mean body (ν = 0: the mean adult of the 2026-12-04 bake, 5-90
# years), rounded; a test checks them against the model.
# Copied rather than read from the model: reading them needs the 12 MB model file and
# its mesh, while motion generation and the pose prior stay numpy-only without it; and
# every seeded motion depends on these exact (rounded) numbers, so deriving them would
# change every generated motion and training set.
_DEFAULT_JOINTS = np.array(
    [
        [0.0, 0.0, 0.8836],
        [-0.0001, 0.0163, 1.0502],
        [0.0003, -0.0141, 1.4684],
        [0.1749, -0.0208, 1.3431],
        [0.3488, -0.0325, 1.154],
        [0.4681, -0.1903, 1.0363],
        [-0.1749, -0.0208, 1.3431],
        [-0.3488, -0.0325, 1.154],
        [-0.4681, -0.1903, 1.0363],
        [0.1126, -0.0005, 0.8832],
        [0.1428, -0.0304, 0.5087],
        [0.1858, 0.0021, 0.0767],
        [-0.1126, -0.0005, 0.8832],
        [-0.1428, -0.0304, 0.5087],
        [-0.1858, 0.0021, 0.0767],
    ]
)
_DEFAULT_HINGES = np.zeros((N_PARTS, 3))
_DEFAULT_HINGES[JOINTS.index("elbow_l")] = [-0.76083, -0.14891, -0.63163]
_DEFAULT_HINGES[JOINTS.index("elbow_r")] = [-0.76083, 0.14891, 0.63163]
_DEFAULT_HINGES[JOINTS.index("knee_l")] = [1.0, 0.0, 0.0]
_DEFAULT_HINGES[JOINTS.index("knee_r")] = [1.0, 0.0, 0.0]
_DEFAULT_SOLES = np.array(
    [
        [
            [0.1858, 0.0524, 0.0],
            [0.1565, -0.2005, 0.0],
            [0.1431, -0.1744, 0.0],
            [0.2215, -0.1636, 0.0],
        ],
        [
            [-0.1858, 0.0524, 0.0],
            [-0.1565, -0.2005, 0.0],
            [-0.1431, -0.1744, 0.0],
            [-0.2215, -0.1636, 0.0],
        ],
    ]
)
_ARM_L = (-0.8186, -0.09196, -0.1591, 0.18042)  # straight elbow, wrist in line (both poses)
_DEFAULT_TPOSE = np.zeros(N_POSE)
_DEFAULT_TPOSE[9:16] = (0.00454, -0.87883, -0.00967, *_ARM_L)
_DEFAULT_APOSE = np.zeros(N_POSE)
_DEFAULT_APOSE[9:16] = (-0.00418, -0.09346, -0.00418, *_ARM_L)


def _mirror_tables() -> tuple[np.ndarray, np.ndarray]:
    perm = np.arange(N_POSE)
    sign = np.ones(N_POSE)
    swap = {"l": "r", "r": "l"}
    for j, joint in enumerate(JOINTS):
        other = joint[:-1] + swap[joint[-1]] if joint[-2:] in ("_l", "_r") else joint
        k = JOINTS.index(other)
        perm[JOINT_SLICES[j]] = np.arange(JOINT_SLICES[k].start, JOINT_SLICES[k].stop)
        if JOINT_DOFS[j] == 3:
            sign[JOINT_SLICES[j].start + 1 : JOINT_SLICES[j].stop] = -1.0
    return perm, sign


_MIRROR_PERM, _MIRROR_SIGN = _mirror_tables()
# The model's T- and A-pose right arm is the mirror image of the left one.
for _p in (_DEFAULT_TPOSE, _DEFAULT_APOSE):
    _p[:] = np.where(np.arange(N_POSE) >= 16, _p[_MIRROR_PERM] * _MIRROR_SIGN, _p)


def mirror_pose(theta: np.ndarray) -> np.ndarray:
    """Left-right mirror image of poses ``theta`` (..., 37): sides swap, y and z angles flip.

    Mirroring x -> -x maps ``Rz(c) Ry(b) Rx(a)`` to ``Rz(-c) Ry(-b) Rx(a)``; hinge
    angles (elbow, knee) keep their sign. The default limits are mirror-symmetric.
    """
    theta = np.asarray(theta, dtype=float)
    return theta[..., _MIRROR_PERM] * _MIRROR_SIGN


def symmetric(theta: np.ndarray) -> np.ndarray:
    """Copy the left arm and leg of ``theta`` (..., 37) onto the right side (mirrored)."""
    out = theta.copy()
    right = np.array([j.endswith("_r") for j in JOINTS])
    idx = np.concatenate(
        [np.arange(JOINT_SLICES[j].start, JOINT_SLICES[j].stop) for j in np.flatnonzero(right)]
    )
    out[..., idx] = mirror_pose(theta)[..., idx]
    return out


# ----------------------------------------------------------------------------------------
# Default limits (the committed model's: the elbow may straighten fully)
# ----------------------------------------------------------------------------------------
def default_limits() -> JointLimits:
    """The committed model's joint limits (``BodyModel.limits``), without loading it.

    ``JointLimits.default()`` with the elbow's lower bound at the straight arm minus
    0.05 rad, as the bake sets it (θ = 0 has the elbows bent by 0.8186 rad).
    """
    base = JointLimits.default()
    lower = base.lower.copy()
    for side in "lr":
        lower[DOF_INDEX[f"elbow_{side}"]] = _ARM_L[0] - 0.05
    return JointLimits(lower, base.upper.copy())
