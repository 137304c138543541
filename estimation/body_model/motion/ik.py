"""Key poses of scripted motion: arm inverse kinematics, sagittal legs, the neutral stance.

:func:`arm_angles` finds shoulder Euler angles that point the upper arm along a
direction (choosing the twist so the arm moves in the plane of the move),
:func:`point_arm` does so for a direction in the heading frame, :func:`set_legs`
poses a leg from thigh and shin pitch with the foot flat, and :func:`neutral_pose`
is the relaxed standing pose scripted actions start from and return to. Angles in
radians, θ (37,) in the layout of ``skeleton.dof_names()``; directions in the
canonical body frame (x = the subject's left, y = backwards, z = up).
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.motion.rest import DOF_INDEX, RestPoseInfo, symmetric
from bodymetry.estimation.body_model.motion.signals import inner_clip, wrap_angle
from bodymetry.estimation.body_model.rotations import (
    axis_rotation,
    euler_to_matrix,
    matrix_to_euler,
    rotation_between,
)
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, JointLimits


def set_dofs(theta: np.ndarray, **dofs: float) -> np.ndarray:
    """Set DOFs of ``theta`` (..., 37) by name, in place; ``__`` stands for the dot.

    ``set_dofs(theta, spine__x=0.3, elbow_l=0.5)``; returns ``theta``.
    """
    for key, value in dofs.items():
        theta[..., DOF_INDEX[key.replace("__", ".")]] = value
    return theta


def unit(x: float, y: float, z: float) -> np.ndarray:
    """The (3,) unit vector along (x, y, z)."""
    v = np.array([x, y, z], dtype=float)
    return v / np.linalg.norm(v)


def straight_elbow(rest: RestPoseInfo) -> float:
    """Elbow angle of the straight arm (the model's A-pose), radians."""
    return float(rest.apose[DOF_INDEX["elbow_l"]])


def _upper_arm_dir(rest: RestPoseInfo) -> np.ndarray:
    s, e = JOINTS.index("shoulder_l"), JOINTS.index("elbow_l")
    d = rest.joints[e] - rest.joints[s]
    return d / np.linalg.norm(d)


def _euler_branches(R: np.ndarray) -> np.ndarray:
    """Both Euler triples (..., 2, 3) of rotations R (..., 3, 3): (a, b, c), (a+pi, pi-b, c+pi)."""
    e1 = matrix_to_euler(R)
    e2 = np.stack(
        [
            wrap_angle(e1[..., 0] + np.pi),
            np.copysign(np.pi, e1[..., 1]) - e1[..., 1],
            wrap_angle(e1[..., 2] + np.pi),
        ],
        axis=-1,
    )
    return np.stack([e1, e2], axis=-2)


_TWISTS = np.linspace(-1.5, 1.5, 13)
_PATH_STEPS = np.linspace(0.0, 1.0, 11)


def arm_angles(
    direction: np.ndarray,
    side: str,
    rest: RestPoseInfo,
    limits: JointLimits,
    reference: np.ndarray | None = None,
    twist: float = 0.0,
) -> np.ndarray:
    """Shoulder Euler angles (3,) pointing the upper arm along ``direction`` (3,), torso frame.

    A direction leaves the twist about the arm free, and Euler angles interpolate
    linearly between key poses, so a careless choice makes the arm sweep far out of
    the plane of the move (a forward raise flaring out sideways). With a
    ``reference`` pose (37,) (the hanging arm of :func:`neutral_pose`), the
    candidates (swings from the rest and from the reference arm, twists of ±1.5 rad,
    both Euler triples) inside the limits are scored by how far the arm leaves the
    great circle when moving there from the reference arm, plus 3 degrees per radian
    of twist away from ``twist``; the best wins. Without, the smallest swing from
    the rest arm is used. ``side`` "r" is solved as the mirror image of the left arm.
    """
    d = np.asarray(direction, dtype=float).copy()
    d /= np.linalg.norm(d)
    if side == "r":
        d[0] = -d[0]
    u0 = _upper_arm_dir(rest)
    sl = JOINT_SLICES[JOINTS.index("shoulder_l")]
    lo, hi = limits.lower[sl], limits.upper[sl]
    if reference is None:
        cands = _euler_branches(rotation_between(u0, d) @ axis_rotation(u0, twist))
        viol = np.sum(np.maximum(lo - cands, 0.0) + np.maximum(cands - hi, 0.0), axis=-1)
        e = np.clip(cands[int(np.argmin(viol))], lo, hi)
    else:
        ref = reference[sl]
        R_ref = euler_to_matrix(ref)
        d_ref = R_ref @ u0
        rots = []
        for base_dir, base_R in ((u0, np.eye(3)), (d_ref, R_ref)):
            swing = rotation_between(base_dir, d)
            rots.append(swing @ axis_rotation(base_dir, _TWISTS) @ base_R)
        cands = _euler_branches(np.concatenate(rots)).reshape(-1, 3)  # (4 * twists, 3)
        tws = np.tile(np.repeat(_TWISTS, 2), 2)
        viol = np.sum(np.maximum(lo - cands, 0.0) + np.maximum(cands - hi, 0.0), axis=-1)
        path = ref + _PATH_STEPS[None, :, None] * (cands - ref)[:, None, :]  # (C, S, 3)
        dirs = euler_to_matrix(path) @ u0  # (C, S, 3)
        normal = np.cross(d_ref, d)
        if np.linalg.norm(normal) < 1e-9:
            dev = np.zeros(len(cands))
        else:
            normal /= np.linalg.norm(normal)
            # Out of plane, plus the wrong way round (a sweep the long way).
            off = np.degrees(np.arcsin(np.clip(np.abs(dirs @ normal), 0.0, 1.0))).max(axis=1)
            chord = np.degrees(np.arccos(np.clip(d_ref @ d, -1.0, 1.0)))
            steps = np.degrees(np.arccos(np.clip(np.sum(dirs[:, 1:] * dirs[:, :-1], -1), -1, 1)))
            dev = off + np.maximum(steps.sum(axis=1) - chord, 0.0)
        score = dev + 3.0 * np.abs(tws - twist) + 1e3 * viol
        e = np.clip(cands[int(np.argmin(score))], lo, hi)
    return e * np.array([1.0, -1.0, -1.0]) if side == "r" else e


def _torso_frame(theta: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) of the torso in the heading frame (root pitch/roll, then the spine)."""
    root = theta[JOINT_SLICES[0]].copy()
    root[2] = 0.0
    return euler_to_matrix(root) @ euler_to_matrix(theta[JOINT_SLICES[1]])


def point_arm(
    theta: np.ndarray,
    side: str,
    direction_heading: np.ndarray,
    rest: RestPoseInfo,
    limits: JointLimits,
    reference: np.ndarray,
    twist: float = 0.0,
) -> None:
    """Point an upper arm of ``theta`` (37,) along a (3,) direction in the heading frame.

    In place; the shoulder angles come from :func:`arm_angles` with ``reference``.
    """
    d = _torso_frame(theta).T @ np.asarray(direction_heading, dtype=float)
    theta[JOINT_SLICES[JOINTS.index(f"shoulder_{side}")]] = arm_angles(
        d, side, rest, limits, reference, twist
    )


def set_legs(theta: np.ndarray, thigh: float, shin: float, side: str = "both") -> None:
    """Sagittal leg pose with the foot flat, given the pelvis pitch already in ``theta``.

    ``thigh``: forward pitch of the thigh from vertical (knee ahead of the hip);
    ``shin``: forward pitch of the shin (knee ahead of the ankle). +x tips a
    downward segment backwards, so hip.x = -thigh - pelvis, knee = thigh + shin,
    ankle.x = -shin (dorsiflexion negative).
    """
    pelvis = theta[DOF_INDEX["root.x"]]
    for s in ("l", "r") if side == "both" else (side,):
        set_dofs(
            theta,
            **{f"hip_{s}__x": -thigh - pelvis, f"knee_{s}": thigh + shin, f"ankle_{s}__x": -shin},
        )


def neutral_pose(rest: RestPoseInfo, limits: JointLimits) -> np.ndarray:
    """(37,) relaxed standing: arms hanging about 12 degrees out, elbows slightly bent."""
    theta = rest.apose.copy()
    sl = JOINT_SLICES[JOINTS.index("shoulder_l")]
    theta[sl] = arm_angles(unit(0.21, -0.05, -1.0), "l", rest, limits)
    set_dofs(theta, elbow_l=straight_elbow(rest) + 0.3)
    return inner_clip(symmetric(theta), limits)
