"""Tests for bodymetry.estimation.body_model.motion.library (and its clips): the motion library.

Bounds come from ``clips`` (``MAX_JOINT_SPEED`` etc.); every motion is checked
against them at 60 fps by finite differences. Semantic checks pose the skeleton
with forward kinematics to catch sign errors (a squat must bend the knees forward,
a bend must tip the trunk forward, a T-pose must hold the arms out level).
"""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.motion.clips import (
    MAX_JOINT_ACCEL,
    MAX_JOINT_SPEED,
    MAX_ROOT_SPEED,
    MAX_YAW_RATE,
    RANDOM_JOINT_SPEED,
)
from bodymetry.estimation.body_model.motion.contact import arm_intrusion
from bodymetry.estimation.body_model.motion.library import (
    DEFAULT_MOTION,
    MOTIONS,
    Motion,
    ground_motion,
    make_motion,
)
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo, default_limits
from bodymetry.estimation.body_model.motion.seeds import seed_for
from bodymetry.estimation.body_model.skeleton import (
    JOINTS,
    N_POSE,
    YAW,
    JointLimits,
    forward_kinematics,
)

# --------------------------------------------------------------------------------------
# Tolerances and sizes, all in one place.
# --------------------------------------------------------------------------------------
FPS = 60.0
N_FRAMES = 600  # 10 s at 60 fps
SEEDS = (seed_for("test", 0), seed_for("test", 1))
# ground_motion on the LOD puts its lowest vertex on the floor (float round-off only).
GROUND_LOD_ATOL = 1e-6
# The full mesh's lowest vertex against the LOD's: the LOD lies within 1.2 cm of the
# full surface (test_body_model); measured up to 1.3 cm at the soles.
GROUND_FULL_ATOL = 0.02
# Skeleton-only root placement (place_root) against the mesh grounding: measured
# -10..+8 mm over all motions and 6 seeds.
PLACE_ROOT_ATOL = 0.02
HEADING_BINS = 36


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


def _finite_differences(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame velocity (F-1, 37) and acceleration (F-2, 37), heading unwrapped."""
    d = np.diff(motion.theta, axis=0)
    d[:, YAW] = (d[:, YAW] + np.pi) % (2.0 * np.pi) - np.pi
    return d * motion.fps, np.diff(d, axis=0) * motion.fps**2


def _fk(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    rest = RestPoseInfo.default()
    return forward_kinematics(motion.theta, motion.tau, rest.joints, rest.hinge_axes)


def _forward(motion: Motion) -> np.ndarray:
    """(F, 3) the direction each frame's body faces (heading applied to -y)."""
    h = motion.theta[:, YAW]
    return np.stack([np.sin(h), -np.cos(h), np.zeros_like(h)], axis=1)


J = {name: i for i, name in enumerate(JOINTS)}


# --------------------------------------------------------------------------------------
# Library, shapes, limits, determinism
# --------------------------------------------------------------------------------------
def test_library_has_the_required_motions() -> None:
    required = {
        "random",
        "walk_turn",
        "arm_raises",
        "reach",
        "squat",
        "bend",
        "tpose",
        "apose",
        "mixed",
    }
    assert required <= set(MOTIONS)
    assert DEFAULT_MOTION == "mixed"


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_motion_shapes_limits_and_root_height(name: str) -> None:
    limits = default_limits()
    for seed in SEEDS:
        m = make_motion(name, N_FRAMES, FPS, seed)
        assert m.theta.shape == (N_FRAMES, N_POSE)
        assert m.tau.shape == (N_FRAMES, 3)
        assert m.fps == FPS and m.name == name and len(m) == N_FRAMES
        assert np.all(limits.contains(m.theta))
        assert np.all(m.theta[:, YAW] >= -np.pi) and np.all(m.theta[:, YAW] < np.pi)
        assert np.all(m.tau[:, 2] > 0.3)


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_motion_is_smooth_within_stated_bounds(name: str) -> None:
    for seed in SEEDS:
        m = make_motion(name, N_FRAMES, FPS, seed)
        vel, acc = _finite_differences(m)
        joint_vel = np.delete(vel, YAW, axis=1)
        assert np.abs(joint_vel).max() <= MAX_JOINT_SPEED
        assert np.abs(acc).max() <= MAX_JOINT_ACCEL
        assert np.abs(vel[:, YAW]).max() <= MAX_YAW_RATE
        root_speed = np.linalg.norm(np.diff(m.tau, axis=0), axis=1) * m.fps
        assert root_speed.max() <= MAX_ROOT_SPEED


def test_random_motion_stays_under_its_design_speed() -> None:
    m = make_motion("random", N_FRAMES, FPS, SEEDS[0])
    vel, _ = _finite_differences(m)
    # The arm fade (keep-clear) may add up to ~1 rad/s on top of the design speed.
    assert np.abs(np.delete(vel, YAW, axis=1)).max() <= RANDOM_JOINT_SPEED + 1.0


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_same_seed_same_motion_other_seed_other_motion(name: str) -> None:
    a = make_motion(name, 200, FPS, SEEDS[0])
    b = make_motion(name, 200, FPS, SEEDS[0])
    c = make_motion(name, 200, FPS, SEEDS[1])
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.tau, b.tau)
    assert not np.allclose(a.theta, c.theta)


