"""Background model and shadow-suppressing subtraction on synthetic images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from video_frames import through_h264

from bodymetry.capture.background import (
    BackgroundModel,
    SubtractionConfig,
    Subtractor,
    horprasert_distortions,
    read_clip,
)
from bodymetry.capture.colour import (
    CHANGE_CHROMA_WEIGHT,
    CHROMA_WEIGHT,
    LUMA,
    video_distance2,
    video_metric,
)
from bodymetry.capture.toy import ToyScene, toy_background, toy_frame, write_video
from bodymetry.errors import InputError

SCENE = ToyScene(size=(160, 120))


def _model(seed: int = 0, frames: int = 15) -> tuple[BackgroundModel, np.ndarray]:
    bg = toy_background(SCENE, seed)
    rng = np.random.default_rng(seed)
    clip = np.stack([toy_frame(SCENE, bg, [], rng, shadows=False)[0] for _ in range(frames)])
    return BackgroundModel.from_frames("cam_00", clip), bg


def _scene_image(bg: np.ndarray, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Background with a darker-same-chroma patch (shadow) and a red patch (object)."""
    rng = np.random.default_rng(seed)
    img = bg.copy()
    shadow = np.zeros(bg.shape[:2], bool)
    shadow[20:60, 10:60] = True
    obj = np.zeros(bg.shape[:2], bool)
    obj[40:100, 90:130] = True
    img[shadow] *= 0.55
    img[obj] = (40, 50, 170)
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).round().astype(np.uint8), shadow, obj


def test_brightness_is_the_log_ratio_to_the_background() -> None:
    # The shadow patch is the background times 0.55 (plus noise): log 0.55 = -0.60.
    model, bg = _model()
    image, shadow, obj = _scene_image(bg)
    person, labelled, dist2, log_alpha = Subtractor(model).labels(
        image, distances=True, brightness=True
    )
    assert log_alpha.shape == dist2.shape == person.shape and log_alpha.dtype == np.float32
    np.testing.assert_allclose(np.median(log_alpha[shadow]), np.log(0.55), atol=0.03)
    np.testing.assert_allclose(np.median(log_alpha[~(shadow | obj)]), 0.0, atol=0.03)
    # The labels are the same with or without the extra outputs.
    plain = Subtractor(model).labels(image)
    assert (plain[0] == person).all() and (plain[1] == labelled).all()
    assert len(Subtractor(model).labels(image, brightness=True)) == 3


def test_model_statistics_are_robust() -> None:
    bg = toy_background(SCENE, 0)
    rng = np.random.default_rng(0)
    frames = np.stack(
        [np.clip(bg + rng.normal(0, 3.0, bg.shape), 0, 255).astype(np.uint8) for _ in range(21)]
    )
    frames[5] = 255  # a flash in one frame does not move the median
    model = BackgroundModel.from_frames("cam_00", frames)
    assert np.abs(model.median - bg).mean() < 1.0
    assert 2.0 < float(np.median(model.sigma)) < 4.0
    assert model.source == "clip" and model.frames == 21 and model.size == (160, 120)


def test_model_rejects_bad_input() -> None:
    with pytest.raises(InputError, match="cam_09"):
        BackgroundModel.from_frames("cam_09", np.zeros((0, 4, 4, 3), np.uint8))
    with pytest.raises(InputError, match="cam_09"):
        BackgroundModel.from_frames("cam_09", np.zeros((3, 4, 4), np.uint8))


def test_read_clip(tmp_path) -> None:
    frames = [np.full((48, 64, 3), 8 * i, np.uint8) for i in range(30)]
    path = write_video(tmp_path / "bg.avi", frames)
    clip = read_clip(path, "cam_00", max_frames=10)
    assert clip.shape == (10, 48, 64, 3)
    with pytest.raises(InputError, match="'cam_02': background clip not found"):
        read_clip(tmp_path / "missing.avi", "cam_02")


