"""Studio sessions like real recordings: no empty-scene clip, bystanders in the room."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from tiny_run import SYNTH_SIZE, SYNTH_TINY

from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import DEFAULT_SHAPE_DOFS, BodyModel, BodyState
from bodymetry.fileio import load_npz
from bodymetry.preflight import check_session
from bodymetry.studio.bystanders import (
    MAX_BYSTANDERS,
    Bystander,
    BystanderPlacement,
    place_bystanders,
)
from bodymetry.studio.render import Body, Studio
from bodymetry.studio.rig import studio_rig
from bodymetry.studio.synth import SynthConfig, describe, synthesize

SIZE = SYNTH_SIZE
#: The synth tests' session with four cameras and no background clip.
TINY = {**SYNTH_TINY, "cameras": 4, "background_clip": False}
#: A bystander's pixels differ from the scene without it by more than this (DN).
DIFF_DN = 40


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """No background clip, no bystanders."""
    return synthesize(tmp_path_factory.mktemp("plain") / "s", SynthConfig(**TINY), workers=2)


@pytest.fixture(scope="module")
def crowd(tmp_path_factory):
    """The same session (same seed) with two bystanders."""
    out = tmp_path_factory.mktemp("crowd") / "s"
    return synthesize(out, SynthConfig(**TINY, bystanders=2), workers=2)


def _bystanders(session) -> list[Bystander]:
    data = json.loads((session.folder / "ground_truth" / "studio.json").read_text())
    return [
        Bystander(
            b["heldout_index"],
            tuple(b["nu"]),
            tuple(b["theta"]),
            tuple(b["tau"]),
            b["shirt"],
            b["trousers"],
            tuple(b["seen_by"]),
        )
        for b in data["bystanders"]
    ]


def _first_frame(path) -> np.ndarray:
    cap = cv2.VideoCapture(str(path))
    ok, frame = cap.read()
    cap.release()
    assert ok, path
    return frame


def _silhouette(session, camera: str, frame: int) -> np.ndarray:
    mask = cv2.imread(str(session.ground_truth_silhouette_path(camera, frame)), 0)
    assert mask is not None
    return mask > 0


def test_no_background_clip(plain):
    assert not (plain.folder / "background").exists()
    loaded = load_session(plain.folder)
    assert all(loaded.background_path(cam) is None for cam in loaded.camera_names)
    assert "background" not in (plain.folder / "session.yaml").read_text()
    report = check_session(plain.folder)
    assert report.ok, report.problems
    # No bystanders asked for: none recorded.
    assert _bystanders(plain) == []


def test_bystanders_are_recorded(crowd):
    subject = json.loads((crowd.folder / "ground_truth" / "subject.json").read_text())
    bystanders = _bystanders(crowd)
    assert len(bystanders) == 2
    indices = {b.heldout_index for b in bystanders}
    assert len(indices) == 2 and subject["heldout_index"] not in indices
    for b in bystanders:
        assert 1 <= len(b.seen_by) <= 2
        assert np.hypot(b.tau[0], b.tau[1]) >= 2.0
        assert len(b.nu) == DEFAULT_SHAPE_DOFS and len(b.theta) == 37
    assert "2 bystander(s)" in describe(crowd)


def test_ground_truth_is_the_subject_alone(plain, crowd):
    a = load_npz(plain.folder / "ground_truth" / "states.npz")
    b = load_npz(crowd.folder / "ground_truth" / "states.npz")
    for key in ("tau", "theta", "nu", "joints"):
        np.testing.assert_array_equal(a[key], b[key])
    for cam in plain.camera_names:
        for frame in (0, 2, 4):
            np.testing.assert_array_equal(
                _silhouette(plain, cam, frame), _silhouette(crowd, cam, frame), err_msg=cam
            )


def test_bystanders_show_in_the_cameras_that_see_them(plain, crowd):
    seen = {cam for b in _bystanders(crowd) for cam in b.seen_by}
    assert seen and seen != set(crowd.camera_names)
    kernel = np.ones((7, 7), np.uint8)
    for cam in crowd.camera_names:
        person = cv2.dilate(_silhouette(crowd, cam, 0).astype(np.uint8), kernel) > 0
        diff = np.abs(
            _first_frame(crowd.video_path(cam)).astype(int)
            - _first_frame(plain.video_path(cam)).astype(int)
        ).max(axis=-1)
        changed = (diff > DIFF_DN) & ~person
        # Elsewhere only a bystander's cast shadow may reach into the view.
        if cam in seen:
            assert changed.sum() > 100, cam


def test_bystanders_differ_from_the_empty_room_and_keep_the_person_mask(crowd, model):
    """Rendered clean: bystander pixels differ from the empty room, the person mask is
    the subject's alone, and bystanders are z-buffered and shaded like the subject."""
    cameras = crowd.calibration()
    states = load_npz(crowd.folder / "ground_truth" / "states.npz")
    subject = model.pose(
        BodyState(states["tau"][:1], states["theta"][:1], states["nu"][None])
    ).vertices[0]
    studio = Studio.from_model(model)
    bystanders = _bystanders(crowd)
    others = [Body(b.vertices(model), b.appearance()) for b in bystanders]
    for cam in cameras:
        alone = studio.render_frame(cam, subject, effects=False)
        frame = studio.render_frame(cam, subject, effects=False, others=others)
        np.testing.assert_array_equal(frame.person_mask, alone.person_mask)
        empty = studio.render_background(cam, effects=False)
        # Clean renders (no noise): any difference is the bystanders' or their shadows'.
        diff = np.abs(frame.image.astype(int) - empty).max(axis=-1) > 4
        person = cv2.dilate(frame.person_mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        outside = diff & ~person
        raster = np.zeros(SIZE[::-1], bool)
        for b in others:
            raster |= studio.person_raster(cam, b.vertices).mask
        if any(cam.name in b.seen_by for b in bystanders):
            assert raster.sum() > 200, cam.name
            # Most of the bystanders' pixels differ visibly from the empty room.
            assert (outside & raster).sum() > 0.8 * (raster & ~person).sum(), cam.name
        else:
            assert raster.sum() < 20, cam.name


def test_bystanders_never_overlap_the_subject(crowd, model):
    cameras = crowd.calibration()
    states = load_npz(crowd.folder / "ground_truth" / "states.npz")
    subject = model.pose(BodyState(states["tau"], states["theta"], states["nu"][None])).vertices
    studio = Studio.from_model(model)
    others = [b.vertices(model) for b in _bystanders(crowd)]
    kernel = np.ones((5, 5), np.uint8)
    for cam in cameras:
        bystander = np.zeros(SIZE[::-1], bool)
        for v in others:
            bystander |= studio.person_raster(cam, v).mask
        grown = cv2.dilate(bystander.astype(np.uint8), kernel) > 0
        for f, verts in enumerate(subject):
            person = studio.person_raster(cam, verts).mask
            assert person.sum() > 100
            assert not np.any(grown & person), (cam.name, f)


def test_same_seed_same_bystanders(crowd, tmp_path):
    again = synthesize(tmp_path / "again", SynthConfig(**TINY, bystanders=2), workers=2)
    assert _bystanders(again) == _bystanders(crowd)
    for cam in crowd.camera_names:
        np.testing.assert_array_equal(_silhouette(again, cam, 2), _silhouette(crowd, cam, 2))


def test_placement_is_seeded_and_refuses_what_does_not_fit(model):
    cameras = studio_rig(4, SIZE, seed=0)
    subject = np.array([[[0.0, 0.0, 0.0], [0.3, 0.2, 1.8], [-0.3, -0.2, 0.9]]])
    a = place_bystanders(model, cameras, subject, 2, seed=11)
    b = place_bystanders(model, cameras, subject, 2, seed=11)
    c = place_bystanders(model, cameras, subject, 2, seed=12)
    assert a == b and a != c
    assert len({x.heldout_index for x in a}) == 2
    with pytest.raises(InputError, match="--bystanders 1: placed 0"):
        place_bystanders(
            model, cameras, subject, 1, seed=11, placement=BystanderPlacement(min_distance_m=10.0)
        )
    with pytest.raises(InputError, match="--bystanders"):
        place_bystanders(model, cameras, subject, MAX_BYSTANDERS + 1, seed=11)


@pytest.mark.parametrize("n", [-1, MAX_BYSTANDERS + 1])
def test_config_refuses_bad_bystander_counts(n):
    with pytest.raises(InputError, match="--bystanders"):
        SynthConfig(bystanders=n)


def test_background_frames_are_not_needed_without_a_clip():
    SynthConfig(background_clip=False, background_frames=0)
    with pytest.raises(InputError, match="background clips"):
        SynthConfig(background_frames=0)
