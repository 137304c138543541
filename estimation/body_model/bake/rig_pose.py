"""The rig's keypoints of MakeHuman bodies and straight-arm poses from them (bake time only).

Shared by the body model's bake (:mod:`.bake`: rest skeleton, T-pose and A-pose)
and the bake of the studio's independent bodies (:mod:`.independent`: each
body's T-pose).
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.bake.assets import MakeHumanAssets, to_world
from bodymetry.estimation.body_model.bake.rigging import EXTRA_KEYPOINT_BONE, JOINT_BONE, KEYPOINTS
from bodymetry.estimation.body_model.rotations import (
    axis_rotation,
    matrix_to_euler,
    rotation_between,
)
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, N_POSE


def rig_keypoints(assets: MakeHumanAssets, raw_vertices: np.ndarray) -> np.ndarray:
    """World keypoints of bodies given as raw OBJ vertices.

    Parameters
    ----------
    assets : MakeHumanAssets
        The rig (bone heads as vertex averages).
    raw_vertices : (..., N, 3) float
        Full ``base.obj`` vertices in raw OBJ units (decimetres, y up).

    Returns
    -------
    (..., K, 3) float
        The rig's joint centres and knuckles in metres, z up, order
        ``rigging.KEYPOINTS`` ("root" is the mid-point of the hips); not shifted
        to the canonical frame.
    """
    pts = {name: assets.bone_head(bone, raw_vertices) for name, bone in JOINT_BONE.items()}
    pts.update(
        {name: assets.bone_head(bone, raw_vertices) for name, bone in EXTRA_KEYPOINT_BONE.items()}
    )
    pts["root"] = 0.5 * (pts["hip_l"] + pts["hip_r"])
    return to_world(np.stack([pts[k] for k in KEYPOINTS], axis=-2))


def arm_pose(
    rest: np.ndarray, hinge_axes: np.ndarray, knuckles: dict[str, np.ndarray], elevation: float
) -> np.ndarray:
    """θ with both arms straight, ``elevation`` radians below horizontal, palms down.

    Parameters
    ----------
    rest : (15, 3) float
        Rest joints.
    hinge_axes : (15, 3) float
        Hinge axis per joint (the elbows' are used).
    knuckles : dict side -> (3,) float
        Rest knuckle positions.
    elevation : float
        0 gives the T-pose; 45° the A-pose.

    Returns
    -------
    (37,) float
        The pose θ (not clipped to the joint limits).
    """
    theta = np.zeros(N_POSE)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        s, e, w = (JOINTS.index(f"{j}_{side}") for j in ("shoulder", "elbow", "wrist"))
        target = np.array([sx * np.cos(elevation), 0.0, -np.sin(elevation)])
        upper = rest[e] - rest[s]
        lower = rest[w] - rest[e]
        hand = knuckles[side] - rest[w]
        flex = np.arccos(
            np.clip(upper @ lower / np.linalg.norm(upper) / np.linalg.norm(lower), -1, 1)
        )
        R_upper = rotation_between(upper, target)
        theta[JOINT_SLICES[s]] = matrix_to_euler(R_upper)
        theta[JOINT_SLICES[e].start] = -flex
        R_lower = R_upper @ axis_rotation(hinge_axes[e], -flex)
        R_hand = rotation_between(R_lower @ hand, target) @ R_lower
        theta[JOINT_SLICES[w]] = matrix_to_euler(R_lower.T @ R_hand)
    return theta