def test_shadow_is_suppressed_and_a_coloured_object_kept() -> None:
    model, bg = _model()
    image, shadow, obj = _scene_image(bg)
    person, labelled_shadow = Subtractor(model).labels(image)
    assert person[shadow].mean() < 0.01
    assert labelled_shadow[shadow].mean() > 0.95
    assert person[obj].mean() > 0.99
    assert person[~(shadow | obj)].mean() < 0.005
    # Without suppression the shadow is foreground.
    raw, _ = Subtractor(model, SubtractionConfig(method="none")).labels(image)
    assert raw[shadow].mean() > 0.95 and raw[obj].mean() > 0.99


def test_darker_object_of_another_colour_is_not_shadow() -> None:
    model, bg = _model()
    rng = np.random.default_rng(3)
    img = bg.copy()
    region = np.zeros(bg.shape[:2], bool)
    region[30:90, 40:100] = True
    img[region] = img[region] * 0.55 * np.array([1.25, 0.9, 0.6])  # darker and bluer
    img = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).round().astype(np.uint8)
    person, shadow = Subtractor(model).labels(img)
    assert person[region].mean() > 0.95 and shadow[region].mean() < 0.05


def test_very_dark_is_person_not_shadow() -> None:
    model, bg = _model()
    img = bg.copy()
    img[30:90, 40:100] *= 0.15  # black shoes, dark hair: deeper than any shadow
    person, _ = Subtractor(model).labels(np.clip(img, 0, 255).round().astype(np.uint8))
    assert person[30:90, 40:100].mean() > 0.99


def test_mog2_option() -> None:
    model, bg = _model()
    image, shadow, obj = _scene_image(bg)
    person, _labelled_shadow = Subtractor(model, SubtractionConfig(method="mog2")).labels(image)
    assert person[obj].mean() > 0.95
    assert person[shadow].mean() < 0.2
    assert person[~(shadow | obj)].mean() < 0.02


def test_invariant_to_a_global_gain() -> None:
    """Scaling the scene (background and image) by an exposure change keeps the labels."""
    model, bg = _model()
    image, _shadow, _obj = _scene_image(bg)
    person, _ = Subtractor(model).labels(image)
    k = 0.7
    rng = np.random.default_rng(0)
    clip = np.stack([toy_frame(SCENE, bg * k, [], rng, shadows=False)[0] for _ in range(15)])
    scaled_model = BackgroundModel.from_frames("cam_00", clip)
    scaled = np.clip(image.astype(np.float32) * k, 0, 255).round().astype(np.uint8)
    person_k, _ = Subtractor(scaled_model).labels(scaled)
    assert (person_k != person).mean() < 0.005


def test_invariant_to_flips_and_to_noise_seed() -> None:
    model, bg = _model()
    image, _, _ = _scene_image(bg)
    sub = Subtractor(model)
    person, shadow = sub.labels(image)
    flipped = BackgroundModel(
        "cam_00", model.median[:, ::-1].copy(), model.sigma[:, ::-1].copy(), "clip", model.frames
    )
    p2, s2 = Subtractor(flipped).labels(np.ascontiguousarray(image[:, ::-1]))
    np.testing.assert_array_equal(p2, person[:, ::-1])
    np.testing.assert_array_equal(s2, shadow[:, ::-1])
    other, _, _ = _scene_image(bg, seed=7)
    assert (sub.labels(other)[0] != person).mean() < 0.005


def test_distortions_match_definition() -> None:
    rng = np.random.default_rng(0)
    bg = rng.uniform(30, 220, (8, 9, 3)).astype(np.float32)
    sigma = rng.uniform(1, 4, (8, 9, 3)).astype(np.float32)
    img = np.clip(bg * 0.6 + rng.normal(0, 1, bg.shape), 0, 255).astype(np.float32)
    alpha, cd, _dist = horprasert_distortions(img, bg, sigma)
    a = ((img * bg / sigma**2).sum(2)) / ((bg**2 / sigma**2).sum(2))
    np.testing.assert_allclose(alpha, a, rtol=1e-5)
    np.testing.assert_allclose(cd, np.sqrt((((img - a[..., None] * bg) / sigma) ** 2).sum(2)), 1e-4)
    model = BackgroundModel("c", bg, sigma, "clip", 1)
    sub = Subtractor(model, SubtractionConfig(min_sigma=0.5))
    a2, cd2, d2 = sub._distortions(img.round().astype(np.uint8))
    a3, cd3, d3 = horprasert_distortions(img.round().astype(np.uint8), bg, sub.sigma)
    np.testing.assert_allclose(a2, a3, rtol=1e-4)
    np.testing.assert_allclose(np.sqrt(np.maximum(cd2, 0)), cd3, atol=1e-2)
    np.testing.assert_allclose(np.sqrt(d2), d3, rtol=1e-4)


