"""Camera registration from the fitted bodies: known shifts found, noise left alone."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.registration import (
    CameraShift,
    RegistrationConfig,
    camera_shifts,
    read_registration,
    shift_mask,
    write_registration,
)
from bodymetry.studio.rig import studio_rig

#: A 4-camera rig around the subject, and where the subject stands.
RIG = studio_rig(4, (160, 120), seed=5)
CENTRE = np.array([0.0, 0.0, 1.0])

#: Sub-pixel rasterization: cv2's fixed-point shift (1/16 px).
SUB = 4
#: How close a recovered sub-pixel offset must be (px): the parabola through a
#: pooled IoU sampled at whole pixels, on silhouettes rasterized to 1/16 px.
TOL_PX = 0.3


def _body(centre: tuple[float, float], axes: tuple[int, int], angle: float) -> np.ndarray:
    """(120, 160) bool: a filled ellipse with a limb, placed to 1/16 px."""
    mask = np.zeros((120, 160), np.uint8)
    c = (round(centre[0] * 2**SUB), round(centre[1] * 2**SUB))
    cv2.ellipse(
        mask, c, (axes[0] * 2**SUB, axes[1] * 2**SUB), angle, 0, 360, 1, -1, cv2.LINE_8, SUB
    )
    tip = (round((centre[0] + 30) * 2**SUB), round((centre[1] - 12) * 2**SUB))
    cv2.line(mask, c, tip, 1, 5, cv2.LINE_8, SUB)
    return mask.astype(bool)


def _frames(
    rng: np.random.Generator, shift: tuple[float, float], n: int, jitter: float = 0.0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (observed, model) pairs: the observed silhouette is the model's moved by
    ``shift`` (plus per-frame jitter), different bodies in each frame."""
    pairs = []
    for _ in range(n):
        centre = (rng.uniform(60, 100), rng.uniform(50, 70))
        axes = (int(rng.integers(12, 25)), int(rng.integers(25, 40)))
        angle = float(rng.uniform(0, 180))
        dx, dy = np.add(shift, rng.uniform(-jitter, jitter, 2))
        model = _body(centre, axes, angle)
        observed = _body((centre[0] + dx, centre[1] + dy), axes, angle)
        pairs.append((observed, model))
    return pairs


def test_shift_mask_moves_without_wrapping_and_back():
    rng = np.random.default_rng(0)
    mask = np.zeros((20, 30), bool)
    mask[5:15, 8:22] = rng.random((10, 14)) > 0.3
    for dx, dy in [(0, 0), (2, -3), (-4, 1)]:
        moved = shift_mask(mask, dx, dy)
        assert moved.sum() == mask.sum()  # nothing fell off: the mask is inside
        np.testing.assert_array_equal(shift_mask(moved, -dx, -dy), mask)
    edge = np.zeros((5, 5), bool)
    edge[:, -1] = True
    assert not shift_mask(edge, 1, 0).any()  # shifted out, not wrapped round


def _shifts(rng, offsets, n=6, jitter=0.0) -> list[CameraShift]:
    """camera_shifts of RIG where camera c's observed silhouettes sit ``offsets[c]`` off."""
    return camera_shifts(RIG, [_frames(rng, o, n, jitter) for o in offsets], CENTRE)


@pytest.mark.parametrize("shift", [(1.6, -0.8), (-2.3, 1.2), (0.0, 2.5), (6.4, -1.0)])
def test_a_camera_off_by_a_known_offset_is_found_to_a_third_of_a_pixel(shift):
    rng = np.random.default_rng(1)
    found = _shifts(rng, [(0, 0), shift, (0, 0), (0, 0)])
    assert [s.applied for s in found] == [False, True, False, False]
    off = found[1]
    assert abs(off.dx - shift[0]) < TOL_PX and abs(off.dy - shift[1]) < TOL_PX, off
    assert (off.seen_dx, off.seen_dy) == pytest.approx((off.dx, off.dy), abs=TOL_PX)
    assert off.iou_after > off.iou_before and off.frames == 6 and off.agreement == 1.0
    assert off.camera == RIG[1].name


def test_the_body_meeting_a_camera_halfway_is_taken_out():
    """Offsets seen are what the fit left: the body moved by t to meet camera 2, so every
    camera sees J_c t besides camera 2's own offset; the sparsest choice undoes it."""
    own = np.array([[0.0, 0.0], [0.0, 0.0], [3.0, -2.0], [0.0, 0.0]])
    moved = np.array(
        [np.ravel(cam.project(CENTRE + [0.025, -0.02, 0.01]) - cam.project(CENTRE)) for cam in RIG]
    )
    assert np.abs(moved).max() > 0.8  # the body's motion alone would read as offsets
    rng = np.random.default_rng(6)
    found = _shifts(rng, own + moved)
    got = np.array([(s.dx, s.dy) for s in found])
    # Half a pixel: the peaks' own error plus the gauge's (the body's motion is
    # linearized at its centre, and the sparsest choice is an L1 compromise).
    np.testing.assert_allclose(got, own, atol=0.5)
    assert [s.applied for s in found] == [False, False, True, False]


