"""Counting people from each view's detections (capture/headcount.py), on a studio rig
with skeletons projected exactly (known answers) and with landmark noise."""

from __future__ import annotations

import numpy as np
import pytest
from skeletons import detection

from bodymetry.capture.consistency import VisualHull
from bodymetry.capture.headcount import MATCH_ERROR, count_people, group_people, match_error
from bodymetry.capture.person import LANDMARKS
from bodymetry.errors import InputError
from bodymetry.studio.rig import studio_rig

SIZE = (640, 480)


@pytest.fixture(scope="module")
def rig():
    return studio_rig(4, SIZE, seed=3)


@pytest.fixture(scope="module")
def floor_box(rig):
    return VisualHull(rig).floor_box


def _views(rig, people, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    return [[detection(cam, at, noise, rng) for at in people] for cam in rig]


def test_one_skeleton_seen_twice_matches_exactly(rig):
    a, b = (detection(cam, (0.1, -0.2)) for cam in rig.select([0, 1]))
    assert match_error(rig.select([0, 1]), a, b) < 1e-6
    # Another person 0.8 m away: two views alone can be fooled (a shift along their
    # epipolar lines costs nothing), so a person needs three cameras that all agree;
    # most pairs of cameras tell the two apart.
    a = detection(rig[0], (0.1, -0.2))
    apart = [
        match_error(rig.select([0, k]), a, detection(rig[k], (0.9, -0.2))) > MATCH_ERROR
        for k in (1, 2, 3)
    ]
    assert sum(apart) >= 2


def test_counts_one_and_two_people(rig, floor_box):
    assert count_people(rig, _views(rig, [(0.0, 0.0)]), floor_box) == 1
    two = _views(rig, [(-0.5, 0.0), (0.5, 0.1)], noise=1.5)
    assert count_people(rig, two, floor_box) == 2
    # The detector's order differs between views: the count does not care.
    assert count_people(rig, [v[::-1] if c % 2 else v for c, v in enumerate(two)], floor_box) == 2


def test_a_person_hidden_in_one_view_still_counts(rig, floor_box):
    views = _views(rig, [(-0.5, 0.0), (0.5, 0.1)])
    views[2] = views[2][:1]  # the second person is behind the first in camera 2
    assert count_people(rig, views, floor_box) == 2


def test_a_bystander_seen_by_two_cameras_is_nobody(rig, floor_box):
    views = _views(rig, [(0.0, 0.0)])
    for c in (0, 1):
        views[c].append(detection(rig[c], (0.9, 0.6)))
    assert count_people(rig, views, floor_box) == 1


def test_outside_the_capture_volume_is_nobody(rig, floor_box):
    hi = floor_box[1]
    far = (hi[0] + 3.0, hi[1] + 3.0)
    views = [[detection(cam, far)] if cam.to_camera(np.array([[*far, 1.0]]))[0, 2] > 0 else []
             for cam in rig]  # fmt: skip
    assert count_people(rig, views, floor_box) == 0


def test_nobody_and_bad_input(rig, floor_box):
    assert count_people(rig, [[] for _ in rig], floor_box) == 0
    blind = np.full((len(LANDMARKS), 3), np.nan)
    assert count_people(rig, [[blind] for _ in rig], floor_box) == 0
    with pytest.raises(InputError, match="4 cameras"):
        count_people(rig, [[]], floor_box)


def test_a_camera_that_sees_one_person_in_front_of_another_gives_it_to_the_front_one(
    rig, floor_box
):
    # B stands 0.5 m behind A on camera 2's line of sight: camera 2 detects A only, and
    # A's landmarks there lie on the rays through B's too, so pairs of views cannot
    # tell (with this noise the pairwise grouping alone gives camera 2's detection to
    # B); the skeleton triangulated from the other cameras can.
    a = np.array([0.0, 0.0])
    away = a - rig[2].center[:2]
    b = a + 0.5 * away / np.linalg.norm(away)
    rng = np.random.default_rng(0)
    views = [[detection(cam, tuple(p), 2.0, rng) for p in (a, b)] for cam in rig]
    views[2] = [detection(rig[2], tuple(a), 2.0, rng)]
    groups = group_people(rig, views, floor_box)
    assert len(groups) == 2
    front = min(groups, key=lambda g: np.linalg.norm(g.position[:2] - a))
    back = max(groups, key=lambda g: np.linalg.norm(g.position[:2] - a))
    assert front.detections[2] == 0 and back.detections[2] is None
    np.testing.assert_allclose(front.position[:2], a, atol=0.05)
    np.testing.assert_allclose(back.position[:2], b, atol=0.05)
