"""Each person's pixels per camera (capture/people.py), on a studio rig with
detections made from projected skeletons: who is who, and who hides whom."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from skeletons import detection

from bodymetry.capture.consistency import VisualHull
from bodymetry.capture.people import MIXED_SHARE, astray, partition, people_boxes, sightings
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


def _detections(places):
    """Per camera, the detections of people standing at ``places`` as the segmenter
    leaves them (nearest first; a later person's probability is zero where an
    earlier one was found)."""
    out = []
    for cam in RIG:
        order = sorted(places, key=lambda at: np.linalg.norm([*at, 1.0] - cam.center))
        found = []
        for at in order:
            person = _person(cam, at)
            taken = np.logical_or.reduce([p.mask(0.5) for p in found]) if found else None
            if taken is not None:
                person = Person(np.where(taken, 0, person.probability).astype(np.float32),
                                person.landmarks)  # fmt: skip
            found.append(person)
        out.append(found)
    return out


def test_each_person_gets_their_own_pixels_and_one_behind_another_is_occluded():
    # B stands 0.6 m behind A as camera 0 sees them: hidden there, in full view elsewhere.
    a = np.array([0.0, 0.0])
    away = a - RIG[0].center[:2]
    b = a + 0.6 * away / np.linalg.norm(away)
    people = sightings(RIG, _detections([tuple(a), tuple(b)]), 0.5, VisualHull(RIG).floor_box)
    assert len(people) == 2
    by_place = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    for seen, at in zip(by_place, (a, b), strict=True):
        assert seen.views == 4
        np.testing.assert_allclose(seen.position[:2], at, atol=0.05)
    front, back = by_place
    assert back.occluded[0] and not front.occluded[0]
    for c in range(4):
        assert not (front.masks[c] & back.masks[c]).any()
    # Side by side, 1 m apart across camera 0's line of sight: nobody hides anybody
    # there.
    side = np.array([-away[1], away[0]]) / np.linalg.norm(away)
    apart = sightings(RIG, _detections([tuple(a - 0.5 * side), tuple(a + 0.5 * side)]), 0.5)
    assert len(apart) == 2 and not any(p.occluded[0] for p in apart)


def test_a_person_one_camera_misses_has_no_mask_there():
    detections = [[_person(cam, (0.0, 0.0))] for cam in RIG]
    detections[2] = []
    (seen,) = sightings(RIG, detections, 0.5)
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


def _behind(camera, aside: float) -> tuple[np.ndarray, np.ndarray]:
    """Floor positions (2,) of A at the origin and of B 0.6 m behind A as ``camera``
    sees them, ``aside`` metres to the side."""
    a = np.array([0.0, 0.0])
    away = a - camera.center[:2]
    side = np.array([-away[1], away[0]]) / np.linalg.norm(away)
    return a, a + 0.6 * away / np.linalg.norm(away) + aside * side


def test_someone_a_camera_missed_behind_another_keeps_their_visible_pixels():
    # B stands behind A as camera 0 sees them, a little to the side: half visible.
    a, b = _behind(RIG[0], 0.3)
    detections = _detections([tuple(a), tuple(b)])
    front, back = detections[0]
    both = front.mask(0.5) | back.mask(0.5)
    # Camera 0's segmenter found only A, and marked B's visible part as A's too.
    detections[0] = [Person(both.astype(np.float32), front.landmarks)]
    people = sightings(RIG, detections, 0.5, VisualHull(RIG).floor_box)
    seen_a, seen_b = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    assert seen_b.masks[0] is not None and seen_b.landmarks[0] is None
    # Half of B is hidden: their covered pixels are unknown (A's, over B's body); a
    # camera that did not detect B leaves the view out of B's fit (``occluded``).
    assert seen_b.occluded[0]
    hidden = seen_b.hidden[0]
    assert hidden is not None and hidden.any() and not (hidden & seen_b.masks[0]).any()
    assert (hidden <= seen_a.masks[0]).all()
    only_b = back.mask(0.5) & ~_person(RIG[0], tuple(a)).mask(0.5)
    assert only_b.any()
    assert seen_b.masks[0][only_b].mean() > 0.8 and not seen_a.masks[0][only_b].mean() > 0.2
    assert not seen_a.occluded[0]


def test_a_detected_person_half_behind_another_keeps_the_view_with_hidden_pixels():
    a, b = _behind(RIG[0], 0.3)
    people = sightings(RIG, _detections([tuple(a), tuple(b)]), 0.5, VisualHull(RIG).floor_box)
    seen_a, seen_b = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    # Camera 0 found B: half of them hidden is fitted, the covered pixels unknown.
    assert not seen_b.occluded[0] and not seen_a.occluded[0]
    hidden = seen_b.hidden[0]
    assert hidden is not None and (hidden <= seen_a.masks[0]).all()
    # The hidden pixels are A's over B's body, not all of A: A's far side stays
    # background for B.
    truly = _person(RIG[0], tuple(b)).mask(0.5) & seen_a.masks[0]
    assert np.count_nonzero(hidden & truly) > 0.5 * np.count_nonzero(truly)
    assert np.count_nonzero(hidden) < 0.8 * np.count_nonzero(seen_a.masks[0])
    assert seen_a.hidden[0] is None  # nobody is nearer to camera 0 than A


def test_a_detection_mostly_on_someone_else_is_named_mixed():
    a, b = _behind(RIG[0], 0.35)
    detections = _detections([tuple(a), tuple(b)])
    front, back = detections[0]
    floor = VisualHull(RIG).floor_box
    clean = sightings(RIG, detections, 0.5, floor)
    assert not any(any(p.mixed) for p in clean)
    # Camera 0's detector drew A's left arm and legs on B behind them (13 of 33
    # landmarks), and A's mask followed: that view of A is mixed, no other is.
    wrong = front.landmarks.copy()
    moved = [13, 15, 17, 19, 21, *range(25, 33)]
    wrong[moved] = back.landmarks[moved]
    detections[0] = [Person(front.probability, wrong), back]
    seen_a, seen_b = sorted(
        sightings(RIG, detections, 0.5, floor), key=lambda p: np.linalg.norm(p.position[:2] - a)
    )
    assert seen_a.mixed == (True, False, False, False)
    assert not any(seen_b.mixed) and not seen_a.occluded[0]


def test_someone_a_camera_missed_in_front_of_the_one_it_found_is_mixed_there():
    a, b = _behind(RIG[0], 0.3)  # B behind A as camera 0 sees them, half hidden
    detections = _detections([tuple(a), tuple(b)])
    whole_a = _person(RIG[0], tuple(a)).mask(0.5)
    back = detections[0][1]  # B's visible pixels, with B's skeleton
    rows = np.flatnonzero(whole_a.any(axis=1))
    legs = whole_a.copy()
    legs[: rows[0] + 2 * (rows[-1] - rows[0]) // 3] = False  # A's lowest third
    floor = VisualHull(RIG).floor_box

    def seen(mask, foreground=None):
        # Camera 0's detector found B only, with B's skeleton and ``mask``.
        found = [*detections]
        found[0] = [Person(mask.astype(np.float32), back.landmarks)]
        people = sightings(RIG, found, 0.5, floor, foreground=foreground)
        return sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))

    # Its mask followed B and held A's legs, not A's trunk: nobody hides A from
    # camera 0, yet most of A's projected skeleton lies on pixels A's fit would
    # read as background. That view of A is mixed, not fitted as A's silhouette.
    seen_a, seen_b = seen(back.mask(0.5) | legs)
    assert seen_a.landmarks[0] is None and seen_a.masks[0] is not None
    assert seen_a.mixed == (True, False, False, False) and not seen_a.occluded[0]
    assert not any(seen_b.mixed)
    # Where everyone's fused silhouette is known (an empty-scene clip), A's trunk
    # that no detection's mask holds is in it, and nearest A's projected skeleton:
    # A's pixels, and the view is kept. Where A's body and B's overlap, the
    # skeletons cannot tell whose a pixel is: unknown to both.
    everyone = [whole_a | _person(RIG[0], tuple(b)).mask(0.5), None, None, None]
    seen_a, seen_b = seen(back.mask(0.5) | legs, everyone)
    assert not any(seen_a.mixed) and not seen_a.occluded[0]
    trunk = whole_a & ~legs
    assert np.count_nonzero(seen_a.masks[0] & trunk) > 0.6 * np.count_nonzero(trunk)
    unknown = seen_a.hidden[0]
    assert unknown is not None and (seen_a.masks[0] | unknown)[trunk].mean() > 0.95
    assert seen_b.hidden[0] is not None and (seen_b.hidden[0] & unknown).any()
    # One detection of both whose mask holds all of A: A's pixels there, not mixed.
    seen_a, seen_b = seen(back.mask(0.5) | whole_a)
    assert not any(seen_a.mixed) and not any(seen_b.mixed)
    assert seen_a.masks[0][whole_a].mean() > 0.9


def test_people_boxes_frame_where_the_other_cameras_put_each_person():
    places = [(-0.5, 0.2), (0.6, -0.1)]
    landmarks = [[detection(cam, at) for at in places] for cam in RIG]
    floor = VisualHull(RIG).floor_box
    for c, cam in enumerate(RIG):
        boxes = people_boxes(RIG, landmarks, c, floor)
        assert len(boxes) == 2
        for at in places:
            # Each person's own landmarks in camera c lie in one box, tight to 2 px.
            xy = detection(cam, at)[:, :2]
            xy = xy[np.isfinite(xy[:, 0])]
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            assert any(
                np.all(np.abs([x0 - lo[0], y0 - lo[1], x1 - hi[0], y1 - hi[1]]) < 2.0)
                for x0, y0, x1, y1 in boxes
            ), (c, at, boxes)
    # Camera c's own detections are not used: the boxes are the same without them.
    without = [list(v) for v in landmarks]
    without[1] = []
    assert people_boxes(RIG, without, 1, floor) == people_boxes(RIG, landmarks, 1, floor)
    # Someone only one other camera found is nowhere.
    one = [[], [detection(RIG[1], places[0])], [], []]
    assert people_boxes(RIG, one, 0, floor) == []


def test_how_far_a_detection_strays_from_the_other_cameras():
    cam = RIG[0]
    lm = detection(cam, (0.0, 0.0))
    assert astray(lm, lm, cam) == 0.0 and astray(lm, None, cam) == 0.0
    drawn = np.isfinite(lm).all(axis=1) & (lm[:, 2] >= 0.3)
    off = lm.copy()
    off[:11, 0] += 0.05 * cam.size[1]  # the face moved 5 % of the image height
    assert astray(off, lm, cam) == pytest.approx(drawn[:11].sum() / drawn.sum())
    assert astray(off, lm, cam) < MIXED_SHARE  # mended, not mixed
    # Landmarks drawn too faintly are not counted.
    faint = off.copy()
    faint[:11, 2] = 0.1
    assert astray(faint, lm, cam) == 0.0


def test_landmarks_a_camera_put_on_someone_else_are_drawn_where_the_others_see_them():
    a, b = _behind(RIG[0], 0.35)
    detections = _detections([tuple(a), tuple(b)])
    front, back = detections[0]
    # Camera 0's detector built A's skeleton partly on B behind them (a crowd): A's
    # head and left arm drawn on B's.
    wrong = front.landmarks.copy()
    moved = [*range(11), 11, 13, 15, 17, 19, 21]
    wrong[moved] = back.landmarks[moved]
    detections[0] = [Person(front.probability, wrong), back]
    people = sightings(RIG, detections, 0.5, VisualHull(RIG).floor_box)
    seen_a, seen_b = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    detections[0] = [front, back]
    right = sightings(RIG, detections, 0.5, VisualHull(RIG).floor_box)
    right_a, right_b = sorted(right, key=lambda p: np.linalg.norm(p.position[:2] - a))
    # A's nearer skeleton is drawn where the other three cameras put A: the same
    # pixels for each as with camera 0's landmarks right (without that, A's core
    # claims 48 % of B's visible pixels, where the right landmarks give A 13 %).
    for seen, truth in ((seen_a, right_a), (seen_b, right_b)):
        assert np.array_equal(seen.masks[0], truth.masks[0])
    only_b = back.mask(0.5) & ~front.mask(0.5)
    assert only_b.sum() > 1000
    assert seen_a.masks[0][only_b].mean() < 0.2 and seen_b.masks[0][only_b].mean() > 0.8
    only_a = front.mask(0.5) & ~back.mask(0.5)
    assert seen_a.masks[0][only_a].mean() > 0.95


def test_limbs_a_camera_barely_sees_are_drawn_where_the_others_see_them():
    a, b = _behind(RIG[0], 0.35)
    detections = _detections([tuple(a), tuple(b)])
    front, back = detections[0]
    right = sightings(RIG, detections, 0.5, VisualHull(RIG).floor_box)
    _, right_b = sorted(right, key=lambda p: np.linalg.norm(p.position[:2] - a))
    # Camera 0's detector barely sees B's legs below the hips (behind A): too
    # little visibility to draw them.
    blind = back.landmarks.copy()
    blind[25:33, 2] = 0.05
    detections[0] = [front, Person(back.probability, blind)]
    people = sightings(RIG, detections, 0.5, VisualHull(RIG).floor_box)
    seen_a, seen_b = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    # B's legs are drawn where the other cameras put them: the same pixels as with
    # camera 0's landmarks seen well (without that, A's bones claim 82 % of B's
    # visible lower half; with them A gets 12 %).
    assert np.array_equal(seen_b.masks[0], right_b.masks[0])
    only_b = back.mask(0.5) & ~front.mask(0.5)
    rows = np.flatnonzero(only_b.any(axis=1))
    legs = only_b.copy()
    legs[: rows[0] + (rows[-1] - rows[0]) // 2] = False
    assert legs.sum() > 1000
    assert seen_a.masks[0][legs].mean() < 0.2 and seen_b.masks[0][legs].mean() > 0.8


def _side_by_side() -> list[list[Person]]:
    """:func:`_detections` of A and B 1 m apart across camera 0's line of sight."""
    away = -RIG[0].center[:2] / np.linalg.norm(RIG[0].center[:2])
    side = np.array([-away[1], away[0]])
    return _detections([tuple(-0.5 * side), tuple(0.5 * side)])


