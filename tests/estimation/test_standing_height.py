"""Standing height read from the floor (estimation.standing_height)."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.standing_height import (
    MAX_SOLE_DEPTH,
    from_the_floor,
    lowest_points,
    reads_from_floor,
    sole_depth,
)


def test_sole_depth_known_answers():
    # Above the floor, or on it: nothing to take off.
    assert sole_depth(np.array([0.01, 0.02, 0.0])) == (0.0, 0.0)
    # The median frame decides: one frame deep in the floor does not.
    depth, se = sole_depth(np.array([-0.004, -0.006, -0.005, 0.003, -0.5]))
    assert depth == pytest.approx(-0.005)
    values = np.array([-0.004, -0.006, -0.005, 0.003, -0.5])
    assert se == pytest.approx(1.2533 * np.std(values, ddof=1) / np.sqrt(5))
    assert sole_depth(np.array([-0.003])) == (-0.003, 0.0)  # one frame: no spread
    for bad in (np.array([]), np.array([0.0, np.nan]), np.zeros((2, 2))):
        with pytest.raises(ValueError, match="lowest"):
            sole_depth(bad)


def test_from_the_floor_known_answers():
    bios = {"height_mm": 1800.0, "weight_kg": 81.0, "bmi": 25.0, "arm_span_mm": 1790.0}
    se = {"height_mm": 0.3, "weight_kg": 0.2, "bmi": 0.1, "arm_span_mm": 1.0}
    same, same_se = from_the_floor(bios, se, 0.0, 0.0)
    assert same == bios and same_se == se and same is not bios
    out, out_se = from_the_floor(bios, se, -0.0084, 0.0004)
    assert out["height_mm"] == pytest.approx(1791.6)
    assert out["bmi"] == pytest.approx(81.0 / 1.7916**2)
    assert out_se["height_mm"] == pytest.approx(np.hypot(0.3, 0.4))
    # Only the height (and the BMI it enters) change.
    assert out["weight_kg"] == 81.0 and out["arm_span_mm"] == 1790.0
    assert out_se["weight_kg"] == 0.2 and bios["height_mm"] == 1800.0


def test_lowest_points_follow_the_body_up_and_down():
    model = BodyModel.load()
    rest = BodyState.rest(model.n_shape).vector()[0]
    states = np.stack([rest, rest, rest])
    states[1, 2] += 0.1  # raised by 10 cm
    states[2, 3:6] = (0.0, 0.0, 1.0)  # turned about the vertical: the same height
    low = lowest_points(model.pose_states(states))
    assert low[0] == pytest.approx(
        model.pose(BodyState.rest(model.n_shape), lod=False).vertices[0, :, 2].min()
    )
    assert low[1] - low[0] == pytest.approx(0.1, abs=1e-9)
    assert low[2] == pytest.approx(low[0], abs=1e-6)
    with pytest.raises(ValueError, match="states"):
        lowest_points(model.pose_states(np.zeros((2, 5))))


def test_the_floor_is_trusted_down_to_the_bound_only():
    """Soles that sink a few millimetres (shadow under the shoes) read the height from
    the floor; soles far deeper (a floor below the calibration's) and soles above it
    do not."""
    assert pytest.approx(0.015) == MAX_SOLE_DEPTH
    assert reads_from_floor(-0.0084) and reads_from_floor(-MAX_SOLE_DEPTH)
    assert not reads_from_floor(-0.0318)  # Demo_MultiPerson's woman
    assert not reads_from_floor(0.0) and not reads_from_floor(0.03)
    assert not reads_from_floor(float("nan"))
