"""`fit.preload`: what the parent loads before forking its workers changes no result."""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.model import BodyState
from bodymetry.estimation.fit import preload, shared_body_model
from bodymetry.estimation.refinement import RefineConfig
from bodymetry.studio.rig import studio_rig


def test_preload_changes_no_pose_and_survives_cameras_that_see_nothing():
    body = shared_body_model()
    state = np.r_[np.zeros(3), np.random.default_rng(3).normal(0, 0.1, 37), np.zeros(body.n_shape)]

    before = body.pose(BodyState.from_vector(state[None]), lod=True).vertices
    preload(studio_rig(4, (160, 120), seed=2), RefineConfig(iterations=5))
    # Cameras looking away from the volume: nothing in view, nothing to align.
    away = studio_rig(2, (80, 60), seed=2, target=(40.0, 40.0, 0.0))
    preload(away)
    after = body.pose(BodyState.from_vector(state[None]), lod=True).vertices
    np.testing.assert_array_equal(after, before)
