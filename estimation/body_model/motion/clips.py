"""Clips of the motion library: body-relative θ tracks before heading and root placement.

A clip generator ``(n, ctx) -> Clip`` draws from ``ctx.rng`` the joint angles of
``n`` frames, with ``root.z`` holding a heading *offset*, plus a heading rate:
held T- and A-poses, arm raises, reaching, squats, bending forward, marching on the
spot while turning, smooth random trajectories, and ``mixed``, a non-cyclic
sequence of all of them joined by minimum-jerk cross-fades. ``CLIPS`` maps the
library names to generators; ``library`` turns a clip into a ``Motion`` (soft clip
into the limits, headings, root placement) and ``prior`` samples poses from
``mixed`` clips.

The plausibility bounds the library promises are defined here (SI units); the
design speeds of scripted moves, random motion and blends keep clips inside them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bodymetry.estimation.body_model.motion.contact import arm_intrusion
from bodymetry.estimation.body_model.motion.ik import (
    neutral_pose,
    point_arm,
    set_dofs,
    set_legs,
    straight_elbow,
    unit,
)
from bodymetry.estimation.body_model.motion.rest import (
    DOF_INDEX,
    RestPoseInfo,
    mirror_pose,
    symmetric,
)
from bodymetry.estimation.body_model.motion.signals import (
    inner_clip,
    max_filter,
    minjerk,
    smooth_time,
    smooth_unit,
    wrap_angle,
)
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, N_POSE, YAW, JointLimits

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


@dataclass
class Clip:
    """θ with ``root.z`` holding a heading *offset*, plus a heading rate (rad/s)."""

    theta: np.ndarray  # (F, 37)
    yaw_rate: np.ndarray  # (F,)
    stance: np.ndarray | None = None  # (F,) intended support, +1 left foot, -1 right foot

    def support(self) -> np.ndarray:
        """(F,) intended support: ``stance``, or 0 (either foot) without one."""
        return np.zeros(len(self.theta)) if self.stance is None else self.stance

    def headings(self, fps: float, heading0: float) -> np.ndarray:
        """(F,) world headings in [-pi, pi): ``heading0``, the integrated rate, the offset."""
        rate = self.yaw_rate
        turned = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) / fps)])
        return wrap_angle(heading0 + turned + self.theta[:, YAW])


@dataclass(frozen=True)
class ClipContext:
    """What a clip generator draws with: frame rate, generator, limits and body."""

    fps: float
    rng: np.random.Generator
    limits: JointLimits
    rest: RestPoseInfo

    def times(self, n: int) -> np.ndarray:
        """(n,) seconds of the first ``n`` frames."""
        return np.arange(n) / self.fps

    @cached_property
    def neutral(self) -> np.ndarray:
        """(37,) relaxed standing (:func:`~.ik.neutral_pose`)."""
        return neutral_pose(self.rest, self.limits)


def _neutral(ctx: ClipContext) -> np.ndarray:
    """A writable copy of ``ctx.neutral`` (37,)."""
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


def _sway(ctx: ClipContext, n: int, scale: float = 1.0) -> np.ndarray:
    """Small natural sway (n, 37): 0.1-0.5 Hz, a few centiradians (more for head and arms)."""
    return scale * _SWAY * smooth_unit(ctx.rng, ctx.times(n), 0.1, 0.5)


def _move_time(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> float:
    """Duration of a minimum-jerk move a -> b within KEY_SPEED and KEY_ACCEL, plus pace."""
    d = float(np.max(np.abs(np.delete(b - a, YAW)))) if a is not None else 0.0
    T = max(0.4, 1.875 * d / KEY_SPEED, np.sqrt(5.77 * d / KEY_ACCEL))
    return T * rng.uniform(1.0, 1.5)


def _keyframes(n: int, ctx: ClipContext, keys: Iterator[tuple[np.ndarray, float]]) -> np.ndarray:
    """(n, 37) track through key poses: hold each for its time, then a minimum-jerk move."""
    t = ctx.times(n)
    out = np.zeros((n, N_POSE))
    clock = -ctx.rng.uniform(0.0, 0.3)
    prev: np.ndarray | None = None
    for pose, hold in keys:
        pose = inner_clip(pose, ctx.limits)
        if prev is not None:
            T = _move_time(prev, pose, ctx.rng)
            sel = (t >= clock) & (t < clock + T)
            out[sel] = prev + minjerk((t[sel] - clock) / T)[:, None] * (pose - prev)
            clock += T
        sel = (t >= clock) & (t < clock + hold)
        out[sel] = pose
        clock += hold
        prev = pose
        if clock > t[-1]:
            break
    return out


def _held(n: int, ctx: ClipContext, pose: np.ndarray) -> Clip:
    theta = inner_clip(pose, ctx.limits) + _sway(ctx, n)
    return Clip(theta, np.zeros(n))


def _clip_tpose(n: int, ctx: ClipContext) -> Clip:
    return _held(n, ctx, ctx.rest.tpose)


def _clip_apose(n: int, ctx: ClipContext) -> Clip:
    return _held(n, ctx, ctx.rest.apose)


def _side_variants(ctx: ClipContext, left_pose: np.ndarray) -> np.ndarray:
    """A left-side action as done by the left arm, the right arm, or both (mirrored)."""
    which = ctx.rng.choice(3, p=(0.35, 0.35, 0.3))
    if which == 0:
        return left_pose
    mirrored = mirror_pose(left_pose)
    if which == 1:
        return mirrored
    both = symmetric(left_pose)
    both[:9] = 0.5 * (left_pose[:9] + mirrored[:9])  # trunk: the two sides cancel
    return both


def _clip_arm_raises(n: int, ctx: ClipContext) -> Clip:
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
            point_arm(pose, "l", d, ctx.rest, ctx.limits, ctx.neutral, rng.uniform(-0.3, 0.3))
            set_dofs(pose, elbow_l=straight_elbow(ctx.rest) + rng.uniform(0.0, 0.2))
            set_dofs(
                pose, wrist_l__x=ctx.rest.apose[DOF_INDEX["wrist_l.x"]] + rng.uniform(-0.3, 0.3)
            )
            set_dofs(pose, spine__y=-0.08 * np.sin(plane) * np.sin(E), neck__x=-0.15 * overhead)
            yield _side_variants(ctx, pose), rng.uniform(0.2, 1.0)
            yield neutral, rng.uniform(0.1, 0.8)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.7)
    return Clip(theta, np.zeros(n))


def _clip_reach(n: int, ctx: ClipContext) -> Clip:
    """Reach in varied directions (forward, sideways, across, up, down to the knees)."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def reach_pose() -> np.ndarray:
        az = np.deg2rad(rng.uniform(-35, 100))  # + towards the reaching arm's side
        el = np.deg2rad(rng.uniform(-55, 65))  # + up
        down = max(0.0, -np.sin(el)) * rng.uniform(0.6, 1.0)
        pose = neutral.copy()
        pelvis = 0.45 * down
        set_dofs(
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
        set_legs(pose, back + 0.6 * bend, -back + 0.4 * bend)
        d = np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
        point_arm(pose, "l", d, ctx.rest, ctx.limits, ctx.neutral, rng.uniform(-0.3, 0.3))
        set_dofs(pose, elbow_l=straight_elbow(ctx.rest) + rng.uniform(0.0, 0.35))
        return _side_variants(ctx, pose)

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 0.8)
        while True:
            yield reach_pose(), rng.uniform(0.3, 1.2)
            if rng.random() < 0.6:
                yield neutral, rng.uniform(0.1, 0.6)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.7)
    return Clip(theta, np.zeros(n))


