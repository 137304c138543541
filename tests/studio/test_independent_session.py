"""A studio session of an independent subject: written, scored and evaluated end to end."""

from __future__ import annotations

import json
import logging
import shutil

import cv2
import numpy as np
import pytest
from tiny_run import SYNTH_TINY, TINY_TRAIN

from bodymetry.capture.session import load_session
from bodymetry.estimation.fit import FitConfig
from bodymetry.estimation.records import CORE_MEASUREMENTS
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.fileio import load_npz
from bodymetry.process import process_session
from bodymetry.review.evaluation import evaluate_run
from bodymetry.studio.evaluate import GroundTruth
from bodymetry.studio.independent import IndependentSpec, IndependentSubject
from bodymetry.studio.synth import SubjectSpec, SynthConfig, synthesize

SPEC = IndependentSpec(9, clothing="loose", hair=True)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("independent") / "session"
    return synthesize(out, SynthConfig(**SYNTH_TINY, subject=SubjectSpec(independent=SPEC)), 1)


def test_ground_truth_has_no_shape_and_measures_the_nude_body(session):
    gt = session.folder / "ground_truth"
    states = load_npz(gt / "states.npz")
    assert "nu" not in states and states["joints"].shape == (6, 15, 3)
    subject = json.loads((gt / "subject.json").read_text())
    assert subject["source"] == "independent" and subject["subject"] == SPEC.to_text()
    truth = IndependentSubject(SPEC).biometrics().to_dict()
    for key in CORE_MEASUREMENTS:
        assert subject[key] == pytest.approx(truth[key], abs=1e-3)
    studio = json.loads((gt / "studio.json").read_text())
    assert studio["config"]["subject"]["independent"]["clothing"] == "loose"


def test_true_joints_lie_in_the_silhouettes_and_the_feet_on_the_floor(session):
    states = load_npz(session.folder / "ground_truth" / "states.npz")
    subject = IndependentSubject(SPEC)
    lowest = subject.lowest_point(states["tau"], states["theta"])
    np.testing.assert_allclose(lowest, 0.0, atol=1e-9)
    for cam in session.calibration():
        for frame in (0, 2, 4):
            mask = cv2.imread(
                str(session.ground_truth_silhouette_path(cam.name, frame)), cv2.IMREAD_GRAYSCALE
            )
            grown = cv2.dilate(mask, np.ones((5, 5), np.uint8)) > 0
            px = np.round(cam.project(states["joints"][frame])).astype(int)
            assert grown[px[:, 1], px[:, 0]].all(), f"{cam.name} frame {frame}"


def test_shadow_scoring_rebuilds_the_clothed_subject(session, tmp_path, caplog):
    gt = GroundTruth(load_session(session.folder))
    shadow = gt.shadow("cam_00", 2)
    person = gt.person("cam_00", 2)
    assert shadow is not None and shadow.any() and not (shadow & person).any()
    # The stored masks are what the render drew; a session rendered before the studio
    # stored them gets them re-rendered (the same body model here: the same pixels),
    # with a warning that a changed model would move them.
    assert (session.folder / "ground_truth" / "shadows" / "cam_00" / "000002.png").is_file()
    old = tmp_path / "old"
    shutil.copytree(session.folder, old)
    shutil.rmtree(old / "ground_truth" / "shadows")
    with caplog.at_level(logging.WARNING, logger="bodymetry.studio.evaluate"):
        rerendered = GroundTruth(load_session(old)).shadow("cam_00", 2)
    assert np.array_equal(rerendered, shadow)
    assert "no stored shadow masks" in caplog.text


@pytest.mark.slow
def test_process_and_evaluate_read_the_session(session, tmp_path):
    config = ProcessConfig.preset(
        "fast",
        fit=FitConfig.preset("fast", min_iou=0.5),
        training=TINY_TRAIN,
        workers=1,
        cache_dir=tmp_path / "cache",
        review=False,
    )
    results = process_session(session.folder, tmp_path / "run", config)
    assert results.ground_truth.source == "independent"
    assert results.ground_truth.nu is None
    ev = evaluate_run(tmp_path / "run", workers=1)
    assert ev.frames >= 1
    for key in CORE_MEASUREMENTS:
        assert ev.actual[key] == results.ground_truth.get(key)
        assert np.isfinite(ev.table[key]["gt_generative"].mean)
    assert all(np.isfinite(v) for v in ev.mpjpe_mm.values())