def _block(mask: np.ndarray, half: int) -> np.ndarray:
    """(H, W) bool: a square ``2 * half`` pixels wide at the middle of ``mask``."""
    ys, xs = np.nonzero(mask)
    cy, cx = int(np.median(ys)), int(np.median(xs))
    out = np.zeros_like(mask)
    out[cy - half : cy + half, cx - half : cx + half] = True
    return out


def test_what_a_detector_could_not_see_is_unknown_not_background():
    from bodymetry.capture.masks import grown_mask

    detections = _side_by_side()
    # Camera 0's segmenter: A first, whose mask also holds a bit of B (a hand); B
    # found next with A painted over (grown by the margin), which hid more of B
    # than the bit (Demo_MultiPerson, frame 30, cam03).
    first, second = detections[0]
    whole_b = second.mask(0.5)
    bit = _block(whole_b, 3)
    first = Person((first.mask(0.5) | bit).astype(np.float32), first.landmarks)
    painted = grown_mask(first.mask(0.5), 0.04)
    second = Person(np.where(painted, 0, second.probability).astype(np.float32),
                    second.landmarks, painted)  # fmt: skip
    detections[0] = [first, second]
    floor = VisualHull(RIG).floor_box
    people = sightings(RIG, detections, 0.5, floor)
    seen_a, seen_b = sorted(people, key=lambda p: np.count_nonzero(p.masks[0] & whole_b))
    hole = whole_b & ~seen_b.masks[0]
    assert hole.sum() > 4 * bit.sum()  # the margin hid more than the bit
    hidden = seen_b.hidden[0]
    assert hidden is not None and hidden[hole].mean() > 0.9
    assert not (hidden & seen_b.masks[0]).any() and not (hidden & seen_a.masks[0]).any()
    # Not someone hiding them: the view stays in their fit; A, found first, saw it all.
    assert not seen_b.occluded[0] and seen_a.hidden[0] is None
    # A detection that saw the whole image has nothing unknown.
    detections[0] = [first, Person(second.probability, second.landmarks)]
    again = sightings(RIG, detections, 0.5, floor)
    _, plain_b = sorted(again, key=lambda p: np.count_nonzero(p.masks[0] & whole_b))
    assert plain_b.hidden[0] is None


