"""Contour refinement: sub-pixel outlines, occluding contours, and recovery of a known body."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from capture.studio.rig import studio_rig
from estimation.body_model.biometrics import measure
from estimation.body_model.model import BodyModel, BodyState
from estimation.projection import project_silhouettes
from estimation.refinement import (
    RefineConfig,
    boundary_points,
    mesh_edges,
    occluding_contour,
    outline_normals,
    prepare_contours,
    refine,
)

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


@pytest.fixture(scope="module")
def scene():
    model = BodyModel.load()
    cameras = studio_rig(4, (320, 240), seed=4)
    nu = np.array([0.8, -0.5, 0.3, 0.0, 0.4, 0.0, -0.3, 0.0, 0.2])
    truth = BodyState([0.1, -0.2, 0.93], model.poses["apose"], nu)
    # The observation comes from the full mesh, the fit uses the level of detail.
    masks = project_silhouettes(model.pose(truth).vertices[0], model.faces(), cameras)
    return model, cameras, truth, masks


def test_refine_recovers_a_perturbed_body(scene):
    model, cameras, truth, masks = scene
    rng = np.random.default_rng(3)
    start = truth.vector()[0].copy()
    start[:3] += [0.03, -0.02, 0.02]
    start[3:40] += rng.normal(0, 0.06, 37)
    start[40:] = 0.0  # the mean shape
    obs = prepare_contours(cameras, masks, 1.0)
    result = refine(model, obs, start, RefineConfig(iterations=30))
    assert result.cost < result.initial_cost
    before = model.pose(BodyState.from_vector(start[None])).joints[0]
    after = model.pose(result.state).joints[0]
    true_joints = model.pose(truth).joints[0]
    err_before = np.linalg.norm(before - true_joints, axis=1).mean()
    err_after = np.linalg.norm(after - true_joints, axis=1).mean()
    assert err_after < 0.5 * err_before and err_after < 0.02
    bio_true, bio_fit = measure(model, np.vstack([truth.nu, result.state.nu]))
    assert abs(bio_fit.height_mm - bio_true.height_mm) < 15.0


def test_refine_keeps_joint_limits_and_wraps_heading(scene):
    model, cameras, truth, masks = scene
    start = truth.vector()[0].copy()
    start[3 + 2] += 2 * np.pi  # the same heading, one turn further
    obs = prepare_contours(cameras, masks, 0.5)
    result = refine(model, obs, start, RefineConfig(iterations=3))
    assert np.all(model.limits.contains(result.vector[3:40][None]))
    assert -np.pi <= result.vector[3 + 2] < np.pi


def test_refine_without_contours_returns_the_start(scene):
    model, cameras, truth, masks = scene
    obs = prepare_contours(cameras, np.zeros_like(masks), 0.5)
    start = truth.vector()[0]
    result = refine(model, obs, start)
    assert result.iterations == 0 and not np.isfinite(result.cost)
    np.testing.assert_allclose(result.vector, start)
    with pytest.raises(ValueError, match="expected 49"):
        refine(model, obs, start[:40])
