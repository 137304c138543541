"""Motion library of the synthetic studio: seeded, plausible body motion within the joint limits.

No motion-capture database ships in any package we can use, so motion is generated:
smooth random trajectories plus scripted actions (walking on the spot while turning,
arm raises, reaching, squats, bending forward, held T- and A-poses) and ``mixed``, a
non-cyclic sequence of all of them joined by smooth blends (the default for sessions).
``docs/motion-prior.md`` describes every motion, the plausibility bounds and the
seed convention.

Typical use::

    motion = make_motion("mixed", n_frames=850, fps=60.0, seed=seed_for("demo", 0))
    motion = ground_motion(model, motion, nu)          # lowest vertex on z = 0
    poses = sample_pose_prior(np.random.default_rng(seed_for("train", 0)), 3000)

Conventions (``estimation.body_model.skeleton``): θ (37,) in radians, 3-DOF joints
``R = Rz(c) Ry(b) Rx(a)`` about the canonical body axes (x = the subject's left,
y = backwards, z = up; the body faces -y). ``root.z`` is the heading (rotation about
the world vertical), wrapped into ``[-pi, pi)``. τ is the root joint (mid-hip) in
world coordinates, metres, z up, floor at z = 0.

Plausibility bounds, held by construction and checked by the tests at 60 fps (finite
differences): every DOF ``|dθ/dt| <= MAX_JOINT_SPEED`` and ``|d²θ/dt²| <=
MAX_JOINT_ACCEL``; the heading turns at most ``MAX_YAW_RATE``; the root moves at most
``MAX_ROOT_SPEED``. Numpy only (plus the numpy-only ``skeleton`` and ``rotations``
modules); :func:`ground_motion` takes a ``BodyModel`` but the module does not import one.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING, Literal

import numpy as np

from bodymetry.estimation.body_model.rotations import (
    axis_rotation,
    euler_to_matrix,
    matrix_to_euler,
    rotation_between,
)
from bodymetry.estimation.body_model.skeleton import (
    JOINT_DOFS,
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    N_POSE,
    YAW,
    JointLimits,
    dof_names,
    forward_kinematics,
)

if TYPE_CHECKING:  # pragma: no cover - typing only; keeps this module numpy-only at run time
    from bodymetry.estimation.body_model.model import BodyModel

# ----------------------------------------------------------------------------------------
# Plausibility bounds (SI units). Gait-lab figures for comparison: the knee peaks at about
# 7 rad/s and 100 rad/s² in brisk walking; everyday reaching stays under 4 rad/s.
# ----------------------------------------------------------------------------------------
#: Largest angular speed of any DOF, rad/s (the marching knee comes closest, ~4.5 rad/s).
MAX_JOINT_SPEED = 6.0
#: Largest angular acceleration of any DOF, rad/s².
MAX_JOINT_ACCEL = 60.0
#: Largest turning rate of the heading (root.z), rad/s: a full turn takes >= 4.2 s.
MAX_YAW_RATE = 1.5
#: Largest speed of the root joint τ, m/s (squatting down, stepping while turning).
MAX_ROOT_SPEED = 1.5
#: Design speed of the ``random`` motion: each DOF stays under this, rad/s.
RANDOM_JOINT_SPEED = 2.0
#: Design limits of scripted moves between key poses (minimum-jerk), rad/s and rad/s².
KEY_SPEED = 2.5
KEY_ACCEL = 15.0

_NAMES = dof_names()
_IX = {name: i for i, name in enumerate(_NAMES)}
_FOOT_JOINTS = (JOINTS.index("ankle_l"), JOINTS.index("ankle_r"))

# ----------------------------------------------------------------------------------------
# Seeds: training, test and demo draws come from disjoint seed ranges.
# ----------------------------------------------------------------------------------------
Purpose = Literal["train", "test", "demo"]
_SEED_BLOCK = 1_000_000_000
#: Seed range of each purpose (disjoint; seeds below 10^9 are free for ad-hoc use).
SEED_RANGES: dict[str, range] = {
    "train": range(1 * _SEED_BLOCK, 2 * _SEED_BLOCK),
    "test": range(2 * _SEED_BLOCK, 3 * _SEED_BLOCK),
    "demo": range(3 * _SEED_BLOCK, 4 * _SEED_BLOCK),
}


def seed_for(purpose: Purpose, index: int) -> int:
    """The seed of the ``index``-th draw for ``purpose`` ("train", "test" or "demo").

    Training sets use ``seed_for("train", i)``, test fixtures and benchmarks
    ``seed_for("test", i)``, the committed demo recording ``seed_for("demo", 0)``; the
    ranges never overlap, so no test motion or pose is ever a training draw.
    """
    if purpose not in SEED_RANGES:
        raise ValueError(f"seed_for: purpose must be one of {sorted(SEED_RANGES)}, got {purpose!r}")
    span = SEED_RANGES[purpose]
    ok = isinstance(index, int | np.integer) and not isinstance(index, bool)
    if not ok or not 0 <= int(index) < len(span):
        raise ValueError(f"seed_for: index must be an integer in [0, {len(span)}), got {index!r}")
    return span.start + int(index)


def seed_purpose(seed: int) -> str | None:
    """Which purpose's range ``seed`` falls in (None for ad-hoc seeds)."""
    for purpose, span in SEED_RANGES.items():
        if int(seed) in span:
            return purpose
    return None


def motion_rng(name: str, seed: int) -> np.random.Generator:
    """The generator behind ``make_motion(name, ..., seed)``: independent per (name, seed)."""
    if int(seed) < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]))


