"""Evidence fusion (capture/fusion.py): the terms, their sum and the view agreement."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.capture.background import BackgroundModel
from bodymetry.capture.fusion import (
    CHANGE_CLIP,
    FEATURES,
    LOGIT_CLIP,
    RIM_PX,
    STRONG_CHANGE,
    WEIGHTS,
    FusionConfig,
    FusionWeights,
    GeometryTerms,
    change_evidence,
    confirmed_change,
    fuse,
    mask_iou,
    outline_contrast,
    segmenter_evidence,
    sources_key,
    view_agreement,
    view_features,
)
from bodymetry.capture.person import LANDMARKS, Person
from bodymetry.capture.segmentation import CaptureConfig, FrameSegmenter
from bodymetry.errors import InputError
from bodymetry.estimation.studio_accuracy import LOW_CONTRAST
from bodymetry.studio.rig import studio_rig


def test_change_term_is_zero_at_the_threshold_monotone_and_clipped():
    fg = 6.0
    d = np.array([[0.0, 3.0, 6.0, 12.0, 1e4]], np.float32)
    c = change_evidence(d**2, fg)
    assert c[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert c[0, 3] == pytest.approx(np.log(2.0), abs=1e-5)
    assert np.all(np.diff(c[0]) >= 0)
    assert c.min() == -CHANGE_CLIP and c.max() == CHANGE_CLIP


def test_segmenter_term_is_an_odd_clipped_logit():
    p = np.array([[0.0, 0.1, 0.5, 0.9, 1.0]], np.float32)
    s = segmenter_evidence(p)
    assert s[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert s[0, 1] == pytest.approx(-s[0, 3], abs=1e-5)
    assert s[0, 3] == pytest.approx(np.log(9.0), abs=1e-5)
    assert s[0, 0] == -LOGIT_CLIP and s[0, 4] == LOGIT_CLIP


def test_features_stack_the_present_sources_and_name_them():
    rng = np.random.default_rng(0)
    shape = (6, 5)
    change = rng.normal(size=shape).astype(np.float32)
    shadow = rng.random(shape) < 0.3
    body = rng.random(shape) < 0.5
    anywhere = body | (rng.random(shape) < 0.3)
    floor = shadow & (rng.random(shape) < 0.5)
    feats, key = view_features(shape, change, shadow, None, GeometryTerms(body, anywhere, floor))
    assert key == "background+hull" and feats.shape == (*shape, len(FEATURES))
    np.testing.assert_array_equal(feats[..., FEATURES.index("change")], change)
    np.testing.assert_array_equal(feats[..., FEATURES.index("floor_shadow")], floor)
    np.testing.assert_array_equal(feats[..., FEATURES.index("hull_body")], body)
    assert not feats[..., FEATURES.index("segmenter")].any()
    _, key = view_features(shape, segmenter=change)
    assert key == "segmenter"
    _, key = view_features(shape, segmenter=change, geometry=GeometryTerms(body, anywhere))
    assert key == "segmenter+hull"
    with pytest.raises(InputError, match="pairs"):
        view_features(shape, change=change)
    with pytest.raises(InputError, match="expected"):
        view_features(shape, segmenter=change[:3])


def test_fuse_is_the_weighted_sum_plus_bias():
    rng = np.random.default_rng(1)
    feats = rng.normal(size=(4, 3, len(FEATURES))).astype(np.float32)
    w = FusionWeights(-0.5, tuple(float(v) for v in rng.normal(size=len(FEATURES))))
    expected = feats @ np.asarray(w.weights, np.float32) - 0.5
    np.testing.assert_allclose(fuse(feats, w), expected, rtol=1e-6, atol=1e-6)
    with pytest.raises(InputError, match="expected 6"):
        FusionWeights(0.0, (1.0, 2.0))


def test_every_combination_of_sources_has_weights():
    # Fusion runs where a camera has a background clip; without one the segmenter's
    # mask is the silhouette.
    config = FusionConfig()
    for segmenter in (True, False):
        for hull in (True, False):
            config.weights_for(sources_key(True, segmenter, hull))
    with pytest.raises(InputError, match="no weights"):
        config.weights_for(sources_key(False, True, True))


def test_weights_trust_the_hull_over_the_shadow_label():
    # An achromatic garment's shaded side: labelled shadow, twice the change
    # threshold, inside the hull's projection, but the other views see its floor
    # point lit; a floor shadow beside the feet: the same, but confirmed on the floor.
    w = WEIGHTS["background+hull"]
    shape = (1, 2)
    change = np.full(shape, 0.7, np.float32)
    shadow = np.ones(shape, bool)
    inside = np.ones(shape, bool)
    floor = np.array([[False, True]])
    feats, _ = view_features(shape, change, shadow, None, GeometryTerms(inside, inside, floor))
    garment, cast = fuse(feats, w)[0]
    assert garment > 0 > cast


def test_agreement_is_the_better_of_hull_confirmation_and_segmenter_iou():
    a = np.zeros((10, 10), bool)
    a[2:8, 2:8] = True
    shifted = np.roll(a, 3, axis=1)
    fat = np.zeros_like(a)
    fat[1:9, 1:9] = True  # the other views' hull: larger than the body
    assert mask_iou(a, a) == 1.0 and mask_iou(a, np.zeros_like(a)) == 0.0
    scores = view_agreement(
        [a, a, a, np.zeros_like(a), shifted],
        [fat, None, None, a, fat],
        [shifted, shifted, None, a, None],
    )
    assert scores[0] == 1.0  # inside the hull: confirmed, whatever the segmenter says
    assert scores[1] == pytest.approx(mask_iou(a, shifted))
    assert scores[2] is None and scores[3] is None
    assert scores[4] == pytest.approx(np.count_nonzero(shifted & fat) / shifted.sum())


def test_confirmed_change_gives_back_thin_parts_and_strong_changes_only():
    # One row per case: (fused, subtracted, change, hull, thin) -> kept.
    cases = [
        (True, False, -2.0, False, False, True),  # the fusion's own answer stays
        (False, True, 0.3, True, True, True),  # a finger: weak change, thin, confirmed
        (False, True, 0.3, True, False, False),  # the same change on the trunk's edge
        (False, True, STRONG_CHANGE, True, False, True),  # a shoe: strong change
        (False, True, 0.3, False, True, False),  # no other view confirms it
        (False, False, 0.3, True, True, False),  # subtraction said shadow
        (False, True, -0.5, True, True, False),  # below the change threshold
    ]
    fused, subtracted, change, hull, thin, kept = (
        np.array([c[k] for c in cases])[None] for k in range(6)
    )
    out = confirmed_change(fused, subtracted, change.astype(np.float32), hull, thin)
    np.testing.assert_array_equal(out, kept)


def test_thin_parts_are_confirmed_within_the_hulls_reach_strong_changes_not():
    # Outside the hull's own footprint but within its reach (a finger thinner than a
    # voxel): a thin change is confirmed, a strong change on a thick part is not.
    cases = [
        (False, True, 0.3, True, True),  # thin, within reach: person
        (False, True, STRONG_CHANGE, False, False),  # strong but not thin: needs the hull
        (False, True, 0.3, True, True),
    ]
    fused, subtracted, change, thin, kept = (
        np.array([c[k] for c in cases])[None] for k in range(5)
    )
    hull = np.zeros_like(fused)
    reach = np.array([[True, True, False]])
    out = confirmed_change(fused, subtracted, change.astype(np.float32), hull, thin, reach)
    np.testing.assert_array_equal(out, kept & reach)
    # Without a reach, the hull's footprint decides (nothing here).
    assert not confirmed_change(fused, subtracted, change.astype(np.float32), hull, thin).any()


def test_outline_contrast_reads_the_rims_lower_quartile_median_over_views():
    mask = np.zeros((60, 60), bool)
    mask[20:40, 20:40] = True
    inner = np.zeros_like(mask)
    inner[20 + RIM_PX : 40 - RIM_PX, 20 + RIM_PX : 40 - RIM_PX] = True
    rim = mask & ~inner

    def change(on_rim: float) -> np.ndarray:
        c = np.full(mask.shape, -CHANGE_CLIP, np.float32)  # outside: unchanged
        c[inner] = 0.3  # deeper inside: not read
        c[rim] = on_rim
        return c

    assert outline_contrast([mask], [change(1.7)]) == pytest.approx(1.7)
    # What lies outside the silhouette or deeper in it does not count.
    other = change(1.7)
    other[~mask] = CHANGE_CLIP
    other[inner] = -1.0
    assert outline_contrast([mask], [other]) == pytest.approx(1.7)
    # The median over the views; a view without a background or a silhouette is skipped.
    empty = np.zeros_like(mask)
    views = [mask, mask, mask, empty, mask]
    changes = [change(1.0), change(2.0), change(1.5), change(0.0), None]
    assert outline_contrast(views, changes) == pytest.approx(1.5)
    assert outline_contrast([mask], [None]) is None
    assert outline_contrast([empty], [change(1.0)]) is None
    # The change three quarters of the rim reach: a lit side alone is not enough.
    lit = change(CHANGE_CLIP)
    ys, xs = np.nonzero(rim)
    left = xs < 30
    assert 0.3 < left.mean() < 0.7  # about half the rim
    lit[ys[left], xs[left]] = 0.0
    assert outline_contrast([mask], [lit]) == pytest.approx(0.0)
    few = change(CHANGE_CLIP)
    few[ys[:5], xs[:5]] = 0.0  # a few weak pixels do not matter
    assert outline_contrast([mask], [few]) == pytest.approx(CHANGE_CLIP)


def test_outline_contrast_leaves_out_the_rim_beside_someone_else():
    """A person's rim that borders someone else (or someone nearer who hides them)
    says nothing of the empty scene: it is left out, the rest decides."""
    mask = np.zeros((60, 60), bool)
    mask[20:40, 20:40] = True
    change = np.full(mask.shape, -CHANGE_CLIP, np.float32)
    change[mask] = 1.8
    change[20:40, 20:26] = -1.0  # their left side, where the other person stands
    other = np.zeros_like(mask)
    other[20:40, 10:20] = True
    assert outline_contrast([mask], [change]) == pytest.approx(-1.0)
    assert outline_contrast([mask], [change], [other]) == pytest.approx(1.8)
    assert outline_contrast([mask], [change], [None]) == pytest.approx(-1.0)
    # Beside others all round: nothing is read.
    assert outline_contrast([mask], [change], [np.ones_like(mask)]) is None


def test_config_validation():
    with pytest.raises(InputError, match="floor_band"):
        FusionConfig(floor_band=-0.1)
    with pytest.raises(InputError, match="min_agreement"):
        FusionConfig(min_agreement=1.0)


# --- the fusion inside the capture stage: a grey subject in a grey room ---------------

SIZE = (320, 240)


@pytest.fixture(scope="module")
def grey_room():
    """A 4-camera rig, a plain grey room with sensor noise, an upright grey cylinder
    (the subject) whose left half in every view is shaded like a cast shadow (darker,
    same chromaticity), and its cast shadow on the floor beside it."""
    rig = studio_rig(4, SIZE, seed=3)
    rng = np.random.default_rng(7)
    w, h = SIZE
    empty = np.full((h, w, 3), 120.0)
    models = [
        BackgroundModel.from_frames(
            cam.name, np.clip(empty + rng.normal(0, 2, (8, h, w, 3)), 0, 255).astype(np.uint8)
        )
        for cam in rig
    ]
    shadow_quad = np.array([[0.2, -0.2, 0.0], [1.0, -0.2, 0.0], [1.0, 0.2, 0.0], [0.2, 0.2, 0.0]])
    images, truth, shaded, cast = [], [], [], []
    for cam in rig:
        person = _cylinder(cam)
        floor = _quad(cam, shadow_quad) & ~person
        cols = np.nonzero(person)[1]
        left = person & (np.arange(w)[None, :] < np.median(cols))
        img = empty.copy()
        img[floor] *= 0.6
        img[person] *= 1.5  # the lit side: brighter than the highlight band
        img[left] = empty[left] * 0.7  # the shaded side: a shadow to the colour test
        img += rng.normal(0, 2, img.shape)
        images.append(np.clip(img, 0, 255).astype(np.uint8))
        truth.append(person)
        shaded.append(left)
        cast.append(floor)
    return rig, models, images, truth, shaded, cast


def test_a_second_person_in_the_capture_volume_is_counted(grey_room):
    # Beside the subject: a second, slimmer person 1.2 m away and a low box (a stool,
    # 0.45 m): two people in the volume, the stool is not one.
    rig, models, _, truth, *_ = grey_room
    rng = np.random.default_rng(11)
    images, second = [], []
    for cam, subject in zip(rig, truth, strict=True):
        other = _cylinder(cam, radius=0.15, center=(-0.9, 0.8))
        stool = _cylinder(cam, radius=0.2, height=0.45, center=(0.9, -0.8))
        img = np.full((*subject.shape, 3), 120.0)
        img[stool] = (60, 160, 60)
        img[other] = (40, 60, 200)
        img[subject] = (200, 90, 40)
        img += rng.normal(0, 2, img.shape)
        images.append(np.clip(img, 0, 255).astype(np.uint8))
        second.append(other & ~subject)
    config = CaptureConfig(method="background", fusion=FusionConfig(enabled=True))
    frame = FrameSegmenter(models, rig.sizes, config, None, None, rig)
    try:
        views, _, _, persons, _, contrast = frame(images)
        assert persons == 2
        assert contrast > LOW_CONTRAST  # saturated colours stand out all round
        # The silhouettes stay the largest body's: the second person is removed in
        # every view where the two are apart in the image (where they overlap, the
        # image cannot part them: issue 29).
        apart = 0
        for view, subject, other in zip(views, truth, second, strict=True):
            near = cv2.dilate(other.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
            if (near & subject).any():
                continue
            apart += 1
            assert mask_iou(view.mask, subject) > 0.9
            assert view.mask[other].mean() < 0.05
        assert apart >= 2
        # Alone in the room, the subject is one person.
        alone = [np.where(t[..., None], im, 120).astype(np.uint8)
                 for im, t in zip(images, truth, strict=True)]  # fmt: skip
        assert frame(alone).persons == 1
    finally:
        frame.close()


def _cylinder(camera, radius=0.2, height=1.7, center=(0.0, 0.0)) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.column_stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)])
    pts = np.vstack([np.column_stack([ring, np.full(len(a), z)]) for z in (0.0, height)])
    return _hull_mask(camera, pts)


def _quad(camera, corners) -> np.ndarray:
    return _hull_mask(camera, corners)


def _hull_mask(camera, points) -> np.ndarray:
    px = camera.project(points).astype(np.float32)
    mask = np.zeros((camera.size[1], camera.size[0]), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(px).astype(np.int32), 1)
    return mask.astype(bool)


def _segment(grey_room, enabled: bool):
    rig, models, images, *_ = grey_room
    config = CaptureConfig(method="background", fusion=FusionConfig(enabled=enabled))
    frame = FrameSegmenter(models, rig.sizes, config, None, None, rig)
    try:
        return frame(images)
    finally:
        frame.close()


def test_the_fusion_keeps_a_shaded_grey_side_and_drops_the_cast_shadow(grey_room):
    _, _, _, truth, shaded, cast = grey_room
    views, _, agreement, persons, *_ = _segment(grey_room, enabled=True)
    for view, true, dark, floor in zip(views, truth, shaded, cast, strict=True):
        assert mask_iou(view.mask, true) > 0.9
        assert view.mask[dark].mean() > 0.8  # the shaded side is person
        assert view.mask[floor].mean() < 0.05  # the cast shadow is not
        assert "unreliable" not in view.flags
    assert all(a is not None and a > 0.9 for a in agreement)
    assert persons == 1  # the subject; its cast shadow is no second body
    # Without the fusion the colour test takes the shaded side for a shadow.
    views, *_ = _segment(grey_room, enabled=False)
    assert np.mean([v.mask[d].mean() for v, d in zip(views, shaded, strict=True)]) < 0.3


def test_a_view_that_disagrees_with_the_others_is_unreliable(grey_room):
    rig, models, images, truth, *_ = grey_room
    # Camera 2 sees something attached to the subject that no other view has (a coat
    # on a stand right behind the person, a reflection): as wide as the subject.
    img = images[2].copy()
    ys, xs = np.nonzero(truth[2])
    width = xs.max() - xs.min()
    rows = slice((ys.min() + ys.max()) // 2, ys.max())
    img[rows, xs.max() - 2 : xs.max() + width] = 230
    frame = FrameSegmenter(
        models, rig.sizes, CaptureConfig(method="background", consistency=True), None, None, rig
    )
    views, _, agreement, *_ = frame([*images[:2], img, images[3]])
    assert "unreliable" in views[2].flags, agreement
    assert all("unreliable" not in v.flags for k, v in enumerate(views) if k != 2), (
        agreement,
        [v.flags for v in views],
    )


class _LostShinSegmenter:
    """A segmenter that, in the whole image of one camera, loses a shin in trousers of
    the floor's colour and the shoe below it, and finds them in a box (the person
    seen larger); every other camera's person it finds whole."""

    def __init__(self, whole, lossy, feet):
        self.whole = whole  # image id -> (H, W) bool
        self.lossy = lossy
        self.feet = feet  # image id -> (x, y): where its skeleton puts the feet
        self.asked = []

    def detect(self, image, roi=None):
        self.asked.append((id(image), roi))
        mask = self.whole[id(image)] if roi is not None else self.lossy.get(id(image))
        if mask is None:
            mask = self.whole[id(image)]
        landmarks = np.full((33, 3), np.nan)
        for name in ("left_ankle", "right_ankle", "left_heel", "right_heel"):
            landmarks[LANDMARKS.index(name)] = (*self.feet[id(image)], 0.9)
        return Person(mask.astype(np.float32), landmarks)

    def close(self):
        pass


