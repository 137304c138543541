"""``bodymetry evaluate RUN``: the paper's Figure 3 for a processed studio session.

Columns: Actual (ground truth), Discriminative, Disc. + Generative (from the
run), and GT + Generative: the generative fit started from the ground-truth
pose and the mean shape, the algorithm of Balan et al. [5], computed here on
the same observed silhouettes. Mean and standard deviation over the frames
that succeeded; MPJPE of each stage against the true joints.
"""

from __future__ import annotations

import json
import multiprocessing as mp
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import BodyState
from bodymetry.estimation.pipeline import CORE, ProcessConfig, generative_fit, shared_body_model
from bodymetry.fileio import load_npz, write_json_atomic

#: Spread of the GT + Generative start around the true pose (τ m, θ rad, ν).
GT_START_STD = (0.01, 0.02, 0.3)


def _gt_generative(args) -> tuple[int, dict, list]:
    frame, masks, cameras, tau, theta, quality, seed = args
    body = shared_body_model()  # loaded once per worker process
    n_shape = body.n_shape
    config = ProcessConfig(quality=quality, seed=seed)
    cfg = config.annealing
    rng = np.random.default_rng([seed, frame, 7])
    y0 = np.r_[tau, theta, np.zeros(n_shape)]
    std = np.r_[
        np.full(3, GT_START_STD[0]), np.full(37, GT_START_STD[1]), np.full(n_shape, GT_START_STD[2])
    ]
    init = y0 + rng.standard_normal((cfg.n_particles, len(y0))) * std
    state = generative_fit(body, cameras, masks, init, config, rng).refined.state
    bio = measure(body, state.nu)[0].to_dict()
    joints = body.pose(state).joints[0].tolist()
    return frame, bio, joints


def _stats(values: list[float]) -> dict:
    v = np.asarray(values, float)
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
        "n": len(v),
    }


def evaluate_run(
    run: str | Path,
    workers: int | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Compute the Figure 3 numbers for a run and write ``run/evaluation.json``."""
    from bodymetry.capture.silhouette import segment_session

    run = Path(run)
    path = run / "results.json"
    if not path.is_file():
        raise InputError(f"{path}: not found; run `bodymetry process` first")
    results = json.loads(path.read_text())
    session = load_session(results["session"]["path"])
    truth = results.get("ground_truth")
    gt_dir = session.ground_truth_path
    if truth is None or gt_dir is None or not (gt_dir / "states.npz").is_file():
        raise InputError(f"{session.folder}: the session has no ground truth to evaluate against")
    states = load_npz(gt_dir / "states.npz")
    ok = [f for f in results["frames"] if f.get("status") == "ok"]
    if not ok:
        raise InputError(f"{path}: no frame was fitted")
    quality = results["config"]["quality"]
    seed = results["config"]["seed"]
    cameras = list(session.calibration())
    body = shared_body_model()
    wanted = {f["frame"] for f in ok}
    jobs = []
    for sil in segment_session(session, frames=sorted(wanted), keep_images=False):
        f = sil.frame
        jobs.append(
            (
                f,
                sil.stack(),
                cameras,
                states["tau"][f],
                states["theta"][f],
                quality,
                seed,
            )
        )
    gt_gen: dict[int, tuple[dict, list]] = {}
    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(max(1, workers or mp.cpu_count() or 1), mp_context=ctx) as pool:
        for frame, bio, joints in pool.map(_gt_generative, jobs):
            gt_gen[frame] = (bio, joints)
            if progress:
                progress("GT + generative", len(gt_gen), len(jobs))

    def mpjpe(stage: str) -> float:
        errs = []
        for f in ok:
            state = BodyState(**{k: np.asarray(v) for k, v in f[stage]["state"].items()})
            joints = body.pose(state, lod=True).joints[0]
            errs.append(np.linalg.norm(joints - states["joints"][f["frame"]], axis=1).mean())
        return float(1000 * np.mean(errs))

    table = {}
    for key in CORE:
        table[key] = {
            "actual": truth[key],
            "discriminative": _stats([f["discriminative"][key] for f in ok]),
            "disc_generative": _stats([f["generative"][key] for f in ok]),
            "gt_generative": _stats([gt_gen[f["frame"]][0][key] for f in ok]),
        }
    gt_mpjpe = float(
        1000
        * np.mean(
            [
                np.linalg.norm(
                    np.asarray(gt_gen[f["frame"]][1]) - states["joints"][f["frame"]], axis=1
                ).mean()
                for f in ok
            ]
        )
    )
    evaluation = {
        "run": str(run.resolve()),
        "session": results["session"]["name"],
        "frames": len(ok),
        "frames_failed": len(results["frames"]) - len(ok),
        "table": table,
        "mpjpe_mm": {
            "discriminative": mpjpe("discriminative"),
            "disc_generative": mpjpe("generative"),
            "gt_generative": gt_mpjpe,
        },
        "silhouette_iou_mean": float(
            np.mean([np.mean(list(f["silhouette_iou"].values())) for f in ok])
        ),
    }
    write_json_atomic(run / "evaluation.json", evaluation)
    return evaluation
