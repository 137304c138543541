"""``bodymetry evaluate RUN``: the paper's Figure 3 for a processed studio session.

Columns: Actual (ground truth), Discriminative, Disc. + Generative (from the
run's records), and GT + Generative: the generative fit started from the
ground-truth pose and the mean shape, the algorithm of Balan et al. [5],
computed here on the observed silhouettes the run recorded, with the fit
settings the run recorded. Mean and standard deviation over the frames that
succeeded; MPJPE of each stage against the true joints.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.ground_truth import GROUND_TRUTH_STATES
from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.fit import FitConfig, generative_fit, shared_body_model
from bodymetry.estimation.records import CORE_MEASUREMENTS, FRAME_STAGES, Stat
from bodymetry.estimation.run_files import GT_STAGE, Evaluation, RunLayout
from bodymetry.estimation.view_selection import blank_unusable, usable_views
from bodymetry.fileio import load_npz
from bodymetry.log import Progress
from bodymetry.review.run_data import RunData, load_frame_arrays, load_run

#: Spread of the GT + Generative start around the true pose (τ m, θ rad, ν).
GT_START_STD = (0.01, 0.02, 0.3)

__all__ = ["GT_START_STD", "evaluate_run"]


def _gt_generative(
    args: tuple[int, list[np.ndarray], CameraGroup, np.ndarray, np.ndarray, FitConfig],
) -> tuple[int, dict[str, float], list]:
    frame, masks, cameras, tau, theta, config = args
    body = shared_body_model()  # loaded once per worker process
    n_shape = body.n_shape
    rng = np.random.default_rng([config.seed, frame, 7])
    y0 = np.r_[tau, theta, np.zeros(n_shape)]
    std = np.r_[
        np.full(3, GT_START_STD[0]), np.full(37, GT_START_STD[1]), np.full(n_shape, GT_START_STD[2])
    ]
    init = y0 + rng.standard_normal((config.annealing.n_particles, len(y0))) * std
    state = generative_fit(body, cameras, masks, init, config, rng).refined.state
    bio = measure(body, state.nu, density=config.density)[0].to_dict()
    joints = body.pose(state).joints[0].tolist()
    return frame, bio, joints


def _gt_generative_fits(
    data: RunData, states: dict[str, np.ndarray], workers: int | None, progress: Progress | None
) -> dict[int, tuple[dict[str, float], list]]:
    """Per ok frame, the measurements and joints of the generative fit started at the
    true pose (:func:`_gt_generative`), on the frame's recorded silhouettes, in a pool.

    Raises
    ------
    InputError
        When a frame's recorded silhouettes are missing.
    """
    layout, names, config = data.layout, data.camera_names, data.results.config.fit
    jobs = []
    for record in data.ok_frames:
        arrays = load_frame_arrays(layout.folder, record.frame)
        if arrays is None or set(arrays.observed) != set(names):
            raise InputError(
                f"{layout.frame_arrays(record.frame)}: the frame's recorded silhouettes are "
                "missing; run `bodymetry process` again"
            )
        # The views the frame's own fit left out (unreliable, too small) stay out.
        masks = blank_unusable(
            [arrays.observed[n] for n in names],
            usable_views(names, record.person_pixels, record.flags),
        )
        f = record.frame
        jobs.append((f, masks, data.cameras, states["tau"][f], states["theta"][f], config))
    gt_gen: dict[int, tuple[dict, list]] = {}
    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(max(1, workers or mp.cpu_count() or 1), mp_context=ctx) as pool:
        for frame, bio, joints in pool.map(_gt_generative, jobs):
            gt_gen[frame] = (bio, joints)
            if progress:
                progress("GT + generative", len(gt_gen), len(jobs))
    return gt_gen


def evaluate_run(
    run: str | Path,
    workers: int | None = None,
    progress: Progress | None = None,
) -> Evaluation:
    """Compute the Figure 3 numbers for a run and write ``run/evaluation.json``.

    Raises
    ------
    InputError
        When the run is missing or unreadable, its session has no ground truth,
        no frame was fitted, or it measured a chosen person (``--person``).
    """
    data = load_run(run)
    layout: RunLayout = data.layout
    if data.results.config.person is not None:
        # The session's truth is its subject's, and which tracked person that is
        # is not known yet: no comparison with somebody else's numbers.
        raise InputError(
            f"{layout.results}: the run measured person {data.results.config.person} "
            "(--person); evaluating a chosen person against their own truth is not "
            "supported yet"
        )
    truth = data.ground_truth
    session = load_session(data.results.session.path) if data.session_folder else None
    gt_dir = session.ground_truth_path if session is not None else None
    if truth is None or gt_dir is None or not (gt_dir / GROUND_TRUTH_STATES).is_file():
        raise InputError(
            f"{data.results.session.path}: the session has no ground truth to evaluate against"
        )
    states = load_npz(gt_dir / GROUND_TRUTH_STATES)
    ok = data.ok_frames
    if not ok:
        raise InputError(f"{layout.results}: no frame was fitted")
    if data.cameras is None:
        raise InputError(f"{layout.calibration}: the run has no recorded cameras")
    gt_gen = _gt_generative_fits(data, states, workers, progress)

    body = shared_body_model()

    def mpjpe(stage: str) -> float:
        errs = []
        for record in ok:
            joints = body.pose(record.estimates[stage].state, lod=True).joints[0]
            errs.append(np.linalg.norm(joints - states["joints"][record.frame], axis=1).mean())
        return float(1000 * np.mean(errs))

    def bio(record, stage: str, key: str) -> float:
        return record.estimates[stage].biometrics[key]

    # The session stage: one value and its standard error (in "std"), when the run has it.
    session = data.results.summary.get("session", {})
    table: dict[str, dict[str, Stat]] = {}
    for key in CORE_MEASUREMENTS:
        table[key] = {stage: Stat.of([bio(r, stage, key) for r in ok]) for stage in FRAME_STAGES}
        if key in session and session[key].mean is not None:
            table[key]["session"] = session[key]
        table[key][GT_STAGE] = Stat.of([gt_gen[r.frame][0][key] for r in ok])
    gt_mpjpe = float(
        1000
        * np.mean(
            [
                np.linalg.norm(
                    np.asarray(gt_gen[r.frame][1]) - states["joints"][r.frame], axis=1
                ).mean()
                for r in ok
            ]
        )
    )
    evaluation = Evaluation(
        run=str(layout.folder.resolve()),
        session=data.name,
        frames=len(ok),
        frames_failed=len(data.frames) - len(ok),
        actual={key: truth.measurements[key] for key in CORE_MEASUREMENTS},
        table=table,
        mpjpe_mm={
            **{stage: mpjpe(stage) for stage in FRAME_STAGES},
            **({"session": mpjpe("session")} if session else {}),
            GT_STAGE: gt_mpjpe,
        },
        silhouette_iou_mean=float(np.mean([r.mean_iou for r in ok])),
    )
    evaluation.write(layout)
    return evaluation