def _slab(camera, z0, z1, radius=0.2) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    return _hull_mask(
        camera, np.vstack([np.column_stack([ring, np.full(len(a), z)]) for z in (z0, z1)])
    )


def test_a_part_the_segmenter_lost_is_kept_and_asked_for_again(grey_room):
    """Look 334 of the capture benchmark: camera 0's segmenter loses the near shin
    (trousers of the floor's grey) and the shoe; the shoe, a strong change the hull
    confirms, is kept although the segmenter's person does not touch it, and the view
    is asked again in the hull's box, where the shin is found."""
    rig, models, *_ = grey_room
    rng = np.random.default_rng(5)
    images, whole, lossy, feet, shins, shoes = [], {}, {}, {}, [], []
    for c, cam in enumerate(rig):
        body = _slab(cam, 0.35, 1.7)
        shin = _slab(cam, 0.1, 0.35) & ~body
        shoe = _slab(cam, 0.0, 0.1, radius=0.22) & ~body & ~shin
        img = np.full((*body.shape, 3), 120.0)
        img[body] = (200, 90, 40)
        img[shoe] = (30, 30, 30)  # darker than any shadow: a change, not a shadow
        img += rng.normal(0, 2, img.shape)
        image = np.clip(img, 0, 255).astype(np.uint8)
        images.append(image)
        whole[id(image)] = body | shin | shoe
        ys, xs = np.nonzero(shin)
        feet[id(image)] = (xs.mean(), ys.max())  # the ankle: the shin's lowest point
        if c == 0:
            lossy[id(image)] = body
        shins.append(shin)
        shoes.append(shoe)
    config = CaptureConfig(method="background", fusion=FusionConfig(enabled=True))
    frame = FrameSegmenter(models, rig.sizes, config, None, None, rig)
    frame.segmenter = _LostShinSegmenter(whole, lossy, feet)
    try:
        views = frame(images)[0]
        asked_again = [roi for image, roi in frame.segmenter.asked if image == id(images[0])]
        assert asked_again[0] is None and asked_again[-1] is not None
        assert all(roi is None for image, roi in frame.segmenter.asked if image != id(images[0]))
        for view, shin, shoe in zip(views, shins, shoes, strict=True):
            assert view.mask[shoe].mean() > 0.9
            assert view.mask[shin].mean() > 0.9
        # Where the segmenter misses the shin in the box too, the shoe still stays.
        frame.segmenter = _LostShinSegmenter({**whole, **lossy}, lossy, feet)
        view = frame(images)[0][0]
        assert view.mask[shoes[0]].mean() > 0.9 and view.mask[shins[0]].mean() < 0.2
        # Where its skeleton puts no foot near the piece (a hard cast shadow beside the
        # feet, which the hull's projection also covers), the piece stays out.
        away = {k: (x + 80.0, y - 60.0) for k, (x, y) in feet.items()}
        frame.segmenter = _LostShinSegmenter(whole, lossy, away)
        view = frame(images)[0][0]
        assert view.mask[shoes[0]].mean() < 0.1
    finally:
        frame.close()
