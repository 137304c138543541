"""Silhouettes to weight without any posing: ``python -m benchmarks standing_shape``.

The weight error of the subjects the model was not built from
(``python -m benchmarks session_bias``) has a floor even from their true poses
and rendered true silhouettes. This report separates the shape space from the
posing. Bank bodies of the studio's independent subjects (``docs/studio.md``)
stand in their rest pose, where the rig's skinning is the rest mesh itself,
so our posed model and theirs differ only in shape. Each is rendered through
the demo rig's working cameras at four headings (0, 30, 60, 90 degrees: 16
views), and the session stage
(:func:`~bodymetry.estimation.session_shape.fit_session_shape`, default
settings) fits one shape to them from the true pose and the body's own
projection onto the shape space
(:meth:`~bodymetry.estimation.body_model.model.BodyModel.shape_from_vertices`).

Per body and shape-space size (9, the default, and 20 components): the weight
error of the projection (what the shape space can represent: vertex
least-squares) and of the silhouette fit (what the outlines choose), the fit's
height error, and a control: the projected shape rendered by our own model and
fitted the same way (its error against the projection's weight is the stage's
own, with outlines it can meet exactly). ``BODYMETRY_BENCH_BODIES=20,16,19,43``
(the default: the bank bodies of seeds 71, 43, 42 and 49) picks the bodies.
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np

from bodymetry.capture.session import load_session
from bodymetry.cli import DEMO_SESSION
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import BodyState, shipped_model
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.session_shape import SessionFrame, fit_session_shape
from bodymetry.studio.independent import IndependentSpec, IndependentSubject

#: Bank bodies of the independent sessions: seeds 71 (held out), 43, 42, 49.
DEFAULT_BODIES = (20, 16, 19, 43)
HEADINGS_DEG = (0.0, 30.0, 60.0, 90.0)
SHAPE_SIZES = (9, 20)


def standing_fit(body, cameras, config: ProcessConfig, index: int) -> dict:
    """One bank body standing at the four headings, fitted by the session stage."""
    subject = IndependentSubject(IndependentSpec(seed=0, body=index), model=body)
    truth = subject.biometrics()
    nu = body.shape_from_vertices(subject.rest[None])[0]
    projected = measure(body, nu)[0]
    tau = subject.rest_joints[0]
    states = []
    for yaw in np.radians(HEADINGS_DEG):
        theta = np.zeros(37)
        theta[2] = yaw  # heading: a rotation about the vertical through the root
        states.append(np.r_[tau, theta, nu])

    def fitted(render) -> dict:
        """The session stage on the four headings rendered by ``render(state)``."""
        frames = [
            SessionFrame(k, y, project_silhouettes(render(y), body.faces(), cameras), 1.0)
            for k, y in enumerate(states)
        ]
        fit = fit_session_shape(
            body,
            cameras,
            frames,
            config.fit.refinement,
            replace(config.session_shape, max_iou_drop=1.0),
            config.fit.density,
        )
        return fit.summary.biometrics

    subject_fit = fitted(lambda y: subject.pose(y[None, :3], y[None, 3:40])[0][0])
    # Control: the projected shape rendered by our own model, so that the outlines
    # can be met exactly; its error is the stage's own, without the shape mismatch.
    control = fitted(lambda y: body.pose(BodyState.from_vector(y[None])).vertices[0])
    return {
        "true_weight_kg": round(truth.weight_kg, 2),
        "projection_weight_error_kg": round(projected.weight_kg - truth.weight_kg, 2),
        "fit_weight_error_kg": round(subject_fit["weight_kg"] - truth.weight_kg, 2),
        "fit_height_error_mm": round(subject_fit["height_mm"] - truth.height_mm, 1),
        "control_weight_error_kg": round(control["weight_kg"] - projected.weight_kg, 2),
    }


def run() -> dict:
    chosen = os.environ.get("BODYMETRY_BENCH_BODIES")
    bodies = [int(b) for b in chosen.split(",")] if chosen else list(DEFAULT_BODIES)
    config = ProcessConfig()
    session = load_session(DEMO_SESSION)
    resolution = WorkingResolution.choose(session.calibration(), config.working_person_px)
    cameras = resolution.apply(session.calibration())
    out = {}
    for n_shape in SHAPE_SIZES:
        body = shipped_model(n_shape)
        out[f"{n_shape}_components"] = {
            str(b): standing_fit(body, cameras, config, b) for b in bodies
        }
    return {
        "setup": (
            f"bank bodies {bodies} in their rest pose at headings {list(HEADINGS_DEG)} deg, "
            "the demo rig's working cameras, the session stage from the true pose and the "
            "projected shape"
        ),
        "bodies": out,
    }
