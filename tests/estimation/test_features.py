"""Tests for estimation.features on synthetic silhouettes drawn with OpenCV: the
largest blob's outer contour, and the input checks every feature function shares.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.codebook import fit_codebook
from bodymetry.estimation.features import silhouette_contour
from bodymetry.estimation.rdf import rdf, rdf_batch
from bodymetry.estimation.shape_context import shape_context_descriptors
from bodymetry.estimation.view_features import sc_features

# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9


def test_contour_is_ordered_boundary_of_largest_blob():
    mask = np.zeros((50, 60), bool)
    mask[10:30, 5:25] = True  # 20x20 square: the largest blob
    mask[40:44, 40:44] = True  # a small one, ignored
    c = silhouette_contour(mask)
    assert c.shape == (4 * 19, 2) and c.dtype == np.float64
    assert np.all((c[:, 0] >= 5) & (c[:, 0] <= 24) & (c[:, 1] >= 10) & (c[:, 1] <= 29))
    # ordered: consecutive points (cyclically) are 8-neighbours
    step = np.abs(np.diff(np.concatenate([c, c[:1]]), axis=0)).max(axis=1)
    assert np.all(step == 1)
    # starts at the top-left pixel, clockwise on screen (positive shoelace area, y down)
    assert tuple(c[0]) == (5.0, 10.0)
    x, y = c[:, 0], c[:, 1]
    assert np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)) > 0
    # the RDF ignores the small blob too (centroid of the square alone)
    alone = mask.copy()
    alone[40:44, 40:44] = False
    np.testing.assert_array_equal(rdf(mask), rdf(alone))
    np.testing.assert_allclose(rdf(mask)[:2], (14.5, 19.5), atol=ATOL_EXACT)


@pytest.mark.parametrize("bad", [np.zeros((20, 20), bool), np.zeros((20, 20), np.uint8)])
def test_empty_mask_raises(bad, codebook):
    with pytest.raises(ValueError, match=r"mask.*empty"):
        silhouette_contour(bad)
    with pytest.raises(ValueError, match=r"mask.*empty"):
        rdf(bad)
    with pytest.raises(ValueError, match=r"mask.*empty"):
        sc_features(bad, codebook, 0)


def test_bad_inputs_name_the_argument(codebook):
    with pytest.raises(ValueError, match="mask"):
        rdf(np.ones((3, 4, 5), bool))
    with pytest.raises(ValueError, match="masks"):
        rdf_batch(np.ones((4, 5), bool))
    with pytest.raises(ValueError, match=r"masks\[1\]"):
        rdf_batch(np.stack([np.ones((4, 5), bool), np.zeros((4, 5), bool)]))
    with pytest.raises(ValueError, match="n:"):
        rdf(np.ones((4, 5), bool), n=0)
    with pytest.raises(ValueError, match="contour"):
        shape_context_descriptors(np.zeros((10, 3)), 5, 0)
    with pytest.raises(ValueError, match="rng"):
        shape_context_descriptors(np.zeros((10, 2)), 5, "seed")
    with pytest.raises(ValueError, match="kappa"):
        shape_context_descriptors(np.zeros((10, 2)), 5, 0, kappa=-1.0)
    with pytest.raises(ValueError, match="descriptors"):
        codebook.encode(np.zeros((2, 10, 60)))
    with pytest.raises(ValueError, match="k:"):
        fit_codebook(np.zeros((5, 60)), k=10)
