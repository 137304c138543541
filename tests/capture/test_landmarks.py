"""Triangulating the segmenter's landmarks: known points through a synthetic rig,
a wrong view dropped, views that do not count."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.capture.landmarks import (
    LandmarkConfig,
    principal_point_offsets,
    triangulate_landmarks,
)
from bodymetry.errors import InputError
from bodymetry.studio.rig import studio_rig


@pytest.fixture(scope="module")
def rig():
    return studio_rig(4, (640, 480), seed=5)


@pytest.fixture(scope="module")
def truth():
    rng = np.random.default_rng(0)
    return rng.uniform([-0.4, -0.4, 0.1], [0.4, 0.4, 1.8], (33, 3))


def _observed(rig, points, visibility=1.0) -> list[np.ndarray]:
    return [np.column_stack([c.project(points), np.full(len(points), visibility)]) for c in rig]


def test_known_points_come_back(rig, truth):
    got = triangulate_landmarks(rig, _observed(rig, truth))
    np.testing.assert_allclose(got, truth, atol=1e-6)


def test_a_wrong_view_is_dropped(rig, truth):
    views = _observed(rig, truth)
    views[2][5, :2] += (60.0, -40.0)  # e.g. left and right swapped in one view
    views[0][9, :2] += (0.0, 80.0)
    got = triangulate_landmarks(rig, views)
    np.testing.assert_allclose(got, truth, atol=1e-6)


def test_views_that_do_not_count(rig, truth):
    views = _observed(rig, truth)
    views[0][:, 2] = 0.2  # below min_visibility: not used
    views[1] = None  # nobody found in this view
    views[3][3, 2] = 0.0  # landmark 3 is then seen by camera 2 alone
    got = triangulate_landmarks(rig, views)
    assert np.isnan(got[3]).all()
    ok = np.arange(33) != 3
    np.testing.assert_allclose(got[ok], truth[ok], atol=1e-6)
    loose = triangulate_landmarks(rig, views, LandmarkConfig(min_visibility=0.1))
    np.testing.assert_allclose(loose[3], truth[3], atol=1e-6)


def test_bad_input_is_named(rig, truth):
    views = _observed(rig, truth)
    with pytest.raises(InputError, match="for 4 cameras"):
        triangulate_landmarks(rig, views[:3])
    with pytest.raises(InputError, match=r"cam_01.*\(33, 3\)"):
        triangulate_landmarks(rig, [views[0], views[1][:10], *views[2:]])
    with pytest.raises(InputError, match="max_error"):
        LandmarkConfig(max_error=0)


def _frames(rig, n_frames=6, shift=None):
    """Per frame, per camera landmarks of a random body-sized point cloud; camera 1's
    detections displaced by ``shift`` pixels (a calibration that does not fit)."""
    rng = np.random.default_rng(1)
    frames = []
    for _ in range(n_frames):
        points = rng.uniform([-0.4, -0.4, 0.1], [0.4, 0.4, 1.8], (33, 3))
        views = _observed(rig, points)
        if shift is not None:
            views[1][:, :2] += shift
        frames.append(views)
    return frames


def test_a_camera_that_is_off_is_found_and_shifted(rig):
    cameras, offsets = principal_point_offsets(rig, _frames(rig, shift=(8.0, -3.0)))
    assert [o.applied for o in offsets] == [False, True, False, False]
    # The others absorb a little of it through the triangulated points.
    assert np.hypot(offsets[1].dx - 8.0, offsets[1].dy + 3.0) < 0.5, offsets[1]
    assert all(np.hypot(o.dx, o.dy) < 0.5 for o in offsets if not o.applied)
    assert offsets[1].observations == 6 * 33
    np.testing.assert_allclose(
        cameras[1].K[:2, 2] - rig[1].K[:2, 2], [offsets[1].dx, offsets[1].dy]
    )
    assert cameras[0] is rig[0]
    assert "+8.0 px in x" in offsets[1].describe() or "+7." in offsets[1].describe()


def test_an_exact_rig_is_left_alone(rig):
    cameras, offsets = principal_point_offsets(rig, _frames(rig))
    assert not any(o.applied for o in offsets)
    assert all(np.hypot(o.dx, o.dy) < 1e-6 for o in offsets)
    assert all(a is b for a, b in zip(cameras, rig, strict=True))


def test_small_offsets_and_thin_evidence_are_not_applied(rig):
    small = principal_point_offsets(rig, _frames(rig, shift=(1.5, 0.0)))[1]
    assert not any(o.applied for o in small)  # 1.5 px < 1 % of 480 px
    thin = principal_point_offsets(rig, _frames(rig, n_frames=2, shift=(8.0, 0.0)))[1]
    assert not thin[1].applied and thin[1].observations == 66  # < 100 observations