def _clip_squat(n: int, ctx: ClipContext) -> Clip:
    """Squats of varied depth (half to parallel), arms hanging or held forward."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def squat_pose() -> np.ndarray:
        thigh = rng.uniform(0.6, 1.35)  # thigh pitch from vertical
        shin = min(0.36, 0.15 + 0.2 * thigh)  # dorsiflexion limit ~0.4 rad
        pose = neutral.copy()
        set_dofs(
            pose, root__x=0.2 + 0.25 * thigh, spine__x=0.05 + 0.12 * thigh, neck__x=-0.2 * thigh
        )
        set_legs(pose, thigh, shin)
        if rng.random() < 0.5:  # arms forward for balance
            pitch = rng.uniform(-0.1, 0.25)
            for side, sx in (("l", 1.0), ("r", -1.0)):
                d = unit(sx * 0.15, -1.0, pitch)
                point_arm(pose, side, d, ctx.rest, ctx.limits, ctx.neutral)
                elbow = straight_elbow(ctx.rest) + rng.uniform(0.0, 0.3)
                set_dofs(pose, **{f"elbow_{side}": elbow})
        return pose

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 1.0)
        while True:
            yield squat_pose(), rng.uniform(0.0, 0.6)
            yield neutral, rng.uniform(0.3, 1.5)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.5)
    return Clip(theta, np.zeros(n))


def _clip_bend(n: int, ctx: ClipContext) -> Clip:
    """Bend forward at the hips and spine (hips shift back, arms hang), and straighten."""
    rng = ctx.rng
    neutral = _neutral(ctx)

    def bend_pose() -> np.ndarray:
        total = rng.uniform(0.6, 1.65)  # trunk pitch from vertical
        pelvis = min(0.62, 0.55 * total)
        pose = neutral.copy()
        set_dofs(
            pose,
            root__x=pelvis,
            spine__x=total - pelvis,
            spine__y=rng.uniform(-0.15, 0.15),
            spine__z=rng.uniform(-0.2, 0.2),
            neck__x=-0.35 * total * rng.uniform(0.2, 1.0),
        )
        back = 0.1 * total  # hips shift back over the heels
        knees = rng.uniform(0.0, 0.3)
        set_legs(pose, back + 0.5 * knees, -back + 0.5 * knees)
        for side, sx in (("l", 1.0), ("r", -1.0)):
            d = unit(sx * rng.uniform(0.05, 0.3), -rng.uniform(0, 0.3), -1)
            point_arm(pose, side, d, ctx.rest, ctx.limits, ctx.neutral)
            set_dofs(pose, **{f"elbow_{side}": straight_elbow(ctx.rest) + rng.uniform(0.05, 0.4)})
        return pose

    def keys() -> Iterator[tuple[np.ndarray, float]]:
        yield neutral, rng.uniform(0.2, 1.0)
        while True:
            yield bend_pose(), rng.uniform(0.3, 1.5)
            yield neutral, rng.uniform(0.3, 1.2)

    theta = _keyframes(n, ctx, keys()) + _sway(ctx, n, 0.5)
    return Clip(theta, np.zeros(n))


def _clip_walk_turn(n: int, ctx: ClipContext) -> Clip:
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
        theta[:, DOF_INDEX[f"hip_{s}.x"]] += -hip * lift
        theta[:, DOF_INDEX[f"knee_{s}"]] += knee * lift
        theta[:, DOF_INDEX[f"ankle_{s}.x"]] += ankle * lift
    swing = rng.uniform(0.2, 0.45) * np.sin(phase)  # > 0 while the left knee rises
    theta[:, DOF_INDEX["shoulder_l.x"]] += swing  # left arm back as the left knee comes up
    theta[:, DOF_INDEX["shoulder_r.x"]] -= swing
    theta[:, DOF_INDEX["elbow_l"]] += 0.15 + 0.08 * np.sin(phase + np.pi)  # more bent when forward
    theta[:, DOF_INDEX["elbow_r"]] += 0.15 + 0.08 * np.sin(phase)
    theta[:, DOF_INDEX["spine.z"]] += 0.04 * np.sin(phase)
    theta[:, DOF_INDEX["root.y"]] += 0.025 * np.sin(phase)  # lean over the standing leg
    theta += _sway(ctx, n, 0.5)
    rate = min(1.4, max(0.45, 2.0 * np.pi / (0.92 * duration))) * rng.choice([-1.0, 1.0])
    return Clip(theta, np.full(n, rate))


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


def _random_track(n: int, ctx: ClipContext, keys: list[str]) -> np.ndarray:
    """(n, len(keys)) smooth random values, each in a random sub-range of its range."""
    rng = ctx.rng
    lo = np.array([_RANDOM_RANGES[k][0] for k in keys])
    hi = np.array([_RANDOM_RANGES[k][1] for k in keys])
    width = (hi - lo) * rng.uniform(0.5, 1.0, size=len(keys))
    start = lo + rng.uniform(0.0, 1.0, size=len(keys)) * (hi - lo - width)
    half = 0.5 * width
    f_hi = np.minimum(0.5, RANDOM_JOINT_SPEED / (2.0 * np.pi * np.maximum(half, 1e-3)))
    unit = smooth_unit(rng, ctx.times(n), 0.25 * f_hi, f_hi)
    return start + half + half * unit


def _keep_arms_clear(theta: np.ndarray, ctx: ClipContext) -> np.ndarray:
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
            weight = smooth_time(max_filter(flagged[:, k].astype(float), half), ctx.fps, 0.4)
            idx = np.r_[
                JOINT_SLICES[JOINTS.index(f"shoulder_{side}")],
                JOINT_SLICES[JOINTS.index(f"elbow_{side}")],
                JOINT_SLICES[JOINTS.index(f"wrist_{side}")],
            ]
            out[:, idx] += weight[:, None] * (neutral[idx] - theta[:, idx])
    return out


def _clip_random(n: int, ctx: ClipContext) -> Clip:
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
    theta[:, [DOF_INDEX[k] for k in central]] = _random_track(n, ctx, central)
    arm_idx = [DOF_INDEX[k] for k in arm]
    for side in "lr":
        values = np.zeros((n, N_POSE))
        values[:, arm_idx] = _random_track(n, ctx, arm)
        if side == "r":
            values = mirror_pose(values)
        sel = [DOF_INDEX[k.replace("_l", f"_{side}")] for k in arm]
        theta[:, sel] = values[:, sel]
    swap = smooth_unit(rng, t, 0.04, 0.2)[:, 0]  # +1: the left leg moves, -1: the right
    leg_idx = [DOF_INDEX[k] for k in leg]
    for side, weight in (("l", (0.5 * (1.0 + swap)) ** 2), ("r", (0.5 * (1.0 - swap)) ** 2)):
        values = np.zeros((n, N_POSE))
        values[:, leg_idx] = _random_track(n, ctx, leg) * weight[:, None]
        if side == "r":
            values = mirror_pose(values)
        sel = [DOF_INDEX[k.replace("_l", f"_{side}")] for k in leg]
        theta[:, sel] = values[:, sel]
    for side in "lr":  # legs hang from the pelvis: undo its tilt so the ranges are global
        theta[:, DOF_INDEX[f"hip_{side}.x"]] -= theta[:, DOF_INDEX["root.x"]]
        theta[:, DOF_INDEX[f"hip_{side}.y"]] -= theta[:, DOF_INDEX["root.y"]]
    theta[:, YAW] = 0.0
    theta = _keep_arms_clear(theta, ctx)
    mean_rate = rng.uniform(0.25, 0.6) * rng.choice([-1.0, 1.0])
    rate = mean_rate + 0.45 * smooth_unit(rng, t, 0.03, 0.15)[:, 0]
    return Clip(theta, rate, stance=-swap)


CLIPS: dict[str, Callable[[int, ClipContext], Clip]] = {
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


def _clip_mixed(n: int, ctx: ClipContext) -> Clip:
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
            clip = CLIPS[name](seg, ctx)
            theta, yaw_rate, stance = clip.theta, clip.yaw_rate, clip.support()
        else:
            nb_max = max(1, min(round(2.5 * ctx.fps), last_len // 2, seg))
            clip = CLIPS[name](seg + nb_max, ctx)
            nb = _blend_frames(theta, clip.theta, ctx.fps, nb_max)
            w = minjerk((np.arange(nb) + 1.0) / (nb + 1.0))
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
    return Clip(theta[:n], yaw_rate[:n], stance[:n])


CLIPS["mixed"] = _clip_mixed