def test_wrong_image_size_and_bad_config() -> None:
    model, _ = _model()
    with pytest.raises(InputError, match=r"'cam_00'.*80x60"):
        Subtractor(model).labels(np.zeros((60, 80, 3), np.uint8))
    with pytest.raises(InputError, match="method"):
        SubtractionConfig(method="magic")
    with pytest.raises(InputError, match="shadow_alpha_min"):
        SubtractionConfig(shadow_alpha_min=1.5)


def test_video_distance_keeps_luma_and_weighs_chroma_down() -> None:
    # Known answers of the metric: a grey step is all luma, a step along a direction
    # orthogonal to luma is all chroma.
    luma = 5.0 * LUMA
    chroma = np.cross(LUMA, [1.0, 0.0, 0.0])
    chroma *= 5.0 / np.linalg.norm(chroma)
    assert video_distance2(luma) == pytest.approx(25.0, rel=1e-5)
    assert video_distance2(chroma) == pytest.approx(CHROMA_WEIGHT * 25.0, rel=1e-5)
    assert video_distance2(luma + chroma) == pytest.approx((1 + CHROMA_WEIGHT) * 25.0, rel=1e-5)
    weighed = video_metric(0.01)
    assert video_distance2(luma + chroma, weighed) == pytest.approx(25.25, rel=1e-5)
    assert video_distance2(luma + chroma, video_metric(1.0)) == pytest.approx(50.0, rel=1e-5)


@pytest.mark.parametrize("gap", [60, 61])
def test_a_narrow_gap_beside_a_saturated_garment_is_unchanged_in_luma(gap, tmp_path) -> None:
    # A red garment on both sides of a 3-pixel gap of grey wall (a hanging arm beside
    # the trunk), blurred as the studio's optics blur it, through H.264 4:2:0: the
    # garment's chroma fills the gap (its middle pixel is "changed" by the full colour
    # distance at either block phase), its luma does not; the garment stays changed.
    wall, red = (120, 118, 115), (40, 40, 200)
    rng = np.random.default_rng(3)
    empty = [
        np.clip(np.full((64, 128, 3), wall) + rng.normal(0, 1.5, (64, 128, 3)), 0, 255)
        for _ in range(5)
    ]
    clip = [
        through_h264(f.astype(np.uint8), tmp_path / f"wall{k}.mp4") for k, f in enumerate(empty)
    ]
    img = np.full((64, 128, 3), wall, np.float32)
    img[:, :gap] = red
    img[:, gap + 3 :] = red
    img = np.clip(cv2.GaussianBlur(img, (0, 0), 0.7) + 0.5, 0, 255).astype(np.uint8)
    decoded = through_h264(img, tmp_path / "gap.mp4")
    sub = Subtractor(BackgroundModel.from_frames("cam_00", np.stack(clip)))
    _, _, dist2, video = sub.labels(decoded, distances=True, video=True)
    # The same distance as the video metric at the change term's chroma weight gives.
    whitened = (decoded.astype(np.float32) - sub.model.median) / sub.sigma
    expected = video_distance2(whitened, video_metric(CHANGE_CHROMA_WEIGHT))
    np.testing.assert_allclose(video, expected, rtol=1e-4, atol=1e-3)
    threshold = sub.config.fg_sigma**2
    rows = slice(8, 56)  # away from the top and bottom, where the codec's blocks end
    middle = gap + 1
    assert (dist2[rows, middle] > threshold).all()
    assert (video[rows, middle] < threshold).all()
    assert (video[rows, gap - 3] > 7.0 * threshold).all() and (
        video[rows, gap + 6] > 7.0 * threshold
    ).all()
