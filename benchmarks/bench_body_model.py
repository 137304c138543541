"""Body model speed (single thread) and the baked model's held-out accuracy.

Targets (issue 2): full-resolution mesh <= 10 ms per state; LOD mesh <= 1 ms per
state when batched by 256. Accuracy figures come from the bake's validation
(held-out bodies and poses, ``estimation/body_model/data/body_model.validation.json``).
"""

from __future__ import annotations

import json
import time

import numpy as np

from bodymetry.estimation.body_model.model import DEFAULT_MODEL_PATH, BodyModel, BodyState


def _states(model: BodyModel, n: int, rng: np.random.Generator) -> BodyState:
    lo, hi = model.limits.lower, model.limits.upper
    theta = rng.uniform(np.maximum(lo, -1.0), np.minimum(hi, 1.0), size=(n, len(lo)))
    return BodyState(rng.normal(0, 0.5, (n, 3)), theta, rng.normal(0, 1, (n, model.n_shape)))


def _time_per_state(fn, n_states: int, repeats: int) -> float:
    fn()  # warm-up (caches, factorization already done at load)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return 1000.0 * best / n_states


def run() -> dict:
    t0 = time.perf_counter()
    model = BodyModel.load()
    _ = model._anchor_basis  # build the cached bases now, not in the timed loops
    load_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    result: dict = {"load_seconds": round(load_s, 3)}
    for lod, batch in ((False, 1), (False, 16), (True, 1), (True, 256)):
        states = _states(model, batch, rng)
        ms = _time_per_state(lambda s=states, lod=lod: model.pose(s, lod=lod), batch, repeats=5)
        key = f"{'lod' if lod else 'full'}_ms_per_state_batch_{batch}"
        result[key] = round(ms, 3)
    result["targets"] = {"full_ms_per_state": 10.0, "lod_ms_per_state_batch_256": 1.0}
    validation = DEFAULT_MODEL_PATH.with_suffix(".validation.json")
    if validation.exists():
        result["bake_validation"] = json.loads(validation.read_text())
    return result
