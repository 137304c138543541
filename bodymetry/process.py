"""``bodymetry process``: from a session folder to a run folder of measurements.

The application's workflow, stage by stage: the cameras (:mod:`bodymetry.cameras`),
the discriminative models of the rig (trained once, cached), the silhouettes
of every kept frame (capture), the per-frame fit in worker processes
(:func:`bodymetry.estimation.fit.fit_frame`), the summary and the review
outputs. Every finished frame is written to the run folder atomically, its
arrays and mesh before its record (``frames/FFFFFF.json``, which marks it
done), so a killed run resumes from the frames it finished. The layout and
schema of the run folder are :mod:`bodymetry.estimation.records`
(docs/outputs.md).

Training and the fit work at each camera's working resolution
(:mod:`bodymetry.estimation.resolution`, chosen from the calibration by
:func:`prepare_run`): the models are trained with the working cameras, and
the observed silhouettes, segmented at the cameras' resolution, are
downscaled to it (:func:`fit_job`) before the fit and the record.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import save_calibration
from bodymetry.cameras import resolve_cameras
from bodymetry.capture.landmarks import (
    LandmarkConfig,
    principal_point_offsets,
    triangulate_landmarks,
)
from bodymetry.capture.segmentation import segment_session
from bodymetry.capture.session import Session, load_session
from bodymetry.config import ProcessConfig
from bodymetry.errors import InputError
from bodymetry.estimation.fit import (
    MIN_PIXELS,
    FrameFit,
    preload,
    session_gate,
    shared_body_model,
)
from bodymetry.estimation.outline_check import check_outline
from bodymetry.estimation.records import (
    FrameArrays,
    FrameRecord,
    RunLayout,
    RunResults,
    SessionInfo,
    SessionShape,
    summarize,
)
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.session_shape import fit_session_shape, session_frame
from bodymetry.estimation.training import cached_models_path, load_or_train
from bodymetry.fileio import write_json_atomic
from bodymetry.frame_jobs import (
    FitJob,
    fit_job,
    read_done_frames,
    rescue_poor_frames,
    run_fit_job,
    write_frame,
)
from bodymetry.log import Progress
from bodymetry.preflight import check_session
from bodymetry.review.build import build_review
from bodymetry.run_folder import prepare_run_folder

log = logging.getLogger(__name__)

__all__ = [
    "PreparedRun",
    "RigModels",
    "check_calibration",
    "finish_run",
    "prepare_run",
    "process_session",
    "rig_models",
    "session_stage",
]


class _Workers:
    """The run's process pool for frame fits, started on first use and shared by the
    first pass and the rescue (a worker keeps its loaded models and kernels)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> _Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)

    def _submit(self, jobs: Sequence[FitJob]) -> list[Future]:
        if self.pool is None:
            # fork: workers inherit the loaded modules (the spawn start method re-imports).
            self.pool = ProcessPoolExecutor(
                self.n,
                mp_context=mp.get_context("fork"),
                initializer=_die_with_parent,
                initargs=(os.getpid(),),
            )
        return [self.pool.submit(run_fit_job, job) for job in jobs]

    def as_completed(self, jobs: Sequence[FitJob]) -> Iterator[FrameFit]:
        """Each job's fit as it finishes."""
        if jobs:
            for future in as_completed(self._submit(jobs)):
                yield future.result()

    def run(self, jobs: Sequence[FitJob]) -> list[FrameFit]:
        """The jobs' fits, in their order."""
        return [future.result() for future in self._submit(jobs)] if jobs else []


