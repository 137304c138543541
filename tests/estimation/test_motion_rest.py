"""Tests for bodymetry.estimation.body_model.motion.rest: mirror, default limits, mean body."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo, default_limits, mirror_pose
from bodymetry.estimation.body_model.skeleton import N_POSE

# RestPoseInfo.default() against the committed model: rounded to 0.1 mm / 1e-5 rad.
DEFAULTS_ATOL = 1e-3


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


def test_mirror_pose_is_an_involution_and_limits_are_symmetric() -> None:
    rng = np.random.default_rng(0)
    theta = rng.normal(size=(5, N_POSE))
    assert np.allclose(mirror_pose(mirror_pose(theta)), theta)
    limits = default_limits()
    lo, hi = mirror_pose(limits.lower), mirror_pose(limits.upper)
    assert np.allclose(np.minimum(lo, hi), limits.lower)
    assert np.allclose(np.maximum(lo, hi), limits.upper)
    rest = RestPoseInfo.default()
    assert np.allclose(mirror_pose(rest.tpose), rest.tpose, atol=1e-4)


def test_defaults_match_the_committed_model(model: BodyModel) -> None:
    default, actual = RestPoseInfo.default(), RestPoseInfo.from_model(model)
    for field in ("joints", "hinge_axes", "soles", "tpose", "apose"):
        assert np.allclose(getattr(default, field), getattr(actual, field), atol=DEFAULTS_ATOL)
    limits = default_limits()
    assert np.allclose(limits.lower, model.limits.lower, atol=1e-6)
    assert np.allclose(limits.upper, model.limits.upper, atol=1e-6)
