"""Evidence fusion (capture/fusion.py): the terms, their sum and the view agreement."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.capture.fusion import (
    CHANGE_CLIP,
    FEATURES,
    LOGIT_CLIP,
    WEIGHTS,
    FusionConfig,
    FusionWeights,
    GeometryTerms,
    change_evidence,
    fuse,
    mask_iou,
    segmenter_evidence,
    sources_key,
    view_agreement,
    view_features,
)
from bodymetry.errors import InputError


def test_change_term_is_zero_at_the_threshold_monotone_and_clipped():
    fg = 6.0
    d = np.array([[0.0, 3.0, 6.0, 12.0, 1e4]], np.float32)
    c = change_evidence(d**2, fg)
    assert c[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert c[0, 3] == pytest.approx(np.log(2.0), abs=1e-5)
    assert np.all(np.diff(c[0]) >= 0)
    assert c.min() == -CHANGE_CLIP and c.max() == CHANGE_CLIP


def test_segmenter_term_is_an_odd_clipped_logit():
    p = np.array([[0.0, 0.1, 0.5, 0.9, 1.0]], np.float32)
    s = segmenter_evidence(p)
    assert s[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert s[0, 1] == pytest.approx(-s[0, 3], abs=1e-5)
    assert s[0, 3] == pytest.approx(np.log(9.0), abs=1e-5)
    assert s[0, 0] == -LOGIT_CLIP and s[0, 4] == LOGIT_CLIP


def test_features_stack_the_present_sources_and_name_them():
    rng = np.random.default_rng(0)
    shape = (6, 5)
    change = rng.normal(size=shape).astype(np.float32)
    shadow = rng.random(shape) < 0.3
    body = rng.random(shape) < 0.5
    anywhere = body | (rng.random(shape) < 0.3)
    floor = shadow & (rng.random(shape) < 0.5)
    feats, key = view_features(shape, change, shadow, None, GeometryTerms(body, anywhere, floor))
    assert key == "background+hull" and feats.shape == (*shape, len(FEATURES))
    np.testing.assert_array_equal(feats[..., FEATURES.index("change")], change)
    np.testing.assert_array_equal(feats[..., FEATURES.index("floor_shadow")], floor)
    np.testing.assert_array_equal(feats[..., FEATURES.index("hull_body")], body)
    assert not feats[..., FEATURES.index("segmenter")].any()
    _, key = view_features(shape, segmenter=change)
    assert key == "segmenter"
    _, key = view_features(shape, segmenter=change, geometry=GeometryTerms(body, anywhere))
    assert key == "segmenter+hull"
    with pytest.raises(InputError, match="pairs"):
        view_features(shape, change=change)
    with pytest.raises(InputError, match="expected"):
        view_features(shape, segmenter=change[:3])


def test_fuse_is_the_weighted_sum_plus_bias():
    rng = np.random.default_rng(1)
    feats = rng.normal(size=(4, 3, len(FEATURES))).astype(np.float32)
    w = FusionWeights(-0.5, tuple(float(v) for v in rng.normal(size=len(FEATURES))))
    expected = feats @ np.asarray(w.weights, np.float32) - 0.5
    np.testing.assert_allclose(fuse(feats, w), expected, rtol=1e-6, atol=1e-6)
    with pytest.raises(InputError, match="expected 6"):
        FusionWeights(0.0, (1.0, 2.0))


def test_with_the_segmenter_alone_the_fused_mask_is_the_segmenters_own():
    # No background: the learned segmenter's mask at 0.5, as before the fusion.
    p = np.random.default_rng(2).random((20, 30)).astype(np.float32)
    feats, key = view_features(p.shape, segmenter=segmenter_evidence(p))
    np.testing.assert_array_equal(fuse(feats, WEIGHTS[key]) > 0, p > 0.5)


def test_every_combination_of_sources_has_weights():
    config = FusionConfig()
    for background in (True, False):
        for hull in (True, False):
            config.weights_for(sources_key(background, True, hull))
            if background:
                config.weights_for(sources_key(background, False, hull))
    with pytest.raises(InputError, match="no weights"):
        config.weights_for("none")


def test_weights_trust_the_hull_over_the_shadow_label():
    # An achromatic garment's shaded side: labelled shadow, twice the change
    # threshold, inside the hull's projection, but the other views see its floor
    # point lit; a floor shadow beside the feet: the same, but confirmed on the floor.
    w = WEIGHTS["background+hull"]
    shape = (1, 2)
    change = np.full(shape, 0.7, np.float32)
    shadow = np.ones(shape, bool)
    inside = np.ones(shape, bool)
    floor = np.array([[False, True]])
    feats, _ = view_features(shape, change, shadow, None, GeometryTerms(inside, inside, floor))
    garment, cast = fuse(feats, w)[0]
    assert garment > 0 > cast


def test_agreement_is_the_better_of_hull_confirmation_and_segmenter_iou():
    a = np.zeros((10, 10), bool)
    a[2:8, 2:8] = True
    shifted = np.roll(a, 3, axis=1)
    fat = np.zeros_like(a)
    fat[1:9, 1:9] = True  # the other views' hull: larger than the body
    assert mask_iou(a, a) == 1.0 and mask_iou(a, np.zeros_like(a)) == 0.0
    scores = view_agreement(
        [a, a, a, np.zeros_like(a), shifted],
        [fat, None, None, a, fat],
        [shifted, shifted, None, a, None],
    )
    assert scores[0] == 1.0  # inside the hull: confirmed, whatever the segmenter says
    assert scores[1] == pytest.approx(mask_iou(a, shifted))
    assert scores[2] is None and scores[3] is None
    assert scores[4] == pytest.approx(np.count_nonzero(shifted & fat) / shifted.sum())


def test_config_validation():
    with pytest.raises(InputError, match="floor_band"):
        FusionConfig(floor_band=-0.1)
    with pytest.raises(InputError, match="min_agreement"):
        FusionConfig(min_agreement=1.0)
