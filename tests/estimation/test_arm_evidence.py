"""Whether a session saw the arms away from the body (estimation.arm_evidence)."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.arm_evidence import (
    MIN_RAISED_FRAMES,
    RAISED_DEG,
    arm_elevations,
    raised_frames,
)
from bodymetry.estimation.body_model.model import POSE_DIM, BodyState, shipped_model
from bodymetry.estimation.records import FrameRecord, StageEstimate

#: Degrees: the elevations are read from posed keypoints (float rounding only).
ANGLE_TOL = 1e-6


@pytest.fixture(scope="module")
def body():
    return shipped_model()


def _state(body, pose: np.ndarray, heading: float = 0.0, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    y = np.zeros(POSE_DIM + body.n_shape)
    y[:3] = (0.0, 0.0, 0.95) + np.asarray(shift)
    y[3:POSE_DIM] = pose
    y[3:6] = (0.0, 0.0, heading)  # about the vertical
    return y


def _hanging(body) -> np.ndarray:
    """The A-pose with each shoulder lowered further by 1.5 × (T-pose less A-pose)."""
    apose, tpose = np.asarray(body.poses["apose"]), np.asarray(body.poses["tpose"])
    return apose - 1.5 * (tpose - apose)


def test_named_poses_give_their_elevations(body):
    tpose = arm_elevations(body, _state(body, body.poses["tpose"])[None])
    apose = arm_elevations(body, _state(body, body.poses["apose"])[None])
    hanging = arm_elevations(body, _state(body, _hanging(body))[None])
    assert tpose.shape == (1, 2)
    # Held out level; half-way; below the threshold; left and right alike (a symmetric pose).
    assert tpose[0] == pytest.approx([90.0, 90.0], abs=1.0)
    assert apose[0] == pytest.approx([45.0, 45.0], abs=1.0)
    assert np.all(hanging < RAISED_DEG - 15)
    for e in (tpose, apose, hanging):
        assert e[0, 0] == pytest.approx(e[0, 1], abs=1e-3)


def test_elevation_is_invariant_to_heading_and_position(body):
    pose = body.poses["tpose"].copy()
    pose[9:12] += (0.3, -0.2, 0.1)  # an arbitrary left shoulder
    base = arm_elevations(body, _state(body, pose)[None])
    moved = arm_elevations(
        body,
        np.stack(
            [
                _state(body, pose, heading=1.3),
                _state(body, pose, heading=-2.0, shift=(1.5, -0.7, 0.2)),
            ]
        ),
    )
    np.testing.assert_allclose(moved, np.repeat(base, 2, axis=0), atol=ANGLE_TOL)


def test_elevation_rejects_a_state_of_another_body(body):
    with pytest.raises(ValueError, match="states"):
        arm_elevations(body, np.zeros((2, POSE_DIM + body.n_shape + 1)))


def _record(body, frame: int, pose: np.ndarray, status: str = "ok") -> FrameRecord:
    state = BodyState.from_vector(_state(body, pose)[None])
    return FrameRecord(frame, status, estimates={"generative": StageEstimate(state, {})})


def test_raised_frames_counts_measured_frames_with_an_arm_up(body):
    one_up = _hanging(body).copy()
    one_up[16:19] = body.poses["tpose"][16:19]  # the right arm held out, the left hanging
    records = [
        _record(body, 0, _hanging(body)),
        _record(body, 25, body.poses["tpose"]),
        _record(body, 50, one_up),
        _record(body, 75, body.poses["tpose"], "poor fit: mean silhouette IoU 0.41 < 0.90"),
        FrameRecord(100, "no person found"),
    ]
    # Either arm counts; frames left out of the summary do not.
    assert raised_frames(records, body) == (25, 50)
    assert raised_frames(records) == (25, 50)  # the shipped model by default
    assert len(raised_frames(records)) < MIN_RAISED_FRAMES
    # Nothing measured: nothing to judge.
    assert raised_frames(records[3:], body) is None
    assert raised_frames([], body) is None
