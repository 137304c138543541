"""Where the steps of :mod:`bodymetry.pipeline` run: a local process pool, or Dask.

Both executors offer the same few operations to :func:`bodymetry.pipeline.run_session`,
which wires the steps once:

- ``submit(fn, *args)``: run a step; returns a future. Arguments may be futures
  of the same executor (a step's input is another step's output).
- ``submit_many(fn, args)``: the frame-grain steps (the fits), in parallel.
- ``shared(key, fn, *args)``: a step whose result sessions share (a rig's
  training): the first call with a key submits it, later calls get its future.
- ``item(future, i)``: the ``i``-th element of a list-valued step's result
  (the segmentation of a chunk of frames), as a future.
- ``frame_chunks(frames)`` and ``read_method``: the grain at which frames are
  segmented and how the videos are read (one sequential pass here; one frame
  a task, by seeking, on Dask).

:class:`LocalExecutor` runs the session-grain steps in this process and the
fits on a fork pool whose workers die with their parent (a killed
``bodymetry process`` leaves nothing fitting and writing behind).
:class:`DaskExecutor` submits every step to a Dask cluster; results stay on
the cluster until a step needs them.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing as mp
import operator
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures import as_completed as futures_as_completed
from typing import Any, Protocol

from bodymetry.frame_jobs import run_fit_job, run_serially
from bodymetry.threads import limit_threads

log = logging.getLogger(__name__)

__all__ = ["DaskExecutor", "Executor", "LocalExecutor"]


class Executor(Protocol):
    """What :func:`bodymetry.pipeline.run_session` needs of an executor."""

    read_method: str
    remote: bool

    def job_runner(self) -> Callable: ...

    def wait_warm(self) -> None: ...

    def submit(self, fn: Callable, *args: Any) -> Any: ...

    def submit_many(self, fn: Callable, args: Iterable[tuple]) -> list[Any]: ...

    def shared(self, key: str, fn: Callable, *args: Any) -> Any: ...

    def item(self, future: Any, index: int) -> Any: ...

    def frame_chunks(self, frames: Sequence[int]) -> list[tuple[int, ...]]: ...

    def as_completed(self, futures: Sequence[Any]) -> Iterator[Any]: ...

    def warm_up(self, fn: Callable, *args: Any) -> None: ...


def _done(value: Any = None, error: BaseException | None = None) -> Future:
    fut: Future = Future()
    if error is not None:
        fut.set_exception(error)
    else:
        fut.set_result(value)
    return fut


def _resolve(args: Iterable[Any]) -> list[Any]:
    """The arguments with every future (also inside a list or tuple) replaced by its result."""

    def one(a: Any) -> Any:
        if isinstance(a, Future):
            return a.result()
        if isinstance(a, list | tuple) and any(isinstance(x, Future) for x in a):
            return type(a)(one(x) for x in a)
        return a

    return [one(a) for a in args]


def die_with_parent(parent: int) -> None:
    """Pool worker initializer: exit when the parent process is gone; limit BLAS threads.

    A SIGKILLed ``bodymetry process`` cannot tear its pool down, and orphaned
    workers would keep fitting and writing. On Linux the kernel kills the worker
    when its parent dies (``PR_SET_PDEATHSIG``); everywhere, a watchdog thread
    checks the parent twice a second.
    """
    limit_threads()
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


class _SharedSteps:
    """What both executors do the same way, on top of their own ``submit``."""

    def __init__(self) -> None:
        self._shared: dict[str, Any] = {}
        self._lock = threading.Lock()

    def submit(self, fn: Callable, *args: Any) -> Any:
        raise NotImplementedError

    def shared(self, key: str, fn: Callable, *args: Any) -> Any:
        """The future of ``fn(*args)``, submitted by the first call with ``key`` only
        (thread-safe: batch's sessions ask from their threads)."""
        with self._lock:
            if key not in self._shared:
                self._shared[key] = self.submit(fn, *args)
            return self._shared[key]

    def item(self, future: Any, index: int) -> Any:
        """A future of ``future.result()[index]``."""
        return self.submit(operator.getitem, future, index)


class LocalExecutor(_SharedSteps):
    """This process for the session's steps, a fork pool of ``workers`` for the fits.

    Parameters
    ----------
    workers : int
        Worker processes of the pool (started on first use, shared by the
        first pass and the rescue: a worker keeps its loaded models and kernels).
    """

    read_method = "sequential"
    remote = False

    def __init__(self, workers: int) -> None:
        super().__init__()
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None
        self._warming: Future | None = None

    def __enter__(self) -> LocalExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def submit(self, fn: Callable, *args: Any) -> Future:
        try:
            return _done(fn(*_resolve(args)))
        except Exception as exc:  # held in the future, raised where its result is read
            return _done(error=exc)

    def submit_many(self, fn: Callable, args: Iterable[tuple]) -> list[Future]:
        jobs = [_resolve(a) for a in args]
        if not jobs:
            return []
        if self._pool is None:
            # Before anything else poses the body model: the workers inherit what it loaded.
            self.wait_warm()
            # fork: workers inherit the loaded modules (the spawn start method re-imports).
            self._pool = ProcessPoolExecutor(
                self.workers,
                mp_context=mp.get_context("fork"),
                initializer=die_with_parent,
                initargs=(os.getpid(),),
            )
        return [self._pool.submit(fn, *job) for job in jobs]

    def job_runner(self) -> Callable[[Sequence[Any]], list[Any]]:
        """Fits a round of the rescue's jobs on the pool, in their order."""

        def run(jobs: Sequence[Any]) -> list[Any]:
            return [f.result() for f in self.submit_many(run_fit_job, [(j,) for j in jobs])]

        return run

    def frame_chunks(self, frames: Sequence[int]) -> list[tuple[int, ...]]:
        # One sequential pass over the videos (decoding is the cost; a thread prefetches).
        return [tuple(frames)] if frames else []

    def as_completed(self, futures: Sequence[Future]) -> Iterator[Future]:
        return futures_as_completed(futures)

    def warm_up(self, fn: Callable, *args: Any) -> None:
        """Run ``fn`` on a thread while the session is segmented (it loads the fit's
        models and kernels, which the forked workers then inherit)."""
        loader = ThreadPoolExecutor(1, thread_name_prefix="warm-up")
        self._warming = loader.submit(fn, *args)
        loader.shutdown(wait=False)

    def wait_warm(self) -> None:
        """Wait for :meth:`warm_up` (before the main thread poses the body model)."""
        if self._warming is not None:
            self._warming.result()


class DaskExecutor(_SharedSteps):
    """Every step a task on the Dask cluster of ``client``.

    Task keys carry a token unique to this executor, so a long-lived scheduler
    never hands back an earlier call's results. Safe to share between the
    threads of :func:`bodymetry.batch.run_batch` (one per session).
    """

    read_method = "seek"
    remote = True

    def __init__(self, client: Any) -> None:
        super().__init__()
        self.client = client
        self.token = uuid.uuid4().hex[:8]

    def submit(self, fn: Callable, *args: Any) -> Any:
        key = f"{fn.__name__}-{uuid.uuid4().hex[:8]}-{self.token}"
        return self.client.submit(fn, *args, key=key, pure=False)

    def submit_many(self, fn: Callable, args: Iterable[tuple]) -> list[Any]:
        return [self.submit(fn, *a) for a in args]

    def job_runner(self) -> Callable[[Sequence[Any]], list[Any]]:
        """The rescue's rounds, one job after another inside its task (the few frames
        below the gate; the task cannot submit to the cluster)."""
        return run_serially

    def frame_chunks(self, frames: Sequence[int]) -> list[tuple[int, ...]]:
        # A frame a task, read by seeking: the cluster balances them.
        return [(f,) for f in frames]

    def as_completed(self, futures: Sequence[Any]) -> Iterator[Any]:
        from distributed import as_completed

        return iter(as_completed(list(futures)))

    def warm_up(self, fn: Callable, *args: Any) -> None:
        """Nothing: a Dask worker loads the models with its first fit."""

    def wait_warm(self) -> None:
        """Nothing to wait for."""
