"""Contours for the refinement: sub-pixel outlines, their normals, mesh edges and
occluding contours."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from bodymetry.estimation.contours import (
    boundary_points,
    mask_at,
    mesh_edges,
    near_outside,
    occluding_contour,
    outline_normals,
)
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.studio.rig import studio_rig

#: A digitized disc's outline points lie this close (pixels, mean) to the true circle.
OUTLINE_BIAS_PX = 0.05


def _disc(radius: float, size: int = 64, centre: float = 31.7) -> np.ndarray:
    y, x = np.mgrid[:size, :size]
    return (x - centre) ** 2 + (y - centre + 0.4) ** 2 <= radius**2


def test_boundary_points_are_unbiased():
    """Pixel centres of the boundary lie half a pixel inside; the crossings do not."""
    for radius in (8.0, 15.5, 25.0):
        p = boundary_points(_disc(radius))
        r = np.hypot(p[:, 0] - 31.7, p[:, 1] - 31.3)
        assert abs(r.mean() - radius) < OUTLINE_BIAS_PX


def test_boundary_points_of_a_square():
    mask = np.zeros((10, 10), bool)
    mask[2:5, 3:7] = True  # rows 2..4, columns 3..6
    p = boundary_points(mask)
    assert len(p) == 2 * 3 + 2 * 4
    assert p[:, 0].min() == 2.5 and p[:, 0].max() == 6.5
    assert p[:, 1].min() == 1.5 and p[:, 1].max() == 4.5
    with pytest.raises(ValueError, match="2-D"):
        boundary_points(np.zeros(5, bool))


def test_outline_normals_point_outwards():
    mask = _disc(20.0)
    p = boundary_points(mask)
    n = outline_normals(mask, p)
    radial = (p - [31.7, 31.3]) / np.linalg.norm(p - [31.7, 31.3], axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", n, radial) > 0.95)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)


def test_mesh_edges_of_a_closed_mesh_and_refusal_of_an_open_one():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    edges, faces_of = mesh_edges(sphere.faces)
    assert len(edges) == 3 * len(sphere.faces) // 2
    # Each edge's two faces really contain both of its vertices.
    for (a, b), (f, g) in zip(edges[:50], faces_of[:50], strict=True):
        assert {a, b} <= set(sphere.faces[f]) and {a, b} <= set(sphere.faces[g])
    with pytest.raises(ValueError, match="not closed"):
        mesh_edges(sphere.faces[1:])


def test_occluding_contour_of_a_sphere_is_its_outline():
    """The contour edges of a sphere project onto the rim of its image disc."""
    cam = studio_rig(1, (320, 240), seed=0)[0]
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    centre = np.array([0.0, 0.0, 1.0])
    verts = sphere.vertices + centre
    edges, faces_of = mesh_edges(sphere.faces)
    ids = occluding_contour(verts, sphere.faces, edges, faces_of, cam, cam.center)
    assert len(ids) > 30
    mid = cam.project(0.5 * (verts[edges[ids, 0]] + verts[edges[ids, 1]]))
    mask = project_silhouettes(verts, sphere.faces, [cam])[0]
    # Every contour point is within a pixel of the silhouette's outline.
    outline = boundary_points(mask)
    d = np.min(np.linalg.norm(mid[:, None] - outline[None], axis=2), axis=1)
    assert np.percentile(d, 95) < 1.0
    # The 3-D contour generator lies where the view ray grazes the sphere.
    p = 0.5 * (verts[edges[ids, 0]] + verts[edges[ids, 1]])
    ray = p - cam.center
    normal = (p - centre) / np.linalg.norm(p - centre, axis=1, keepdims=True)
    cosine = np.einsum("ij,ij->i", ray / np.linalg.norm(ray, axis=1, keepdims=True), normal)
    assert np.abs(cosine).max() < 0.1


@pytest.mark.parametrize("seed", [0, 1])
def test_near_outside_is_the_distance_transform_within_one_pixel(seed):
    """Random blobs touching the image border: every pixel's answer is OpenCV's
    ``distanceTransform(DIST_L2, 3) <= 1``."""
    rng = np.random.default_rng(seed)
    mask = cv2.GaussianBlur(rng.random((40, 50)).astype(np.float32), (0, 0), 2.0) > 0.5
    mask[:, :3] = True  # touches the left border
    want = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3) <= 1.0
    ys, xs = np.mgrid[:40, :50]
    got = near_outside(mask, np.c_[xs.ravel(), ys.ravel()]).reshape(40, 50)
    assert np.array_equal(got, want)
    assert got.any() and not got.all()


def test_mask_at_reads_the_nearest_pixel_and_nothing_outside():
    mask = np.zeros((4, 5), bool)
    mask[1, 3] = True
    points = np.array([[3.0, 1.0], [3.4, 0.6], [2.4, 1.0], [-0.6, 1.0], [5.0, 1.0], [np.nan, 1.0]])
    assert mask_at(mask, points).tolist() == [True, True, False, False, False, False]
    assert mask_at(mask, np.zeros((0, 2))).shape == (0,)
