"""The compiled shape-context histograms and codebook encoding against the numpy reference.

``features.BACKEND`` picks the path; the reference is ``"numpy"``. Histograms are
counts divided by their sum, so the two paths must give the same bins: they are
compared for equality, on rendered silhouettes (whose diagonal pixel runs put
many point pairs on the 45-degree orientation edges, up to rounding) and on
random point sets (integer grids, duplicates, odd ``n_theta``). Encodings sum
the distances in another order than BLAS: equal to ``ATOL_ENCODE``; RDF
extents to ``ATOL_RDF_PX``.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.estimation import features, shape_context
from bodymetry.estimation.codebook import Codebook, fit_codebook
from bodymetry.estimation.features import silhouette_contour
from bodymetry.estimation.rdf import rdf
from bodymetry.estimation.shape_context import (
    ShapeContextConfig,
    multiscale_shape_contexts,
    sc_descriptors,
)

pytest.importorskip("numba")

# RDF extents: libm's arctan2 / cos / sin against numpy's (last-bit differences);
# measured equal bit for bit on 256 rendered training views.
ATOL_RDF_PX = 1e-9
# Encodings: unit vectors of K = 100 soft votes; the distances' summation order
# differs (BLAS vs a loop over non-zero bins) by ~1e-16, measured <= 2e-16.
ATOL_ENCODE = 1e-12


def _both(monkeypatch, fn):
    """``fn()`` on the numpy reference and on the compiled path."""
    monkeypatch.setattr(features, "BACKEND", "numpy")
    ref = fn()
    monkeypatch.setattr(features, "BACKEND", "numba")
    return ref, fn()


def _figure(scale: float, arm: float, shape=(480, 640)) -> np.ndarray:
    """A body-like silhouette (head, torso, slanted arms and legs) ``scale`` px tall."""
    mask = np.zeros(shape, np.uint8)
    cx, top = shape[1] / 2, 0.05 * shape[0]

    def limb(p, q, width):
        p, q = np.asarray(p, float), np.asarray(q, float)
        n = np.array([q[1] - p[1], p[0] - q[0]]) / np.hypot(*(q - p)) * width / 2
        return np.array([p + n, q + n, q - n, p - n])

    polys = [limb((0, 0.16), (0, 0.52), 0.2)]
    for side in (-1, 1):
        polys.append(
            limb(
                (0.09 * side, 0.18),
                (0.09 * side + 0.3 * side * np.sin(arm), 0.18 + 0.3 * np.cos(arm)),
                0.06,
            )
        )
        polys.append(limb((0.06 * side, 0.5), (0.2 * side, 1.0), 0.08))
    pts = [np.round(p * scale + (cx, top)).astype(np.int32) for p in polys]
    cv2.fillPoly(mask, pts, 1)
    cv2.circle(mask, (round(cx), round(top + 0.07 * scale)), max(1, round(0.07 * scale)), 1, -1)
    return mask.astype(bool)


def _masks() -> list[np.ndarray]:
    ellipses = []
    for angle in (0.0, 45.0, 20.0):
        m = np.zeros((480, 640), np.uint8)
        cv2.ellipse(m, (320, 240), (60, 150), angle, 0, 360, 1, -1)
        ellipses.append(m.astype(bool))
    return [_figure(s, a) for s, a in ((400, 0.3), (250, 1.5), (120, 2.6))] + ellipses


@pytest.mark.parametrize(
    "config",
    [
        ShapeContextConfig(),
        ShapeContextConfig(kappas=(0.25,), n_theta=7, n_r=3, n_points=150),
        ShapeContextConfig(kappas=(0.1, 2.0), n_theta=8, n_r=6, r_in_fraction=0.2),
    ],
)
def test_histograms_equal_the_reference_on_silhouettes(monkeypatch, config):
    for i, mask in enumerate(_masks()):
        ref, fast = _both(monkeypatch, lambda m=mask, i=i: sc_descriptors(m, i, config))
        np.testing.assert_array_equal(fast, ref)


def test_histograms_equal_the_reference_on_random_points(monkeypatch):
    """Integer grids (exactly horizontal, vertical and diagonal pairs), duplicates,
    every n_theta from 1 (one edge, at pi) up to 16: the same bins."""
    rng = np.random.default_rng(11)
    for trial in range(60):
        n = int(rng.integers(2, 120))
        pts = rng.uniform(-50.0, 300.0, (n, 2))
        if trial % 2 == 0:
            pts = np.round(pts)
        if trial % 5 == 0:
            pts[-1] = pts[0]
        n_theta = 1 + trial % 16
        kwargs = {
            "kappas": tuple(rng.uniform(0.1, 1.5, 2)),
            "n_theta": n_theta,
            "n_r": int(rng.integers(1, 7)),
            "r_in_fraction": float(rng.uniform(0.02, 0.5)),
            "height": float(rng.uniform(50.0, 400.0)),
        }
        # the points are the contour itself (as many samples as vertices, phase 0
        # or not): the histograms see the integer coordinates
        ref, fast = _both(
            monkeypatch, lambda p=pts, k=kwargs: multiscale_shape_contexts(p, len(p), 3, **k)
        )
        np.testing.assert_array_equal(fast, ref, err_msg=f"trial {trial}")


def test_one_orientation_bin_keeps_the_neighbour_at_pi_in_its_ring(monkeypatch):
    """n_theta = 1: a neighbour straight to the left (arctan2 = pi, on the one bin
    edge) counts in the ring of its distance, like the one to the right (the
    reference once moved it to the next ring)."""
    pts = np.array([[0.0, 0.0], [5.0, 0.0], [2.0, 3.0]])
    ref, fast = _both(monkeypatch, lambda: shape_context._histograms(pts, 100.0, (1.0,), 1, 2, 0.1))
    np.testing.assert_array_equal(fast, ref)
    # r_in = 10, r_out = 100: every pair is closer than r_in, so in the inner ring.
    np.testing.assert_array_equal(ref[0], [[1.0, 0.0]] * 3)


def test_histograms_of_a_single_pixel(monkeypatch):
    """All sampled points coincide: every neighbour in the innermost bin at angle 0."""
    mask = np.zeros((20, 20), bool)
    mask[5, 7] = True
    config = ShapeContextConfig(n_points=10)
    ref, fast = _both(monkeypatch, lambda: sc_descriptors(mask, 0, config))
    np.testing.assert_array_equal(fast, ref)
    np.testing.assert_array_equal(fast[:, :, 0], 1.0)


@pytest.mark.parametrize("n_nearest", [1, 3, 5, 100])
def test_encoding_matches_the_reference(monkeypatch, n_nearest):
    config = ShapeContextConfig(n_points=200)
    descriptors = [sc_descriptors(m, i, config) for i, m in enumerate(_masks())]
    codebook = fit_codebook(np.concatenate(descriptors, axis=1), k=100, rng=0, config=config)
    codebook = Codebook(codebook.centers, codebook.sigma, config, n_nearest)
    for d in descriptors:
        ref, fast = _both(monkeypatch, lambda d=d: codebook.encode(d))
        np.testing.assert_allclose(fast, ref, rtol=0, atol=ATOL_ENCODE)
        assert abs(np.linalg.norm(fast) - 1.0) < ATOL_ENCODE


def test_rdf_matches_the_reference(monkeypatch):
    """Silhouettes, a C shape whose centroid lies outside it (rays that miss: 0),
    one pixel, two pixels, a straight bar (collinear runs all dropped but one)."""
    c_shape = np.zeros((200, 200), np.uint8)
    cv2.ellipse(c_shape, (100, 100), (80, 80), 0, 40, 320, 1, 12)
    small = [np.zeros((9, 9), bool) for _ in range(3)]
    small[0][4, 4] = True
    small[1][4, 4:6] = True
    small[2][2, 1:8] = True
    for mask in [*_masks(), c_shape.astype(bool), *small]:
        for n in (100, 7):
            ref, fast = _both(monkeypatch, lambda m=mask, n=n: rdf(m, n))
            np.testing.assert_allclose(fast, ref, rtol=0, atol=ATOL_RDF_PX)
    # the C's opening: rays through it meet no edge
    assert np.any(rdf(c_shape)[2:] == 0.0)


def test_backend_setting_is_checked(monkeypatch):
    monkeypatch.setattr(features, "BACKEND", "fortran")
    with pytest.raises(ValueError, match=r"features\.BACKEND"):
        sc_descriptors(_figure(100, 1.0, shape=(120, 100)), 0)
    contour = silhouette_contour(_figure(100, 1.0, shape=(120, 100)))
    monkeypatch.setattr(features, "BACKEND", "numpy")
    assert multiscale_shape_contexts(contour, 20, 0).shape == (3, 20, 60)