# ----------------------------------------------------------------------------------------
# Data types
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Motion:
    """A body motion: joint angles and root position per frame.

    Attributes
    ----------
    theta : (F, 37) float
        Joint angles, radians (layout of ``skeleton.dof_names()``); ``root.z`` is the
        heading in ``[-pi, pi)``.
    tau : (F, 3) float
        World position of the root joint (mid-hip), metres; z up, floor at z = 0.
    fps : float
        Frames per second.
    name : str
        The library motion it came from.
    """

    theta: np.ndarray
    tau: np.ndarray
    fps: float
    name: str

    def __post_init__(self) -> None:
        theta = np.array(self.theta, dtype=float)
        tau = np.array(self.tau, dtype=float)
        if theta.ndim != 2 or theta.shape[1] != N_POSE:
            raise ValueError(f"Motion.theta: expected shape (F, {N_POSE}), got {theta.shape}")
        if tau.shape != (len(theta), 3):
            raise ValueError(f"Motion.tau: expected shape ({len(theta)}, 3), got {tau.shape}")
        if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(tau))):
            raise ValueError("Motion: theta and tau must be finite")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Motion.fps: expected a positive number, got {self.fps}")
        theta.flags.writeable = False
        tau.flags.writeable = False
        object.__setattr__(self, "theta", theta)
        object.__setattr__(self, "tau", tau)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def n_frames(self) -> int:
        return len(self.theta)

    def __len__(self) -> int:
        return len(self.theta)

    @property
    def times(self) -> np.ndarray:
        """(F,) float: seconds since the first frame."""
        return np.arange(len(self.theta)) / self.fps

    def __getitem__(self, index: slice | np.ndarray) -> Motion:
        """Frames ``index`` (a slice or index array) as a new Motion."""
        return Motion(self.theta[index], self.tau[index], self.fps, self.name)


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


