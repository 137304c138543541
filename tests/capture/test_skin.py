"""Skin told from clothing by the colour of the face and hands (capture/skin.py)."""

import numpy as np
import pytest

from bodymetry.capture.skin import (
    FACE,
    HANDS,
    SkinConfig,
    clothing_masks,
    colour_coords,
    facing,
    hand_skin,
    landmark_discs,
    seed_mask,
    skin_models,
)

H, W = 240, 160
SKIN = (120, 150, 205)  # BGR, a light skin tone
SHIRT = (40, 40, 200)  # saturated red
TROUSERS = (120, 60, 30)  # navy
HAIR = (25, 35, 55)  # dark brown


def _person(rng, skin=SKIN, shirt=SHIRT, gain=(1.0, 1.0, 1.0)):
    """A front-facing figure: head and forearms of skin, a shirt, trousers, hair on top.

    Returns the BGR image (noise sigma 3), the silhouette, the truth of which pixels
    are clothing (shirt, trousers, hair) and BlazePose landmarks (x, y, visibility)."""
    img = np.full((H, W, 3), (90, 90, 90), float)
    person = np.zeros((H, W), bool)
    worn = np.zeros((H, W), bool)

    def paint(y0, y1, x0, x1, colour, cloth):
        img[y0:y1, x0:x1] = colour
        person[y0:y1, x0:x1] = True
        worn[y0:y1, x0:x1] = cloth

    paint(20, 60, 60, 100, skin, False)  # head
    paint(14, 26, 58, 102, HAIR, True)  # hair on top
    paint(60, 130, 50, 110, shirt, True)  # torso
    paint(60, 100, 30, 50, shirt, True)  # sleeves
    paint(60, 100, 110, 130, shirt, True)
    paint(100, 140, 30, 50, skin, False)  # forearms and hands
    paint(100, 140, 110, 130, skin, False)
    paint(130, 230, 55, 105, TROUSERS, True)  # legs
    img = img * np.asarray(gain) + rng.normal(0, 3, img.shape)
    marks = np.full((33, 3), np.nan)
    marks[:, 2] = 0.0
    face = {0: (80, 42), 1: (76, 38), 2: (74, 38), 3: (72, 38), 4: (84, 38), 5: (86, 38),
            6: (88, 38), 7: (64, 40), 8: (96, 40), 9: (76, 50), 10: (84, 50)}  # fmt: skip
    hands = {17: (36, 134), 19: (40, 134), 21: (46, 130),
             18: (124, 134), 20: (120, 134), 22: (114, 130)}  # fmt: skip
    body = {11: (62, 62), 12: (98, 62), 23: (65, 128), 24: (95, 128)}
    for i, (x, y) in {**face, **hands, **body}.items():
        marks[i] = (x, y, 0.99)
    return np.clip(img, 0, 255).astype(np.uint8), person, worn, marks


def _accuracy(found, truth, person):
    return np.mean(found[person] == truth[person])


def test_clothing_is_what_is_not_the_colour_of_face_and_hands():
    rng = np.random.default_rng(0)
    img, person, worn, marks = _person(rng)
    (found,) = clothing_masks([img], [person], [[(marks, True)]])
    assert found is not None and found.dtype == bool
    assert not (found & ~person).any()  # only the silhouette's pixels
    # Within 2 % of the pixels (the 3x3 clean-up trims the parts' corners).
    assert _accuracy(found, worn, person) > 0.98


@pytest.mark.parametrize("shirt", [(40, 40, 200), (200, 200, 200), (30, 160, 30), (20, 20, 20)])
def test_shirts_unlike_skin_in_colour_or_lightness_are_clothing(shirt):
    rng = np.random.default_rng(1)
    img, person, worn, marks = _person(rng, shirt=shirt)
    (found,) = clothing_masks([img], [person], [[(marks, True)]])
    assert _accuracy(found, worn, person) > 0.97


