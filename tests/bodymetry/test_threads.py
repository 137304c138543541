"""bodymetry limits BLAS to one thread per process, whatever the shell says (threads.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from bodymetry.threads import THREADS_ENV, blas_threads

#: The variables a plain shell may or may not have; each check starts without them.
PLAIN = {
    k: v
    for k, v in os.environ.items()
    if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS", THREADS_ENV)
}
MANY_CORES = (os.cpu_count() or 1) > 1


def _run(code: str, **env: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
        env={**PLAIN, **env},
    )
    return out.stdout.strip()


@pytest.mark.skipif(not MANY_CORES, reason="one core: BLAS runs one thread anyway")
def test_numpy_alone_would_use_every_core():
    """The control: without bodymetry, OpenBLAS starts a thread per core here."""
    code = "import numpy, threadpoolctl\nprint(threadpoolctl.threadpool_info()[0]['num_threads'])"
    assert int(_run(code)) > 1


@pytest.mark.parametrize("numpy_first", [False, True])
def test_importing_bodymetry_limits_blas_to_one_thread(numpy_first):
    code = (
        ("import numpy\n" if numpy_first else "")
        + "import bodymetry\nfrom bodymetry.threads import blas_threads_in_use\n"
        + "import numpy\nprint(blas_threads_in_use())"
    )
    assert _run(code) == "1"


def test_the_process_pool_and_dask_workers_run_one_blas_thread():
    """In a fit worker of `process` and in a worker of a local Dask cluster (`batch`)."""
    code = """
import numpy
from bodymetry.batch import dask_client
from bodymetry.executors import DaskExecutor, LocalExecutor
from bodymetry.threads import blas_threads_in_use

with LocalExecutor(1) as local:
    (pool,) = local.submit_many(blas_threads_in_use, [()])
    print(pool.result())
with dask_client(workers=1) as client:
    print(DaskExecutor(client).submit(blas_threads_in_use).result())
"""
    assert _run(code).split() == ["1", "1"]


def test_another_count_is_set_by_its_variable(monkeypatch):
    code = "import bodymetry, numpy\nfrom bodymetry.threads import blas_threads_in_use\n"
    code += "print(blas_threads_in_use())"
    assert _run(code, **{THREADS_ENV: "2"}) == "2"
    monkeypatch.setenv(THREADS_ENV, "many")
    with pytest.raises(ValueError, match=THREADS_ENV):
        blas_threads()