# The committed model's mean body (ν = 0), rounded; a test checks them against the model.
_DEFAULT_JOINTS = np.array(
    [
        [0.0, 0.0, 0.881],
        [0.0, 0.0165, 1.0462],
        [0.0003, -0.0133, 1.4648],
        [0.1753, -0.0201, 1.3397],
        [0.3489, -0.032, 1.1509],
        [0.468, -0.1891, 1.033],
        [-0.1753, -0.0201, 1.3397],
        [-0.3489, -0.032, 1.1509],
        [-0.468, -0.1891, 1.033],
        [0.112, 0.0, 0.8811],
        [0.143, -0.0301, 0.5083],
        [0.1854, 0.002, 0.0765],
        [-0.112, 0.0, 0.8811],
        [-0.143, -0.0301, 0.5083],
        [-0.1854, 0.002, 0.0765],
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
for _p in (_DEFAULT_TPOSE, _DEFAULT_APOSE):
    _p[:] = np.where(np.arange(N_POSE) >= 16, _p[_MIRROR_PERM] * _MIRROR_SIGN, _p)


def mirror_pose(theta: np.ndarray) -> np.ndarray:
    """Left-right mirror image of poses ``theta`` (..., 37): sides swap, y and z angles flip.

    Mirroring x -> -x maps ``Rz(c) Ry(b) Rx(a)`` to ``Rz(-c) Ry(-b) Rx(a)``; hinge
    angles (elbow, knee) keep their sign. The default limits are mirror-symmetric.
    """
    theta = np.asarray(theta, dtype=float)
    return theta[..., _MIRROR_PERM] * _MIRROR_SIGN


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
        lower[_IX[f"elbow_{side}"]] = _ARM_L[0] - 0.05
    return JointLimits(lower, base.upper.copy())


# ----------------------------------------------------------------------------------------
# Small helpers
# ----------------------------------------------------------------------------------------
def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def _minjerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 0 -> 1 on s in [0, 1] (zero velocity and acceleration at the ends)."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def _margins(limits: JointLimits) -> np.ndarray:
    return np.minimum(0.05, 0.1 * np.maximum(limits.upper - limits.lower, 0.0))


def _inner_clip(theta: np.ndarray, limits: JointLimits) -> np.ndarray:
    """Clip key poses into the limits shrunk by the soft-clip margin (heading left free)."""
    m = _margins(limits)
    lo, hi = limits.lower + m, limits.upper - m
    out = np.clip(theta, lo, np.maximum(lo, hi))
    out[..., YAW] = np.asarray(theta)[..., YAW]
    return out


def _soft_clip(theta: np.ndarray, limits: JointLimits) -> np.ndarray:
    """Smoothly squash θ into the limits (C² with the identity inside the margins).

    Values more than the margin ``m = min(0.05, range / 10)`` inside a bound are
    unchanged; beyond, ``bound -/+ m (1 - tanh(...))`` approaches the bound without
    reaching it. The heading (root.z) is not clipped: it is wrapped.
    """
    theta = np.array(theta, dtype=float)
    m = _margins(limits)
    lo_in, hi_in = limits.lower + m, limits.upper - m
    safe_m = np.where(m > 0, m, 1.0)
    over = (theta > hi_in) & (m > 0)
    under = (theta < lo_in) & (m > 0)
    hi_val = hi_in + safe_m * np.tanh((theta - hi_in) / safe_m)
    lo_val = lo_in - safe_m * np.tanh((lo_in - theta) / safe_m)
    out = np.where(over, hi_val, np.where(under, lo_val, theta))
    out = np.where(m > 0, out, limits.lower)  # zero-width DOFs sit on their bound
    out[..., YAW] = theta[..., YAW]
    return out


def _smooth_unit(rng: np.random.Generator, t: np.ndarray, f_lo, f_hi, k: int = 3) -> np.ndarray:
    """Smooth random signals in [-1, 1]: weighted sums of ``k`` sinusoids per column.

    ``f_lo``, ``f_hi`` are (D,) frequency bounds in Hz; weights sum to 1 so the bound
    holds exactly and the speed is at most ``2 pi f_hi``. Frequencies are drawn
    independently (incommensurate), so the signal does not repeat.
    """
    f_lo = np.atleast_1d(np.asarray(f_lo, dtype=float))
    f_hi = np.atleast_1d(np.asarray(f_hi, dtype=float))
    D = np.broadcast_shapes(f_lo.shape, f_hi.shape)[0]
    freq = rng.uniform(0.0, 1.0, size=(k, D)) * (f_hi - f_lo) + f_lo
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(k, D))
    weight = rng.dirichlet(np.full(k, 0.7), size=D).T  # (k, D), one component usually dominates
    arg = 2.0 * np.pi * freq[:, None, :] * t[None, :, None] + phase[:, None, :]
    return np.einsum("kd,ktd->td", weight, np.sin(arg))


# ----------------------------------------------------------------------------------------
# Clips: body-relative motion before heading and root placement
# ----------------------------------------------------------------------------------------
@dataclass
class _Clip:
    """θ with ``root.z`` holding a heading *offset*, plus a heading rate (rad/s)."""

    theta: np.ndarray  # (F, 37)
    yaw_rate: np.ndarray  # (F,)
    stance: np.ndarray | None = None  # (F,) intended support, +1 left foot, -1 right foot

    def support(self) -> np.ndarray:
        return np.zeros(len(self.theta)) if self.stance is None else self.stance


@dataclass(frozen=True)
class _Ctx:
    fps: float
    rng: np.random.Generator
    limits: JointLimits
    rest: RestPoseInfo

    def times(self, n: int) -> np.ndarray:
        return np.arange(n) / self.fps

    @cached_property
    def neutral(self) -> np.ndarray:
        """(37,) relaxed standing: arms hanging about 12 degrees out, elbows slightly bent."""
        theta = self.rest.apose.copy()
        sl = JOINT_SLICES[JOINTS.index("shoulder_l")]
        theta[sl] = _arm_angles(_unit(0.21, -0.05, -1.0), "l", self, natural=False)
        _set(theta, elbow_l=_straight_elbow(self) + 0.3)
        return _inner_clip(_symmetric(theta), self.limits)


def _set(theta: np.ndarray, **dofs: float) -> np.ndarray:
    """Set DOFs by name, written with ``__`` for the dot: ``_set(th, spine__x=0.3)``."""
    for key, value in dofs.items():
        theta[..., _IX[key.replace("__", ".")]] = value
    return theta


def _symmetric(theta: np.ndarray) -> np.ndarray:
    """Copy the left arm and leg onto the right side (mirrored)."""
    out = theta.copy()
    right = np.array([j.endswith("_r") for j in JOINTS])
    idx = np.concatenate(
        [np.arange(JOINT_SLICES[j].start, JOINT_SLICES[j].stop) for j in np.flatnonzero(right)]
    )
    out[..., idx] = mirror_pose(theta)[..., idx]
    return out


def _upper_arm_dir(rest: RestPoseInfo) -> np.ndarray:
    s, e = JOINTS.index("shoulder_l"), JOINTS.index("elbow_l")
    d = rest.joints[e] - rest.joints[s]
    return d / np.linalg.norm(d)


def _euler_branches(R: np.ndarray) -> np.ndarray:
    """Both Euler triples (..., 2, 3) of rotations R (..., 3, 3): (a, b, c), (a+pi, pi-b, c+pi)."""
    e1 = matrix_to_euler(R)
    e2 = np.stack(
        [
            _wrap(e1[..., 0] + np.pi),
            np.copysign(np.pi, e1[..., 1]) - e1[..., 1],
            _wrap(e1[..., 2] + np.pi),
        ],
        axis=-1,
    )
    return np.stack([e1, e2], axis=-2)


_TWISTS = np.linspace(-1.5, 1.5, 13)
_PATH_STEPS = np.linspace(0.0, 1.0, 11)


def _arm_angles(
    direction: np.ndarray, side: str, ctx: _Ctx, twist: float = 0.0, natural: bool = True
) -> np.ndarray:
    """Shoulder Euler angles pointing the upper arm along ``direction`` (torso frame).

    A direction leaves the twist about the arm free, and Euler angles interpolate
    linearly between key poses, so a careless choice makes the arm sweep far out of
    the plane of the move (a forward raise flaring out sideways). With ``natural``,
    the candidates (swings from the rest and from the hanging arm, twists of ±1.5 rad,
    both Euler triples) inside the limits are scored by how far the arm leaves the
    great circle when moving there from the hanging arm, plus 3 degrees per radian
    of twist away from ``twist``; the best wins. Without, the smallest swing from
    the rest arm is used. ``side`` "r" is solved as the mirror image of the left arm.
    """
    d = np.asarray(direction, dtype=float).copy()
    d /= np.linalg.norm(d)
    if side == "r":
        d[0] = -d[0]
    u0 = _upper_arm_dir(ctx.rest)
    sl = JOINT_SLICES[JOINTS.index("shoulder_l")]
    lo, hi = ctx.limits.lower[sl], ctx.limits.upper[sl]
    if not natural:
        cands = _euler_branches(rotation_between(u0, d) @ axis_rotation(u0, twist))
        viol = np.sum(np.maximum(lo - cands, 0.0) + np.maximum(cands - hi, 0.0), axis=-1)
        e = np.clip(cands[int(np.argmin(viol))], lo, hi)
    else:
        ref = ctx.neutral[sl]
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
    """Rotation of the torso in the heading frame (root pitch/roll, then the spine)."""
    root = theta[JOINT_SLICES[0]].copy()
    root[2] = 0.0
    return euler_to_matrix(root) @ euler_to_matrix(theta[JOINT_SLICES[1]])


def _point_arm(theta: np.ndarray, side: str, direction_heading, ctx: _Ctx, twist=0.0) -> None:
    """Point an upper arm along a direction given in the heading frame (in place)."""
    d = _torso_frame(theta).T @ np.asarray(direction_heading, dtype=float)
    theta[JOINT_SLICES[JOINTS.index(f"shoulder_{side}")]] = _arm_angles(d, side, ctx, twist)


def _unit(x: float, y: float, z: float) -> np.ndarray:
    v = np.array([x, y, z], dtype=float)
    return v / np.linalg.norm(v)


def _straight_elbow(ctx: _Ctx) -> float:
    return float(ctx.rest.apose[_IX["elbow_l"]])


def _set_legs(theta: np.ndarray, thigh: float, shin: float, side: str = "both") -> None:
    """Sagittal leg pose with the foot flat, given the pelvis pitch already in ``theta``.

    ``thigh``: forward pitch of the thigh from vertical (knee ahead of the hip);
    ``shin``: forward pitch of the shin (knee ahead of the ankle). +x tips a
    downward segment backwards, so hip.x = -thigh - pelvis, knee = thigh + shin,
    ankle.x = -shin (dorsiflexion negative).
    """
    pelvis = theta[_IX["root.x"]]
    for s in ("l", "r") if side == "both" else (side,):
        _set(
            theta,
            **{f"hip_{s}__x": -thigh - pelvis, f"knee_{s}": thigh + shin, f"ankle_{s}__x": -shin},
        )


def _neutral(ctx: _Ctx) -> np.ndarray:
    return ctx.neutral.copy()


def _sway_amplitudes() -> np.ndarray:
    amp = np.zeros(N_POSE)
    table = {
        "root": (0.012, 0.012, 0.03),
        "spine": (0.02, 0.015, 0.03),
        "neck": (0.06, 0.04, 0.1),
        "shoulder": (0.04, 0.04, 0.04),
        "elbow": (0.05,),
        "wrist": (0.06, 0.04, 0.06),
        "hip": (0.012, 0.008, 0.012),
        "knee": (0.015,),
        "ankle": (0.012, 0.006, 0.01),
    }
    for j, joint in enumerate(JOINTS):
        amp[JOINT_SLICES[j]] = table[joint.split("_")[0]]
    return amp


_SWAY = _sway_amplitudes()


def _sway(ctx: _Ctx, n: int, scale: float = 1.0) -> np.ndarray:
    """Small natural sway (n, 37): 0.1-0.5 Hz, a few centiradians (more for head and arms)."""
    return scale * _SWAY * _smooth_unit(ctx.rng, ctx.times(n), 0.1, 0.5)


def _move_time(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> float:
    """Duration of a minimum-jerk move a -> b within KEY_SPEED and KEY_ACCEL, plus pace."""
    d = float(np.max(np.abs(np.delete(b - a, YAW)))) if a is not None else 0.0
    T = max(0.4, 1.875 * d / KEY_SPEED, np.sqrt(5.77 * d / KEY_ACCEL))
    return T * rng.uniform(1.0, 1.5)


def _keyframes(n: int, ctx: _Ctx, keys: Iterator[tuple[np.ndarray, float]]) -> np.ndarray:
    """(n, 37) track through key poses: hold each for its time, then a minimum-jerk move."""
    t = ctx.times(n)
    out = np.zeros((n, N_POSE))
    clock = -ctx.rng.uniform(0.0, 0.3)
    prev: np.ndarray | None = None
    for pose, hold in keys:
        pose = _inner_clip(pose, ctx.limits)
        if prev is not None:
            T = _move_time(prev, pose, ctx.rng)
            sel = (t >= clock) & (t < clock + T)
            out[sel] = prev + _minjerk((t[sel] - clock) / T)[:, None] * (pose - prev)
            clock += T
        sel = (t >= clock) & (t < clock + hold)
        out[sel] = pose
        clock += hold
        prev = pose
        if clock > t[-1]:
            break
    return out


def _held(n: int, ctx: _Ctx, pose: np.ndarray) -> _Clip:
    theta = _inner_clip(pose, ctx.limits) + _sway(ctx, n)
    return _Clip(theta, np.zeros(n))


def _clip_tpose(n: int, ctx: _Ctx) -> _Clip:
    return _held(n, ctx, ctx.rest.tpose)


def _clip_apose(n: int, ctx: _Ctx) -> _Clip:
    return _held(n, ctx, ctx.rest.apose)


def _side_variants(ctx: _Ctx, left_pose: np.ndarray) -> np.ndarray:
    """A left-side action as done by the left arm, the right arm, or both (mirrored)."""
    which = ctx.rng.choice(3, p=(0.35, 0.35, 0.3))
    if which == 0:
        return left_pose
    mirrored = mirror_pose(left_pose)
    if which == 1:
        return mirrored
    both = _symmetric(left_pose)
    both[:9] = 0.5 * (left_pose[:9] + mirrored[:9])  # trunk: the two sides cancel
    return both


def _clip_arm_raises(n: int, ctx: _Ctx) -> _Clip:
    """Raise an arm (or both) sideways, forwards, in the scapular plane or overhead, and lower."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 0.8)
        while True:
            kind = rng.choice(["lateral", "front", "scaption"])
            overhead = rng.random() < 0.35
            E = np.deg2rad(rng.uniform(140, 168) if overhead else rng.uniform(70, 100))
            plane = {"lateral": np.pi / 2, "front": 0.1, "scaption": np.deg2rad(35)}[kind]
            pose = neutral.copy()
            d = np.array([np.sin(E) * np.sin(plane), -np.sin(E) * np.cos(plane), -np.cos(E)])
            _point_arm(pose, "l", d, ctx, twist=rng.uniform(-0.3, 0.3))
            _set(pose, elbow_l=_straight_elbow(ctx) + rng.uniform(0.0, 0.2))
            _set(pose, wrist_l__x=ctx.rest.apose[_IX["wrist_l.x"]] + rng.uniform(-0.3, 0.3))
            _set(pose, spine__y=-0.08 * np.sin(plane) * np.sin(E), neck__x=-0.15 * overhead)
            yield _side_variants(ctx, pose), rng.uniform(0.2, 1.0)
            yield neutral, rng.uniform(0.1, 0.8)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.7)
    return _Clip(theta, np.zeros(n))


def _clip_reach(n: int, ctx: _Ctx) -> _Clip:
    """Reach in varied directions (forward, sideways, across, up, down to the knees)."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def reach_pose() -> np.ndarray:
        az = np.deg2rad(rng.uniform(-35, 100))  # + towards the reaching arm's side
        el = np.deg2rad(rng.uniform(-55, 65))  # + up
        down = max(0.0, -np.sin(el)) * rng.uniform(0.6, 1.0)
        pose = neutral.copy()
        pelvis = 0.45 * down
        _set(
            pose,
            root__x=pelvis,
            spine__x=0.1 * np.cos(az) * np.cos(el) + 0.55 * down,
            spine__y=0.2 * np.sin(az) * np.cos(el),
            spine__z=0.35 * np.sin(az) * rng.uniform(0.4, 1.0),
            neck__x=-0.45 * np.sin(el),
            neck__z=0.4 * np.sin(az),
        )
        bend = rng.uniform(0.0, 0.5) * down
        back = 0.1 * down
        _set_legs(pose, back + 0.6 * bend, -back + 0.4 * bend)
        d = np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
        _point_arm(pose, "l", d, ctx, twist=rng.uniform(-0.3, 0.3))
        _set(pose, elbow_l=_straight_elbow(ctx) + rng.uniform(0.0, 0.35))
        return _side_variants(ctx, pose)

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 0.8)
        while True:
            yield reach_pose(), rng.uniform(0.3, 1.2)
            if rng.random() < 0.6:
                yield neutral, rng.uniform(0.1, 0.6)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.7)
    return _Clip(theta, np.zeros(n))


