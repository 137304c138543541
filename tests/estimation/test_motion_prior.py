"""Tests for bodymetry.estimation.body_model.motion.prior and root placement of its poses."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.motion.contact import place_root
from bodymetry.estimation.body_model.motion.prior import sample_pose_prior
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo, default_limits
from bodymetry.estimation.body_model.motion.seeds import seed_for
from bodymetry.estimation.body_model.skeleton import N_POSE, YAW


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


def test_sample_pose_prior_draws_plausible_independent_poses() -> None:
    limits = default_limits()
    rng = np.random.default_rng(seed_for("test", 5))
    poses = sample_pose_prior(rng, 120, limits)
    assert poses.shape == (120, N_POSE)
    assert np.all(limits.contains(poses))
    again = sample_pose_prior(np.random.default_rng(seed_for("test", 5)), 120, limits)
    assert np.array_equal(poses, again)
    counts, _ = np.histogram(poses[:, YAW], bins=4, range=(-np.pi, np.pi))
    assert np.all(counts > 10)
    assert len(np.unique(poses[:, 3:], axis=0)) == 120
    assert sample_pose_prior(rng, 0).shape == (0, N_POSE)


def test_place_root_for_independent_poses_centres_the_feet(model: BodyModel) -> None:
    poses = sample_pose_prior(np.random.default_rng(3), 24)
    tau = place_root(poses)
    assert tau.shape == (24, 3)
    assert np.all(tau[:, 2] > 0.5)
    rest = RestPoseInfo.from_model(model)
    assert np.allclose(
        place_root(np.zeros((1, N_POSE)), rest=rest)[0, 2], rest.root_height, atol=0.005
    )