def test_motions_with_the_same_seed_are_independent() -> None:
    a = make_motion("random", 100, FPS, 7)
    b = make_motion("mixed", 100, FPS, 7)
    assert not np.allclose(a.theta[:, YAW], b.theta[:, YAW])


def test_narrower_limits_are_respected() -> None:
    limits = JointLimits.default()  # elbow cannot straighten fully here
    for name in ("tpose", "arm_raises", "mixed"):
        m = make_motion(name, 300, FPS, SEEDS[0], limits=limits)
        assert np.all(limits.contains(m.theta))


def test_root_height_scales_with_the_subject() -> None:
    short = make_motion("squat", 300, FPS, SEEDS[0], root_height=0.75)
    tall = make_motion("squat", 300, FPS, SEEDS[0], root_height=1.05)
    assert np.array_equal(short.theta, tall.theta)
    ratio = tall.tau[:, 2] / short.tau[:, 2]
    # Proportional up to the 2 mm softness of the lowest-contact minimum (not scaled).
    assert np.allclose(ratio, 1.05 / 0.75, rtol=3e-3)
    # Standing frames keep the root near its standing height, squats lower it.
    assert tall.tau[:, 2].max() == pytest.approx(1.05, abs=0.03)
    assert tall.tau[:, 2].min() < 1.05 - 0.2


# --------------------------------------------------------------------------------------
# Headings
# --------------------------------------------------------------------------------------
def test_walk_turn_covers_all_headings() -> None:
    for seed in SEEDS:
        m = make_motion("walk_turn", 360, FPS, seed)  # 6 s
        heading = m.theta[:, YAW]
        counts, _ = np.histogram(heading, bins=HEADING_BINS, range=(-np.pi, np.pi))
        assert np.all(counts > 0)
        assert abs(np.unwrap(heading)[-1] - heading[0]) >= 2.0 * np.pi


def test_random_heading_drifts_through_a_full_turn() -> None:
    m = make_motion("random", 1200, 30.0, SEEDS[0])  # 40 s
    turned = np.unwrap(m.theta[:, YAW])
    assert abs(turned[-1] - turned[0]) >= 2.0 * np.pi


def test_start_headings_are_uniform_over_seeds() -> None:
    starts = [make_motion("tpose", 2, FPS, s).theta[0, YAW] for s in range(200)]
    counts, _ = np.histogram(starts, bins=4, range=(-np.pi, np.pi))
    assert np.all(counts > 25)


# --------------------------------------------------------------------------------------
# Semantics (sign conventions) via forward kinematics
# --------------------------------------------------------------------------------------
def test_tpose_holds_the_arms_out_level() -> None:
    m = make_motion("tpose", 60, FPS, SEEDS[0])
    _, joints = _fk(m)
    for side in "lr":
        s, w = joints[:, J[f"shoulder_{side}"]], joints[:, J[f"wrist_{side}"]]
        arm = w - s
        assert np.all(np.abs(arm[:, 2]) < 0.06)  # level within 6 cm over ~50 cm
        assert np.all(np.linalg.norm(arm[:, :2], axis=1) > 0.4)
        # Outwards: away from the other shoulder.
        other = joints[:, J["shoulder_r" if side == "l" else "shoulder_l"]]
        assert np.all(np.einsum("fi,fi->f", arm, s - other) > 0)


def test_squat_bends_the_knees_forward_and_lowers_the_hips() -> None:
    m = make_motion("squat", N_FRAMES, FPS, SEEDS[0])
    _, joints = _fk(m)
    f = int(np.argmin(m.tau[:, 2]))
    fwd = _forward(m)[f]
    assert m.tau[f, 2] < m.tau[:, 2].max() - 0.2
    for side in "lr":
        hip, knee, ankle = (joints[f, J[f"{j}_{side}"]] for j in ("hip", "knee", "ankle"))
        assert (knee - hip) @ fwd > 0.15  # knee well ahead of the hip
        assert (knee - ankle) @ fwd > 0.05  # and ahead of the ankle
        assert ankle[2] < 0.12  # feet stay on the floor
    # The trunk leans forward.
    trunk = joints[f, J["neck"]] - joints[f, J["root"]]
    assert trunk @ fwd > 0.1


