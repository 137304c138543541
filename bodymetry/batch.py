"""``bodymetry batch``: many sessions on Dask, from one laptop to a cluster.

Every session runs the step graph of ``bodymetry process``
(:func:`bodymetry.pipeline.run_session`) on one
:class:`~bodymetry.executors.DaskExecutor`: the same steps, as Dask tasks at the
grain that balances (docs/batch.md): per session the up-front check, the plan
and the background models; per distinct rig the discriminative models, trained
once (a task keyed by the rig's cache key, so sessions on one rig share it) into
the model cache that every worker reads; per kept frame its silhouettes (that
frame only, read by seeking, segmented once) and its fit, written into the
session's run folder; per session the rescue, the summary (``results.json``) and
the review outputs. Then ``study.json`` and the cohort table and report
(``cohort.csv``, ``cohort.html``).

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
import os
import socket
import threading
import time
import urllib.parse
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import as_completed as futures_completed
from dataclasses import dataclass, field
from pathlib import Path

import dask
from distributed import Client, LocalCluster

from bodymetry.capture.session import SESSION_FILE
from bodymetry.errors import InputError
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RigEntry, RunResults, StudyResults, StudySession
from bodymetry.executors import DaskExecutor
from bodymetry.fileio import read_text_limited
from bodymetry.log import Progress
from bodymetry.pipeline import SessionRun, run_session
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

#: Sessions in flight at once (each a thread here that waits on its steps).
MAX_SESSION_THREADS = 32
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


# --- the cluster ----------------------------------------------------------------------------------
def dashboard_link(client: Client) -> str | None:
    """The cluster's dashboard address, or None when it runs without one."""
    services = client.scheduler_info().get("services", {})
    return client.dashboard_link if "dashboard" in services else None


#: Dask's scheduler port when an address names none.
DEFAULT_SCHEDULER_PORT = 8786


def scheduler_unreachable(address: str, timeout: float = 5.0) -> str | None:
    """Why nothing answers at a scheduler's TCP address (None: something does, or the
    address is not TCP, e.g. ``inproc://``, and only Dask can tell).

    Parameters
    ----------
    address : str
        ``tcp://host:port``, ``tls://host:port`` or ``host:port``.
    timeout : float
        Seconds to wait for the connection.
    """
    parts = urllib.parse.urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme not in ("tcp", "tls") or not parts.hostname:
        return None
    try:
        port = parts.port or DEFAULT_SCHEDULER_PORT
    except ValueError as exc:  # a port that is not a number
        return str(exc)
    try:
        with socket.create_connection((parts.hostname, port), timeout=timeout):
            return None
    except OSError as exc:
        return exc.strerror or str(exc)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A Dask client: of the cluster at ``scheduler``, or of a local cluster of ``workers``.

    The local cluster has one single-threaded worker process per core (the
    fit is CPU-bound numpy), listens on localhost only, and its workers may
    start processes of their own (training renders in parallel).
    """
    if scheduler:
        # A refused port or an unknown host fails at once here; Dask's client would
        # retry until its timeout (20 s, for a busy cluster's slow answer).
        unreachable = scheduler_unreachable(scheduler)
        if unreachable:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({unreachable})")
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

    Each session runs the step graph of ``bodymetry process``
    (:func:`bodymetry.pipeline.run_session`) on one shared ``DaskExecutor``, all
    at once (a thread each here, their steps on the cluster).

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
    tally = _Tally(names, progress)
    executor = DaskExecutor(client)

    def one(name: str, path: Path) -> SessionRun:
        return run_session(
            path, study / name, config, executor, tally.frames(name), restart=restart
        )

    runs: dict[str, SessionRun] = {}
    entries: dict[str, StudySession] = {}
    tally.report()
    # A thread per session waits on its steps; the cluster does the work.
    with ThreadPoolExecutor(min(len(names), MAX_SESSION_THREADS) or 1) as threads:
        futures = {
            threads.submit(one, name, path): (name, path)
            for name, path in zip(names, sessions, strict=True)
        }
        for fut in futures_completed(futures):
            name, path = futures[fut]
            try:
                run = fut.result()
            except Exception as exc:  # a session's failure is its own: the others go on
                entries[name] = StudySession(name, str(path), "failed", _reason(exc))
                log.error("%s: %s", name, entries[name].reason)
            else:
                runs[name] = run
                entries[name] = StudySession(name, str(path), "done", "", run.rig)
                log.info("%s: %s", name, "done" if run.ran else "already finished")
            tally.finished(name)
    study_results = StudyResults(
        sessions=tuple(entries[n] for n in names),
        rigs=_rigs(names, runs),
        timing_seconds={"total": round(time.perf_counter() - t0, 1)},
    )
    study_results.write(study / STUDY_FILE)
    write_cohort(study)
    return BatchResult(study_results, {n: r.results for n, r in runs.items() if r.ran})


def _rigs(names: Sequence[str], runs: dict[str, SessionRun]) -> dict[str, RigEntry]:
    """Per rig of the finished sessions: its sessions, and whether this call trained it."""
    rigs: dict[str, RigEntry] = {}
    for rig in dict.fromkeys(r.rig for r in runs.values()):
        on_rig = [n for n in names if n in runs and runs[n].rig == rig]
        models = next((runs[n].models for n in on_rig if runs[n].models is not None), None)
        rigs[rig] = RigEntry(
            tuple(sorted(on_rig)),
            None if models is None else not models.reused,
            None if models is None else round(models.seconds, 1),
        )
    return rigs


class _Tally:
    """The study's progress: sessions finished, and frames summed over the sessions."""

    def __init__(self, names: Sequence[str], progress: Progress | None) -> None:
        self.progress = progress
        self.total = len(names)
        self.done_sessions = 0
        self.frame_counts: dict[str, tuple[int, int]] = {}
        self.lock = threading.Lock()

    def report(self) -> None:
        if self.progress is None:
            return
        with self.lock:
            self.progress("sessions", self.done_sessions, self.total)
            done = sum(d for d, _ in self.frame_counts.values())
            total = sum(t for _, t in self.frame_counts.values())
            if total:
                self.progress("frames", done, total)

    def frames(self, name: str) -> Progress:
        """The progress callback of one session (its ``frames``; other labels are dropped)."""

        def update(label: str, done: int, total: int) -> None:
            if label == "frames":
                with self.lock:
                    self.frame_counts[name] = (done, total)
                self.report()

        return update

    def finished(self, name: str) -> None:
        with self.lock:
            self.done_sessions += 1
        self.report()
