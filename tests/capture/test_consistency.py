"""The multi-view consistency check: a synthetic subject seen by four calibrated
cameras, and blobs that only one camera sees."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from silhouette_shapes import cylinder_mask

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.consistency import (
    PERSON_MIN_HEIGHT,
    PERSON_MIN_VOLUME,
    TOP_DEPTH,
    HullBodies,
    HullConfig,
    VisualHull,
    count_persons,
    visual_hull,
)
from bodymetry.errors import InputError
from bodymetry.studio.rig import studio_rig

SIZE = (320, 240)


@pytest.fixture(scope="module")
def rig():
    return studio_rig(4, SIZE, seed=3)


@pytest.fixture(scope="module")
def hull(rig):
    return VisualHull(rig)


def _cylinder_mask(camera, center=(0.0, 0.0), radius=0.2, height=1.7) -> np.ndarray:
    """(H, W) bool: the filled projection of an upright cylinder (the 'subject')."""
    return cylinder_mask(camera, center, radius, height)


def _blob(camera, avoid: np.ndarray) -> np.ndarray:
    """A 30x60 px blob in an image corner away from ``avoid``."""
    w, h = camera.size
    for x0, y0 in ((5, 5), (w - 35, 5), (5, h - 65), (w - 35, h - 65)):
        blob = np.zeros((h, w), bool)
        blob[y0 : y0 + 60, x0 : x0 + 30] = True
        if not (blob & cv2.dilate(avoid.astype(np.uint8), np.ones((15, 15))).astype(bool)).any():
            return blob
    raise AssertionError("no free corner")


def test_capture_volume_holds_the_origin_and_is_seen_by_three_cameras(hull, rig):
    assert hull.seen.shape == (4, len(hull.points))
    assert (hull.seen.sum(axis=0) >= 3).all()
    lo, hi = hull.points.min(axis=0), hull.points.max(axis=0)
    assert (lo[:2] < -0.5).all() and (hi[:2] > 0.5).all()
    assert lo[2] >= 0 and hi[2] <= 2.4
    assert 0.01 < hull.voxel < 0.1


def test_the_subject_is_occupied_and_kept_whole(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    occ = hull.occupied(masks)
    pts = hull.points[occ]
    # Known answer: the hull holds the cylinder's axis and lies within a few voxels of it.
    assert np.linalg.norm(pts[:, :2], axis=1).min() < hull.voxel
    assert np.linalg.norm(pts[:, :2], axis=1).max() < 0.2 + 3 * hull.voxel + 0.3
    check = hull.check(masks)
    assert not any(check.inconsistent)
    for before, after in zip(masks, check.masks, strict=True):
        np.testing.assert_array_equal(before, after)


def test_the_hulls_reach_widens_its_footprint_by_about_a_voxel(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    occ = hull.occupied(masks)
    for c in range(len(rig)):
        own, reach = hull.support(occ, c), hull.support(occ, c, reach=1.5)
        assert (own <= reach).all() and reach.sum() > own.sum()
        # The reach widens each voxel's square (half-side: splat, half a voxel in
        # pixels) to 1.5 voxel sides: by 2 splats, diagonally sqrt(2) times that.
        extra = cv2.distanceTransform((~own).astype(np.uint8), cv2.DIST_L2, 3)[reach]
        assert extra.max() <= np.sqrt(2) * (np.ceil(3 * hull.splat[c]) - hull.splat[c]) + 1
        assert (masks[c] & ~own).sum() >= (masks[c] & ~reach).sum()


def test_a_blob_one_camera_sees_is_removed(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    extra = _blob(rig[0], masks[0])
    with_blob = [masks[0] | extra, *masks[1:]]
    check = hull.check(with_blob)
    np.testing.assert_array_equal(check.masks[0], masks[0])
    assert not any(check.inconsistent)


def test_a_view_of_someone_else_is_inconsistent_with_the_subjects_box(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    other = _blob(rig[1], masks[1])
    check = hull.check([masks[0], other, masks[2], masks[3]])
    assert check.inconsistent == (False, True, False, False)
    assert not check.masks[1].any()  # the blob is nowhere near the subject
    x0, y0, x1, y1 = check.rois[1]
    ys, xs = np.nonzero(masks[1])
    # The box where the other views put the subject covers its true projection.
    assert x0 <= xs.min() + 2 and y0 <= ys.min() + 2 and x1 >= xs.max() - 2 and y1 >= ys.max() - 2


def test_an_empty_view_abstains_and_is_flagged(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    empty = np.zeros_like(masks[2])
    check = hull.check([masks[0], masks[1], empty, masks[3]])
    assert check.inconsistent == (False, False, True, False)
    assert check.voxels > 0 and check.rois[2] is not None
    for c in (0, 1, 3):
        np.testing.assert_array_equal(check.masks[c], masks[c])


def test_views_that_agree_on_nothing_are_left_as_they_are(hull, rig):
    masks = [_blob(c, np.zeros((c.size[1], c.size[0]), bool)) for c in rig]
    check = hull.check(masks)
    assert check.voxels == 0 and all(check.inconsistent)
    for before, after in zip(masks, check.masks, strict=True):
        np.testing.assert_array_equal(before, after)
    nobody = [np.zeros_like(m) for m in masks]
    assert not any(hull.check(nobody).inconsistent)


def test_mask_size_and_count_are_checked(hull, rig):
    masks = [_cylinder_mask(c) for c in rig]
    with pytest.raises(InputError, match="expected 4 masks"):
        hull.occupied(masks[:3])
    with pytest.raises(InputError, match=r"cam_01.*mask is 160x120"):
        hull.occupied([masks[0], np.zeros((120, 160), bool), *masks[2:]])


def test_config_and_rig_validation(rig):
    with pytest.raises(InputError, match="min_views"):
        HullConfig(min_views=1)
    with pytest.raises(InputError, match="misses"):
        HullConfig(min_views=3, misses=2)
    with pytest.raises(InputError, match="at least 3 cameras"):
        VisualHull(rig[:2])
    # Cameras that share no floor: a clear error, not an empty capture volume.
    apart = CameraGroup(
        [  # each camera moved 50 m further along x than the one before
            type(c)(c.name, c.size, c.K, c.dist, c.R, c.t - c.R @ np.array([50.0 * k, 0, 0]))
            for k, c in enumerate(rig)
        ]
    )
    with pytest.raises(InputError, match="no part of the room"):
        VisualHull(apart)


def test_a_rigs_hull_is_built_once_per_process(rig):
    copy = CameraGroup(
        [type(c)(c.name, c.size, c.K.copy(), c.dist.copy(), c.R.copy(), c.t.copy()) for c in rig]
    )
    first = visual_hull(rig)
    assert visual_hull(copy) is first  # the same rig, other objects
    assert visual_hull(rig, HullConfig(max_voxels=100_000)) is not first
    moved = CameraGroup(
        [*copy[:3], type(copy[3])(copy[3].name, copy[3].size, copy[3].K, t=copy[3].t + 0.01)]
    )
    assert visual_hull(moved) is not first


def test_the_hull_s_tops_are_world_points_over_the_people(hull, rig):
    masks = [_cylinder_mask(cam, center=(0.3, -0.2), height=1.7) for cam in rig]
    tops = hull.bodies(masks).tops
    assert tops.shape == (1, 3)
    # The hull of four views is a little wider and taller than the cylinder.
    np.testing.assert_allclose(tops[0, :2], (0.3, -0.2), atol=1.5 * hull.voxel)
    assert 1.7 - hull.voxel <= tops[0, 2] <= 1.7 + 3 * hull.voxel
    assert hull.bodies([np.zeros_like(m) for m in masks]).tops.shape == (0, 3)


def test_a_top_is_held_only_where_every_seeing_camera_holds_it(hull, rig):
    masks = [_cylinder_mask(cam, center=(0.3, -0.2), height=1.7) for cam in rig]
    bodies = hull.bodies(masks)
    assert bodies.held.tolist() == [True]
    # One camera's silhouette stops 15 cm lower: the three others still put the
    # top at 1.7 m (one miss allowed), but no camera-agreed voxel stands under it:
    # the sliver the crossing cones of a few views let through, not a head.
    masks[0] = _cylinder_mask(rig[0], center=(0.3, -0.2), height=1.55)
    cut = hull.bodies(masks)
    assert len(cut.tops) == 1 and cut.tops[0, 2] > 1.55 + TOP_DEPTH
    assert cut.held.tolist() == [False]
    # A 10 cm cut leaves agreed voxels within TOP_DEPTH of the top: held.
    masks[0] = _cylinder_mask(rig[0], center=(0.3, -0.2), height=1.65)
    assert hull.bodies(masks).held.tolist() == [True]
    assert hull.bodies([np.zeros_like(m) for m in masks]).held.shape == (0,)


def test_a_body_is_confirmed_where_every_seeing_camera_holds_some_voxel_of_it(hull, rig):
    masks = [_cylinder_mask(cam, center=(0.3, -0.2), height=1.7) for cam in rig]
    bodies = hull.bodies(masks)
    person = int(np.argmax(bodies.voxels))
    assert bodies.confirmed[person] and bodies.confirmed.sum() == 1
    # A blob that only three of the four cameras see there (the fourth sees the spot
    # empty, not behind the subject: its one miss allowed) stands in the hull, but no
    # voxel of it is held by every seeing camera: a ghost.
    ghost = [
        m | _cylinder_mask(cam, center=(0.8, 0.6), height=1.5)
        for m, cam in zip(masks, rig, strict=True)
    ]
    ghost[1] = masks[1]
    seen = hull.bodies(ghost)
    assert seen.person_sized.sum() == 2
    assert seen.confirmed.tolist() == [
        k == int(np.argmax(seen.voxels)) for k in range(len(seen.voxels))
    ]


def test_hull_bodies_person_sized_bodies_only():
    voxel = 0.05
    labels = np.array([0, 1, 1, 2, 3, 4])
    # Body 1: a person; 2: a stool (too low); 3: a thin pole (too small); 4: a child.
    voxels = np.array([0, 2000, 2000, 50, 200])
    heights = np.array([0.0, 1.7, 0.45, 1.2, 1.1])
    assert voxels[4] * voxel**3 >= PERSON_MIN_VOLUME and heights[2] < PERSON_MIN_HEIGHT
    bodies = HullBodies(labels, voxels, heights, voxel)
    assert bodies.person_sized.tolist() == [False, True, False, False, True]
    np.testing.assert_array_equal(bodies.largest, labels == 1)  # the first of the largest
    empty = HullBodies(np.zeros(6, np.int32), np.zeros(1, int), np.zeros(1), voxel)
    assert empty.persons == 0 and not empty.largest.any()


CELL = 0.05
GRID = np.stack(
    np.meshgrid(*(np.arange(n) * CELL + CELL / 2 for n in (60, 60, 46)), indexing="ij"), -1
)


def _limb(grid, a, b, radius):
    """Fill the voxels of ``grid`` (X, Y, Z) within ``radius`` of the segment a-b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.clip(((GRID - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    grid |= np.linalg.norm(GRID - (a + t[..., None] * (b - a)), axis=-1) <= radius


def _person(grid, x, y, height=1.75):
    """A standing person at floor position (x, y): legs, trunk, head."""
    k = height / 1.75
    for side in (-0.1, 0.1):
        _limb(grid, (x, y + side, 0.0), (x, y + side, 0.8 * k), 0.07)
    _limb(grid, (x, y, 0.8 * k), (x, y, 1.4 * k), 0.17)
    _limb(grid, (x, y, 1.45 * k), (x, y, height - 0.1), 0.1)


def test_count_persons_counts_separate_heads_not_arms():
    one = np.zeros(GRID.shape[:3], bool)
    _person(one, 1.5, 1.5)
    assert count_persons(one, CELL) == 1
    # A second, shorter person beside the first, their hulls joined by a low bridge
    # (hands, or the hull's excess between them).
    two = one.copy()
    _person(two, 1.5, 2.1, height=1.6)
    _limb(two, (1.5, 1.5, 0.9), (1.5, 2.1, 0.9), 0.08)
    assert count_persons(two, CELL) == 2
    # One person, arms raised in a wide V: the hands stand higher than the head and
    # far from it, but nothing stands under them.
    arms = one.copy()
    for side in (-1, 1):
        _limb(arms, (1.5, 1.5 + side * 0.2, 1.4), (1.5, 1.5 + side * 0.5, 2.05), 0.05)
    assert count_persons(arms, CELL) == 1
    # ... or held out at shoulder height: a ridge, no top of its own.
    tpose = one.copy()
    _limb(tpose, (1.5, 0.7, 1.4), (1.5, 2.3, 1.4), 0.05)
    assert count_persons(tpose, CELL) == 1
    # A low body (a stool) and nothing at all.
    low = np.zeros(GRID.shape[:3], bool)
    _limb(low, (1.0, 1.0, 0.0), (1.0, 1.0, 0.45), 0.2)
    assert count_persons(low, CELL) == 0 and count_persons(np.zeros((5, 5, 5), bool), CELL) == 0