def test_two_cameras_off_are_both_moved_their_way_but_not_the_whole_way():
    """The sparsest choice assumes most cameras are right: with two of four off, it
    shares their offsets out ((3.0, 0) and (0, -2.2) px read (1.7, 0.4) and (1.2, -1.8)
    px), so both are moved towards their calibration, not onto it (the run
    registers once)."""
    rng = np.random.default_rng(7)
    both = _shifts(rng, [(0, 0), (3.0, 0), (0, 0), (0, -2.2)])
    assert [s.applied for s in both] == [False, True, False, True]
    assert 1.0 < both[1].dx < 3.0 + TOL_PX and -2.2 - TOL_PX < both[3].dy < -1.0


def test_a_registered_camera_and_a_small_offset_are_left_alone():
    rng = np.random.default_rng(2)
    found = _shifts(rng, [(0, 0), (0.4, 0), (0, 0), (0, 0)], n=5)
    assert not any(s.applied for s in found)
    assert all(abs(s.dx) < TOL_PX + 0.4 and abs(s.dy) < TOL_PX for s in found)
    assert found[0].iou_after == found[0].iou_before == 1.0


def test_offsets_the_frames_do_not_agree_on_are_left_alone():
    """Each frame off by up to 3 px in its own direction (a wrong pose, not a camera)."""
    rng = np.random.default_rng(3)
    pairs = []
    for _ in range(8):
        pairs += _frames(rng, tuple(rng.uniform(-3, 3, 2)), 1)
    still = [_frames(rng, (0, 0), 8) for _ in range(3)]
    found = camera_shifts(RIG, [pairs, *still], CENTRE)
    assert found[0].agreement < RegistrationConfig().min_agreement
    assert not any(s.applied for s in found)


def test_too_few_frames_or_cameras_are_left_alone():
    rng = np.random.default_rng(4)
    few = _shifts(rng, [(0, 0), (2, 0), (0, 0), (0, 0)], n=2)
    assert not any(s.applied for s in few) and few[1].frames == 2
    assert abs(few[1].dx - 2) < TOL_PX
    # Two cameras cannot say which of them is off.
    two = camera_shifts(RIG, [_frames(rng, (3, 0), 5), _frames(rng, (0, 0), 5), [], []], CENTRE)
    assert not any(s.applied for s in two)
    assert two[2] == CameraShift(RIG[2].name, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0, False)
    # Empty silhouettes are not frames.
    empty = np.zeros((120, 160), bool)
    blank = camera_shifts(RIG, [[(empty, empty)] * 5] * 4, CENTRE)
    assert all(s.frames == 0 and not s.applied for s in blank)


def test_the_result_does_not_depend_on_the_order_of_the_frames():
    rng = np.random.default_rng(5)
    lists = [_frames(rng, o, 5, jitter=0.5) for o in [(0, 0), (1.2, -1.7), (0, 0), (0, 0)]]
    a = camera_shifts(RIG, lists, CENTRE)
    b = camera_shifts(RIG, [p[::-1] for p in lists], CENTRE)
    assert a == b


def test_bad_settings_and_inputs_are_named():
    with pytest.raises(InputError, match="search_px"):
        RegistrationConfig(search_px=0)
    with pytest.raises(InputError, match="min_shift_px"):
        RegistrationConfig(min_shift_px=0)
    with pytest.raises(InputError, match="min_agreement"):
        RegistrationConfig(min_agreement=1.5)
    with pytest.raises(InputError, match="4 cameras but 1"):
        camera_shifts(RIG, [[]], CENTRE)


def test_registration_file_round_trip_and_bad_files(tmp_path):
    shifts = [
        CameraShift("cam01", 1.25, -0.5, 1.0, -0.25, 10, 0.85, 0.88, 0.9, True),
        CameraShift("cam02", 0.1, 0.0, -0.2, 0.1, 10, 0.9, 0.9, 1.0, False),
    ]
    path = tmp_path / "registration.json"
    write_registration(path, shifts)
    assert read_registration(path) == shifts
    path.write_text(json.dumps({"format": 99, "cameras": []}))
    with pytest.raises(InputError, match=r"registration\.json: format 99"):
        read_registration(path)
    path.write_text(json.dumps({"format": 1, "cameras": [{"camera": "x"}]}))
    with pytest.raises(InputError, match=r"cameras\[0\]"):
        read_registration(path)
    path.write_text("{not json")
    with pytest.raises(InputError, match=r"registration\.json"):
        read_registration(path)
