"""Tests for estimation.features on synthetic silhouettes drawn with OpenCV.

The paper (§3) says the codebook shape-context feature is translation and scale
invariant, and the radial distance function is neither: both claims are tested
here, plus the definitions (disk RDF, histogram sums, unit-length encodings),
determinism by seed, serialization and input validation.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.estimation.features import (
    Codebook,
    ShapeContextConfig,
    _kmeans,
    _nearest,
    fit_codebook,
    multiscale_shape_contexts,
    rdf,
    rdf_batch,
    sample_contour_points,
    sc_descriptors,
    sc_features,
    shape_context_descriptors,
    silhouette_contour,
    silhouette_features,
)

# --------------------------------------------------------------------------
# Tolerances, all in one place.
# --------------------------------------------------------------------------
# SC encodings of the same figure at another offset and scale (1/2x, 3/2x):
# cosine similarity measured 0.997-0.999 (stratified sampling, 300 points, 3
# scales, K = 100); a 0.2 rad arm change gives ~0.94, a different pose ~0.2.
MIN_COS_SCALED = 0.98
MAX_COS_OTHER_POSE = 0.6
# RDF of an ellipse rendered at two scales: per-direction extent ratio within
# 2 % of the scale (half-pixel rasterization effects are < 1 % at these sizes).
RTOL_RDF_SCALE = 0.02
# RDF of a rasterized disk of radius R: extents to boundary pixel centres lie in
# [R - 1, R] pixels.
DISK_ABS_PX = 1.0
# Shape contexts of exactly scaled / rotated point sets: float round-off can move
# a point across a bin edge; mean L1 distance between histograms (max 2).
MAX_L1_ROUNDOFF = 0.02
# Exact identities (sums, norms, translations) up to float64 round-off.
ATOL_EXACT = 1e-9

SHIFT = 4  # sub-pixel bits for cv2.fillPoly


def _limb(p, q, width):
    p, q = np.asarray(p, float), np.asarray(q, float)
    d = q - p
    n = np.array([-d[1], d[0]]) / np.hypot(*d) * width / 2
    return np.array([p + n, q + n, q - n, p - n])


def _disk(center, radius, k=40):
    a = np.linspace(0, 2 * np.pi, k, endpoint=False)
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], 1)


def figure_mask(scale, offset, shape=(480, 640), arm=1.0, leg=0.3):
    """A stick figure ``scale`` pixels tall with the top of its head at ``offset``."""
    polys = [_disk((0, 0.07), 0.07), _limb((0, 0.16), (0, 0.52), 0.2)]
    for side in (-1, 1):
        shoulder = np.array([0.09 * side, 0.18])
        polys.append(
            _limb(shoulder, shoulder + 0.33 * np.array([np.sin(arm) * side, np.cos(arm)]), 0.06)
        )
        hip = np.array([0.06 * side, 0.5])
        polys.append(_limb(hip, hip + 0.5 * np.array([np.sin(leg) * side, np.cos(leg)]), 0.08))
    mask = np.zeros(shape, np.uint8)
    pts = [np.round((p * scale + offset) * (1 << SHIFT)).astype(np.int32) for p in polys]
    cv2.fillPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=SHIFT)
    return mask.astype(bool)


def ellipse_mask(center, axes, angle_deg=20.0, shape=(480, 640)):
    mask = np.zeros(shape, np.uint8)
    c = tuple(round(v * (1 << SHIFT)) for v in center)
    a = tuple(round(v * (1 << SHIFT)) for v in axes)
    cv2.ellipse(mask, c, a, angle_deg, 0, 360, 1, -1, cv2.LINE_8, SHIFT)
    return mask.astype(bool)


def shifted(mask, dx, dy):
    """The mask translated by whole pixels (content must stay inside)."""
    out = np.zeros_like(mask)
    h, w = mask.shape
    out[max(dy, 0) : h + min(dy, 0), max(dx, 0) : w + min(dx, 0)] = mask[
        max(-dy, 0) : h - max(dy, 0), max(-dx, 0) : w - max(dx, 0)
    ]
    assert out.sum() == mask.sum()
    return out


@pytest.fixture(scope="module")
def codebook():
    cfg = ShapeContextConfig()
    masks = [
        figure_mask(300, (320, 60), arm=a, leg=g)
        for a in np.linspace(0.2, 2.8, 6)
        for g in (0.1, 0.3, 0.5)
    ]
    desc = np.concatenate([sc_descriptors(m, i, cfg) for i, m in enumerate(masks)], axis=1)
    return fit_codebook(desc, k=100, rng=0, config=cfg)


# --------------------------------------------------------------------------
# contour
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# radial distance function
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# shape context
# --------------------------------------------------------------------------


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


def _mean_l1(a, b):
    return float(np.abs(a - b).sum(axis=1).mean())


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


# --------------------------------------------------------------------------
# codebook
# --------------------------------------------------------------------------


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
