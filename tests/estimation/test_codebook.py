"""Tests for estimation.codebook: unit-length encodings, pooled descriptor blocks,
determinism by seed, serialization, and the k-means steps.
"""

from __future__ import annotations

import numpy as np
import pytest
from silhouette_shapes import figure_mask

from bodymetry.estimation.codebook import Codebook, _kmeans, _nearest, fit_codebook
from bodymetry.estimation.shape_context import ShapeContextConfig, sc_descriptors
from bodymetry.estimation.view_features import sc_features

# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9


def test_encoding_is_unit_length_and_non_negative(codebook):
    assert codebook.centers.shape == (3, 100, 60) and codebook.dim == 300
    for seed, arm in [(0, 0.4), (1, 2.0)]:
        x = sc_features(figure_mask(280, (300, 50), arm=arm), codebook, seed)
        assert x.shape == (300,)
        assert np.all(x >= 0)
        assert np.linalg.norm(x) == pytest.approx(1.0, abs=ATOL_EXACT)
        # every scale's block carries the same weight
        np.testing.assert_allclose(
            np.linalg.norm(x.reshape(3, 100), axis=1), 1 / np.sqrt(3), atol=ATOL_EXACT
        )


@pytest.mark.parametrize("max_samples", [150, 100_000])
def test_codebook_of_descriptor_blocks_equals_that_of_their_concatenation(max_samples):
    # Training passes the silhouettes' descriptors as blocks, gathering only the
    # sampled rows; the codebook must be the one of the pooled array, bit for bit,
    # both when rows are sampled (150 of 300) and when all are used.
    cfg = ShapeContextConfig(kappas=(0.25, 0.5), n_points=50)
    blocks = [
        sc_descriptors(figure_mask(200, (320, 40), arm=a), i, cfg)
        for i, a in enumerate((0.3, 1.2, 2.4, 0.8, 1.9, 2.9))
    ]
    pooled = fit_codebook(np.concatenate(blocks, axis=1), k=12, rng=4, config=cfg,
                          max_samples=max_samples)  # fmt: skip
    split = fit_codebook(blocks, k=12, rng=4, config=cfg, max_samples=max_samples)
    np.testing.assert_array_equal(split.centers, pooled.centers)
    np.testing.assert_array_equal(split.sigma, pooled.sigma)


def test_codebook_refuses_blocks_that_do_not_pool():
    good = np.zeros((2, 10, 60))
    with pytest.raises(ValueError, match="blocks of one shape"):
        fit_codebook([good, np.zeros((3, 10, 60))], k=2)
    with pytest.raises(ValueError, match="blocks of one shape"):
        fit_codebook([good, np.zeros((10, 60))], k=2)  # not a block of scales
    bad = good.copy()
    bad[1, 3, 7] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        fit_codebook([good, bad], k=2)


def test_codebook_is_deterministic_by_seed():
    cfg = ShapeContextConfig(kappas=(0.25, 0.5), n_points=100)
    desc = np.concatenate(
        [
            sc_descriptors(figure_mask(200, (320, 40), arm=a), i, cfg)
            for i, a in enumerate((0.3, 1.2, 2.4))
        ],
        axis=1,
    )
    a = fit_codebook(desc, k=20, rng=5, config=cfg)
    b = fit_codebook(desc, k=20, rng=5, config=cfg)
    c = fit_codebook(desc, k=20, rng=6, config=cfg)
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    assert not np.array_equal(a.centers, c.centers)
    # sc_features is deterministic by seed too
    m = figure_mask(200, (320, 40))
    np.testing.assert_array_equal(sc_features(m, a, 3), sc_features(m, a, 3))


def test_codebook_round_trips_through_npz(codebook, tmp_path):
    path = tmp_path / "codebook.npz"
    np.savez(path, **codebook.to_arrays(prefix="sc_"))
    with np.load(path, allow_pickle=False) as data:
        back = Codebook.from_arrays(data, prefix="sc_")
    np.testing.assert_array_equal(back.centers, codebook.centers)
    np.testing.assert_array_equal(back.sigma, codebook.sigma)
    assert back.config == codebook.config and back.n_nearest == codebook.n_nearest
    m = figure_mask(300, (320, 60))
    np.testing.assert_array_equal(sc_features(m, back, 2), sc_features(m, codebook, 2))
    with pytest.raises(ValueError, match="missing"):
        Codebook.from_arrays({"centers": codebook.centers})


def test_nearest_centres_match_argpartition():
    """The soft vote's nearest centres: the same set as argpartition, nearest first."""
    d2 = np.random.default_rng(8).random((200, 100))
    for nn in (1, 3, 4, 6):
        idx = _nearest(d2, nn)
        expected = np.sort(np.argpartition(d2, nn - 1, axis=1)[:, :nn], axis=1)
        np.testing.assert_array_equal(np.sort(idx, axis=1), expected)
        if nn <= 4:  # the argmin passes give them in order
            assert np.all(np.diff(np.take_along_axis(d2, idx, axis=1), axis=1) > 0)


def test_kmeans_runs_lloyd_to_a_fixed_point():
    """Lloyd's iterations continue past the first: converged centres are the means
    of the points nearest to them (the first iteration's test used to read
    ``inf - inertia <= tol * inf`` as converged and stop after one step)."""
    x = np.random.default_rng(3).random((600, 2))  # no clusters: Lloyd needs many steps
    one = _kmeans(x, 8, np.random.default_rng(1), max_iter=1, tol=0.0)
    centers = _kmeans(x, 8, np.random.default_rng(1), max_iter=200, tol=0.0)

    def inertia(c):
        return ((x[:, None] - c[None]) ** 2).sum(-1).min(1).sum()

    label = ((x[:, None] - centers[None]) ** 2).sum(-1).argmin(1)
    means = np.stack([x[label == j].mean(0) for j in range(8)])
    np.testing.assert_allclose(centers, means, rtol=0, atol=ATOL_EXACT)
    assert inertia(centers) < 0.95 * inertia(one)
    # the default tolerance stops near there, not after the first step
    near = _kmeans(x, 8, np.random.default_rng(1), max_iter=200, tol=1e-6)
    assert inertia(near) < 1.001 * inertia(centers)
