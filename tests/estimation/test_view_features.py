"""Tests for estimation.view_features: the codebook shape-context feature is
translation and scale invariant (paper §3); one contour trace gives both features.
"""

from __future__ import annotations

import numpy as np
from silhouette_shapes import figure_mask, shifted

from bodymetry.estimation.rdf import rdf
from bodymetry.estimation.shape_context import ShapeContextConfig, sc_descriptors
from bodymetry.estimation.view_features import sc_features, silhouette_features

# SC encodings of the same figure at another offset and scale (1/2x, 3/2x):
# cosine similarity measured 0.997-0.999 (stratified sampling, 300 points, 3
# scales, K = 100); a 0.2 rad arm change gives ~0.94, a different pose ~0.2.
MIN_COS_SCALED = 0.98
MAX_COS_OTHER_POSE = 0.6
# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9


def test_sc_features_translation_and_scale_invariant(codebook):
    ref = sc_features(figure_mask(300, (320, 60)), codebook, 7)
    # whole-pixel translation: the same pixels, the same samples, the same vector
    moved = sc_features(shifted(figure_mask(300, (320, 60)), -150, 90), codebook, 7)
    np.testing.assert_allclose(moved, ref, atol=ATOL_EXACT)
    # other offsets and scales (re-rendered, so only approximately equal)
    for scale, offset, seed in [(150, (140.5, 210.2), 7), (450, (300.0, 12.0), 11)]:
        other = sc_features(figure_mask(scale, offset), codebook, seed)
        assert float(ref @ other) > MIN_COS_SCALED, (scale, float(ref @ other))
    # ... while a different pose is far away
    pose = sc_features(figure_mask(300, (320, 60), arm=2.5, leg=0.1), codebook, 7)
    assert float(ref @ pose) < MAX_COS_OTHER_POSE


def test_silhouette_features_equal_rdf_and_sc_descriptors():
    """One contour trace for both features gives the two functions' values bit for bit."""
    mask = np.zeros((120, 90), bool)
    mask[20:100, 30:60] = True
    mask[40:50, 10:80] = True  # arms
    mask[5:8, 5:8] = True  # a speck: the largest blob is the body
    config = ShapeContextConfig(n_points=50)
    x_rdf, descriptors = silhouette_features(mask, np.random.default_rng(4), config)
    np.testing.assert_array_equal(x_rdf, rdf(mask))
    np.testing.assert_array_equal(
        descriptors, sc_descriptors(mask, np.random.default_rng(4), config)
    )
