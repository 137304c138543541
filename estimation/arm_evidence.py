"""Whether a session saw the arms away from the body: the evidence of its arm span.

The arm span is knuckle to knuckle in a T-pose (docs/biometrics.md). The
silhouettes measure it only where the arms leave the body's outline: an arm
raised or held out shows its length in every view; an arm hanging by the side
lies along the trunk and the thigh in most views, and the fit can trade the
arm's length against the shoulders' breadth and the hand's height with little
change of the outline. On the studio's benchmarks (tight clothing, every body
of the mid, edge, looks and unseen edge sets: 41 sessions, ``python -m
benchmarks pipeline`` with ``--edge``, ``--looks``, ``--edge-unseen`` and the
recheck of issue 15's eleven) the sessions in which no more than one measured
frame had an arm raised read the arm span high, +0.7 to +26.9 mm (mean +12.8,
8 sessions, all walking or walking and turning), where the sessions with arms
raised in three or more frames read it within ±13.3 mm, bar a 6-year-old
(-25.1 mm, the body model's representation of a small child's arms). Even
started from the true poses and the body's own projection onto the shape
space, the session stage of the thinnest woman walking settled at +21.6 mm:
the outline of arms by the sides holds the error, not the search.

So a run says so (the ``arms_down`` caveat of
:mod:`bodymetry.estimation.caveats`) when fewer than :data:`MIN_RAISED_FRAMES`
of its measured frames had an arm raised at least :data:`RAISED_DEG` from
straight down.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bodymetry.estimation.body_model.model import POSE_DIM, BodyModel, shipped_model
from bodymetry.estimation.records import FrameRecord

__all__ = ["MIN_RAISED_FRAMES", "RAISED_DEG", "arm_elevations", "arms_raised", "raised_frames"]

#: An arm is raised when its shoulder-to-wrist direction is at least this far
#: (degrees) from straight down: half-way to held out sideways or forwards.
RAISED_DEG = 45.0
#: Fewer measured frames with an arm raised than this: the arm span rests on arms
#: by the sides (the studio's sessions with none or one read it +0.7 to +26.9 mm).
MIN_RAISED_FRAMES = 3


def arm_elevations(body: BodyModel, states: np.ndarray) -> np.ndarray:
    """Each arm's elevation from straight down, per frame, in degrees.

    Parameters
    ----------
    body : BodyModel
    states : (F, 40 + n_shape) float
        ``[τ, θ, ν]`` per frame (world frame, z up).

    Returns
    -------
    (F, 2) float
        Angle between the shoulder-to-wrist direction and -z (left arm, right
        arm): 0 hanging, 90 held out level, 180 straight up.
    """
    keypoints = body.pose_states(states, lod=True).keypoints
    names = body.keypoint_names
    out = np.empty((len(states), 2))
    for k, side in enumerate("lr"):
        arm = (
            keypoints[:, names.index(f"wrist_{side}")]
            - keypoints[:, names.index(f"shoulder_{side}")]
        )
        down = -arm[:, 2] / np.linalg.norm(arm, axis=1)
        out[:, k] = np.degrees(np.arccos(np.clip(down, -1.0, 1.0)))
    return out


def raised_frames(
    records: Sequence[FrameRecord], body: BodyModel | None = None
) -> tuple[int, ...] | None:
    """The measured frames in which the generative fit has an arm raised.

    Parameters
    ----------
    records : sequence of FrameRecord
        A run's kept frames; only measured (``ok``) frames count.
    body : BodyModel, optional
        The run's body model (default: the shipped one with as many shape
        components as the records' states have).

    Returns
    -------
    tuple of int or None
        The frames with either arm at least :data:`RAISED_DEG` from straight
        down; None when no measured frame has a fit to judge.
    """
    measured = [(r.frame, r.estimate()) for r in records if r.ok]
    states = [(f, e.vector()) for f, e in measured if e is not None]
    if not states:
        return None
    body = body or shipped_model(len(states[0][1]) - POSE_DIM)
    elevation = arm_elevations(body, np.stack([y for _, y in states]))
    return tuple(
        int(f) for (f, _), e in zip(states, elevation, strict=True) if e.max() >= RAISED_DEG
    )


def arms_raised(raised: Sequence[int] | None) -> bool | None:
    """Whether enough measured frames had an arm raised (at least
    :data:`MIN_RAISED_FRAMES` of ``raised``, :func:`raised_frames`' answer); None
    where not judged."""
    return None if raised is None else len(raised) >= MIN_RAISED_FRAMES
