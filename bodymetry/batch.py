"""``bodymetry batch``: many sessions on Dask, from one laptop to a cluster.

The study's work is a Dask task graph at the grain that balances (docs/batch.md):

- per session: the up-front check, the run folder and the cameras
  (:func:`bodymetry.process.prepare_run`), then which frames are still to do;
- per distinct rig: the discriminative models, trained once (a task keyed by
  the rig's cache key, so sessions on one rig share it) into the model cache
  that every worker reads;
- per session: the background models (once, kept on the cluster);
- per kept frame: its silhouettes (that frame only, read by seeking) and its
  fit, written into the session's run folder exactly as ``bodymetry process``
  writes it;
- per session: the summary (``results.json``) and the review outputs;
- then ``study.json`` and the cohort table and report (``cohort.csv``,
  ``cohort.html``).

Each session's results land in ``STUDY/<session>/`` exactly as
``bodymetry process --out STUDY/<session>`` would write them. A rerun of the
same command skips finished frames and sessions; a session that fails (bad
input) is reported with its one-line reason and does not stop the others.
The workers need the session folders and the model cache at the same paths
(a shared filesystem on a cluster).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import dask
from distributed import Client, Future, LocalCluster, as_completed

from bodymetry.capture.background import BackgroundModel
from bodymetry.capture.ingest import SyncReport, check_sync
from bodymetry.capture.segmentation import background_models, segment_session
from bodymetry.capture.session import SESSION_FILE
from bodymetry.config import ProcessConfig
from bodymetry.errors import InputError
from bodymetry.estimation.records import (
    FrameRecord,
    RunResults,
    StudyResults,
    StudySession,
)
from bodymetry.estimation.training import rig_key
from bodymetry.fileio import read_text_limited, write_json_atomic
from bodymetry.frame_jobs import (
    fit_job,
    read_done_frames,
    rescue_poor_frames,
    run_fit_job,
    write_frame,
)
from bodymetry.log import Progress
from bodymetry.process import (
    PreparedRun,
    RigModels,
    check_calibration,
    finish_run,
    prepare_run,
    rig_models,
)
from bodymetry.review.cohort import write_cohort

log = logging.getLogger(__name__)

__all__ = [
    "BatchResult",
    "dashboard_link",
    "dask_client",
    "find_sessions",
    "run_batch",
    "run_names",
]

#: A list of sessions given as a file is read whole; it is small.
SESSION_LIST_MAX_BYTES = 1 << 20
STUDY_FILE = "study.json"


# --- which sessions -----------------------------------------------------------------------------
def find_sessions(sources: Sequence[str | Path]) -> list[Path]:
    """Session folders from command-line arguments, in order, without repeats.

    Parameters
    ----------
    sources : sequence of path
        Each a session folder (holding ``session.yaml``), a ``session.yaml``, a
        folder of session folders, or a text file listing any of these (one per
        line; blank lines and ``#`` comments skipped; relative paths are
        relative to the file's folder).

    Raises
    ------
    InputError
        For a path that does not exist, a folder holding no session, or an empty result.
    """
    found: list[Path] = []

    def add(path: Path, where: str) -> None:
        if path.is_file() and path.name == SESSION_FILE:
            path = path.parent
        if path.is_dir() and (path / SESSION_FILE).is_file():
            found.append(path.resolve())
        elif path.is_dir():
            subs = sorted(p for p in path.iterdir() if (p / SESSION_FILE).is_file())
            if not subs:
                raise InputError(f"{where}{path}: no session folder (with {SESSION_FILE}) in it")
            found.extend(p.resolve() for p in subs)
        elif path.is_file():
            text = read_text_limited(path, SESSION_LIST_MAX_BYTES, "list of sessions")
            for n, line in enumerate(text.splitlines(), 1):
                entry = line.split("#", 1)[0].strip()
                if entry:
                    target = Path(entry).expanduser()
                    add(target if target.is_absolute() else path.parent / target, f"{path}:{n}: ")
        else:
            raise InputError(f"{where}{path}: no such session folder or list of sessions")

    for source in sources:
        add(Path(source), "")
    unique = list(dict.fromkeys(found))
    if not unique:
        raise InputError("no session given")
    return unique


def run_names(sessions: Sequence[Path]) -> list[str]:
    """A unique run-folder name per session: its folder name, numbered when repeated."""
    names: list[str] = []
    seen: dict[str, int] = {}
    for path in sessions:
        base = path.name
        seen[base] = seen.get(base, 0) + 1
        names.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return names


# --- the tasks (module level: workers import them by name) ------------------------------------
@dataclass(frozen=True)
class SessionPlan:
    """What is left to do in a session's run folder.

    Attributes
    ----------
    report : SyncReport
        The session's videos and kept frames (probed once, reused by its tasks).
    done : dict of int to FrameRecord
        Frames already recorded whole.
    finished : bool
        ``results.json`` holds every kept frame and the review is written: nothing to do.
    """

    report: SyncReport
    done: dict[int, FrameRecord]
    finished: bool

    @property
    def kept(self) -> tuple[int, ...]:
        """The session's kept frames."""
        return tuple(int(f) for f in self.report.kept)

    @property
    def pending(self) -> list[int]:
        return [f for f in self.kept if f not in self.done]


def _prepare_task(
    session_path: Path, out: Path, config: ProcessConfig, restart: bool
) -> PreparedRun:
    prepared = prepare_run(session_path, out, config, restart=restart)
    if not (config.capture.landmarks.refine_calibration and config.capture.uses_segmenter):
        return prepared
    # The calibration check needs every kept frame's landmarks before any frame is
    # fitted (as in `process`); the frame tasks segment their frame again.
    views = [
        sil.view_landmarks
        for sil in segment_session(
            prepared.session, config=config.capture, cameras=prepared.calibrated, keep_images=False
        )
    ]
    return check_calibration(prepared, views, config)


def _train_task(prepared: PreparedRun, config: ProcessConfig) -> RigModels:
    # A worker of a cluster started with `dask worker` is a daemon process, which
    # may not start processes: it trains in its own process (a local cluster's
    # workers are not daemons and render the training set in parallel).
    workers = 1 if mp.current_process().daemon else None
    return rig_models(prepared.cameras, config, workers=workers)


def _plan_task(prepared: PreparedRun, config: ProcessConfig) -> SessionPlan:
    report = check_sync(prepared.session)
    kept = {int(f) for f in report.kept}
    layout = prepared.layout
    done = read_done_frames(layout)
    finished = False
    if layout.results.is_file() and set(done) == kept:
        try:
            recorded = RunResults.read(layout.results)
            finished = {r.frame for r in recorded.frames} == kept and (
                not config.review or all(p.is_file() for p in layout.review_files)
            )
        except InputError as exc:
            log.warning("%s; summarizing the run again", exc)
    return SessionPlan(report, done, finished)


def _background_task(
    prepared: PreparedRun, plan: SessionPlan, config: ProcessConfig
) -> list[BackgroundModel | None]:
    median = not config.capture.uses_segmenter
    return list(background_models(prepared.session, plan.report, method="seek", median=median))


def _frame_task(
    prepared: PreparedRun,
    plan: SessionPlan,
    bg: list[BackgroundModel | None],
    models: RigModels,
    frame: int,
    config: ProcessConfig,
) -> FrameRecord:
    # One frame, read by seeking: the silhouettes never travel between machines.
    (sil,) = segment_session(
        prepared.session,
        config=config.capture,
        cameras=prepared.calibrated,
        report=plan.report,
        models=bg,
        frames=[frame],
        read_method="seek",
        keep_images=False,
    )
    fit = run_fit_job(fit_job(sil, prepared.cameras, prepared.resolution, models.path, config.fit))
    return write_frame(prepared.layout, fit)


def _finish_task(
    prepared: PreparedRun,
    config: ProcessConfig,
    models: RigModels,
    plan: SessionPlan,
    *records: FrameRecord,
) -> RunResults:
    done = {**plan.done, **{r.frame: r for r in records}}
    # The few frames the gate leaves out are fitted again here, one after another.
    done = rescue_poor_frames(
        prepared.layout,
        done,
        prepared.cameras,
        models.path,
        config.fit,
        config.fit.rescue_neighbours,
    )
    # Frames ran on many workers at once: the session's wall time is not its own,
    # so the timing says what the work cost (CPU seconds of this call's frames).
    timing = {
        "training": models.seconds,
        "fitting_cpu": sum(r.seconds.get("total", 0.0) for r in records),
    }
    return finish_run(prepared, config, models, done, timing)


# --- the cluster ----------------------------------------------------------------------------------
def dashboard_link(client: Client) -> str | None:
    """The cluster's dashboard address, or None when it runs without one."""
    services = client.scheduler_info().get("services", {})
    return client.dashboard_link if "dashboard" in services else None


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A Dask client: of the cluster at ``scheduler``, or of a local cluster of ``workers``.

    The local cluster has one single-threaded worker process per core (the
    fit is CPU-bound numpy), listens on localhost only, and its workers may
    start processes of their own (training renders in parallel).
    """
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from exc
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    # Any free port: the scheduler's HTTP server (the dashboard with bokeh installed, the
    # health and metrics routes without) would otherwise take 8787 and warn when another
    # cluster already has it.
    dashboard = ":0"
    with dask.config.set({"distributed.worker.daemon": False}):
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=dashboard,
        )
    with cluster, Client(cluster) as client:
        yield client


# --- the study ------------------------------------------------------------------------------------
@dataclass
class BatchResult:
    """What a batch did.

    Attributes
    ----------
    study : StudyResults
        Also in ``STUDY/study.json``.
    results : dict of str to RunResults
        Per session name, the sessions finished by this call.
    """

    study: StudyResults
    results: dict[str, RunResults] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Every session finished."""
        return all(s.status == "done" for s in self.study.sessions)


def _reason(exc: BaseException) -> str:
    text = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def run_batch(
    sessions: Sequence[Path],
    study: Path,
    config: ProcessConfig | None = None,
    client: Client | None = None,
    progress: Progress | None = None,
    *,
    restart: bool = False,
) -> BatchResult:
    """Process every session on the Dask cluster of ``client`` into ``study/<name>/``.

    Parameters
    ----------
    sessions : sequence of Path
        Session folders (:func:`find_sessions`).
    study : Path
        The study folder; each session's run folder is ``study/<name>`` (:func:`run_names`).
    config : ProcessConfig, optional
        For every session (``workers`` is ignored here: the cluster sets the parallelism).
    client : Client, optional
        Default: a local cluster (:func:`dask_client`).
    progress : callable, optional
        ``progress(label, done, total)`` for ``sessions`` and ``frames``.
    restart : bool
        As ``bodymetry process --restart``, for every session.

    Returns
    -------
    BatchResult
        Failed sessions are in it with their reason; nothing is raised for them.
    """
    config = config or ProcessConfig()
    if client is None:
        with dask_client() as local:
            return run_batch(sessions, study, config, local, progress, restart=restart)
    t0 = time.perf_counter()
    study = Path(study)
    study.mkdir(parents=True, exist_ok=True)
    names = run_names(sessions)
    entries: dict[str, StudySession] = {
        n: StudySession(n, str(p), "pending") for n, p in zip(names, sessions, strict=True)
    }
    rigs: dict[str, dict[str, Any]] = {}
    trains: dict[str, Future] = {}
    prepared_futs: dict[str, Future] = {}
    role: dict[str, tuple[str, str]] = {}  # future key -> (kind, session or rig)
    session_rig: dict[str, str] = {}
    started: dict[str, float] = {}
    results: dict[str, RunResults] = {}
    frames_total = frames_done = 0

    def report() -> None:
        if progress:
            finished = sum(e.status != "pending" for e in entries.values())
            progress("sessions", finished, len(entries))
            if frames_total:
                progress("frames", frames_done, frames_total)

    def mark(name: str, status: str, reason: str = "") -> None:
        entries[name] = StudySession(
            name, entries[name].session_path, status, reason, session_rig.get(name, "")
        )
        report()

    def fail(name: str, exc: BaseException) -> None:
        mark(name, "failed", _reason(exc))
        log.error("%s: %s", name, entries[name].reason)

    # Keys unique to this call: a long-lived scheduler must not hand back old results.
    token = uuid.uuid4().hex[:8]
    queue = as_completed()

    def submit(kind: str, owner: str, key: str, func: Callable, *args: Any) -> Future:
        """Submit a task whose completion the loop below handles as ``kind`` of ``owner``."""
        fut = client.submit(func, *args, key=f"{kind}-{key}-{token}", pure=False)
        role[fut.key] = (kind, owner)
        queue.add(fut)
        return fut

    for name, path in zip(names, sessions, strict=True):
        prepared_futs[name] = submit(
            "prepare", name, name, _prepare_task, path, study / name, config, restart
        )
    report()
    for fut in queue:
        kind, name = role[fut.key]
        if kind == "train":
            rig = name
            if fut.status == "error":
                rigs[rig]["error"] = _reason(fut.exception())
            else:
                trained = fut.result()
                rigs[rig].update(trained=not trained.reused, seconds=round(trained.seconds, 1))
            continue
        if entries[name].status == "failed":
            continue
        if fut.status == "error":
            if kind == "frame":
                frames_done += 1
                report()
            else:
                fail(name, fut.exception())
            continue
        if kind == "prepare":
            prepared: PreparedRun = fut.result()
            rig = rig_key(prepared.cameras, config.training)
            session_rig[name] = rig
            if rig not in trains:
                # Keyed by the rig: sessions on one rig share one training task.
                trains[rig] = submit("train", rig, rig, _train_task, fut, config)
                rigs[rig] = {"trained": None, "sessions": []}
            rigs[rig]["sessions"].append(name)
            submit("plan", name, name, _plan_task, fut, config)
        elif kind == "plan":
            plan: SessionPlan = fut.result()
            frames_total += len(plan.kept)
            frames_done += len(plan.done)
            if plan.finished:
                log.info("%s: already finished", name)
                mark(name, "done")
                continue
            prep = prepared_futs[name]
            train = trains[session_rig[name]]
            started[name] = time.perf_counter()
            frame_futs = []
            if plan.pending:
                # Kept on the cluster for the session's frame tasks (not tracked below).
                background = client.submit(
                    _background_task,
                    prep,
                    fut,
                    config,
                    key=f"background-{name}-{token}",
                    pure=False,
                )
                frame_futs = [
                    submit(
                        "frame",
                        name,
                        f"{name}-{frame}",
                        _frame_task,
                        prep,
                        fut,
                        background,
                        train,
                        frame,
                        config,
                    )
                    for frame in plan.pending
                ]
            submit("finish", name, name, _finish_task, prep, config, train, fut, *frame_futs)
            report()
        elif kind == "frame":
            frames_done += 1
            report()
        elif kind == "finish":
            results[name] = fut.result()
            log.info("%s: done in %.0f s", name, time.perf_counter() - started[name])
            mark(name, "done")
    for info in rigs.values():
        info["sessions"] = sorted(info["sessions"])
    study_results = StudyResults(
        sessions=tuple(entries[n] for n in names),
        rigs=rigs,
        timing_seconds={"total": round(time.perf_counter() - t0, 1)},
    )
    write_json_atomic(study / STUDY_FILE, study_results.to_json())
    write_cohort(study)
    return BatchResult(study_results, results)