def _clip_squat(n: int, ctx: _Ctx) -> _Clip:
    """Squats of varied depth (half to parallel), arms hanging or held forward."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def squat_pose() -> np.ndarray:
        thigh = rng.uniform(0.6, 1.35)  # thigh pitch from vertical
        shin = min(0.36, 0.15 + 0.2 * thigh)  # dorsiflexion limit ~0.4 rad
        pose = neutral.copy()
        _set(pose, root__x=0.2 + 0.25 * thigh, spine__x=0.05 + 0.12 * thigh, neck__x=-0.2 * thigh)
        _set_legs(pose, thigh, shin)
        if rng.random() < 0.5:  # arms forward for balance
            pitch = rng.uniform(-0.1, 0.25)
            for side, sx in (("l", 1.0), ("r", -1.0)):
                _point_arm(pose, side, _unit(sx * 0.15, -1.0, pitch), ctx)
                _set(pose, **{f"elbow_{side}": _straight_elbow(ctx) + rng.uniform(0.0, 0.3)})
        return pose

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 1.0)
        while True:
            yield squat_pose(), rng.uniform(0.0, 0.6)
            yield neutral, rng.uniform(0.3, 1.5)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.5)
    return _Clip(theta, np.zeros(n))


def _clip_bend(n: int, ctx: _Ctx) -> _Clip:
    """Bend forward at the hips and spine (hips shift back, arms hang), and straighten."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def bend_pose() -> np.ndarray:
        total = rng.uniform(0.6, 1.65)  # trunk pitch from vertical
        pelvis = min(0.62, 0.55 * total)
        pose = neutral.copy()
        _set(
            pose,
            root__x=pelvis,
            spine__x=total - pelvis,
            spine__y=rng.uniform(-0.15, 0.15),
            spine__z=rng.uniform(-0.2, 0.2),
            neck__x=-0.35 * total * rng.uniform(0.2, 1.0),
        )
        back = 0.1 * total  # hips shift back over the heels
        knees = rng.uniform(0.0, 0.3)
        _set_legs(pose, back + 0.5 * knees, -back + 0.5 * knees)
        for side, sx in (("l", 1.0), ("r", -1.0)):
            _point_arm(
                pose, side, _unit(sx * rng.uniform(0.05, 0.3), -rng.uniform(0, 0.3), -1), ctx
            )
            _set(pose, **{f"elbow_{side}": _straight_elbow(ctx) + rng.uniform(0.05, 0.4)})
        return pose

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 1.0)
        while True:
            yield bend_pose(), rng.uniform(0.3, 1.5)
            yield neutral, rng.uniform(0.3, 1.2)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.5)
    return _Clip(theta, np.zeros(n))


