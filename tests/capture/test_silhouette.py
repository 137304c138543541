"""Silhouette clean-up, flags and the capture stage end to end.

Scoring against ground truth (and `bodymetry silhouettes`) is tested in
tests/studio/test_evaluate.py and tests/bodymetry/test_cli.py.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from bodymetry.capture.background import SubtractionConfig
from bodymetry.capture.session import Session, load_session
from bodymetry.capture.silhouette import (
    CleanupConfig,
    SilhouetteFrame,
    background_models,
    clean_mask,
    overlay,
    refine_edges,
    segment_session,
)
from bodymetry.capture.toy import ToyScene, toy_background, toy_frame, write_toy_session
from bodymetry.errors import InputError

H, W = 240, 320


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks (capture does not import the studio's)."""
    return float(np.count_nonzero(a & b) / np.count_nonzero(a | b))


def _iou_vs_truth(session: Session, camera: str, frame: int, mask: np.ndarray) -> float:
    truth = cv2.imread(
        str(session.ground_truth_silhouette_path(camera, frame)), cv2.IMREAD_GRAYSCALE
    )
    return iou(mask, truth > 0)


def _person(cx: int, cy: int = 120, ax: int = 18, ay: int = 70) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    cv2.ellipse(m, (cx, cy), (ax, ay), 0, 0, 360, 1, -1)
    return m > 0


def test_empty_frame_is_flagged() -> None:
    mask, flags = clean_mask(np.zeros((H, W), bool))
    assert flags == ("empty",) and not mask.any()
    noise = np.random.default_rng(0).random((H, W)) > 0.995  # speckle only
    mask, flags = clean_mask(noise)
    assert flags == ("empty",) and not mask.any()


def test_a_change_over_most_of_the_image_is_not_a_person() -> None:
    """A black or covered lens, a light switched off: the whole view changed."""
    mask, flags = clean_mask(np.ones((H, W), bool))
    assert flags == ("scene_change",) and not mask.any()
    big = np.zeros((H, W), bool)
    big[:, : int(W * 0.55)] = True  # just under the default 0.6 of the image
    mask, flags = clean_mask(big)
    assert "scene_change" not in flags and mask.sum() == big.sum()


def test_person_kept_noise_removed_part_joined() -> None:
    raw = _person(160)
    raw[10:12, 10:12] = True  # speckle far away
    raw[195:205, 150:158] = True  # a foot cut off by a seam, just below the body
    raw[120, 160] = False  # a pinhole
    mask, flags = clean_mask(raw)
    assert flags == ()
    assert not mask[10:12, 10:12].any()
    assert mask[195:205, 150:158].all()
    assert mask[120, 160]
    assert iou(mask, raw & ~_speck()) > 0.97


def _speck() -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[10:12, 10:12] = True
    return m


def test_two_people_sized_blobs_are_flagged_and_the_larger_kept() -> None:
    a, b = _person(80, ax=20), _person(250, ax=16)
    mask, flags = clean_mask(a | b)
    assert "multiple" in flags
    assert iou(mask, a) > 0.97 and not (mask & b).any()


def test_person_touching_the_border_is_flagged() -> None:
    raw = _person(160, cy=60)  # head cut off by the top edge
    mask, flags = clean_mask(raw)
    assert flags == ("border",) and mask[0].any()


def test_holes_filled_only_when_they_changed() -> None:
    raw = _person(160, ax=40, ay=90)
    hole = np.zeros((H, W), bool)
    hole[100:110, 150:160] = True  # clothing labelled shadow
    gap = np.zeros((H, W), bool)
    gap[140:150, 170:180] = True  # background seen between arm and torso
    raw &= ~(hole | gap)
    mask, _ = clean_mask(raw, CleanupConfig(open_radius=0), shadow=hole)
    assert mask[hole].all()
    assert mask[gap].mean() < 0.1  # (the closing rounds the gap's corners)
    # Without shadow information every small hole is filled.
    mask, _ = clean_mask(raw, CleanupConfig(open_radius=0))
    assert mask[hole].all() and mask[gap].all()


