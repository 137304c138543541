"""A pose from the subject's 3D body landmarks: inverse kinematics of the skeleton.

The discriminative mixtures (paper §4) propose poses like the ones they were
trained on; a real subject raising a leg sideways or bending the trunk is far
from them, and the annealing rarely gets there from far. The person segmenter's
landmarks, triangulated through the calibrated cameras
(:func:`bodymetry.capture.landmarks.triangulate_landmarks`), say where the
subject's shoulders, elbows, wrists, hips, knees and ankles are. This module
finds the root position τ and joint angles θ that put the body model's joints
there (for a given shape ν): bounded least squares on the skeleton's forward
kinematics (cheap: no mesh), with the joint limits as bounds and a weak pull of
the weakly observed angles (spine twist, wrists, ankles) towards the neutral
pose. The fit uses it as one more start and a cloud of initial particles
(:func:`bodymetry.estimation.fit.fit_frame`); the silhouettes decide.

Beyond the joints, three landmarks carry orientation: the ears' midpoint and
the nose (head), the heel and the toe (feet), matched to points of the rest
mesh (the head's centroid and its most forward vertex; the foot's rearmost
and most forward vertex on the floor).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.rotations import matrix_to_euler
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, PARTS, forward_kinematics

__all__ = ["LANDMARK_JOINTS", "LandmarkPose", "pose_from_landmarks"]

#: BlazePose landmark index -> the body model's joint it marks.
LANDMARK_JOINTS: dict[int, str] = {
    11: "shoulder_l", 12: "shoulder_r", 13: "elbow_l", 14: "elbow_r",
    15: "wrist_l", 16: "wrist_r", 23: "hip_l", 24: "hip_r",
    25: "knee_l", 26: "knee_r", 27: "ankle_l", 28: "ankle_r",
}  # fmt: skip
_NOSE, _EARS = 0, (7, 8)
_HEELS = {"l": 29, "r": 30}
_TOES = {"l": 31, "r": 32}
#: Landmarks that must be present to solve at all: both shoulders and both hips.
_REQUIRED = (11, 12, 23, 24)
#: Residual weights: joints 1, orientation points less (their rest points are approximate).
_POINT_WEIGHT = 0.5
#: Pull of the weakly observed angles towards the neutral pose, metres per radian.
_PRIOR_WEIGHT = 0.03
_WEAK_JOINTS = ("spine", "neck", "wrist_l", "wrist_r", "ankle_l", "ankle_r")


@dataclass(frozen=True)
class LandmarkPose:
    """The result of :func:`pose_from_landmarks`.

    Attributes
    ----------
    tau : (3,) float
    theta : (37,) float
    rms : float
        Root-mean-square distance of the model's joints to their landmarks, metres.
    n_landmarks : int
        Landmarks used.
    """

    tau: np.ndarray
    theta: np.ndarray
    rms: float
    n_landmarks: int


@dataclass(frozen=True)
class _RestPoints:
    """Rest-pose points of one shape: joints and the orientation points per part."""

    joints: np.ndarray  # (15, 3)
    points: np.ndarray  # (P, 3) orientation points
    parts: np.ndarray  # (P,) part index of each


@functools.lru_cache(maxsize=8)
def _rest_points(body: BodyModel, nu_key: bytes) -> _RestPoints:
    nu = np.frombuffer(nu_key)[None]
    joints = body.rest_keypoints(nu)[0, : len(JOINTS)]
    verts = body.canonical_vertices(nu)[0]
    faces = body.faces()
    tri_parts = body.full.arrays.parts
    vert_part = np.full(len(verts), -1)
    vert_part[faces.ravel()] = np.repeat(tri_parts, 3)
    points, parts = [], []
    head = PARTS.index("head")
    hv = verts[vert_part == head]
    points += [hv.mean(axis=0), hv[np.argmin(hv[:, 1])]]  # centre, nose tip (faces -y)
    parts += [head, head]
    for side in ("l", "r"):
        foot = PARTS.index(f"foot_{side}")
        fv = verts[vert_part == foot]
        low = fv[fv[:, 2] < fv[:, 2].min() + 0.03]
        points += [low[np.argmax(low[:, 1])], low[np.argmin(low[:, 1])]]  # heel, toe
        parts += [foot, foot]
    return _RestPoints(joints, np.array(points), np.array(parts))


def _targets(landmarks: np.ndarray) -> tuple[list[int], list[int], np.ndarray]:
    """Joint indices, orientation point indices and their (k, 3) world targets."""
    ok = np.all(np.isfinite(landmarks), axis=1)
    joint_ids, point_ids, targets = [], [], []
    for lm, name in LANDMARK_JOINTS.items():
        if ok[lm]:
            joint_ids.append(JOINTS.index(name))
            targets.append(landmarks[lm])
    ears = [e for e in _EARS if ok[e]]
    if len(ears) == 2:
        point_ids.append(0)
        targets.append(landmarks[list(ears)].mean(axis=0))
    if ok[_NOSE]:
        point_ids.append(1)
        targets.append(landmarks[_NOSE])
    for k, side in enumerate(("l", "r")):
        for j, lm in enumerate((_HEELS[side], _TOES[side])):
            if ok[lm]:
                point_ids.append(2 + 2 * k + j)
                targets.append(landmarks[lm])
    return joint_ids, point_ids, np.array(targets)


def _initial_root(landmarks: np.ndarray, rest: _RestPoints) -> tuple[np.ndarray, np.ndarray]:
    """τ and the root's Euler angles from the hip line and the trunk's up direction."""
    hip_l, hip_r = landmarks[23], landmarks[24]
    mid_hip = (hip_l + hip_r) / 2
    mid_shoulder = (landmarks[11] + landmarks[12]) / 2
    x = hip_l - hip_r
    x /= np.linalg.norm(x)
    z = mid_shoulder - mid_hip
    z -= (z @ x) * x
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])  # body frame (x left, y back, z up) -> world
    j = rest.joints
    rest_mid = (j[JOINTS.index("hip_l")] + j[JOINTS.index("hip_r")]) / 2
    tau = mid_hip + R @ (j[0] - rest_mid)
    return tau, matrix_to_euler(R)


def pose_from_landmarks(
    body: BodyModel,
    landmarks: np.ndarray,
    nu: np.ndarray,
    neutral: np.ndarray | None = None,
) -> LandmarkPose | None:
    """The pose that puts the body model's joints on the subject's landmarks.

    Parameters
    ----------
    body : BodyModel
    landmarks : (33, 3) float
        World landmarks (NaN rows: not seen), from
        :func:`bodymetry.capture.landmarks.triangulate_landmarks`.
    nu : (n_shape,) float
        The shape to pose (e.g. the discriminative estimate).
    neutral : (37,) float, optional
        Angles the weakly observed joints are pulled towards (default 0, the rest pose).

    Returns
    -------
    LandmarkPose or None
        None when a shoulder or a hip is missing (the trunk's place and
        direction are then unknown).
    """
    landmarks = np.asarray(landmarks, float)
    if landmarks.shape != (33, 3):
        raise ValueError(f"landmarks: expected (33, 3), got {landmarks.shape}")
    if not all(np.all(np.isfinite(landmarks[i])) for i in _REQUIRED):
        return None
    nu = np.asarray(nu, float).reshape(-1)
    rest = _rest_points(body, nu.tobytes())
    joint_ids, point_ids, targets = _targets(landmarks)
    weights = np.r_[np.ones(len(joint_ids)), np.full(len(point_ids), _POINT_WEIGHT)][:, None]
    neutral = np.zeros(37) if neutral is None else np.asarray(neutral, float)
    weak = np.concatenate([np.arange(37)[JOINT_SLICES[JOINTS.index(n)]] for n in _WEAK_JOINTS])
    lo, hi = body.limits.lower.copy(), body.limits.upper.copy()
    tau0, root0 = _initial_root(landmarks, rest)

    parts = rest.parts[point_ids]
    residuals = _Residuals(
        body=body,
        rest_joints=rest.joints,
        joint_ids=joint_ids,
        parts=parts,
        rel=rest.points[point_ids] - rest.joints[parts],
        targets=targets,
        weights=weights,
        weak=weak,
        neutral=neutral,
    )
    best = _solve(residuals, neutral, tau0, root0, lo, hi)
    n_joint = len(joint_ids)
    err = residuals(best.x)[: 3 * n_joint].reshape(-1, 3)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    return LandmarkPose(best.x[:3], best.x[3:], rms, len(joint_ids) + len(point_ids))


@dataclass(frozen=True)
class _Residuals:
    """The landmark fit's residuals of a state ``[τ, θ]`` (40,): the weighted
    offsets of the model's joints and orientation points (head, feet) from their
    landmark targets, then the pull of the weakly observed joints towards
    ``neutral``."""

    body: BodyModel
    rest_joints: np.ndarray
    joint_ids: list[int]
    parts: np.ndarray
    rel: np.ndarray
    targets: np.ndarray
    weights: np.ndarray
    weak: np.ndarray
    neutral: np.ndarray

    def batch(self, X: np.ndarray) -> np.ndarray:
        """Residuals (B, R) of states X (B, 40): one forward kinematics for the batch."""
        # numpy's kinematics: the compiled pass agrees to 1e-16, but the forward
        # differences make that 1e-10 in the Jacobian, and the solve ends elsewhere
        # in its tolerance (4.7e-4 rad), which moves every later fit a little.
        rot, joints = forward_kinematics(X[:, 3:], X[:, :3], self.rest_joints, self.body.hinge_axes)
        posed = joints[:, self.parts] + np.einsum("bkij,kj->bki", rot[:, self.parts], self.rel)
        model = np.concatenate([joints[:, self.joint_ids], posed], axis=1)
        fit = ((model - self.targets) * self.weights).reshape(len(X), -1)
        weak = self.weak
        return np.hstack([fit, _PRIOR_WEIGHT * (X[:, 3:][:, weak] - self.neutral[weak])])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Residuals (R,) of one state (40,)."""
        return self.batch(x[None])[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """(R, 40) by forward differences, all 40 in one batch (the scalar default
        calls the kinematics 40 times)."""
        step = 1e-6
        X = np.vstack([x, x + step * np.eye(len(x))])
        r = self.batch(X)
        return ((r[1:] - r[0]) / step).T


def _solve(
    residuals: _Residuals,
    neutral: np.ndarray,
    tau0: np.ndarray,
    root0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> OptimizeResult:
    """The bounded least-squares solution from the neutral pose, and from the rest
    pose when that is another start (the lower cost wins), with the root placed
    at ``tau0``, ``root0`` and τ within a metre of it."""
    best = None
    starts = [neutral] if not np.any(neutral) else [neutral, np.zeros(37)]
    for start in starts:
        theta0 = np.clip(start, lo, hi).copy()
        theta0[:3] = np.clip(root0, lo[:3], hi[:3])
        x0 = np.r_[tau0, theta0]
        bounds = (np.r_[tau0 - 1.0, lo], np.r_[tau0 + 1.0, hi])
        sol = least_squares(
            residuals, np.clip(x0, *bounds), jac=residuals.jacobian, bounds=bounds, max_nfev=200
        )
        if best is None or sol.cost < best.cost:
            best = sol
    return best