def _die_with_parent(parent: int) -> None:
    """Pool worker initializer: exit when the parent process is gone.

    A SIGKILLed ``bodymetry process`` cannot tear its pool down, and orphaned
    workers would keep fitting and writing. On Linux the kernel kills the worker
    when its parent dies (``PR_SET_PDEATHSIG``); everywhere, a watchdog thread
    checks the parent twice a second.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            pr_set_pdeathsig = 1
            libc.prctl(pr_set_pdeathsig, signal.SIGKILL)
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def camera_warnings(camera_frames: dict[str, int], n_kept: int) -> list[str]:
    """Warnings for cameras that saw no usable silhouette in any kept frame."""
    return [
        f"camera {name!r} saw no person in any of the {n_kept} kept frames (covered, black "
        "or pointing away?); it contributed nothing to the measurements"
        for name, n in camera_frames.items()
        if n == 0 and n_kept > 0
    ]


def _ground_truth(session: Session) -> dict | None:
    gt = session.ground_truth_path
    if gt is None or not (gt / "subject.json").is_file():
        return None
    return json.loads((gt / "subject.json").read_text())


@dataclass(frozen=True)
class PreparedRun:
    """A session checked, its run folder ready and its cameras resolved.

    Attributes
    ----------
    session : Session
    layout : RunLayout
    cameras : list of Camera
        The working cameras (session order): the calibration's cameras at
        their working resolution, what training and the fit use.
    calibration_source : str
    resolution : WorkingResolution
        Each camera's working resolution (recorded in ``results.json``).
    calibrated : list of Camera
        The calibration's cameras at the videos' resolution: what capture
        uses (its silhouettes and landmarks are at that resolution).
    warnings : tuple of str
        The up-front check's warnings (and the calibration check's).
    landmark_config : LandmarkConfig or None
        Set when :func:`check_calibration` shifted cameras: the subject's
        landmarks are then triangulated again through them.
    """

    session: Session
    layout: RunLayout
    cameras: list[Camera]
    calibration_source: str
    resolution: WorkingResolution
    calibrated: list[Camera]
    warnings: tuple[str, ...] = ()
    landmark_config: LandmarkConfig | None = None

    def landmarks(
        self, views: Sequence[np.ndarray | None], recorded: np.ndarray | None
    ) -> np.ndarray | None:
        """A frame's 3D landmarks through the final cameras: ``recorded`` (capture's)
        unless the calibration check shifted cameras, then triangulated again."""
        if self.landmark_config is None or not views:
            return recorded
        if sum(v is not None for v in views) < 2:
            return None
        return triangulate_landmarks(self.calibrated, views, self.landmark_config)


def prepare_run(
    session_path: str | Path,
    out: str | Path,
    config: ProcessConfig,
    progress: Progress | None = None,
    *,
    restart: bool = False,
) -> PreparedRun:
    """Check the session, create or resume the run folder, resolve the cameras and
    choose their working resolution (``config.working_person_px``).

    Every problem with the inputs and the output folder is listed before any
    long work, and before the run folder is created (a bad session leaves
    nothing behind).

    Raises
    ------
    InputError
        Listing every problem found.
    """
    report = check_session(session_path, Path(out))
    report.raise_if_failed()
    for warning in report.warnings:
        log.warning("%s", warning)
    session = load_session(session_path)
    if config.frame_step is not None and config.frame_step != session.frame_step:
        log.info(
            "%s: fitting every %d. frame (session.yaml says %d)",
            session.folder,
            config.frame_step,
            session.frame_step,
        )
        session = replace(session, frame_step=config.frame_step)
    layout = RunLayout(Path(out))
    prepare_run_folder(layout.folder, session, config, restart=restart)
    layout.frames_dir.mkdir(parents=True, exist_ok=True)
    resolved = resolve_cameras(session, layout.folder, progress)
    resolution = WorkingResolution.choose(resolved.cameras, config.working_person_px)
    return PreparedRun(
        session,
        layout,
        resolution.apply(resolved.cameras),
        resolved.source,
        resolution,
        list(resolved.cameras),
        tuple(str(w) for w in report.warnings),
    )


def check_calibration(
    prepared: PreparedRun, view_landmarks: Sequence[Sequence], config: ProcessConfig
) -> PreparedRun:
    """Check the cameras against the subject's landmarks in all kept frames; shift the
    principal point of a camera that is systematically off
    (:func:`bodymetry.capture.landmarks.principal_point_offsets`).

    A shifted camera is written to the run's ``calibration.yaml`` (the session's
    file is never modified) and named in a warning (``results.json``). Without
    landmarks (no segmenter) or with ``capture.landmarks.refine_calibration``
    off, the run keeps the calibration as given.
    """
    cfg = config.capture.landmarks
    frames = [v for v in view_landmarks if v]
    if not cfg.refine_calibration or not frames:
        return prepared
    cameras, offsets = principal_point_offsets(prepared.calibrated, frames, cfg)
    for offset in offsets:
        log.info("%s", offset.describe())
    applied = [o for o in offsets if o.applied]
    if not applied:
        return prepared
    warnings = tuple(
        f"{o.describe()}: the calibration does not fit this video, so its principal point "
        "was shifted by that offset for this run (RUN/calibration.yaml; "
        "--set capture.landmarks.refine_calibration=false keeps the calibration as given)"
        for o in applied
    )
    for text in warnings:
        log.warning("%s", text)
    save_calibration(prepared.layout.calibration, CameraGroup(cameras))
    return replace(
        prepared,
        calibrated=cameras,
        cameras=prepared.resolution.apply(cameras),
        warnings=(*prepared.warnings, *warnings),
        landmark_config=cfg,
    )


@dataclass(frozen=True)
class RigModels:
    """The discriminative models of a rig, in the cache.

    Attributes
    ----------
    key : str
        :func:`bodymetry.estimation.training.rig_key`.
    path : Path
    reused : bool
        Found in the cache (not trained by this call).
    seconds : float
    """

    key: str
    path: Path
    reused: bool
    seconds: float


def rig_models(
    cameras: list[Camera],
    config: ProcessConfig,
    progress: Progress | None = None,
    workers: int | None = None,
) -> RigModels:
    """Load the rig's models from the cache, training them first if needed.

    ``cameras`` are the working cameras (:attr:`PreparedRun.cameras`): the
    training set is rendered at their sizes, and the cache key is theirs.
    """
    t0 = time.perf_counter()
    models, reused = load_or_train(
        cameras,
        config.training,
        config.cache_dir,
        workers=workers if workers is not None else config.workers,
        progress=(lambda label, d, t: progress(f"training: {label}", d, t)) if progress else None,
    )
    path = cached_models_path(models.key, config.cache_dir)
    return RigModels(models.key, path, reused, time.perf_counter() - t0)


def session_stage(
    prepared: PreparedRun,
    config: ProcessConfig,
    records: Sequence[FrameRecord],
    progress: Progress | None = None,
) -> tuple[SessionShape | None, list[FrameRecord]]:
    """One shape for the session (:mod:`bodymetry.estimation.session_shape`).

    Reads the accepted frames' silhouettes back from the run folder (the
    ``frames/FFFFFF.npz`` written with their records), so it runs the same
    after a resumed run and as ``batch``'s reduce task. The frame records on
    disk are left as they are: the ``session`` estimates live in
    ``results.json``.

    Returns
    -------
    SessionShape or None
        None when ``config.session_shape.enabled`` is off.
    list of FrameRecord
        ``records`` with each accepted frame's ``session`` estimate added when
        the stage was accepted (unchanged otherwise).
    """
    if not config.session_shape.enabled:
        return None, list(records)
    ok = [r for r in records if r.ok]
    log.info("%s: session shape from %d accepted frames", prepared.session.folder, len(ok))
    try:
        frames = [
            session_frame(
                r, FrameArrays.load(prepared.layout.frame_arrays(r.frame)), prepared.cameras
            )
            for r in ok
        ]
        fit = fit_session_shape(
            shared_body_model(),
            prepared.cameras,
            frames,
            config.fit.refinement,
            config.session_shape,
            config.fit.density,
            progress,
        )
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        log.warning("%s: the session shape failed: %s", prepared.session.folder, exc)
        return SessionShape(status=f"failed: {exc}", frames=tuple(r.frame for r in ok)), list(
            records
        )
    if not fit.summary.ok:
        log.warning("%s: session shape %s", prepared.session.folder, fit.summary.status)
    # The outline check at the states the summary reports: the shared shape
    # when accepted, else each frame's own fit.
    checked = [
        (f.masks, fit.estimates[f.frame].vector() if f.frame in fit.estimates else f.start)
        for f in frames
    ]
    outline = check_outline(
        shared_body_model(),
        prepared.cameras,
        checked,
        config.fit.refinement,
        alignments=[fit.alignments.get(f.frame) for f in frames],
    )
    out = [
        replace(r, estimates={**r.estimates, "session": fit.estimates[r.frame]})
        if r.frame in fit.estimates
        else r
        for r in records
    ]
    return replace(fit.summary, outline=outline), out


def finish_run(
    prepared: PreparedRun,
    config: ProcessConfig,
    models: RigModels,
    records: dict[int, FrameRecord],
    timing: dict[str, float],
    progress: Progress | None = None,
) -> RunResults:
    """Summarize the recorded frames, fit the session's one shape
    (:func:`session_stage`), write ``results.json``, then the review outputs.

    A failure of the review is logged, never raised: the results are safe on disk.
    """
    session = prepared.session
    gate, gated = session_gate([records[f] for f in sorted(records)], config.fit)
    t0 = time.perf_counter()
    shape, gated = session_stage(prepared, config, gated, progress)
    if shape is not None:
        timing = {**timing, "session_shape": time.perf_counter() - t0}
    ordered = tuple(gated)
    if gate.threshold < gate.min_iou:
        log.info(
            "%s: quality gate %.2f (the session's good frames score %.2f; min_iou %.2f)",
            session.folder,
            gate.threshold,
            gate.reference,
            gate.min_iou,
        )
    camera_frames = {
        name: sum(r.person_pixels.get(name, 0) >= MIN_PIXELS for r in ordered)
        for name in session.camera_names
    }
    warnings = camera_warnings(camera_frames, len(ordered))
    if not any(r.ok for r in ordered):
        warnings.append(f"no frame of the {len(ordered)} kept frames was measured")
    if shape is not None and shape.outline is not None:
        warnings.extend(shape.outline.warnings)
    for text in warnings:
        log.warning("%s: %s", session.folder, text)
    results = RunResults(
        session=SessionInfo(
            path=str(session.folder.resolve()),
            name=session.name,
            cameras=tuple(session.camera_names),
            fps=session.fps,
            frame_step=session.frame_step,
        ),
        config={**config.to_json(), "models": models.key, "models_reused": models.reused},
        frames=ordered,
        summary=summarize(ordered, shape),
        timing_seconds={k: round(v, 1) for k, v in timing.items()},
        calibration_source=prepared.calibration_source,
        ground_truth=_ground_truth(session),
        camera_frames=camera_frames,
        warnings=(*prepared.warnings, *warnings),
        working_resolution=prepared.resolution,
        quality_gate=gate.to_json(),
        session_shape=shape,
    )
    write_json_atomic(prepared.layout.results, results.to_json())
    if config.review:
        try:
            build_review(prepared.layout.folder, pdf=config.pdf, progress=progress)
        except Exception:  # results.json is written; the review is extra
            log.exception("%s: building the review outputs failed", prepared.layout.folder)
    return results


def process_session(
    session_path: str | Path,
    out: str | Path,
    config: ProcessConfig | None = None,
    progress: Progress | None = None,
    *,
    restart: bool = False,
) -> RunResults:
    """Run the whole pipeline on a session; writes ``out/results.json`` and returns it.

    Parameters
    ----------
    session_path : path
        A session folder (docs/session-format.md).
    out : path
        The run folder; frames already recorded there are not fitted again.
    config : ProcessConfig, optional
    progress : callable, optional
        ``progress(label, done, total)`` for each stage.
    restart : bool
        Replace a run of another session or other settings in ``out``
        (:func:`bodymetry.run_folder.prepare_run_folder`); without it that is an error.

    Raises
    ------
    InputError
        For bad inputs, before any long work (:func:`prepare_run`).
    """
    config = config or ProcessConfig()
    t0 = time.perf_counter()
    prepared = prepare_run(session_path, out, config, progress, restart=restart)
    layout = prepared.layout
    done = read_done_frames(layout)
    # The fit's models and kernels load on the idle core while this thread cuts the
    # silhouettes (the forked workers inherit them; the session stage needs them too).
    loader = ThreadPoolExecutor(1, thread_name_prefix="preload")
    loading = loader.submit(preload, prepared.cameras, config.fit.refinement)
    loader.shutdown(wait=False)
    pending: list[tuple[FitJob, tuple]] = []
    view_landmarks = []
    n_kept = 0
    for sil in segment_session(
        prepared.session, config=config.capture, cameras=prepared.calibrated, keep_images=False
    ):
        n_kept += 1
        view_landmarks.append(sil.view_landmarks)
        if sil.frame not in done:
            # Held at the working resolution (a long session's full-size masks are large);
            # the cameras and models are set once the calibration check and training are done.
            job = fit_job(sil, prepared.cameras, prepared.resolution, Path(), config.fit)
            pending.append((job, sil.view_landmarks))
    loading.result()  # before anything else poses the body model (training does)
    t_sil = time.perf_counter() - t0
    prepared = check_calibration(prepared, view_landmarks, config)
    t1 = time.perf_counter()
    models = rig_models(prepared.cameras, config, progress)
    t_train = time.perf_counter() - t1
    jobs = [
        replace(
            job,
            cameras=prepared.cameras,
            models_path=models.path,
            landmarks=prepared.landmarks(views, job.landmarks),
        )
        for job, views in pending
    ]
    if progress:
        progress("frames", len(done), n_kept)
    t2 = time.perf_counter()
    with _Workers(config.workers_or_cores) as workers:
        for fit in workers.as_completed(jobs):
            # As written (rounded): a fresh run and a resumed one summarize the same.
            done[fit.record.frame] = write_frame(layout, fit)
            if progress:
                progress("frames", len(done), n_kept)
        # The rescue's rounds on the same workers (their models and kernels loaded).
        done = rescue_poor_frames(
            layout,
            done,
            prepared.cameras,
            models.path,
            config.fit,
            config.fit.rescue_neighbours,
            progress,
            workers.run,
        )
    timing = {
        "training": t_train,
        "silhouettes": t_sil,
        "fitting": time.perf_counter() - t2,
        "total": time.perf_counter() - t0,
    }
    return finish_run(prepared, config, models, done, timing, progress)