def test_clean_mask_is_translation_equivariant() -> None:
    raw = _person(140) | _person(140, cy=205, ax=6, ay=4)
    mask, _ = clean_mask(raw)
    shifted, _ = clean_mask(np.roll(raw, (7, 11), (0, 1)))
    np.testing.assert_array_equal(shifted, np.roll(mask, (7, 11), (0, 1)))


def test_bad_mask_shape() -> None:
    with pytest.raises(InputError, match="mask"):
        clean_mask(np.zeros((4, 4, 3), bool))


def test_overlay_shapes() -> None:
    img = np.zeros((H, W, 3), np.uint8)
    out = overlay(img, _person(160), _person(200), ("border",))
    assert out.shape == img.shape and out.dtype == np.uint8 and out.any()
    assert overlay(None, np.zeros((H, W), bool)).shape == (H, W, 3)


def test_stack_refuses_cameras_of_different_sizes() -> None:
    """Rigs that mix camera models keep one mask per camera; stack() names the sizes."""
    masks = (np.zeros((120, 160), bool), np.zeros((128, 160), bool))
    sf = SilhouetteFrame(4, ("cam_a", "cam_b"), masks, ((), ()))
    with pytest.raises(ValueError, match=r"frame 4: .*cam_a 160x120, cam_b 160x128"):
        sf.stack()
    assert [m.shape for m in sf.masks] == [(120, 160), (128, 160)]
    same = SilhouetteFrame(4, ("cam_a", "cam_b"), (masks[0], masks[0]), ((), ()))
    assert same.stack().shape == (2, 120, 160)


# --- the stage on toy sessions ---------------------------------------------------------------
@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("toy") / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=10, empty_frames=(20,), seed=1)
    return folder


def test_stage_matches_ground_truth_and_flags_empty_frame(toy: Path) -> None:
    session = load_session(toy)
    frames = list(segment_session(session))
    assert [sf.frame for sf in frames] == [0, 10, 20, 30]
    for sf in frames:
        assert sf.stack().shape == (2, 120, 160)
        if sf.frame == 20:
            assert sf.flags == (("empty",), ("empty",))
            assert not sf.stack().any()
        else:
            assert sf.flags == ((), ())
            for cam, mask in zip(sf.cameras, sf.masks, strict=True):
                # MJPG at 160x120 smears the edges.
                assert _iou_vs_truth(session, cam, sf.frame, mask) > 0.85


def test_cast_shadow_is_not_person(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=1, frames=20, frame_step=10, seed=2)
    session = load_session(folder)
    # The toy shadow of frame 10 (same geometry as the written frame).
    scene = ToyScene()
    cx = (0.25 + 0.5 * (10 / 19)) * scene.size[0]
    _, person, shadow = toy_frame(
        scene, toy_background(scene, 200), [(cx, 0.5 * scene.size[1])], np.random.default_rng(0)
    )
    sf = next(segment_session(session, frames=[10]))
    assert shadow.sum() > 100
    assert (sf.masks[0] & shadow).sum() / shadow.sum() < 0.2
    # Away from the feet (where person and shadow blur together) none of it is person.
    near = cv2.dilate(person.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    far = sf.masks[0] & shadow & ~near
    assert far.sum() / shadow.sum() < 0.03
    none = next(segment_session(session, frames=[10], subtraction=_cfg("none")))
    assert (none.masks[0] & shadow).sum() / shadow.sum() > 0.5


def _cfg(method: str):
    return SubtractionConfig(method=method)


def test_second_person_is_flagged(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=1, frames=20, frame_step=10, second_person=True, seed=3)
    for sf in segment_session(load_session(folder)):
        assert "multiple" in sf.flags[0]


def test_without_background_clip_the_session_median_is_used(tmp_path: Path, caplog) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=60, frame_step=5, backgrounds=False, seed=4)
    session = load_session(folder)
    assert session.background_path("cam_00") is None
    with caplog.at_level(logging.WARNING):
        models = background_models(session)
    assert [m.source for m in models] == ["session", "session"]
    assert "cam_00, cam_01" in caplog.text
    ious = [
        _iou_vs_truth(session, cam, sf.frame, mask)
        for sf in segment_session(session, models=models)
        for cam, mask in zip(sf.cameras, sf.masks, strict=True)
    ]
    assert np.mean(ious) > 0.8