def _clip_walk_turn(n: int, ctx: _Ctx) -> _Clip:
    """March on the spot (alternate knee lifts, opposite arm swing) while turning.

    The heading turns at a constant rate chosen so a clip of n frames turns through at
    least 360 degrees when it lasts 4.5 s or more (rate <= 1.4 rad/s), in a random
    direction. One gait cycle lasts 1.15-1.5 s.
    """
    rng = ctx.rng
    t = ctx.times(n)
    duration = max(n / ctx.fps, 1e-9)
    theta = np.repeat(_neutral(ctx)[None], n, axis=0)
    period = rng.uniform(1.2, 1.5)
    phase = 2.0 * np.pi * t / period + rng.uniform(0, 2 * np.pi)
    lift_l = np.maximum(np.sin(phase), 0.0) ** 2
    lift_r = np.maximum(-np.sin(phase), 0.0) ** 2
    hip, knee, ankle = rng.uniform(0.35, 0.65), rng.uniform(0.55, 0.85), rng.uniform(0.1, 0.3)
    for s, lift in (("l", lift_l), ("r", lift_r)):
        theta[:, _IX[f"hip_{s}.x"]] += -hip * lift
        theta[:, _IX[f"knee_{s}"]] += knee * lift
        theta[:, _IX[f"ankle_{s}.x"]] += ankle * lift
    swing = rng.uniform(0.2, 0.45) * np.sin(phase)  # > 0 while the left knee rises
    theta[:, _IX["shoulder_l.x"]] += swing  # left arm back as the left knee comes up
    theta[:, _IX["shoulder_r.x"]] -= swing
    theta[:, _IX["elbow_l"]] += 0.15 + 0.08 * np.sin(phase + np.pi)  # more bent when forward
    theta[:, _IX["elbow_r"]] += 0.15 + 0.08 * np.sin(phase)
    theta[:, _IX["spine.z"]] += 0.04 * np.sin(phase)
    theta[:, _IX["root.y"]] += 0.025 * np.sin(phase)  # lean over the standing leg
    theta += _sway(ctx, n, 0.5)
    rate = min(1.4, max(0.45, 2.0 * np.pi / (0.92 * duration))) * rng.choice([-1.0, 1.0])
    return _Clip(theta, np.full(n, rate))


