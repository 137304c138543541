"""Where the skeleton meets the world: feet on the floor, arms clear of head and chest.

:func:`place_root` computes the root positions τ (F, 3) that keep the feet of the
rigid skeleton on the floor (the supporting foot stays put in a motion);
:func:`arm_intrusion` is a coarse self-collision test of the arms against the head
and the chest. Both pose the skeleton with ``skeleton.forward_kinematics`` on a
:class:`~.rest.RestPoseInfo` (default: the mean body), numpy only.
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.motion.rest import RestPoseInfo
from bodymetry.estimation.body_model.skeleton import JOINTS, forward_kinematics

_FOOT_JOINTS = (JOINTS.index("ankle_l"), JOINTS.index("ankle_r"))


def _sole_points(theta: np.ndarray, rest: RestPoseInfo) -> np.ndarray:
    """(F, 2, 4, 3) foot contact points relative to the root joint, world orientation."""
    rot, joints = forward_kinematics(theta, np.zeros(3), rest.joints, rest.hinge_axes)
    out = np.empty((len(theta), 2, rest.soles.shape[1], 3))
    for k, a in enumerate(_FOOT_JOINTS):
        rel = rest.soles[k] - rest.joints[a]
        out[:, k] = joints[:, a, None, :] + np.einsum("fij,pj->fpi", rot[:, a], rel)
    return out


#: Softness of the lowest-sole-point minimum (m); the root rides up to SOFTMIN * log(8).
_SOFTMIN = 0.002
#: How quickly the feet drift back to the origin when nothing else moves them (s).
_RECENTRE_S = 4.0


def place_root(
    theta: np.ndarray,
    fps: float | None = None,
    root_height: float | None = None,
    rest: RestPoseInfo | None = None,
    stance: np.ndarray | None = None,
) -> np.ndarray:
    """Root positions τ (F, 3) that keep the feet on the floor for poses ``theta`` (F, 37).

    Height: the lowest foot contact point of the rigid skeleton (heel, toe, ball
    edges; a smooth minimum with 2 mm softness) sits on z = 0. Horizontal: with
    ``fps`` given the frames are a motion, and the supporting foot (the lower one,
    weights blending over 1 cm of height difference) stays where it is, so the
    hips move back in a squat and the body steps around when it turns; the feet
    recentre on the origin with a 4 s time constant. ``stance`` (F,) in [-1, 1]
    biases the support towards the left (+1) or right (-1) foot, as if that foot
    were 3 cm lower (a swinging foot that brushes the floor then does not take the
    weight). Without ``fps`` the frames are
    independent and the feet are centred on the origin. The mesh can reach a few
    millimetres lower than the skeleton's contact points (and hands can be lowest):
    :func:`~.library.ground_motion` corrects the height on the actual mesh.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    rest = RestPoseInfo.default() if rest is None else rest
    if root_height is not None:
        rest = rest.scaled(root_height)
    soles = _sole_points(theta, rest)  # (F, 2, P, 3)
    z = soles[..., 2].reshape(len(theta), -1)
    zmin = z.min(axis=1)
    soft = zmin - _SOFTMIN * np.log(np.exp(-(z - zmin[:, None]) / _SOFTMIN).sum(axis=1))
    tau = np.zeros((len(theta), 3))
    tau[:, 2] = -soft
    height = soles[..., 2].min(axis=2) + tau[:, 2:3]  # (F, 2) lowest point of each foot
    bias = 0.0 if stance is None else 3.0 * np.asarray(stance, dtype=float)
    w_left = 0.5 * (1.0 + np.tanh((height[:, 1] - height[:, 0]) / 0.01 + bias))
    weights = np.stack([w_left, 1.0 - w_left], axis=1)
    centre = soles[..., :2].mean(axis=2)  # (F, 2, 2)
    if fps is None:
        tau[:, :2] = -np.einsum("fk,fkx->fx", weights, centre)
        return tau
    step = np.einsum("fk,fkx->fx", weights[1:], centre[1:] - centre[:-1])
    mid = centre.mean(axis=1)
    pull = 1.0 - np.exp(-1.0 / (fps * _RECENTRE_S))
    xy = -mid[0].copy()
    tau[0, :2] = xy
    for f in range(1, len(theta)):
        xy = xy - step[f - 1] - pull * (xy + mid[f - 1])
        tau[f, :2] = xy
    return tau


def arm_intrusion(theta: np.ndarray, rest: RestPoseInfo | None = None) -> np.ndarray:
    """How deep each arm reaches into the head or the torso, metres (F, 2) (0 = clear).

    ``theta`` is (F, 37) or (37,); columns are the left and the right arm.

    A coarse self-collision test on the skeleton: elbow, mid-forearm, wrist and hand
    (8 cm beyond the wrist) against a sphere of radius 13 cm around the head and a
    box around the chest (±14 cm wide, ±10 cm deep, from 15 cm below the spine joint
    to 40 cm above it, in the torso's frame).
    """
    rest = RestPoseInfo.default() if rest is None else rest
    theta = np.atleast_2d(theta)
    rot, joints = forward_kinematics(theta, np.zeros(3), rest.joints, rest.hinge_axes)
    neck, spine = JOINTS.index("neck"), JOINTS.index("spine")
    head = joints[:, neck] + np.einsum("fij,j->fi", rot[:, neck], [0.0, -0.02, 0.12])
    out = np.zeros((len(theta), 2))
    for k, side in enumerate("lr"):
        e = joints[:, JOINTS.index(f"elbow_{side}")]
        w = joints[:, JOINTS.index(f"wrist_{side}")]
        fore = (w - e) / np.maximum(np.linalg.norm(w - e, axis=1, keepdims=True), 1e-9)
        pts = np.stack([e, 0.5 * (e + w), w, w + 0.08 * fore], axis=1)  # (F, 4, 3)
        into_head = 0.13 - np.linalg.norm(pts - head[:, None], axis=2)
        rel = np.einsum("fji,fpj->fpi", rot[:, spine], pts - joints[:, None, spine])
        into_box = np.min(
            np.stack(
                [
                    0.14 - np.abs(rel[..., 0]),
                    0.10 - np.abs(rel[..., 1]),
                    rel[..., 2] + 0.15,
                    0.40 - rel[..., 2],
                ],
                axis=-1,
            ),
            axis=-1,
        )
        out[:, k] = np.maximum(np.maximum(into_head, into_box).max(axis=1), 0.0)
    return out