def test_each_camera_centres_the_colour_on_its_own_seeds():
    # A second camera with another white balance (blue +15 %, red -15 %): classified
    # with the first camera's centre, its skin would fall outside.
    rng = np.random.default_rng(2)
    a = _person(rng)
    b = _person(rng, gain=(1.15, 1.0, 0.85))
    found = clothing_masks([a[0], b[0]], [a[1], b[1]], [[(a[3], True)], [(b[3], True)]])
    for (_, person, worn, _), mask in zip((a, b), found, strict=True):
        assert _accuracy(mask, worn, person) > 0.97


def test_a_view_of_the_back_of_the_head_seeds_from_the_hands_only():
    rng = np.random.default_rng(3)
    img, person, worn, marks = _person(rng)
    # Seen from behind, the face landmarks fall on hair.
    img[20:60, 60:100] = HAIR
    worn[20:60, 60:100] = True
    seeds = seed_mask(person.shape, person, [(marks, False)], SkinConfig())
    assert not seeds[14:60, 58:102].any() and seeds.any()
    (found,) = clothing_masks([img], [person], [[(marks, False)]])
    assert _accuracy(found, worn, person) > 0.97
    # Taking the hair for a face, the hair would be skin.
    (fooled,) = clothing_masks([img], [person], [[(marks, True)]])
    assert _accuracy(fooled, worn, person) < _accuracy(found, worn, person)


def test_a_view_without_seeds_of_its_own_borrows_the_frames_colour():
    rng = np.random.default_rng(4)
    a = _person(rng)
    b = _person(rng)
    unseen = b[3].copy()
    unseen[:, 2] = 0.0  # the segmenter saw nothing surely in the second view
    found = clothing_masks([a[0], b[0]], [a[1], b[1]], [[(a[3], True)], [(unseen, True)]])
    assert _accuracy(found[1], b[2], b[1]) > 0.97


def test_seeds_on_something_else_do_not_move_a_views_colour():
    # The second view's few seeds are all trousers (hands held against them): its
    # own median lies far from the frame's skin, so the frame's centre is kept.
    rng = np.random.default_rng(5)
    a, b = _person(rng), _person(rng)
    lab_a, lab_b = colour_coords(a[0], 0.15), colour_coords(b[0], 0.15)
    config = SkinConfig()
    own_a = lab_a[seed_mask((H, W), a[1], [(a[3], True)], config)]
    trousers = lab_b[150:170, 60:75].reshape(-1, 3)  # 300 seeds against 1,092
    models = skin_models([own_a, trousers], config)
    skin = np.median(own_a, axis=0)
    assert np.allclose(models[0].mean, skin, atol=1.0)
    assert np.allclose(models[1].mean, skin, atol=1.0)  # the median of all seeds
    assert models[1].distance(np.median(trousers, axis=0)) > SkinConfig().max_distance


def test_too_few_seeds_anywhere_tell_nothing():
    rng = np.random.default_rng(6)
    img, person, _, marks = _person(rng)
    marks[:, 2] = 0.0
    assert clothing_masks([img], [person], [[(marks, True)]]) == [None]
    assert clothing_masks([img], [person], [[]]) == [None]
    assert clothing_masks([None], [person], [[(marks, True)]]) == [None]
    assert clothing_masks([img], [person], [[(marks, True)]], SkinConfig(enabled=False)) == [None]


def test_the_classification_does_not_depend_on_the_order_of_views():
    rng = np.random.default_rng(7)
    a, b = _person(rng), _person(rng, gain=(1.1, 1.0, 0.9))
    views = [a, b]
    one = clothing_masks(
        [v[0] for v in views], [v[1] for v in views], [[(v[3], True)] for v in views]
    )
    two = clothing_masks(
        [v[0] for v in views[::-1]],
        [v[1] for v in views[::-1]],
        [[(v[3], True)] for v in views[::-1]],
    )
    for x, y in zip(one, two[::-1], strict=True):
        assert np.array_equal(x, y)


def test_facing_tells_the_face_from_the_back_of_the_head():
    marks = np.full((33, 3), np.nan)
    marks[0] = (0.0, 0.1, 1.7)  # nose in front (+y) of the ears
    marks[7], marks[8] = (-0.07, 0.0, 1.7), (0.07, 0.0, 1.7)
    assert facing(marks, np.array([0.0, 3.0, 1.5]))
    assert not facing(marks, np.array([0.0, -3.0, 1.5]))
    marks[0] = np.nan
    assert not facing(marks, np.array([0.0, 3.0, 1.5]))