def test_the_nearer_person_s_whole_torso_is_theirs():
    from bodymetry.capture.people import TORSO

    a, b = _behind(RIG[0], 0.05)  # B right behind A as camera 0 sees them
    front, back = _detections([tuple(a), tuple(b)])[0]
    depths = [np.linalg.norm([*a, 1.0] - RIG[0].center), np.linalg.norm([*b, 1.0] - RIG[0].center)]
    got_a, got_b = partition([front, back], 0.5, depths)
    quad = np.zeros_like(got_a, np.uint8)
    cv2.fillPoly(quad, [np.round(front.landmarks[list(TORSO), :2]).astype(np.int32)], 1)
    torso = cv2.erode(quad, np.ones((3, 3), np.uint8)) > 0
    assert torso.sum() > 500
    assert got_a[torso].all() and not got_b[torso].any()


def test_someone_only_two_cameras_tell_apart_is_found_when_the_hull_counts_them():
    # A and B side by side for cameras 2 and 3; cameras 0 and 1 each return one
    # detection holding both (A's skeleton): B is found by two cameras only.
    a, b = _behind(RIG[0], 0.3)
    detections = _detections([tuple(a), tuple(b)])
    only_b = {}
    for c in (0, 1):
        dist = [np.linalg.norm([*at, 1.0] - RIG[c].center) for at in (a, b)]
        near_a = dist[0] < dist[1]
        person_a, person_b = detections[c] if near_a else detections[c][::-1]
        both = person_a.mask(0.5) | person_b.mask(0.5)
        only_b[c] = _person(RIG[c], tuple(b)).mask(0.5) & ~_person(RIG[c], tuple(a)).mask(0.5)
        detections[c] = [Person(both.astype(np.float32), person_a.landmarks)]
    box = VisualHull(RIG).floor_box
    # Three cameras must agree on a person: B is not found.
    assert len(sightings(RIG, detections, 0.5, box)) == 1
    # The background's hull counts two: the two cameras that agree on B make them up.
    people = sightings(RIG, detections, 0.5, box, expected=2)
    assert len(people) == 2
    seen_a, seen_b = sorted(people, key=lambda p: np.linalg.norm(p.position[:2] - a))
    np.testing.assert_allclose(seen_b.position[:2], b, atol=0.05)
    np.testing.assert_allclose(seen_a.position[:2], a, atol=0.05)
    # B's own pixels in the merged detections are B's, not A's.
    for c in (0, 1):
        assert only_b[c].any()
        assert seen_b.masks[c][only_b[c]].mean() > 0.8
        assert seen_a.masks[c][only_b[c]].mean() < 0.2
        # Missed by both cameras in one frame: in each, nobody's pixel is two people's,
        # and what is unknown to a person is not theirs.
        assert not (seen_a.masks[c] & seen_b.masks[c]).any()
        for seen in (seen_a, seen_b):
            hidden = seen.hidden[c] if seen.hidden else None
            assert hidden is None or not (hidden & seen.masks[c]).any()
        assert seen_b.landmarks[c] is None
    # A count higher than the people two cameras agree on adds nobody.
    assert len(sightings(RIG, detections, 0.5, box, expected=3)) == 2


