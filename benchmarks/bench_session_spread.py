"""How much the session stage's result depends on the exact numbers it starts from.

The session stage (:func:`~bodymetry.estimation.session_shape.fit_session_shape`)
descends from the per-frame fits in a few joint Levenberg-Marquardt steps. Its
contour cost is piecewise: which model edges are on the contour, and which
outline point each is paired with, change in jumps. Differences in the last
digits of the starts, such as two CPUs' floating point produce (README, "The
same code on two machines"), can therefore end the descent elsewhere. The
stage's standard error does not cover that: it measures how well the frames
agree at the end point.

``python -m benchmarks session_spread`` processes each studio session (the demo by
default; ``BODYMETRY_BENCH_SESSIONS=a:b:c`` for others, rendered beforehand) into
``$BODYMETRY_BENCH_RUN_DIR/<name>`` (a temporary folder by default; a finished run
there is reused), then runs the stage again from the run's own per-frame fits
(``start 0``) and from :data:`RESTARTS` copies of them with every start value moved
by Gaussian noise of :data:`NOISE` (radians, metres and shape standard deviations:
far below anything a fit resolves), each with a fixed seed. Per biometric it
reports every start's error against the truth, their standard deviation and range,
and the stage's own standard error beside them.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.bench_session_bias import KEYS, per_session, processed_session
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.session_shape import fit_session_shape

#: Perturbed starts per session (besides the run's own).
RESTARTS = 4
#: Standard deviation of the perturbation of every start value.
NOISE = 1e-4


def session_spread(session_dir: Path, run_dir: Path) -> dict:
    """The session stage from the run's starts and from :data:`RESTARTS` perturbed ones."""
    processed = processed_session(session_dir, run_dir)
    body = shared_body_model()
    recorded = processed.recorded
    # The stage's verdict on the IoU is beside the point here.
    config = replace(recorded.session_shape, max_iou_drop=1.0)
    starts = []
    for k in range(RESTARTS + 1):
        rng = np.random.default_rng(k)
        frames = [
            f if k == 0 else replace(f, start=f.start + rng.normal(0.0, NOISE, f.start.shape))
            for f in processed.frames
        ]
        s = fit_session_shape(
            body,
            processed.run.cameras,
            frames,
            recorded.fit.refinement,
            config,
            recorded.fit.density,
        ).summary
        starts.append(
            {
                "errors": {k: round(s.biometrics[k] - processed.truth[k], 2) for k in KEYS},
                "standard_errors": {k: round(s.standard_errors[k], 2) for k in KEYS},
                "cost": [round(s.initial_cost, 2), round(s.cost, 2)],
                "steps": s.iterations,
            }
        )
    spread = {}
    for key in KEYS:
        values = np.array([s["errors"][key] for s in starts])
        spread[key] = {
            "std": round(float(values.std(ddof=1)), 2),
            "range": round(float(values.max() - values.min()), 2),
            "stage_standard_error": starts[0]["standard_errors"][key],
        }
    return {
        "session": str(session_dir),
        "frames": len(processed.frames),
        "noise": NOISE,
        "starts": starts,
        "spread": spread,
    }


def run() -> dict:
    return per_session(session_spread)