def test_bad_input_is_named():
    rng = np.random.default_rng(8)
    img, person, _, marks = _person(rng)
    with pytest.raises(ValueError, match="differ in size"):
        clothing_masks([img[:-1]], [person], [[(marks, True)]])
    with pytest.raises(ValueError, match="one of each per view"):
        clothing_masks([img, img], [person], [[(marks, True)]])
    with pytest.raises(ValueError, match="max_distance"):
        SkinConfig(max_distance=0)
    with pytest.raises(ValueError, match="trim"):
        SkinConfig(trim=0)


def test_landmark_sets_name_the_face_and_hands():
    assert len(FACE) == 11 and len(HANDS) == 6 and not set(FACE) & set(HANDS)


def test_two_views_that_disagree_wholly_still_give_a_colour():
    # Neither view's seeds lie near the median of all: the frame's colour is that median.
    config = SkinConfig()
    rng = np.random.default_rng(9)
    one = rng.normal((60, 10, 20), 0.3, (100, 3))
    two = rng.normal((10, -30, -40), 0.3, (100, 3))
    models = skin_models([one, two], config)
    assert all(m is not None for m in models)
    assert np.allclose(models[0].mean, models[1].mean)


def test_capture_learns_from_every_persons_landmarks_and_classifies_their_pixels():
    from bodymetry.capture.people import Sighting
    from bodymetry.capture.segmentation import CaptureConfig, frame_clothing

    rng = np.random.default_rng(10)
    img, person, worn, marks = _person(rng)
    # The frame's silhouette holds the upper body only; a sighting holds the legs
    # (told apart by the segmenter) and the landmarks.
    upper = person.copy()
    upper[130:] = False
    legs = person & ~upper
    seen = Sighting(np.zeros(3), (legs,), (marks,), (False,))
    (found,) = frame_clothing([img], [upper], None, [None], [seen], None, CaptureConfig())
    assert _accuracy(found, worn, person) > 0.97
    assert found[150:200, 60:100].all()  # the sighting's trousers
    # Without any landmarks, nothing is told.
    assert frame_clothing([img], [upper], None, [None], [], None, CaptureConfig()) == (None,)


def test_landmark_discs_follow_the_torso_length():
    """The discs' radius is a share of the torso length: the same figure drawn twice
    as large covers four times the pixels, and without a hip nothing is drawn."""
    _, _, _, marks = _person(np.random.default_rng(7))
    small = landmark_discs((H, W), marks, HANDS, 0.1)
    big = marks.copy()
    big[:, :2] *= 2
    large = landmark_discs((2 * H, 2 * W), big, HANDS, 0.1)
    assert small.any() and abs(large.sum() / small.sum() - 4.0) < 0.4
    no_hip = marks.copy()
    no_hip[23] = np.nan
    assert not landmark_discs((H, W), no_hip, HANDS, 0.1).any()
    unseen = marks.copy()
    unseen[list(HANDS), 2] = 0.2
    assert not landmark_discs((H, W), unseen, HANDS, 0.1).any()


def test_hand_skin_is_skin_coloured_and_near_the_hands():
    """:func:`hand_skin` marks the forearms' skin by the hands, not the face's (far from
    them), nor grey floor or navy trousers painted by a hand."""
    rng = np.random.default_rng(8)
    img, _, _, marks = _person(rng)
    img[140:150, 30:50] = (90, 90, 90)  # grey floor below the left hand
    img[120:140, 130:140] = TROUSERS  # navy beside the right hand
    near = hand_skin(img, marks)
    assert near[124:140, 32:48].mean() > 0.95  # the left hand's skin
    assert near[124:140, 112:128].mean() > 0.95  # the right hand's
    assert not near[20:60, 60:100].any()  # the face is skin, but far from the hands
    assert not near[140:150, 30:50].any()
    assert not near[120:140, 131:140].any()
    assert not hand_skin(img, np.full((33, 3), np.nan)).any()  # nobody's landmarks