def test_bend_tips_the_trunk_forward() -> None:
    m = make_motion("bend", N_FRAMES, FPS, SEEDS[0])
    _, joints = _fk(m)
    trunk = joints[:, J["neck"]] - joints[:, J["root"]]
    ahead = np.einsum("fi,fi->f", trunk, _forward(m))
    f = int(np.argmax(ahead))
    assert ahead[f] > 0.3
    assert joints[f, J["neck"], 2] < joints[:, J["neck"], 2].max() - 0.15
    # Hips shift back over the heels rather than forward.
    mid_ankle = 0.5 * (joints[f, J["ankle_l"]] + joints[f, J["ankle_r"]])
    assert (joints[f, J["root"]] - mid_ankle) @ _forward(m)[f] < 0.0


def test_arm_raises_reach_shoulder_height_and_above() -> None:
    m = make_motion("arm_raises", 1200, FPS, SEEDS[0])
    _, joints = _fk(m)
    wrist_up = np.maximum(
        joints[:, J["wrist_l"], 2] - joints[:, J["shoulder_l"], 2],
        joints[:, J["wrist_r"], 2] - joints[:, J["shoulder_r"], 2],
    )
    assert wrist_up.max() > 0.0
    assert wrist_up.min() < -0.4  # and hang down in between


def test_walk_turn_lifts_the_knees_forward_alternately() -> None:
    m = make_motion("walk_turn", 360, FPS, SEEDS[0])
    _, joints = _fk(m)
    fwd = _forward(m)
    for side in "lr":
        ahead = np.einsum(
            "fi,fi->f", joints[:, J[f"knee_{side}"]] - joints[:, J[f"hip_{side}"]], fwd
        )
        assert ahead.max() > 0.12
    lift_l = joints[:, J["ankle_l"], 2]
    lift_r = joints[:, J["ankle_r"], 2]
    assert np.corrcoef(lift_l, lift_r)[0, 1] < 0  # alternate


@pytest.mark.parametrize("name", ["random", "reach", "mixed"])
def test_arms_stay_out_of_head_and_chest(name: str) -> None:
    for seed in SEEDS:
        m = make_motion(name, N_FRAMES, 30.0, seed)
        assert np.all(arm_intrusion(m.theta) == 0.0)


# --------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------
def test_make_motion_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="unknown name"):
        make_motion("moonwalk", 10)
    with pytest.raises(ValueError, match="n_frames"):
        make_motion("random", 0)
    with pytest.raises(ValueError, match="fps"):
        make_motion("random", 10, fps=0.0)
    with pytest.raises(ValueError, match="root_height"):
        make_motion("random", 10, root_height=-1.0)
    with pytest.raises(ValueError, match="seed"):
        make_motion("random", 10, seed=-3)


def test_motion_validates_its_arrays() -> None:
    with pytest.raises(ValueError, match="theta"):
        Motion(np.zeros((4, 36)), np.zeros((4, 3)), 60.0, "x")
    with pytest.raises(ValueError, match="tau"):
        Motion(np.zeros((4, N_POSE)), np.zeros((3, 3)), 60.0, "x")
    with pytest.raises(ValueError, match="fps"):
        Motion(np.zeros((4, N_POSE)), np.zeros((4, 3)), 0.0, "x")
    m = Motion(np.zeros((4, N_POSE)), np.zeros((4, 3)), 60.0, "x")
    assert not m.theta.flags.writeable
    assert len(m[1:3]) == 2


# --------------------------------------------------------------------------------------
# Grounding on the body model
# --------------------------------------------------------------------------------------
def test_ground_motion_puts_the_lowest_point_on_the_floor(model: BodyModel) -> None:
    nu = np.zeros(model.n_shape)
    m = make_motion("mixed", 240, FPS, SEEDS[0])
    grounded = ground_motion(model, m, nu)
    assert np.array_equal(grounded.theta, m.theta)
    assert np.allclose(grounded.tau[:, :2], m.tau[:, :2])
    assert np.abs(grounded.tau[:, 2] - m.tau[:, 2]).max() < PLACE_ROOT_ATOL
    lod = model.pose(BodyState(grounded.tau, grounded.theta, nu[None]), lod=True)
    assert np.abs(lod.vertices[..., 2].min(axis=1)).max() < GROUND_LOD_ATOL
    frames = np.arange(0, 240, 60)
    full = model.pose(BodyState(grounded.tau[frames], grounded.theta[frames], nu[None]))
    assert np.abs(full.vertices[..., 2].min(axis=1)).max() < GROUND_FULL_ATOL
