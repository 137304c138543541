"""bodymetry's own thread limits: one BLAS thread per process, set at start-up.

The fit runs many small dense and sparse solves in each of several worker
processes. A threaded BLAS (OpenBLAS starts one thread per core) makes them
20-100x slower through oversubscription, and its results differ in the last
digits with the thread count, so a run must not depend on the shell it was
started from. Importing :mod:`bodymetry` calls :func:`limit_threads`:

- before NumPy is loaded, it sets the BLAS libraries' environment variables,
  which they read once when they load (and which every child process inherits:
  the process pool's workers and a local Dask cluster's);
- once NumPy is loaded (a user's script, a Dask worker that unpickles a task),
  it limits the loaded libraries through ``threadpoolctl``.

``BODYMETRY_BLAS_THREADS`` sets another count (e.g. for a single large solve
outside the pipeline); results are only reproducible at a fixed count.
"""

from __future__ import annotations

import os
import sys

__all__ = ["BLAS_ENV", "THREADS_ENV", "blas_threads", "blas_threads_in_use", "limit_threads"]

#: The variable that overrides the limit.
THREADS_ENV = "BODYMETRY_BLAS_THREADS"
#: What the BLAS libraries NumPy and SciPy may load read at load time.
BLAS_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def blas_threads() -> int:
    """The BLAS thread count bodymetry runs with (``$BODYMETRY_BLAS_THREADS``, default 1)."""
    value = os.environ.get(THREADS_ENV, "1")
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"${THREADS_ENV}: expected a whole number >= 1, got {value!r}")
    return n


def limit_threads() -> int:
    """Limit BLAS to :func:`blas_threads` threads in this process and its children.

    Returns
    -------
    int
        The limit.
    """
    n = blas_threads()
    for var in BLAS_ENV:
        os.environ[var] = str(n)
    if "numpy" in sys.modules:  # BLAS is loaded: the variables are read already
        from threadpoolctl import threadpool_limits

        threadpool_limits(n, user_api="blas")
    return n


def blas_threads_in_use() -> int:
    """The most threads any BLAS loaded in this process uses now (0: none loaded)."""
    from threadpoolctl import threadpool_info

    return max((p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"), default=0)