# Ranges of the random motion, left side (the right one is mirrored). Legs are given as
# thigh pitch / roll (hip corrected for the pelvis tilt) and scaled by a lift weight.
_RANDOM_RANGES: dict[str, tuple[float, float]] = {
    "root.x": (-0.08, 0.25),
    "root.y": (-0.1, 0.1),
    "spine.x": (-0.2, 0.8),
    "spine.y": (-0.35, 0.35),
    "spine.z": (-0.5, 0.5),
    "neck.x": (-0.4, 0.5),
    "neck.y": (-0.35, 0.35),
    "neck.z": (-0.9, 0.9),
    "shoulder_l.x": (-2.5, 0.6),
    "shoulder_l.y": (-2.0, 0.55),
    "shoulder_l.z": (-1.0, 1.0),
    "elbow_l": (-0.8, 1.5),
    "wrist_l.x": (-0.9, 0.7),
    "wrist_l.y": (-0.45, 0.3),
    "wrist_l.z": (-0.7, 1.0),
    "hip_l.x": (-0.9, 0.35),
    "hip_l.y": (-0.4, 0.08),
    "hip_l.z": (-0.3, 0.3),
    "knee_l": (0.4, 1.4),  # the moving leg keeps its foot clear of the floor
    "ankle_l.x": (-0.3, 0.5),
    "ankle_l.y": (-0.2, 0.2),
    "ankle_l.z": (-0.25, 0.25),
}


def _random_track(n: int, ctx: _Ctx, keys: list[str]) -> np.ndarray:
    """(n, len(keys)) smooth random values, each in a random sub-range of its range."""
    rng = ctx.rng
    lo = np.array([_RANDOM_RANGES[k][0] for k in keys])
    hi = np.array([_RANDOM_RANGES[k][1] for k in keys])
    width = (hi - lo) * rng.uniform(0.5, 1.0, size=len(keys))
    start = lo + rng.uniform(0.0, 1.0, size=len(keys)) * (hi - lo - width)
    half = 0.5 * width
    f_hi = np.minimum(0.5, RANDOM_JOINT_SPEED / (2.0 * np.pi * np.maximum(half, 1e-3)))
    unit = _smooth_unit(rng, ctx.times(n), 0.25 * f_hi, f_hi)
    return start + half + half * unit