def test_unreadable_camera_gives_empty_flagged_masks(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=5, seed=5)
    video = folder / "videos" / "cam_00.avi"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    frames = list(segment_session(load_session(folder)))
    assert frames[0].flags[0] == ()
    assert frames[-1].flags[0] == ("unreadable",) and not frames[-1].masks[0].any()
    assert frames[-1].flags[1] == ()


def test_camera_order_does_not_change_the_masks(toy: Path, tmp_path: Path) -> None:
    folder = tmp_path / "s"
    shutil.copytree(toy, folder)
    data = yaml.safe_load((folder / "session.yaml").read_text())
    data["cameras"] = data["cameras"][::-1]
    (folder / "session.yaml").write_text(yaml.safe_dump(data))
    a = list(segment_session(load_session(toy), keep_images=False))
    b = list(segment_session(load_session(folder), keep_images=False))
    assert b[0].cameras == ("cam_01", "cam_00")
    for x, y in zip(a, b, strict=True):
        assert x.flags == y.flags[::-1]
        for u, v in zip(x.masks, y.masks[::-1], strict=True):
            np.testing.assert_array_equal(u, v)


# --------------------------------------------------------------------------
# Edge refinement
# --------------------------------------------------------------------------
def _blurred_edge(person: tuple, background: tuple, sigma: float = 1.5):
    """A vertical straight edge: columns < 50 are the person (pixel centres), blurred by
    ``sigma`` px as optics and compression blur it; the true mask and the image."""
    truth = np.zeros((60, 100), bool)
    truth[:, :50] = True
    img = np.where(truth[..., None], np.float32(person), np.float32(background))
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)
    return truth, np.clip(img + 0.5, 0, 255).astype(np.uint8), np.float32(background)


@pytest.mark.parametrize(
    ("person", "background"),
    [((40, 30, 150), (200, 190, 180)), ((220, 210, 200), (40, 50, 60))],
)
def test_refine_edges_puts_a_blurred_edge_where_half_the_pixel_is_person(person, background):
    # Known answer: the threshold's mask is 2 px too wide (as the change threshold
    # makes it); the refined outline must lie on the true one (half-coverage) along
    # the whole edge, dark person on light background and the reverse. A single pass
    # takes the person's colour from an interior that holds mixed edge pixels and
    # keeps the first outside column (alpha 0.37 here).
    truth, img, bg = _blurred_edge(person, background)
    wide = np.zeros_like(truth)
    wide[:, :52] = True
    bg_img = np.broadcast_to(bg, img.shape).copy()
    out = refine_edges(img, bg_img, wide, radius=2, window=7)
    rows = slice(10, 50)  # away from the image's top and bottom
    np.testing.assert_array_equal(out[rows], truth[rows])
    # Invariance: the same edge transposed (horizontal) gives the transposed answer.
    out_t = refine_edges(
        img.transpose(1, 0, 2).copy(), bg_img.transpose(1, 0, 2).copy(), wide.T.copy(), 2, 7
    )
    np.testing.assert_array_equal(out_t[:, rows], truth.T[:, rows])


def test_refine_edges_never_adds_shadow_and_keeps_an_empty_mask():
    truth, img, bg = _blurred_edge((40, 30, 150), (200, 190, 180))
    bg_img = np.broadcast_to(bg, img.shape).copy()
    narrow = np.zeros_like(truth)
    narrow[:, :48] = True  # 2 px too narrow: refinement grows it back to column 49...
    shadow = np.zeros_like(truth)
    shadow[:30, 48:50] = True  # ...except where those pixels are labelled shadow
    out = refine_edges(img, bg_img, narrow, 2, 7, shadow)
    assert out[40:50, :50].all() and not out[40:50, 50:].any()
    assert not out[:30, 48:].any() and out[:30, :48].all()
    empty = np.zeros_like(truth)
    assert not refine_edges(img, bg_img, empty).any()
