"""The working resolution of each camera: the rule, mask downscaling, the record."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest
from tiny_run import portrait_rig

from bodymetry.calibration.camera import Camera
from bodymetry.capture.session import load_session
from bodymetry.cli import DEMO_SESSION
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.resolution import (
    DEFAULT_WORKING_PERSON_PX,
    CameraScale,
    WorkingResolution,
    downscale_mask,
    person_height_px,
    working_factor,
)
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults, SessionInfo


def test_the_demo_rig_keeps_full_resolution():
    """The bundled 640x480 demo (people of ~300-320 px) is not scaled: its figures stay."""
    cameras = load_session(DEMO_SESSION).calibration()
    heights = [person_height_px(c) for c in cameras]
    assert all(280 < h < 2 * DEFAULT_WORKING_PERSON_PX for h in heights)
    resolution = WorkingResolution.choose(cameras, DEFAULT_WORKING_PERSON_PX)
    assert resolution.factors == {c.name: 1 for c in cameras}
    assert not resolution.scaled
    working = resolution.apply(cameras)
    assert all(w is c for w, c in zip(working, cameras, strict=True))  # the same objects


def test_a_portrait_rig_works_at_a_third(caplog):
    """Four 1080x1920 / 1088x1920 portrait cameras, a person ~960 px: k = 3."""
    cameras = portrait_rig()
    heights = [person_height_px(c) for c in cameras]
    assert all(930 < h < 1000 for h in heights), heights
    with caplog.at_level(logging.INFO, logger="bodymetry.estimation.resolution"):
        resolution = WorkingResolution.choose(cameras, DEFAULT_WORKING_PERSON_PX)
    assert set(resolution.factors.values()) == {3}
    working = resolution.apply(cameras)
    assert [c.size for c in working] == [(360, 640), (363, 640), (360, 640), (363, 640)]
    assert [s.size for s in resolution.scales.values()] == [c.size for c in working]
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 4
    assert lines[0].startswith("cam_00: 1080x1920 -> 360x640 working resolution (person ~")
    assert lines[1].startswith("cam_01: 1088x1920 -> 363x640 working resolution")
    # The person is as tall in a working image as in the demo's (320-640 px).
    assert all(
        DEFAULT_WORKING_PERSON_PX <= person_height_px(c) < 2 * DEFAULT_WORKING_PERSON_PX
        for c in working
    )


@pytest.mark.parametrize(
    ("person", "target", "k"),
    [(960.0, 320.0, 3), (639.0, 320.0, 1), (640.0, 320.0, 2), (300.0, 320.0, 1), (1300.0, 320, 4)],
)
def test_working_factor(person, target, k):
    assert working_factor(person, target) == k


def test_working_factor_none_nan_and_bad_target():
    assert working_factor(5000.0, None) == 1
    assert working_factor(float("nan"), 320.0) == 1  # origin behind the camera: unknown
    with pytest.raises(ValueError, match="target_px"):
        working_factor(900.0, 0.0)


def test_target_none_keeps_every_camera():
    cameras = portrait_rig()
    resolution = WorkingResolution.choose(cameras, None)
    assert resolution.factors == {c.name: 1 for c in cameras}


def test_downscale_mask_is_the_block_average_thresholded_at_half():
    rng = np.random.default_rng(0)
    mask = rng.random((1920, 1080)) < 0.5
    small = downscale_mask(mask, 3, (360, 640))
    blocks = mask.reshape(640, 3, 360, 3).mean(axis=(1, 3))
    np.testing.assert_array_equal(small, blocks >= 0.5)
    # What OpenCV's area interpolation gives for an integer factor.
    area = cv2.resize(mask.astype(np.float32), (360, 640), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(small, area >= 0.5 - 1e-6)
    # k = 1: unchanged.
    assert downscale_mask(mask, 1, (1080, 1920)) is mask


def test_downscale_mask_partial_blocks():
    # 1088 = 3 * 362 + 2: the last column of blocks has 2 columns of pixels.
    mask = np.zeros((6, 1088), bool)
    mask[:, -2:] = True  # the partial block is all person
    mask[:, 0] = True  # 1 of 3 columns: below half
    small = downscale_mask(mask, 3, (363, 2))
    assert small.shape == (2, 363)
    assert small[:, -1].all() and not small[:, 0].any() and small.sum() == 2
    # A size that rounds down drops the partial block (1084 = 3 * 361 + 1).
    assert downscale_mask(np.ones((6, 1084), bool), 3, (361, 2)).all()


def test_downscale_mask_rejects_mismatches():
    with pytest.raises(ValueError, match="does not downscale by 3 to 300x640"):
        downscale_mask(np.zeros((1920, 1080), bool), 3, (300, 640))
    with pytest.raises(ValueError, match="integer >= 1"):
        downscale_mask(np.zeros((4, 4), bool), 1.5, (2, 2))  # type: ignore[arg-type]
    resolution = WorkingResolution.choose(portrait_rig()[:1], DEFAULT_WORKING_PERSON_PX)
    with pytest.raises(ValueError, match="camera cam_00: mask of 640x480"):
        resolution.downscale(["cam_00"], [np.zeros((480, 640), bool)])


def test_downscaled_silhouette_matches_the_working_camera_render():
    """Downscaling the full-resolution render ~ rendering through the working camera."""
    model = BodyModel.load()
    cameras = portrait_rig()[:2]
    resolution = WorkingResolution.choose(cameras, DEFAULT_WORKING_PERSON_PX)
    working = resolution.apply(cameras)
    verts = model.pose(
        BodyState([0.1, 0.0, 0.93], model.poses["apose"], np.zeros(model.n_shape)), lod=True
    ).vertices[0]
    full = project_silhouettes(verts, model.faces(lod=True), cameras)
    direct = project_silhouettes(verts, model.faces(lod=True), working)
    for small, render in zip(resolution.downscale(cameras.names, full), direct, strict=True):
        assert small.shape == render.shape
        iou = (small & render).sum() / (small | render).sum()
        assert iou > 0.97, iou


def test_record_round_trip_and_checks():
    cameras = portrait_rig()
    resolution = WorkingResolution.choose(cameras, DEFAULT_WORKING_PERSON_PX)
    data = resolution.to_json()
    assert data["working_person_px"] == DEFAULT_WORKING_PERSON_PX
    assert data["cameras"]["cam_01"]["factor"] == 3
    assert data["cameras"]["cam_01"]["size"] == [363, 640]
    assert data["cameras"]["cam_01"]["calibrated_size"] == [1088, 1920]
    back = WorkingResolution.from_json(data)
    assert back.factors == resolution.factors
    assert [c.size for c in back.apply(cameras)] == [c.size for c in resolution.apply(cameras)]
    # A calibration whose size changed since the run does not silently mismatch.
    changed = [Camera(c.name, (720, 1280), c.K, c.dist, c.R, c.t) for c in cameras]
    with pytest.raises(InputError, match="chosen for 1080x1920"):
        back.apply(changed)
    with pytest.raises(InputError, match="has no working resolution"):
        back.apply([Camera("cam_09", (1080, 1920), cameras[0].K)])
    with pytest.raises(InputError, match="factor: expected an integer"):
        WorkingResolution.from_json(
            {"cameras": {"a": {"factor": 0, "calibrated_size": [4, 4], "size": [4, 4]}}}
        )
    assert CameraScale.from_json(data["cameras"]["cam_00"], "x").person_px == pytest.approx(
        person_height_px(cameras[0]), abs=0.06
    )


def test_run_results_give_the_working_cameras():
    cameras = portrait_rig()
    resolution = WorkingResolution.choose(cameras, DEFAULT_WORKING_PERSON_PX)
    info = SessionInfo("/s", "s", cameras.names, 30.0, 1)
    results = RunResults.of_subject(info, ProcessConfig(), working_resolution=resolution)
    back = RunResults.from_json(results.to_json())
    assert [c.size for c in back.working_cameras(cameras)][:2] == [(360, 640), (363, 640)]
    # A run recorded before working resolutions worked at full resolution.
    old = results.to_json()
    del old["working_resolution"]
    assert list(RunResults.from_json(old).working_cameras(cameras)) == list(cameras)
