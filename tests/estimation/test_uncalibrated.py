"""Uncalibrated mode (paper Figure 2): the weight change between two studio subjects."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.training import TrainConfig, load_or_train
from bodymetry.estimation.uncalibrated import compare_photos, estimate_photo
from bodymetry.studio.rig import studio_rig

#: The estimated change must have the true sign and lie within this fraction range of it
#: (the paper's own example recovered half of the reported change; SC regresses to the mean).
CHANGE_FRACTION = (0.2, 1.3)
#: Held-out prior adults of about the same height (1758 and 1766 mm), 52.6 and 115.3 kg:
#: the pair within 30 mm of height with the largest weight difference.
THIN, HEAVY = 52, 44


@pytest.mark.slow
def test_weight_change_between_two_studio_subjects(tmp_path):
    cameras = studio_rig(2, (320, 240), seed=1)
    config = TrainConfig(
        n_train=400,
        n_test=20,
        codebook_size=40,
        codebook_examples=60,
        sc_points=100,
        experts=(1, 2),
        ridges=(10.0, 100.0),
        max_iter=20,
    )
    models, _ = load_or_train(cameras, config, tmp_path, workers=1)
    body = BodyModel.load()
    nus = body.prior_shapes("heldout")
    truth = measure(body, nus[[THIN, HEAVY]])
    assert abs(truth[0].height_mm - truth[1].height_mm) < 30
    estimates = []
    for k, bio in zip((THIN, HEAVY), truth, strict=True):
        verts = body.pose(
            BodyState([0.0, 0.0, 0.0], body.poses["apose"], nus[k]), lod=True
        ).vertices[0]
        verts[:, 2] -= verts[:, 2].min()
        mask = project_silhouettes(verts, body.faces(lod=True), cameras[:1])[0]
        estimates.append(estimate_photo(mask, models, body, bio.height_mm))
    true_change = truth[1].weight_kg - truth[0].weight_kg
    change = compare_photos(*estimates)["weight_kg_change"]
    lo, hi = CHANGE_FRACTION
    assert lo * true_change < change < hi * true_change
    assert np.isfinite(change)