def arm_intrusion(theta: np.ndarray, rest: RestPoseInfo | None = None) -> np.ndarray:
    """How deep each arm reaches into the head or the torso, metres (F, 2) (0 = clear).

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


def _smooth_time(x: np.ndarray, fps: float, sigma_s: float) -> np.ndarray:
    """Gaussian smoothing of (F,) ``x`` over time (edges held)."""
    r = max(1, round(3.0 * sigma_s * fps))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / (sigma_s * fps)) ** 2)
    padded = np.concatenate([np.full(r, x[0]), x, np.full(r, x[-1])])
    return np.convolve(padded, k / k.sum(), mode="valid")


def _max_filter(x: np.ndarray, half: int) -> np.ndarray:
    padded = np.concatenate([np.full(half, x[0]), x, np.full(half, x[-1])])
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=1)


def _keep_arms_clear(theta: np.ndarray, ctx: _Ctx) -> np.ndarray:
    """Fade an arm towards hanging wherever it would pass through the head or the chest.

    Frames where :func:`arm_intrusion` sees an arm inside are widened by 0.8 s and
    smoothed (Gaussian, 0.4 s), which gives a fade weight of at least 0.98 there that
    changes by at most 1.0 per second; repeated on the union of flagged frames until
    the arms are clear.
    """
    neutral = ctx.neutral
    flagged = np.zeros((len(theta), 2), dtype=bool)
    out = theta
    half = max(1, round(0.8 * ctx.fps))
    for _ in range(4):
        inside = arm_intrusion(out, ctx.rest) > 0.0
        if not (inside & ~flagged).any():
            break
        flagged |= inside
        out = theta.copy()
        for k, side in enumerate("lr"):
            if not flagged[:, k].any():
                continue
            weight = _smooth_time(_max_filter(flagged[:, k].astype(float), half), ctx.fps, 0.4)
            idx = np.r_[
                JOINT_SLICES[JOINTS.index(f"shoulder_{side}")],
                JOINT_SLICES[JOINTS.index(f"elbow_{side}")],
                JOINT_SLICES[JOINTS.index(f"wrist_{side}")],
            ]
            out[:, idx] += weight[:, None] * (neutral[idx] - theta[:, idx])
    return out


def _clip_random(n: int, ctx: _Ctx) -> _Clip:
    """Smooth random trajectories of every DOF around standing, heading drifting.

    Each DOF follows a weighted sum of three sinusoids of random frequency (up to
    ``RANDOM_JOINT_SPEED`` / (2 pi half-range), at most 0.5 Hz) in a random sub-range
    of ``_RANDOM_RANGES``. Legs move one at a time: a smooth lift weight shares the
    motion between them so that one leg stays close to standing. The heading turns
    at 0.25-0.6 rad/s on average (varying by up to ±0.45 rad/s).
    """
    rng = ctx.rng
    t = ctx.times(n)
    theta = np.repeat(ctx.rest.apose[None], n, axis=0)
    central = [k for k in _RANDOM_RANGES if k.split(".")[0] in ("root", "spine", "neck")]
    arm = [
        k for k in _RANDOM_RANGES if k.split(".")[0].split("_")[0] in ("shoulder", "elbow", "wrist")
    ]
    leg = [k for k in _RANDOM_RANGES if k.split(".")[0].split("_")[0] in ("hip", "knee", "ankle")]
    theta[:, [_IX[k] for k in central]] = _random_track(n, ctx, central)
    arm_idx = [_IX[k] for k in arm]
    for side in "lr":
        values = np.zeros((n, N_POSE))
        values[:, arm_idx] = _random_track(n, ctx, arm)
        if side == "r":
            values = mirror_pose(values)
        sel = [_IX[k.replace("_l", f"_{side}")] for k in arm]
        theta[:, sel] = values[:, sel]
    swap = _smooth_unit(rng, t, 0.04, 0.2)[:, 0]  # +1: the left leg moves, -1: the right
    leg_idx = [_IX[k] for k in leg]
    for side, weight in (("l", (0.5 * (1.0 + swap)) ** 2), ("r", (0.5 * (1.0 - swap)) ** 2)):
        values = np.zeros((n, N_POSE))
        values[:, leg_idx] = _random_track(n, ctx, leg) * weight[:, None]
        if side == "r":
            values = mirror_pose(values)
        sel = [_IX[k.replace("_l", f"_{side}")] for k in leg]
        theta[:, sel] = values[:, sel]
    for side in "lr":  # legs hang from the pelvis: undo its tilt so the ranges are global
        theta[:, _IX[f"hip_{side}.x"]] -= theta[:, _IX["root.x"]]
        theta[:, _IX[f"hip_{side}.y"]] -= theta[:, _IX["root.y"]]
    theta[:, YAW] = 0.0
    theta = _keep_arms_clear(theta, ctx)
    mean_rate = rng.uniform(0.25, 0.6) * rng.choice([-1.0, 1.0])
    rate = mean_rate + 0.45 * _smooth_unit(rng, t, 0.03, 0.15)[:, 0]
    return _Clip(theta, rate, stance=-swap)


_CLIPS: dict[str, Callable[[int, _Ctx], _Clip]] = {
    "random": _clip_random,
    "walk_turn": _clip_walk_turn,
    "arm_raises": _clip_arm_raises,
    "reach": _clip_reach,
    "squat": _clip_squat,
    "bend": _clip_bend,
    "tpose": _clip_tpose,
    "apose": _clip_apose,
}

#: Actions of ``mixed``: (probability, shortest and longest segment in seconds).
MIXED_ACTIONS: dict[str, tuple[float, float, float]] = {
    "random": (0.22, 3.0, 7.0),
    "walk_turn": (0.14, 3.0, 7.0),
    "arm_raises": (0.14, 4.0, 8.0),
    "reach": (0.16, 3.0, 7.0),
    "squat": (0.10, 4.0, 8.0),
    "bend": (0.10, 3.0, 6.0),
    "tpose": (0.07, 1.5, 3.0),
    "apose": (0.07, 1.5, 3.0),
}
#: Blends between ``mixed`` segments: the cross-fade adds at most this speed (rad/s) and
#: acceleration (rad/s²) on top of the segments' own; it lasts 0.5-2.5 s.
BLEND_SPEED = 1.5
BLEND_ACCEL = 10.0


def _blend_frames(a: np.ndarray, b: np.ndarray, fps: float, n_max: int) -> int:
    """Shortest cross-fade (frames) from track ``a`` into ``b`` within the blend bounds."""
    n_min = min(n_max, max(2, round(0.5 * fps)))
    step = max(1, round(0.1 * fps))
    for nb in range(n_min, n_max + 1, step):
        diff = np.delete(b[:nb] - a[len(a) - nb :], YAW, axis=1)
        d = float(np.max(np.abs(diff)))
        T = nb / fps
        if 1.875 * d / T <= BLEND_SPEED and 5.77 * d / T**2 <= BLEND_ACCEL:
            return nb
    return n_max


def _clip_mixed(n: int, ctx: _Ctx) -> _Clip:
    """A non-cyclic sequence of actions, each cross-faded into the next (minimum jerk)."""
    rng = ctx.rng
    names = list(MIXED_ACTIONS)
    prob = np.array([MIXED_ACTIONS[k][0] for k in names])
    theta = np.empty((0, N_POSE))
    yaw_rate = np.empty(0)
    last_name, last_len = None, 0
    while len(theta) < n:
        p = np.where(np.array(names) == last_name, 0.0, prob)
        name = names[rng.choice(len(names), p=p / p.sum())]
        _, lo, hi = MIXED_ACTIONS[name]
        seg = max(1, round(rng.uniform(lo, hi) * ctx.fps))
        if last_name is None:
            clip = _CLIPS[name](seg, ctx)
            theta, yaw_rate, stance = clip.theta, clip.yaw_rate, clip.support()
        else:
            nb_max = max(1, min(round(2.5 * ctx.fps), last_len // 2, seg))
            clip = _CLIPS[name](seg + nb_max, ctx)
            nb = _blend_frames(theta, clip.theta, ctx.fps, nb_max)
            w = _minjerk((np.arange(nb) + 1.0) / (nb + 1.0))
            head = len(theta) - nb
            theta = theta.copy()
            theta[head:] = (1 - w)[:, None] * theta[head:] + w[:, None] * clip.theta[:nb]
            yaw_rate = yaw_rate.copy()
            yaw_rate[head:] = (1 - w) * yaw_rate[head:] + w * clip.yaw_rate[:nb]
            stance = stance.copy()
            stance[head:] = (1 - w) * stance[head:] + w * clip.support()[:nb]
            theta = np.concatenate([theta, clip.theta[nb : nb + seg]])
            yaw_rate = np.concatenate([yaw_rate, clip.yaw_rate[nb : nb + seg]])
            stance = np.concatenate([stance, clip.support()[nb : nb + seg]])
        last_name, last_len = name, seg
    return _Clip(theta[:n], yaw_rate[:n], stance[:n])


_CLIPS["mixed"] = _clip_mixed


# ----------------------------------------------------------------------------------------
# From a clip to a Motion: heading and root placement
# ----------------------------------------------------------------------------------------
def _headings(clip: _Clip, fps: float, heading0: float) -> np.ndarray:
    rate = clip.yaw_rate
    turned = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) / fps)])
    return _wrap(heading0 + turned + clip.theta[:, YAW])


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
    :func:`ground_motion` corrects the height on the actual mesh.
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


def _finish(name: str, clip: _Clip, ctx: _Ctx, root_height: float) -> Motion:
    theta = _soft_clip(clip.theta, ctx.limits)
    theta[:, YAW] = _headings(clip, ctx.fps, ctx.rng.uniform(-np.pi, np.pi))
    tau = place_root(theta, ctx.fps, rest=ctx.rest.scaled(root_height), stance=clip.stance)
    return Motion(theta, tau, ctx.fps, name)


# ----------------------------------------------------------------------------------------
# Public generators
# ----------------------------------------------------------------------------------------
MotionGenerator = Callable[
    [int, float, np.random.Generator, JointLimits, float, RestPoseInfo], Motion
]


def _generator(name: str) -> MotionGenerator:
    clip_fn = _CLIPS[name]

    def generate(
        n_frames: int,
        fps: float,
        rng: np.random.Generator,
        limits: JointLimits,
        root_height: float,
        rest_pose_info: RestPoseInfo,
    ) -> Motion:
        ctx = _Ctx(float(fps), rng, limits, rest_pose_info)
        return _finish(name, clip_fn(int(n_frames), ctx), ctx, float(root_height))

    generate.__name__ = f"generate_{name}"
    generate.__doc__ = (clip_fn.__doc__ or "").split("\n")[0]
    return generate


#: name -> generator ``(n_frames, fps, rng, limits, root_height, rest_pose_info) -> Motion``.
MOTIONS: dict[str, MotionGenerator] = {name: _generator(name) for name in _CLIPS}
#: The motion sessions use unless told otherwise.
DEFAULT_MOTION = "mixed"


def make_motion(
    name: str = DEFAULT_MOTION,
    n_frames: int = 600,
    fps: float = 60.0,
    seed: int = 0,
    *,
    limits: JointLimits | None = None,
    root_height: float | None = None,
    rest: RestPoseInfo | None = None,
) -> Motion:
    """Generate library motion ``name``; the same arguments give identical arrays.

    Parameters
    ----------
    name : str
        A key of :data:`MOTIONS`.
    n_frames : int
        Frames (>= 1).
    fps : float
        Frame rate; trajectories are defined in seconds, so the rate only samples them.
    seed : int
        Non-negative; use :func:`seed_for` to keep training and test draws apart.
    limits : JointLimits, optional
        Default: the committed model's (:func:`default_limits`).
    root_height : float, optional
        Standing root (mid-hip) height of the subject, metres; default: that of
        ``rest`` (0.881 m for the mean body).
    rest : RestPoseInfo, optional
        Body proportions and named poses; default the mean body
        (``RestPoseInfo.from_model(model, nu)`` for a given subject).
    """
    if name not in MOTIONS:
        raise ValueError(f"motion: unknown name {name!r}; expected one of {sorted(MOTIONS)}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, int | np.integer) or n_frames < 1:
        raise ValueError(f"motion {name}: n_frames must be a positive integer, got {n_frames!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"motion {name}: fps must be positive, got {fps!r}")
    rest = RestPoseInfo.default() if rest is None else rest
    root_height = rest.root_height if root_height is None else float(root_height)
    if not (np.isfinite(root_height) and 0.3 < root_height < 2.0):
        raise ValueError(f"motion {name}: root_height must be in (0.3, 2.0) m, got {root_height}")
    limits = default_limits() if limits is None else limits
    rng = motion_rng(name, seed)
    return MOTIONS[name](int(n_frames), float(fps), rng, limits, root_height, rest)


def sample_pose_prior(
    rng: np.random.Generator,
    n: int,
    limits: JointLimits | None = None,
    *,
    rest: RestPoseInfo | None = None,
    clip_seconds: float = 12.0,
    per_clip: int = 6,
    uniform_heading: bool = True,
) -> np.ndarray:
    """Independent pose draws (n, 37) for training sets (the paper's §6 draws from mocap).

    Draws ``ceil(n / per_clip)`` ``mixed`` clips of ``clip_seconds`` (sampled at 10 fps)
    and takes ``per_clip`` distinct random frames of each, then shuffles. With
    ``uniform_heading`` the heading is redrawn uniformly in [-pi, pi) (the clips'
    headings only drift). For root positions use :func:`place_root` (independent
    frames) and then :func:`ground_motion`.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"sample_pose_prior: n must be a non-negative integer, got {n!r}")
    per_clip = int(per_clip)
    frames = max(per_clip, round(clip_seconds * 10.0))
    if per_clip < 1:
        raise ValueError(f"sample_pose_prior: per_clip must be >= 1, got {per_clip}")
    limits = default_limits() if limits is None else limits
    rest = RestPoseInfo.default() if rest is None else rest
    ctx = _Ctx(10.0, rng, limits, rest)
    out = np.empty((0, N_POSE))
    chunks = []
    for _ in range(-(-int(n) // per_clip)):
        clip = _clip_mixed(frames, ctx)
        theta = _soft_clip(clip.theta, limits)
        theta[:, YAW] = _headings(clip, ctx.fps, rng.uniform(-np.pi, np.pi))
        chunks.append(theta[rng.choice(frames, size=per_clip, replace=False)])
    if chunks:
        out = np.concatenate(chunks)[: int(n)]
        out = out[rng.permutation(len(out))]
    if uniform_heading:
        out[:, YAW] = rng.uniform(-np.pi, np.pi, size=len(out))
    return out


# ----------------------------------------------------------------------------------------
# Grounding on the actual mesh
# ----------------------------------------------------------------------------------------
def ground_motion(
    model: BodyModel, motion: Motion, nu: np.ndarray, *, lod: bool = True, batch: int = 64
) -> Motion:
    """Shift τ_z per frame so the lowest vertex of the posed body touches z = 0.

    Parameters
    ----------
    model : BodyModel
    motion : Motion
    nu : (n_shape,) or (1, n_shape) float
        The subject's shape.
    lod : bool
        Pose the ~3k-triangle level of detail (fast; within a few mm of the full mesh).
    batch : int
        Frames posed per call.
    """
    from bodymetry.estimation.body_model.model import BodyState  # deferred: keeps import numpy-only

    nu = np.atleast_2d(np.asarray(nu, dtype=float))
    lowest = np.empty(len(motion))
    for s in range(0, len(motion), int(batch)):
        e = min(len(motion), s + int(batch))
        body = model.pose(BodyState(motion.tau[s:e], motion.theta[s:e], nu), lod=lod)
        lowest[s:e] = body.vertices[..., 2].min(axis=1)
    tau = motion.tau.copy()
    tau[:, 2] -= lowest
    return Motion(motion.theta, tau, motion.fps, motion.name)
