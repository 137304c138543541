"""How much the session stage's result depends on the exact numbers it starts from.

The session stage (:func:`~bodymetry.estimation.session_shape.fit_session_shape`)
descends from the per-frame fits in a few joint Levenberg-Marquardt steps. Its
contour cost is piecewise: which model edges are on the contour, and which
outline point each is paired with, change in jumps. Differences in the last
digits of the starts, such as two CPUs' floating point produce (README, "The
same code on three machines"), can therefore end a descent elsewhere. The stage
averages several descents from jittered starts (``session_shape.descents``) and
adds their spread to its standard error; this benchmark measures what that buys.

``python -m benchmarks session_spread`` processes each studio session (the demo by
default; ``BODYMETRY_BENCH_SESSIONS=a:b:c`` for others, rendered beforehand) into
``$BODYMETRY_BENCH_RUN_DIR/<name>`` (a temporary folder by default; a finished run
there is reused), then runs, from the run's own per-frame fits:

* ``single``: one descent (``descents=1``) from the run's starts and from
  :data:`RESTARTS` copies of them with every start value moved by Gaussian noise of
  :data:`NOISE` (radians, metres and shape standard deviations: far below anything
  a fit resolves), each with a fixed seed: the spread of one descent's end point;
* ``averaged``: the stage as configured (its descents averaged) with jitter seeds
  ``0`` to :data:`RESTARTS`: the spread that is left, against the standard error
  the stage states (which includes the descents' spread).

Per biometric it reports every start's error against the truth, their standard
deviation and range, and the stage's own standard error beside them.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.bench_session_bias import KEYS, per_session, processed_session
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.session_shape import SessionShapeConfig, fit_session_shape

#: Perturbed starts (single descents) and other seeds (averaged), besides the first.
RESTARTS = 4
#: Standard deviation of the perturbation of every start value (single descents).
NOISE = 1e-4


def _spread(starts: list[dict]) -> dict:
    """Per biometric: standard deviation and range of the starts' errors, and the
    first start's stated standard error."""
    out = {}
    for key in KEYS:
        values = np.array([s["errors"][key] for s in starts])
        out[key] = {
            "std": round(float(values.std(ddof=1)), 2),
            "range": round(float(values.max() - values.min()), 2),
            "stage_standard_error": starts[0]["standard_errors"][key],
        }
    return out


def session_spread(session_dir: Path, run_dir: Path) -> dict:
    """The single descent from perturbed starts, and the averaged stage over seeds."""
    processed = processed_session(session_dir, run_dir)
    body = shared_body_model()
    recorded = processed.recorded
    # The stage's verdict on the IoU is beside the point here.
    configured = replace(recorded.session_shape, max_iou_drop=1.0)

    def stage(frames: list, config: SessionShapeConfig) -> dict:
        s = fit_session_shape(
            body,
            processed.run.cameras,
            frames,
            recorded.fit.refinement,
            config,
            recorded.fit.density,
        ).summary
        return {
            "errors": {k: round(s.biometrics[k] - processed.truth[k], 2) for k in KEYS},
            "standard_errors": {k: round(s.standard_errors[k], 2) for k in KEYS},
            "cost": [round(s.initial_cost, 2), round(s.cost, 2)],
            "steps": s.iterations,
            "seconds": round(s.seconds, 1),
        }

    single = []
    for k in range(RESTARTS + 1):
        rng = np.random.default_rng(k)
        frames = [
            f if k == 0 else replace(f, start=f.start + rng.normal(0.0, NOISE, f.start.shape))
            for f in processed.frames
        ]
        single.append(stage(frames, replace(configured, descents=1)))
    averaged = [stage(processed.frames, replace(configured, seed=k)) for k in range(RESTARTS + 1)]
    return {
        "session": str(session_dir),
        "frames": len(processed.frames),
        "noise": NOISE,
        "descents": configured.descents,
        "jitter": configured.jitter,
        "single": {"starts": single, "spread": _spread(single)},
        "averaged": {"seeds": averaged, "spread": _spread(averaged)},
    }


def run() -> dict:
    return per_session(session_spread)
