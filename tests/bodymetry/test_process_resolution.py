"""`process` on a rig whose cameras are larger than the features need.

A 2-camera 480x640 portrait studio session with a person ~415 px tall and
``working_person_px=130``: both cameras work at 1/3 (160x213, the last
partial row of blocks dropped), as a 1080x1920 rig with a ~960 px person
does at the default target, at a fraction of the cost. Training renders at
the working size (the cache key is the working cameras'), the fit and the
recorded silhouettes are at it, and so are the review and ``evaluate``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import struct

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from tiny_run import TINY_TRAIN

from bodymetry.capture.segmentation import segment_session
from bodymetry.estimation.fit import FitConfig, shared_body_model
from bodymetry.estimation.records import FrameArrays
from bodymetry.estimation.resolution import downscale_mask, person_height_px
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.session_shape import SessionShapeConfig
from bodymetry.estimation.training import rig_key
from bodymetry.process import process_session
from bodymetry.review.evaluation import evaluate_run
from bodymetry.review.run_data import frame_views, load_run
from bodymetry.studio.synth import synthesize
from bodymetry.warmup import TINY_SESSION

TARGET_PX = 130.0
WORKING_SIZE = (160, 213)  # 480 / 3, round(640 / 3)


@pytest.fixture(scope="module")
def hires(tmp_path_factory):
    base = tmp_path_factory.mktemp("hires")
    # The tiny session at four times the pixels, portrait.
    config = dataclasses.replace(TINY_SESSION, size=(480, 640), seed=5)
    session = synthesize(base / "session", config, workers=1)
    config = ProcessConfig.preset(
        "fast",
        fit=FitConfig.preset("fast", min_iou=0.5),
        training=TINY_TRAIN,
        working_person_px=TARGET_PX,
        # The session stage is not what these tests check: one descent of one step.
        session_shape=SessionShapeConfig(descents=1, iterations=1),
        workers=1,
        cache_dir=base / "cache",
    )
    logger = logging.getLogger("bodymetry.estimation.resolution")
    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.INFO)
    handler.emit = records.append  # type: ignore[method-assign]
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    try:
        results = process_session(session.folder, base / "run", config)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
    return session, base / "run", results, config, [r.getMessage() for r in records]


def test_the_rule_picks_a_third_and_logs_it(hires):
    session, _, results, _, lines = hires
    cameras = session.calibration()
    expected = {c.name: math.floor(person_height_px(c) / TARGET_PX) for c in cameras}
    assert expected == {"cam_00": 3, "cam_01": 3}
    assert results.working_resolution.factors == expected
    assert results.working_resolution.target_px == TARGET_PX
    assert lines == [
        f"{c.name}: 480x640 -> 160x213 working resolution "
        f"(person ~{person_height_px(c):.0f} px tall)"
        for c in cameras
    ]


def test_results_json_records_the_working_sizes_and_target(hires):
    _, out, _, _, _ = hires
    data = json.loads((out / "results.json").read_text())
    assert data["config"]["working_person_px"] == TARGET_PX
    for cam in ("cam_00", "cam_01"):
        entry = data["working_resolution"]["cameras"][cam]
        assert entry["factor"] == 3
        assert entry["size"] == list(WORKING_SIZE)
        assert entry["calibrated_size"] == [480, 640]


def test_training_is_at_the_working_size(hires):
    session, out, results, config, _ = hires
    cameras = session.calibration()
    working = load_run(out).cameras
    assert [c.size for c in working] == [WORKING_SIZE] * 2
    assert results.models == rig_key(working, config.training)
    assert results.models != rig_key(cameras, config.training)
    assert (config.cache_dir / "discriminative" / f"{results.models}.npz").is_file()


def test_recorded_masks_are_the_downscaled_silhouettes(hires):
    session, out, results, _, _ = hires
    assert [f.status for f in results.frames] == ["ok"] * 3
    full = {s.frame: s for s in segment_session(session, keep_images=False)}
    for record in results.frames:
        arrays = FrameArrays.load(out / "frames" / f"{record.frame:06d}.npz")
        for c, name in enumerate(("cam_00", "cam_01")):
            assert arrays.observed[name].shape == arrays.model[name].shape == WORKING_SIZE[::-1]
            np.testing.assert_array_equal(
                arrays.observed[name], downscale_mask(full[record.frame].masks[c], 3, WORKING_SIZE)
            )
            assert record.person_pixels[name] == int(arrays.observed[name].sum())


def test_review_outputs_are_at_the_working_size(hires):
    _, out, _, _, _ = hires
    run = load_run(out)
    assert [c.size for c in run.calibrated_cameras] == [(480, 640)] * 2
    view = next(frame_views(run, shared_body_model(), frames=[0]))
    assert [im.shape for im in view.images] == [(*WORKING_SIZE[::-1], 3)] * 2
    assert [m.shape for m in view.observed] == [WORKING_SIZE[::-1]] * 2
    with open(out / "recording.mcap", "rb") as fh:
        messages = [(ch.topic, msg.data) for _, ch, msg in make_reader(fh).iter_messages()]
    # foxglove.CameraCalibration: width and height are fixed32 fields 2 and 3.
    size_fields = (
        b"\x15" + struct.pack("<I", WORKING_SIZE[0]) + b"\x1d" + struct.pack("<I", WORKING_SIZE[1])
    )
    calibrations = [d for t, d in messages if t.endswith("/calibration")]
    assert calibrations and all(size_fields in d for d in calibrations)
    for topic, data in messages:
        if topic.endswith("/overlay") or topic.endswith("/image"):
            start = data.index(b"\xff\xd8\xff")
            image = cv2.imdecode(np.frombuffer(data[start:], np.uint8), cv2.IMREAD_COLOR)
            assert image.shape[:2] == WORKING_SIZE[::-1], topic
    assert (out / "recording.rrd").stat().st_size > 0
    html = (out / "report.html").read_text()
    assert "480×640 (working 160×213)" in html


def test_evaluate_refits_at_the_working_size(hires):
    _, out, results, _, _ = hires
    evaluation = evaluate_run(out, workers=1)
    assert evaluation.frames == len(results.ok_frames)
    assert np.isfinite(evaluation.table["height_mm"]["gt_generative"].mean)
