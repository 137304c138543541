"""The floor-shadow test (capture/shadows.py): a cast shadow on the floor is confirmed
by the other cameras; a dark patch standing in the room is not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.capture.shadows import at_feet, floor_points, floor_shadows
from bodymetry.errors import InputError
from bodymetry.studio.rig import studio_rig

SIZE = (320, 240)


@pytest.fixture(scope="module")
def rig():
    return studio_rig(4, SIZE, seed=3)


def _fill(camera, corners: np.ndarray) -> np.ndarray:
    """(H, W) bool: the projection of a planar quad (4, 3), filled."""
    px = camera.project(corners).astype(np.float32)
    mask = np.zeros((camera.size[1], camera.size[0]), np.uint8)
    cv2.fillConvexPoly(mask, np.round(px).astype(np.int32), 1)
    return mask.astype(bool)


# A 0.6 x 0.3 m cast shadow on the floor, and a 0.4 x 0.5 m dark panel standing
# 1.0-1.5 m above it (the shaded side of a grey shirt).
SHADOW = np.array([[0.1, -0.15, 0.0], [0.7, -0.15, 0.0], [0.7, 0.15, 0.0], [0.1, 0.15, 0.0]])
PANEL = np.array([[-0.2, 0.0, 1.0], [0.2, 0.0, 1.0], [0.2, 0.0, 1.5], [-0.2, 0.0, 1.5]])


def test_floor_points_lie_on_the_floor_and_project_back(rig):
    cam = rig[0]
    px = np.array([[160.0, 200.0], [100.0, 220.0]])
    pts, valid = floor_points(cam, px)
    assert valid.all()
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(cam.project(pts), px, atol=1e-6)
    # A ray above the horizon never meets the floor.
    up = cam.center + np.array([0.0, 0.0, 5.0])
    _, valid = floor_points(cam, cam.project(up[None]))
    assert not valid.any()


def test_a_cast_shadow_is_confirmed_and_a_standing_dark_patch_is_not(rig):
    shadow = [_fill(c, SHADOW) for c in rig]
    panel = [_fill(c, PANEL) for c in rig]
    # Every view labels the floor shadow; view 0 also takes the panel for shadow.
    labels = [
        s | (p if k == 0 else False) for k, (s, p) in enumerate(zip(shadow, panel, strict=True))
    ]
    lit = [~(s | p) for s, p in zip(shadow, panel, strict=True)]
    floor = floor_shadows(rig, labels, lit)
    for k in range(len(rig)):
        true_shadow = shadow[k] & ~panel[k]
        assert floor[k].mask[true_shadow].mean() > 0.95, k
        assert not (floor[k].mask & ~labels[k]).any()  # only shadow labels are kept
    garment = panel[0] & ~shadow[0]
    assert garment.sum() > 200
    assert floor[0].mask[garment].mean() < 0.05


def test_no_confirming_view_means_no_floor_shadow(rig):
    # A shadow label that only camera 0 has: the others see its floor point lit.
    shadow = [_fill(c, SHADOW) for c in rig]
    labels = [shadow[0]] + [np.zeros_like(s) for s in shadow[1:]]
    lit = [np.ones_like(s) for s in shadow]
    lit[0] = ~shadow[0]
    floor = floor_shadows(rig, labels, lit)
    assert not floor[0].mask.any() and len(floor[0].points) == 0
    assert all(not f.mask.any() for f in floor[1:])


def test_views_without_a_background_are_skipped_and_counts_checked(rig):
    shadow = [_fill(c, SHADOW) for c in rig]
    floor = floor_shadows(rig, [None, *shadow[1:]], [None, *(~s for s in shadow[1:])])
    assert floor[0] is None and floor[1].mask.any()
    with pytest.raises(InputError, match="4 cameras"):
        floor_shadows(rig, shadow[:2], shadow[:2])


def test_at_feet_keeps_the_floor_points_near_the_footprint(rig):
    # The floor shadow quad starts 0.1 m from a footprint at the origin and runs to 0.7 m.
    shadow = [_fill(c, SHADOW) for c in rig]
    floor = floor_shadows(rig, shadow, [~s for s in shadow])
    ys, xs = np.nonzero(floor[0].mask)
    points, _ = floor_points(rig[0], np.column_stack([xs, ys]).astype(float))
    # The floor points travel with the mask, in np.nonzero's order.
    np.testing.assert_allclose(floor[0].points, points, atol=1e-9)
    near = at_feet([floor[0], None, None, None], np.zeros((1, 2)), reach=0.3)
    assert near[1] is None
    distance = np.linalg.norm(points[:, :2], axis=1)
    got = near[0][ys, xs]
    # Known answer away from the boundary (pixel centres vs the quad's edges).
    assert got[distance < 0.28].all() and not got[distance > 0.32].any()
    assert got.any() and not got.all()
    assert not (near[0] & ~floor[0].mask).any()
    empty = at_feet(floor, np.zeros((0, 2)), reach=0.3)
    assert not any(m.any() for m in empty)


def test_a_garment_in_front_of_a_real_shadow_fails_the_brightness_test(rig):
    # Soft light: the floor really is in shadow behind the calf, so the plain test
    # confirms the calf's shaded side as floor shadow. A shadow dims the floor by the
    # same ratio in every view; the calf has its own brightness.
    shadow = [_fill(c, SHADOW) for c in rig]
    half = SHADOW.copy()
    half[1:3, 0] = 0.4  # the panel covers the shadow's first half, seen from view 0,
    toward = rig[0].center[None] - half
    panel = _fill(rig[0], half + 0.1 * toward)  # floating 10 % of the way to camera 0
    assert (panel & shadow[0]).sum() > 200 and (shadow[0] & ~panel).sum() > 200
    dim, garment = -0.5, -1.2  # log brightness ratios
    brightness = [np.where(s, dim, 0.0).astype(np.float32) for s in shadow]
    brightness[0][panel] = garment
    labels = [shadow[0] | panel, *shadow[1:]]
    lit = [~s for s in labels]
    plain = floor_shadows(rig, labels, lit)
    photo = floor_shadows(rig, labels, lit, brightness=brightness)
    inner = cv2.erode(panel.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert plain[0].mask[inner].mean() > 0.95  # without photometry: taken for floor shadow
    assert photo[0].mask[inner].mean() < 0.02
    rest = cv2.erode((shadow[0] & ~panel).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert photo[0].mask[rest].mean() > 0.95  # the shadow beside it is still confirmed
    for k in range(1, len(rig)):  # the others confirm each other
        assert photo[k].mask[shadow[k]].mean() > 0.9, k
    # The points travel with the mask.
    assert len(photo[0].points) == photo[0].mask.sum()
    with pytest.raises(InputError, match="brightness maps"):
        floor_shadows(rig, labels, lit, brightness=brightness[:2])
    with pytest.raises(InputError, match="brightness_tol"):
        floor_shadows(rig, labels, lit, brightness=brightness, brightness_tol=0.0)
