"""Each person's pixels per camera (capture/people.py), on a studio rig with
detections made from projected skeletons: who is who, and who hides whom."""

from __future__ import annotations

import cv2
import numpy as np
from skeletons import detection

from bodymetry.capture.consistency import VisualHull
from bodymetry.capture.people import partition, sightings
from bodymetry.capture.person import Person
from bodymetry.studio.rig import studio_rig

SIZE = (640, 480)
RIG = studio_rig(4, SIZE, seed=3)


def _person(camera, at) -> Person:
    """A detection of a person standing at ``at``: their landmarks, and the hull of
    their projected landmarks (grown a little) as the probability."""
    landmarks = detection(camera, at)
    pts = landmarks[np.isfinite(landmarks[:, 0]), :2]
    prob = np.zeros((SIZE[1], SIZE[0]), np.uint8)
    cv2.fillConvexPoly(prob, cv2.convexHull(np.round(pts).astype(np.int32)), 1)
    prob = cv2.dilate(prob, np.ones((9, 9), np.uint8))
    return Person(prob.astype(np.float32), landmarks)


def test_each_person_gets_their_own_pixels_and_the_nearer_one_hides_the_other():
    places = [(-0.35, 0.0), (0.35, 0.0)]
    detections = []
    for c, cam in enumerate(RIG):
        found = [_person(cam, at) for at in places]
        # Masks as detect_others leaves them: a later person's probability is zero
        # where an earlier one was found.
        found[1] = Person(np.where(found[0].probability > 0, 0, found[1].probability).astype(
            np.float32), found[1].landmarks)  # fmt: skip
        detections.append(found if c % 2 == 0 else found[::-1])
    people = sightings(RIG, detections, 0.5, 0.04, VisualHull(RIG).floor_box)
    assert len(people) == 2
    # Ordered along x, found by all four cameras, at their places.
    for seen, at in zip(people, places, strict=True):
        assert seen.views == 4
        np.testing.assert_allclose(seen.position[:2], at, atol=0.05)
    for c, cam in enumerate(RIG):
        a, b = (p.masks[c] for p in people)
        assert not (a & b).any()
        near = [np.linalg.norm(p.position - cam.center) for p in people]
        touching = (cv2.dilate(a.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0) & b
        if touching.any():
            # The farther one may be hidden in part; the nearer one is not.
            far = int(np.argmax(near))
            assert people[far].occluded[c] and not people[1 - far].occluded[c]
        else:
            assert not people[0].occluded[c] and not people[1].occluded[c]
    assert any(p.occluded[c] for p in people for c in range(4))  # they do touch somewhere


def test_a_person_one_camera_misses_has_no_mask_there():
    detections = [[_person(cam, (0.0, 0.0))] for cam in RIG]
    detections[2] = []
    (seen,) = sightings(RIG, detections, 0.5, 0.04)
    assert seen.views == 3 and seen.masks[2] is None and seen.landmarks[2] is None
    assert seen.occluded == (False,) * 4


def test_pixels_another_detection_holds_go_to_the_nearest_skeleton():
    cam = RIG[0]
    a, b = _person(cam, (-0.35, 0.0)), _person(cam, (0.35, 0.0))
    mask_a, mask_b = a.mask(0.5), b.mask(0.5)
    # The segmenter left A's upper third out of A's mask and put it in B's (it marks
    # everyone inside the crop it looks at).
    rows = np.flatnonzero(mask_a.any(axis=1))
    top = np.zeros_like(mask_a)
    top[rows[0] : rows[0] + (rows[-1] - rows[0]) // 3] = True
    leaked_a = Person((mask_a & ~top).astype(np.float32), a.landmarks)
    leaked_b = Person((mask_b | (mask_a & top)).astype(np.float32), b.landmarks)
    got_a, got_b = partition([leaked_a, leaked_b], 0.5)
    assert not (got_a & got_b).any()
    assert (got_a | got_b).sum() == (mask_a | mask_b).sum()
    only_a, only_b = mask_a & ~mask_b, mask_b & ~mask_a
    assert got_a[only_a].mean() > 0.95 and got_b[only_b].mean() > 0.95
    # One detection: its own mask.
    (alone,) = partition([a], 0.5)
    assert np.array_equal(alone, mask_a)
