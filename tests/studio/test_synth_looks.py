"""A tiny session in a non-default look: recorded, rendered and scored with it."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from tiny_run import SYNTH_TINY

from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.fileio import load_npz
from bodymetry.studio.evaluate import GroundTruth
from bodymetry.studio.looks import Look, recorded_look
from bodymetry.studio.render import Studio
from bodymetry.studio.synth import SynthConfig, describe, synthesize

LOOK = Look(clothing="white", room="plain", light="soft")


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("looks") / "white"
    return synthesize(out, SynthConfig(**{**SYNTH_TINY, "cameras": 1}, look=LOOK), workers=1)


@pytest.fixture(scope="module")
def posed(session):
    """The body model and the subject's posed vertices (V, 3) at frame 0."""
    states = load_npz(session.folder / "ground_truth" / "states.npz")
    model = BodyModel.load(n_shape=len(states["nu"]))
    state = BodyState(states["tau"][:1], states["theta"][:1], states["nu"][None])
    return model, model.pose(state).vertices[0]


def test_the_look_is_recorded(session):
    gt = session.folder / "ground_truth"
    config = json.loads((gt / "studio.json").read_text())["config"]
    assert config["look"] == {"clothing": "white", "room": "plain", "light": "soft"}
    assert recorded_look(gt) == LOOK and GroundTruth(session).look == LOOK
    assert "look white/plain/soft (neutral)" in describe(session)


def test_the_shirt_is_white_in_the_images(session, posed):
    model, vertices = posed
    camera = session.calibration()[0]
    ok, image = cv2.VideoCapture(str(session.video_path(camera.name))).read()
    assert ok
    truth = cv2.imread(str(session.ground_truth_silhouette_path(camera.name, 0)), 0) > 0
    inner = cv2.erode(truth.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    torso = vertices[model.vertex_parts == PARTS.index("torso")]
    px = np.round(camera.project(torso)).astype(int)
    h, w = inner.shape
    px = px[(px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)]
    px = px[inner[px[:, 1], px[:, 0]]]
    assert len(px) > 20
    bgr = np.median(image[px[:, 1], px[:, 0]].astype(float), axis=0)
    # White fabric under the studio's light: bright and neutral (channels within 12 %;
    # the saturated red shirt has R about 3x B).
    assert bgr.mean() > 120 and np.ptp(bgr) < 0.12 * bgr.mean(), bgr


def test_ground_truth_shadows_use_the_sessions_light(session, posed):
    model, vertices = posed
    camera = session.calibration()[0]
    truth = GroundTruth(session).shadow(camera.name, 0)
    assert truth is not None and truth.any()

    def shadow(look: Look) -> np.ndarray:
        # The shadow mask does not depend on the albedo: flat clothes, no hair.
        ones = np.ones((len(vertices), 3))
        studio = Studio(
            model.faces(),
            model.full.arrays.parts,
            light=look.build_light(),
            room=look.build_room(),
            vertex_modulation=ones,
        )
        frame = studio.render_frame(camera, vertices, effects=False)
        return frame.shadow_mask & ~frame.person_mask

    np.testing.assert_array_equal(truth, shadow(LOOK))
    assert np.count_nonzero(truth ^ shadow(Look())) > 0.05 * truth.sum()
