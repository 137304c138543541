"""Coverage rasterization (estimation.raster.coverage) against the z-buffer's inside rule."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from bodymetry.estimation.raster import coverage, coverage_views, rasterize


def _zbuffer_mask(xy: np.ndarray, faces: np.ndarray, size, valid=None) -> np.ndarray:
    return rasterize(xy, np.ones(len(xy)), faces, size, perspective=False, valid=valid).mask


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coverage_equals_the_zbuffer_mask_on_triangle_soup(seed):
    """Random triangles, partly off the image, some on integer (pixel-centre) positions."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-20, 120, (300, 2))
    xy[::3] = np.round(xy[::3])  # vertices exactly on pixel centres: ties of the inside rule
    faces = rng.integers(0, 300, (200, 3))
    np.testing.assert_array_equal(
        coverage(xy, faces, (100, 80)), _zbuffer_mask(xy, faces, (100, 80))
    )


def test_front_faces_of_a_closed_mesh_cover_the_same_pixels():
    """An outward sphere seen through a pinhole: front faces alone give the whole silhouette."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    for centre in ([0.0, 0.0, 2.0], [0.3, -0.2, 1.2], [-0.9, 0.5, 3.0]):
        v = sphere.vertices + centre
        xy = 300.0 * v[:, :2] / v[:, 2:] + [160.3, 120.6]  # OpenCV camera, no distortion
        full = _zbuffer_mask(xy, sphere.faces, (320, 240))
        assert full.sum() > 500
        np.testing.assert_array_equal(coverage(xy, sphere.faces, (320, 240), closed=True), full)
        np.testing.assert_array_equal(coverage(xy, sphere.faces, (320, 240)), full)


def test_coverage_skips_invalid_vertices_and_validates():
    xy = np.array([[1.0, 1.0], [8.0, 1.0], [1.0, 8.0], [np.nan, 3.0]])
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    mask = coverage(xy, faces, (10, 10))
    np.testing.assert_array_equal(mask, _zbuffer_mask(np.nan_to_num(xy), faces[:1], (10, 10)))
    assert not coverage(xy, faces, (10, 10), valid=np.array([False, True, True, True])).any()
    assert not coverage(np.zeros((0, 2)), np.zeros((0, 3), int), (10, 10)).any()
    with pytest.raises(ValueError, match="xy must have shape"):
        coverage(np.zeros((3, 3)), faces, (10, 10))


def test_views_in_one_pass_equal_one_call_per_view():
    """Tiles do not bleed: triangles reaching past their view's bottom or top are cut
    at its edge; a NaN vertex drops its triangles in that view only."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(-30, 130, (3, 300, 2))
    xy[1, 5] = np.nan
    faces = rng.integers(0, 300, (200, 3))
    stacked = coverage_views(xy, faces, (100, 80))
    assert stacked.shape == (3, 80, 100)
    for c in range(3):
        valid = np.isfinite(xy[c]).all(axis=1)
        alone = coverage(np.nan_to_num(xy[c]), faces, (100, 80), valid=valid)
        np.testing.assert_array_equal(stacked[c], alone)
    with pytest.raises(ValueError, match="xy must have shape"):
        coverage_views(xy[0], faces, (100, 80))
