"""Tests of the studio renderer: rasterizer, shading, shadows, masks, board."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.calibration.camera import Camera
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.raster import rasterize, signed_area2
from bodymetry.studio.lens import pixel_rays
from bodymetry.studio.render import Body, Studio
from bodymetry.studio.scene import Appearance, BoardPose, BoardTexture, Light

SIZE = (320, 240)
MILD_DIST = np.array([-0.09, 0.03, 0.0005, -0.0004, 0.0])


def look_at(center, target, name="cam", dist=None, f=260.0, size=SIZE) -> Camera:
    center = np.asarray(center, float)
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array([[f, 0, size[0] / 2 + 1.3], [0, f, size[1] / 2 - 0.7], [0, 0, 1.0]])
    return Camera(name, size, K, np.zeros(5) if dist is None else dist, R, -R @ center)


@pytest.fixture(scope="module")
def body():
    model = BodyModel.load()
    theta = model.poses["apose"][None].copy()
    posed = model.pose(BodyState(np.zeros((1, 3)), theta, np.zeros((1, model.n_shape))))
    v = posed.vertices[0].copy()
    v[:, 2] -= v[:, 2].min()
    return model, v


@pytest.fixture(scope="module")
def studio(body):
    return Studio.from_model(body[0])


@pytest.fixture(scope="module")
def cameras():
    target = [0.0, 0.0, 0.95]
    return [
        look_at([2.4, -2.4, 1.5], target, "cam_00"),
        look_at([-2.4, 2.4, 1.5], target, "cam_01", dist=MILD_DIST),
    ]


# --- rasterizer -------------------------------------------------------------------


def _brute_force_inside(tri: np.ndarray, size) -> np.ndarray:
    """Pixel centres inside or on a triangle, by half-plane tests per pixel."""
    w, h = size
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    a = tri
    s = np.sign(
        (a[1, 0] - a[0, 0]) * (a[2, 1] - a[0, 1]) - (a[2, 0] - a[0, 0]) * (a[1, 1] - a[0, 1])
    )
    inside = np.ones((h, w), bool)
    for i in range(3):
        p, q = a[i], a[(i + 1) % 3]
        e = (q[0] - p[0]) * (ys - p[1]) - (q[1] - p[1]) * (xs - p[0])
        inside &= s * e >= -1e-9
    return inside


def _fillpoly(poly: np.ndarray, size) -> np.ndarray:
    mask = np.zeros((size[1], size[0]), np.uint8)
    shift = 8
    cv2.fillPoly(mask, [np.round(poly * (1 << shift)).astype(np.int32)], 1, cv2.LINE_8, shift)
    return mask.astype(bool)


def _edge_band(mask: np.ndarray) -> np.ndarray:
    k = np.ones((3, 3), np.uint8)
    m = mask.astype(np.uint8)
    return (cv2.dilate(m, k) - cv2.erode(m, k)).astype(bool)


def test_single_triangle_exact_and_matches_fillpoly():
    tri = np.array([[10.3, 12.7], [70.6, 20.2], [33.1, 55.9]])
    r = rasterize(tri, np.ones(3), np.array([[0, 1, 2]]), (80, 64))
    expected = _brute_force_inside(tri, (80, 64))
    np.testing.assert_array_equal(r.mask, expected)
    ref = _fillpoly(tri, (80, 64))
    diff = r.mask ^ ref
    assert not np.any(diff & ~_edge_band(ref))
    assert np.all(r.tri[r.mask] == 0)
    # Barycentrics reproduce the pixel positions.
    ys, xs = np.divmod(r.pixels, 80)
    rec = r.bary.astype(float) @ tri
    np.testing.assert_allclose(rec, np.stack([xs, ys], 1), atol=1e-4)


def test_winding_and_culling():
    # Clockwise on screen (y down): a back face for an OpenCV camera.
    tri = np.array([[10.3, 12.7], [70.6, 20.2], [33.1, 55.9]])
    faces = np.array([[0, 1, 2]])
    assert signed_area2(tri, faces)[0] > 0
    assert rasterize(tri, np.ones(3), faces, (80, 64), cull="back").pixels.size == 0
    assert rasterize(tri, np.ones(3), faces, (80, 64), cull="front").pixels.size > 0
    assert rasterize(tri, np.ones(3), faces[:, ::-1], (80, 64), cull="back").pixels.size > 0


def test_cube_silhouette_depth_and_no_cracks():
    cam = look_at([1.7, -2.3, 1.9], [0.1, 0.0, 0.5], size=(160, 120), f=150.0)
    c = np.array([[x, y, z] for x in (-0.4, 0.4) for y in (-0.4, 0.4) for z in (0.1, 0.9)])
    # 12 outward counter-clockwise triangles.
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))])
    xy = cam.project(c)
    z = cam.to_camera(c)[:, 2]
    r = rasterize(xy, z, faces, cam.size, cull="back")
    hull = cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2)
    ref = _fillpoly(hull, cam.size)
    assert not np.any((r.mask ^ ref) & ~_edge_band(ref))
    # Every pixel inside the hull (away from its edge) is covered: no cracks.
    assert np.all(r.mask[ref & ~_edge_band(ref)])
    # Depth equals the ray-cast depth of the box.
    rays = pixel_rays(cam).reshape(-1, 3) @ cam.R
    lo, hi = c.min(0), c.max(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - cam.center) / rays
        t2 = (hi - cam.center) / rays
    tnear = np.nanmax(np.minimum(t1, t2), axis=1)
    got = r.depth.reshape(-1)[r.pixels]
    np.testing.assert_allclose(got, tnear[r.pixels], rtol=1e-4)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_zbuffer_picks_nearer_triangle(order):
    xy = np.array([[5.0, 5.0], [50.0, 8.0], [20.0, 45.0], [8.0, 30.0], [55.0, 40.0], [40.0, 2.0]])
    depth = np.array([2.0, 2.0, 2.0, 1.0, 1.0, 1.0])  # second triangle nearer
    faces = np.array([[0, 1, 2], [3, 4, 5]])[list(order)]
    r = rasterize(xy, depth, faces, (64, 48))
    first = _brute_force_inside(xy[:3], (64, 48))
    second = _brute_force_inside(xy[3:], (64, 48))
    both = first & second
    assert both.sum() > 50
    near_index = order.index(1)
    assert np.all(r.tri[both] == near_index)
    assert np.all(r.tri[first & ~second] == 1 - near_index)
    np.testing.assert_allclose(r.depth[both], 1.0)


def test_rasterize_rejects_bad_input():
    with pytest.raises(ValueError, match="xy must have shape"):
        rasterize(np.zeros((3, 3)), np.ones(3), np.array([[0, 1, 2]]), (10, 10))
    with pytest.raises(ValueError, match="cull"):
        rasterize(np.zeros((3, 2)), np.ones(3), np.array([[0, 1, 2]]), (10, 10), cull="x")


# --- studio ------------------------------------------------------------------------


def test_body_vertices_land_in_person_mask(studio, body, cameras):
    _, v = body
    for cam in cameras:
        frame = studio.render_frame(cam, v, rng=0)
        uv = np.round(cam.project(v)).astype(int)
        w, h = cam.size
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        assert ok.all()
        # At this resolution many vertices sit on the silhouette, within half a
        # pixel of the boundary: all must be within one pixel of the mask.
        inside = frame.person_mask[uv[:, 1], uv[:, 0]]
        grown = cv2.dilate(frame.person_mask.astype(np.uint8), np.ones((3, 3), np.uint8))
        assert inside.mean() > 0.85, cam.name
        assert grown[uv[:, 1], uv[:, 0]].all(), cam.name
        # The interior of the mask is the body: every mask pixel lies near a vertex.
        near = np.zeros_like(frame.person_mask)
        near[uv[:, 1], uv[:, 0]] = True
        near = cv2.dilate(near.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        assert near[frame.person_mask].mean() > 0.99, cam.name


def test_shadow_opposite_light_same_chromaticity(studio, body, cameras):
    _, v = body
    cam = cameras[0]
    frame = studio.render_frame(cam, v, effects=False)
    bg = studio.render_background(cam, effects=False)
    assert frame.shadow_mask.sum() > 0.15 * frame.person_mask.sum()
    # Shadow pixels lie on the floor, displaced from the feet along the light.
    rays = pixel_rays(cam)[frame.shadow_mask] @ cam.R
    t = -cam.center[2] / rays[:, 2]
    floor = cam.center + t[:, None] * rays
    along = studio.light.direction[:2] / np.linalg.norm(studio.light.direction[:2])
    feet = v[v[:, 2] < 0.05, :2].mean(0)
    assert (floor[:, :2].mean(0) - feet) @ along > 0.3
    # Darker by about half, same chromaticity.
    core = frame.shadow_mask & ~cv2.dilate(
        (frame.person_mask | ~frame.shadow_mask).astype(np.uint8), np.ones((5, 5), np.uint8)
    ).astype(bool)
    assert core.sum() > 50
    s = frame.image[core].astype(float).mean(0)
    b = bg[core].astype(float).mean(0)
    ratio = s / b
    assert np.all((ratio > 0.4) & (ratio < 0.6)), ratio
    np.testing.assert_allclose(s[0] / s[1], b[0] / b[1], rtol=0.05)
    np.testing.assert_allclose(s[1] / s[2], b[1] / b[2], rtol=0.05)
    # And away from shadows, person and board the background is unchanged.
    far = ~cv2.dilate(
        (frame.person_mask | (np.abs(frame.image.astype(int) - bg).max(-1) > 0)).astype(np.uint8),
        np.ones((3, 3), np.uint8),
    ).astype(bool)
    assert far.mean() > 0.8


def test_determinism_by_seed(studio, body, cameras):
    _, v = body
    cam = cameras[1]
    a = studio.render_frame(cam, v, rng=5)
    b = studio.render_frame(cam, v, rng=np.random.default_rng(5))
    c = studio.render_frame(cam, v, rng=6)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.person_mask, c.person_mask)
    assert np.any(a.image != c.image)
    noise = a.image.astype(float) - studio.render_frame(cam, v, effects=False).image
    assert 1.5 < np.std(noise[~a.person_mask]) < 6.0
    with pytest.raises(ValueError, match="rng"):
        studio.render_frame(cam, v)


def test_mask_matches_rendered_pixels(body, cameras):
    model, v = body
    studio = Studio.from_model(model, shadows=False)
    for cam in cameras:
        frame = studio.render_frame(cam, v, effects=False)
        bg = studio.render_background(cam, effects=False)
        diff = np.abs(frame.image.astype(int) - bg).max(axis=-1) > 0
        iou = (diff & frame.person_mask).sum() / (diff | frame.person_mask).sum()
        assert iou > 0.99, (cam.name, iou)
        assert not frame.shadow_mask.any()


def test_board_renders_detectable_at_true_pose(studio, body):
    _, v = body
    cam = look_at(
        [2.3, -2.3, 1.5], [0.0, 0.0, 0.95], "cam_b", dist=MILD_DIST, size=(640, 480), f=520
    )
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    board = cv2.aruco.CharucoBoard((5, 7), 0.08, 0.06, dictionary)
    tex = BoardTexture.from_charuco(board)
    tilt = cv2.Rodrigues(np.array([-0.3, 0.4, 0.0]))[0]
    R = cam.R.T @ tilt  # printed side (board -z) towards the camera
    t = cam.center + cam.R.T @ np.array([0.0, 0.1, 1.6]) - R @ np.array([0.2, 0.28, 0.0])
    pose = BoardPose(R, t)
    frame = studio.render_board(cam, tex, pose, rng=1, vertices=v)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(frame.image)
    assert ids is not None and len(ids) >= 18
    truth = cam.project(pose.to_world(board.getChessboardCorners()[ids.reshape(-1)]))
    err = np.linalg.norm(corners.reshape(-1, 2) - truth, axis=1)
    assert err.mean() < 0.25 and err.max() < 0.6, err
    # The board hides the person where it is in front.
    assert frame.board_mask.sum() > 5000
    assert not np.any(frame.board_mask & frame.person_mask)


def test_light_and_studio_validation(body):
    with pytest.raises(ValueError, match="downwards"):
        Light(direction=np.array([0.0, 0.0, 1.0]))
    model, _ = body
    with pytest.raises(ValueError, match="face_parts"):
        Studio(model.faces(), np.zeros(3))


def test_pixel_rays_invert_the_lens(cameras):
    cam = cameras[1]
    rays = pixel_rays(cam)
    back = cam.project(cam.center + rays[::7, ::7] @ cam.R)
    w, h = cam.size
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1)[::7, ::7]
    np.testing.assert_allclose(back, grid, atol=1e-6)


def test_person_raster_is_the_frame_mask(studio, body, cameras):
    _, v = body
    cam = cameras[1]
    frame = studio.render_frame(cam, v, effects=False)
    np.testing.assert_array_equal(studio.person_raster(cam, v).mask, frame.person_mask)


def test_other_bodies_are_z_buffered_shaded_and_cast_shadows(studio, body, cameras):
    """A bystander in front hides the person, one behind is hidden by it; both are
    lit and cast shadows like the person, and never enter the person mask."""
    _, v = body
    cam = cameras[0]
    toward = cam.center[:2] / np.linalg.norm(cam.center[:2])
    side = np.array([-toward[1], toward[0]])
    alone = studio.render_frame(cam, v, effects=False)
    empty = studio.render_background(cam, effects=False)
    # In front: 1.2 m towards the camera, half a body to the side -> partly occludes.
    front = v + np.r_[1.2 * toward + 0.25 * side, 0.0]
    hidden = studio.render_frame(cam, v, effects=False, others=[Body(front)])
    front_raster = studio.person_raster(cam, front).mask
    assert np.any(front_raster & alone.person_mask)
    np.testing.assert_array_equal(hidden.person_mask, alone.person_mask & ~front_raster)
    # Behind: 1.5 m further away and to the side -> the person mask is unchanged, and
    # the bystander shows (in other clothes) where the person does not cover it.
    shirt = Appearance(part_colors=np.full((15, 3), 0.2))
    back = v + np.r_[-1.5 * toward + 0.6 * side, 0.0]
    frame = studio.render_frame(cam, v, effects=False, others=[Body(back, shirt)])
    np.testing.assert_array_equal(frame.person_mask, alone.person_mask)
    visible = studio.person_raster(cam, back).mask & ~alone.person_mask
    assert visible.sum() > 500
    changed = np.abs(frame.image.astype(int) - alone.image).max(-1) > 4
    assert changed[visible].mean() > 0.95
    # Its cast shadow darkens the room beyond what the person's does.
    assert frame.shadow_mask.sum() > alone.shadow_mask.sum() + 100
    assert not np.any(frame.shadow_mask & visible)
    assert (
        frame.image[frame.shadow_mask & ~alone.shadow_mask]
        < empty[frame.shadow_mask & ~alone.shadow_mask]
    ).all(axis=-1).mean() > 0.9
    with pytest.raises(ValueError, match="others"):
        studio.render_frame(cam, v, effects=False, others=[Body(v[:10])])