def test_everyone_s_silhouette_is_divided_among_the_people():
    """With an empty-scene clip, the people's pixels are their masks' snapped to
    everyone's fused silhouette: a halo the coarse mask added but the silhouette does
    not hold is nobody's, a block inside a person that their mask missed is unknown
    to them (not background), and a blob far from everyone (a moved chair) is
    nobody's business."""
    detections = _side_by_side()
    # Camera 0's segmenter missed a block of B's body; its mask also spills a halo
    # over the background around B.
    first, second = detections[0]
    whole_b = second.mask(0.5)
    missed = _block(whole_b, 10) & whole_b
    halo = cv2.dilate(whole_b.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    halo &= ~whole_b & ~first.mask(0.5)
    coarse = np.where(missed, 0, np.where(halo, 1, second.probability))
    detections[0] = [first, Person(coarse.astype(np.float32), second.landmarks)]
    foreground = [np.logical_or.reduce([p.mask(0.5) for p in view]) for view in detections]
    foreground[0] = first.mask(0.5) | whole_b
    chair = np.zeros_like(whole_b)
    chair[:20, :20] = True
    foreground[0] |= chair
    floor = VisualHull(RIG).floor_box
    people = sightings(RIG, detections, 0.5, floor, foreground=foreground)
    seen_a, seen_b = sorted(people, key=lambda p: np.count_nonzero(p.masks[0] & whole_b))
    assert not seen_a.masks[0][missed].any()
    assert not seen_b.masks[0][halo].any() and not seen_a.masks[0][halo].any()
    assert not seen_a.masks[0][chair].any() and not seen_b.masks[0][chair].any()
    assert seen_b.masks[0][whole_b & ~missed].mean() > 0.98
    hidden = seen_b.hidden[0]
    assert hidden is not None and (hidden | seen_b.masks[0])[missed].mean() > 0.95
    assert not hidden[halo | chair].any() and not (hidden & seen_b.masks[0]).any()
    assert not seen_b.occluded[0]  # not counted as hidden by someone
    # Without everyone's silhouette the detections' masks are the pixels, as before:
    # the missed block is background, the halo B's.
    (_, plain_b) = sorted(sightings(RIG, detections, 0.5, floor),
                          key=lambda p: np.count_nonzero(p.masks[0] & whole_b))  # fmt: skip
    assert not plain_b.masks[0][missed].any() and plain_b.masks[0][halo].mean() > 0.9


def test_a_limb_whose_middle_joint_is_not_seen_is_drawn_from_end_to_end():
    from bodymetry.capture.people import skeleton_mask
    from bodymetry.capture.person import LANDMARKS

    landmarks = detection(RIG[0], (0.0, 0.0))
    shoulder, elbow, wrist = (LANDMARKS.index(f"left_{j}") for j in ("shoulder", "elbow", "wrist"))
    full = skeleton_mask(landmarks, (SIZE[1], SIZE[0]))
    landmarks[elbow, 2] = 0.0  # the elbow barely seen
    straight = skeleton_mask(landmarks, (SIZE[1], SIZE[0]))
    mid = np.round(0.5 * (landmarks[shoulder, :2] + landmarks[wrist, :2])).astype(int)
    assert straight[mid[1], mid[0]]
    # The rest of the skeleton is as before; nothing else is drawn.
    assert (straight & ~full).sum() < 0.1 * full.sum()
    # An end not seen: the limb is left out, not guessed.
    landmarks[wrist, 2] = 0.0
    assert not skeleton_mask(landmarks, (SIZE[1], SIZE[0]))[mid[1], mid[0]]


def test_a_middle_joint_nobody_confirms_on_a_limb_put_elsewhere_is_not_drawn():
    from bodymetry.capture.people import _mended
    from bodymetry.capture.person import LANDMARKS

    cam = RIG[0]
    true = detection(cam, (0.0, 0.0))
    elbow, wrist = LANDMARKS.index("right_elbow"), LANDMARKS.index("right_wrist")
    projected = true.copy()
    projected[elbow] = np.nan  # the other cameras cannot place the elbow
    # This camera's detection put the forearm on someone beside them.
    seen = true.copy()
    seen[[elbow, wrist], 0] += 0.3 * SIZE[1]
    mended = _mended(seen, projected, cam)
    np.testing.assert_allclose(mended[wrist, :2], true[wrist, :2])
    assert mended[elbow, 2] == 0.0
    # Where the wrist agrees with the other cameras, the unconfirmed elbow stays.
    agreed = true.copy()
    agreed[elbow, 0] += 2.0
    kept = _mended(agreed, projected, cam)
    np.testing.assert_array_equal(kept[elbow], agreed[elbow])


def test_a_person_s_pixels_on_someone_else_s_hull_and_off_their_own_are_unknown_to_them():
    """One detection holding two people, one behind the other (camera 0): the
    partition gives the nearer one the edges of the one behind that lie within
    their core. The other cameras, which see them apart, carve each one's hull;
    A's pixels in camera 0 that lie on B's hull's projection and off A's are
    unknown to A, not A's."""
    from bodymetry.capture.people import within_hulls

    a, b = _behind(RIG[0], 0.25)
    detections = _detections([tuple(a), tuple(b)])
    front, back = detections[0]
    only_b = back.mask(0.5) & ~front.mask(0.5)
    merged = Person((front.mask(0.5) | back.mask(0.5)).astype(np.float32), front.landmarks)
    detections[0] = [merged]  # camera 0 found one person, with A's skeleton
    hull = VisualHull(RIG)
    people = sightings(RIG, detections, 0.5, hull.floor_box)
    people.sort(key=lambda p: np.linalg.norm(p.position[:2] - a))
    seen_a = people[0]
    taken = np.count_nonzero(seen_a.masks[0] & only_b)
    assert taken > 0.05 * np.count_nonzero(only_b)  # the partition's core took B's edge
    cut_a, _ = within_hulls(people, hull)
    assert np.count_nonzero(cut_a.masks[0] & only_b) < 0.5 * taken
    unknown = cut_a.hidden[0]
    assert unknown is not None and not (unknown & cut_a.masks[0]).any()
    assert np.array_equal(unknown | cut_a.masks[0], seen_a.masks[0])
    # A's own pixels stay A's, or (where B hides part of A from another camera, so
    # that A's hull lacks it) unknown to A: never background for A.
    own = front.mask(0.5) & seen_a.masks[0]
    assert (cut_a.masks[0] | unknown)[own].all() and cut_a.masks[0][own].mean() > 0.75
    for c in (1, 2, 3):  # where A stands apart from B, nothing of A is taken
        assert np.count_nonzero(cut_a.masks[c]) > 0.97 * np.count_nonzero(seen_a.masks[c])
    # Where fewer than two other cameras detected someone, nothing carves their hull...
    alone = [replace(p, landmarks=(p.landmarks[0], None, None, None)) for p in people]
    for kept, person in zip(within_hulls(alone, hull), alone, strict=True):
        assert all(np.array_equal(m, n) for m, n in zip(kept.masks, person.masks, strict=True))
    # ... unless everyone's silhouettes bound them in the cameras that did not: B
    # detected by camera 1 alone is carved from it and cameras 2 and 3's silhouettes.
    fewer = [seen_a, replace(people[1], landmarks=(None, people[1].landmarks[1], None, None))]
    (still_a, _) = within_hulls(fewer, hull)
    assert np.array_equal(still_a.masks[0], seen_a.masks[0])
    everyone = [np.logical_or.reduce([m for m in (p.masks[c] for p in people) if m is not None])
                for c in range(len(RIG))]  # fmt: skip
    (bound_a, _) = within_hulls(fewer, hull, everyone)
    assert np.count_nonzero(bound_a.masks[0] & only_b) < 0.5 * taken
