"""Tests for estimation.shape_context: even sampling, histogram sums, and
translation and scale invariance without rotation invariance.
"""

from __future__ import annotations

import numpy as np
import pytest
from silhouette_shapes import figure_mask

from bodymetry.estimation.features import silhouette_contour
from bodymetry.estimation.shape_context import (
    multiscale_shape_contexts,
    sample_contour_points,
    shape_context_descriptors,
)

# Shape contexts of exactly scaled / rotated point sets: float round-off can move
# a point across a bin edge; mean L1 distance between histograms (max 2).
MAX_L1_ROUNDOFF = 0.02
# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9


def _mean_l1(a, b):
    return float(np.abs(a - b).sum(axis=1).mean())


def test_sampled_points_are_evenly_spaced_on_the_contour():
    # a 40 x 20 rectangle of pixel centres: perimeter 2 * (39 + 19) = 116
    mask = np.zeros((40, 60), bool)
    mask[10:30, 5:45] = True
    contour = silhouette_contour(mask)
    pts = sample_contour_points(contour, 58, 4)
    assert pts.shape == (58, 2)
    on_x = np.isclose(pts[:, 0], 5) | np.isclose(pts[:, 0], 44)
    on_y = np.isclose(pts[:, 1], 10) | np.isclose(pts[:, 1], 29)
    assert np.all(on_x | on_y)
    inside = (pts[:, 0] >= 5) & (pts[:, 0] <= 44) & (pts[:, 1] >= 10) & (pts[:, 1] <= 29)
    assert np.all(inside)
    # consecutive samples 2 px apart along the outline (116 / 58), away from corners
    step = np.abs(np.diff(pts, axis=0)).sum(axis=1)
    assert np.median(step) == pytest.approx(2.0, abs=ATOL_EXACT)


def test_shape_context_histograms_sum_to_one():
    contour = silhouette_contour(figure_mask(300, (320, 60)))
    sc = shape_context_descriptors(contour, 200, np.random.default_rng(1))
    assert sc.shape == (200, 60)
    assert np.all(sc >= 0)
    np.testing.assert_allclose(sc.sum(axis=1), 1.0, atol=ATOL_EXACT)
    multi = multiscale_shape_contexts(contour, 200, 1, kappas=(0.25, 0.5, 1.0))
    assert multi.shape == (3, 200, 60)
    np.testing.assert_allclose(multi.sum(axis=2), 1.0, atol=ATOL_EXACT)
    np.testing.assert_array_equal(multi[0], sc)  # same sampled points for every scale


def test_shape_context_is_translation_and_scale_invariant_but_not_rotation_invariant():
    contour = silhouette_contour(figure_mask(300, (320, 60)))
    h = float(np.ptp(contour[:, 1]))
    a = shape_context_descriptors(contour, 150, 3, height=h)
    # a translated copy: bit-identical samples relative to the first point
    moved = shape_context_descriptors(contour + (-200.0, 75.0), 150, 3, height=h)
    np.testing.assert_array_equal(moved, a)
    # a scaled and moved copy: the same samples, scaled; only round-off at bin
    # edges can move a count (mean L1 between histograms, of at most 2)
    b = shape_context_descriptors(contour * 3.0 + (100.0, -50.0), 150, 3, height=3 * h)
    assert _mean_l1(b, a) < MAX_L1_ROUNDOFF
    # rotated by 90 degrees in the image, (x, y) -> (-y, x): orientation is measured
    # against the image axes, so the histograms change; each orientation bin moves
    # by a quarter turn (3 of 12 bins)
    c = shape_context_descriptors(contour[:, ::-1] * (-1.0, 1.0), 150, 3, height=h)
    assert _mean_l1(c, a) > 0.5
    quarter = np.roll(a.reshape(150, 5, 12), 3, axis=2).reshape(150, 60)
    assert _mean_l1(c, quarter) < MAX_L1_ROUNDOFF
