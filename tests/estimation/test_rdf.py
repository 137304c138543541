"""Tests for estimation.rdf: the radial distance function is neither translation
nor scale invariant (paper §3), and a disk's is its radius.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from silhouette_shapes import ellipse_mask, figure_mask, shifted

from bodymetry.estimation.rdf import rdf, rdf_batch

# RDF of an ellipse rendered at two scales: per-direction extent ratio within
# 2 % of the scale (half-pixel rasterization effects are < 1 % at these sizes).
RTOL_RDF_SCALE = 0.02
# RDF of a rasterized disk of radius R: extents to boundary pixel centres lie in
# [R - 1, R] pixels.
DISK_ABS_PX = 1.0
# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9


def test_rdf_of_disk_is_its_radius():
    mask = np.zeros((300, 320), np.uint8)
    cv2.circle(mask, (170, 140), 80, 1, -1)
    x = rdf(mask.astype(bool))
    assert x.shape == (102,)
    np.testing.assert_allclose(x[:2], (170.0, 140.0), atol=ATOL_EXACT)
    assert np.all(x[2:] <= 80.0 + ATOL_EXACT) and np.all(x[2:] >= 80.0 - DISK_ABS_PX)


def test_rdf_is_not_translation_invariant():
    a = figure_mask(300, (250.3, 60.7))
    b = shifted(a, 37, -21)
    xa, xb = rdf(a), rdf(b)
    np.testing.assert_allclose(xb[:2] - xa[:2], (37.0, -21.0), atol=ATOL_EXACT)
    np.testing.assert_allclose(xb[2:], xa[2:], atol=ATOL_EXACT)


def test_rdf_is_not_scale_invariant():
    s = 2.0
    a = rdf(ellipse_mask((200.0, 150.0), (90.0, 55.0)))
    b = rdf(ellipse_mask((330.0, 250.0), (90.0 * s, 55.0 * s)))
    np.testing.assert_allclose(b[2:] / a[2:], s, rtol=RTOL_RDF_SCALE)
    # and on a body-like figure (extents jump where a ray grazes a limb, so
    # compare the whole profile rather than each direction)
    fa, fb = rdf(figure_mask(200, (320, 30))), rdf(figure_mask(400, (320, 40)))
    assert np.linalg.norm(fb[2:]) / np.linalg.norm(fa[2:]) == pytest.approx(s, rel=RTOL_RDF_SCALE)


def test_rdf_batch_matches_single():
    masks = np.stack([figure_mask(250, (320, 40), arm=a) for a in (0.3, 1.5)])
    out = rdf_batch(masks, n=64)
    assert out.shape == (2, 66)
    np.testing.assert_array_equal(out[1], rdf(masks[1], n=64))
