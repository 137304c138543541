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


def _skeleton() -> np.ndarray:
    """(33, 3) landmarks of a person in a lunge facing -y (their left is +x):
    the left knee forward, the right leg back, the left arm raised."""
    from bodymetry.capture.person import LANDMARKS

    side = {"left": 1.0, "right": -1.0}
    base = {
        "nose": (0.0, -0.10, 1.62), "eye_inner": (0.02, -0.08, 1.66), "eye": (0.035, -0.075, 1.66),
        "eye_outer": (0.05, -0.07, 1.66), "ear": (0.08, 0.0, 1.63), "mouth": (0.025, -0.08, 1.57),
        "shoulder": (0.19, 0.0, 1.42), "elbow": (0.24, -0.05, 1.15), "wrist": (0.27, -0.15, 0.92),
        "pinky": (0.28, -0.18, 0.85), "index": (0.27, -0.19, 0.84), "thumb": (0.25, -0.18, 0.86),
        "hip": (0.10, 0.0, 0.92), "knee": (0.12, -0.05, 0.50), "ankle": (0.13, 0.0, 0.08),
        "heel": (0.13, 0.05, 0.04), "foot_index": (0.13, -0.15, 0.02),
    }  # fmt: skip
    # The lunge: the left knee and foot forward, the right ones back; the left arm up.
    shift = {
        ("left", "knee"): (0, -0.30, 0), ("left", "ankle"): (0, -0.35, 0),
        ("left", "heel"): (0, -0.35, 0), ("left", "foot_index"): (0, -0.35, 0),
        ("right", "knee"): (0, 0.25, -0.05), ("right", "ankle"): (0, 0.45, 0.1),
        ("right", "heel"): (0, 0.45, 0.12), ("right", "foot_index"): (0, 0.4, 0.02),
        ("left", "elbow"): (0, 0, 0.45), ("left", "wrist"): (0, 0.1, 0.85),
    }  # fmt: skip
    out = np.zeros((len(LANDMARKS), 3))
    for i, name in enumerate(LANDMARKS):
        if name == "nose":
            out[i] = base["nose"]
            continue
        s, part = name.split("_", 1)
        if s == "mouth":  # "mouth_left"
            s, part = part, s
        x, y, z = base[part]
        out[i] = np.array([side[s] * x, y, z]) + np.array(shift.get((s, part), (0, 0, 0)))
    return out


@pytest.mark.parametrize(
    "swapped",
    [
        {"arms": (1, 3)},  # two views of four: dropping the worst view cannot mend it
        {"arms": (0, 1), "legs": (2,)},  # the first view among them
        {"legs": (0, 2), "face": (3,)},
    ],
)
def test_views_with_left_and_right_swapped_are_relabelled(rig, swapped):
    from bodymetry.capture.landmarks import MIRROR

    truth = _skeleton()
    groups = {"face": np.arange(1, 11), "arms": np.arange(11, 23), "legs": np.arange(23, 33)}
    views = _observed(rig, truth)
    for name, cams in swapped.items():
        for c in cams:
            g = groups[name]
            views[c][g] = views[c][MIRROR[g]]
    got = triangulate_landmarks(rig, views)
    # Every landmark where it is, labels included (swapped ones land between the sides
    # without the relabelling: up to 0.4 m off).
    np.testing.assert_allclose(got, truth, atol=1e-6)


def test_a_labelling_every_view_agrees_on_is_kept(rig):
    from bodymetry.capture.landmarks import MIRROR

    truth = _skeleton()
    # Every view swapped: the views agree, so the detector's labels stand (nothing to
    # choose between), and the same points come back with left and right exchanged.
    views = [v[MIRROR] for v in _observed(rig, truth)]
    got = triangulate_landmarks(rig, views)
    np.testing.assert_allclose(got, truth[MIRROR], atol=1e-6)
