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
from bodymetry.capture.ground_truth import (
    GROUND_TRUTH_STATES,
    SubjectTruth,
    match_person,
    person_folder,
)
from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.fit import FitConfig, generative_fit, shared_body_model
from bodymetry.estimation.records import CORE_MEASUREMENTS, FRAME_STAGES, Stat
from bodymetry.estimation.run_files import GT_STAGE, Evaluation, RunLayout, RunResults
from bodymetry.estimation.view_selection import blank_unusable, usable_views
from bodymetry.fileio import load_npz
from bodymetry.log import Progress
from bodymetry.review.run_data import RunData, load_frame_arrays, load_run

#: Spread of the GT + Generative start around the true pose (τ m, θ rad, ν).
GT_START_STD = (0.01, 0.02, 0.3)

__all__ = ["GT_START_STD", "evaluate_persons", "evaluate_run"]


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
    data: RunData,
    layout: RunLayout,
    results: RunResults,
    states: dict[str, np.ndarray],
    workers: int | None,
    progress: Progress | None,
) -> dict[int, tuple[dict[str, float], list]]:
    """Per ok frame, the measurements and joints of the generative fit started at the
    true pose (:func:`_gt_generative`), on the frame's recorded silhouettes, in a pool.

    Raises
    ------
    InputError
        When a frame's recorded silhouettes are missing.
    """
    names, config = data.camera_names, results.config.fit
    jobs = []
    for record in results.ok_frames:
        arrays = load_frame_arrays(layout, record.frame)
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
    person: int | None = None,
) -> Evaluation:
    """Compute the Figure 3 numbers for one person of a run and write their
    ``evaluation.json`` (``RUN/evaluation.json``, or ``RUN/persons/K/`` for a run of
    several persons).

    Parameters
    ----------
    run : path
    workers : int, optional
    progress : callable, optional
    person : int, optional
        The run's person to evaluate (default: its first). A person capture told
        apart from others is scored against the studio person whose root their
        fits follow (:func:`bodymetry.capture.ground_truth.match_person`).

    Raises
    ------
    InputError
        When the run is missing or unreadable, it has no person ``person``, its
        session has no ground truth, no studio person matches, or no frame was
        fitted.
    """
    data = load_run(run)
    ident = data.results.person.id if person is None else person
    try:
        results = data.results.for_person(ident)
    except KeyError as exc:
        raise InputError(f"{data.layout.results}: {exc.args[0]}") from None
    several = data.results.several
    layout: RunLayout = data.layout.for_person(ident if several else None)
    session = load_session(data.results.session.path) if data.session_folder else None
    gt_root = session.ground_truth_path if session is not None else None
    if gt_root is None or not (gt_root / GROUND_TRUTH_STATES).is_file():
        raise InputError(
            f"{data.results.session.path}: the session has no ground truth to evaluate against"
        )
    index = 0
    if results.person.told_apart or results.config.person is not None:
        positions = {
            r.frame: r.estimates["generative"].state.tau[0] for r in results.frames if r.fitted
        }
        matched, distance = match_person(gt_root, positions)
        if matched is None:
            raise InputError(
                f"{data.layout.results}: person {ident} is matched to none of the studio's "
                f"people (nearest root {distance:.2f} m away on average, or two about as "
                "near): no truth to score them against"
            )
        index = matched
    gt_dir = person_folder(gt_root, index)
    truth = SubjectTruth.read(gt_dir)
    states = load_npz(gt_dir / GROUND_TRUTH_STATES)
    ok = results.ok_frames
    if not ok:
        raise InputError(f"{layout.results}: no frame of person {ident} was fitted")
    if data.cameras is None:
        raise InputError(f"{layout.calibration}: the run has no recorded cameras")
    gt_gen = _gt_generative_fits(data, layout, results, states, workers, progress)

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
    session = results.summary.get("session", {})
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
        frames_failed=len(results.frames) - len(ok),
        actual={key: truth.measurements[key] for key in CORE_MEASUREMENTS},
        table=table,
        mpjpe_mm={
            **{stage: mpjpe(stage) for stage in FRAME_STAGES},
            **({"session": mpjpe("session")} if session else {}),
            GT_STAGE: gt_mpjpe,
        },
        silhouette_iou_mean=float(np.mean([r.mean_iou for r in ok])),
        person=ident if several else None,
        truth_person=index,
    )
    evaluation.write(layout)
    return evaluation


def evaluate_persons(
    run: str | Path, workers: int | None = None, progress: Progress | None = None
) -> list[Evaluation]:
    """:func:`evaluate_run` for every person of the run, in id order."""
    ids = [p.id for p in load_run(run).results.persons]
    return [evaluate_run(run, workers, progress, person=ident) for ident in ids]
