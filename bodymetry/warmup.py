"""Compile the numeric kernels before the first real run (``bodymetry compile``).

numba compiles each kernel the first time it is called and keeps the machine
code in its on-disk cache (``bodymetry/jit.py`` says where), so
every later process only loads it. On a fresh install that first compilation
would land in the user's first ``bodymetry process``: on the 2-core reference
machine the demo's training took 77 s instead of 56 s and its fitting 50 s
instead of 36 s. ``make demo`` and ``make test`` therefore run this once, at
install time.

It processes a tiny studio session end to end (rendered here, two cameras, three
kept frames, tiny training settings), in a temporary folder with its own model
cache: the same code, hence the same kernel signatures, as a real run, without
a list of kernels to keep in step with the code.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.training import TrainConfig
from bodymetry.process import process_session
from bodymetry.studio.synth import SynthConfig, synthesize

log = logging.getLogger(__name__)

__all__ = ["TINY_SESSION", "TINY_TRAIN", "compile_kernels"]

#: Training settings small enough that a 2-camera session trains in seconds
#: (also the end-to-end tests' settings).
TINY_TRAIN = TrainConfig(
    n_train=60,
    n_test=10,
    codebook_size=8,
    codebook_examples=20,
    sc_points=40,
    experts=(1,),
    ridges=(10.0,),
    max_iter=5,
)

#: The warm-up's studio session: two 240x180 cameras, five frames, every second kept.
TINY_SESSION = SynthConfig(
    frames=5,
    frame_step=2,
    cameras=2,
    size=(240, 180),
    seed=2,
    motion="apose",
    background_frames=3,
    calibration_frames=30,
)


def compile_kernels(workdir: str | Path | None = None) -> float:
    """Run every compiled kernel once, so numba compiles and caches it now.

    Parameters
    ----------
    workdir : path, optional
        Where to render and process the tiny session (default: a temporary
        folder, removed afterwards).

    Returns
    -------
    float
        Seconds taken (most of it compiling, the first time); 0.0 when numba
        cannot be imported (every stage then runs its numpy path).
    """
    t0 = time.perf_counter()
    try:
        import numba  # noqa: F401
    except ImportError as exc:  # the numpy paths run instead: nothing to compile
        log.warning("numba fails to import (%s): no kernels to compile", exc)
        return 0.0
    with tempfile.TemporaryDirectory(prefix="bodymetry-compile-", dir=workdir) as tmp:
        base = Path(tmp)
        session = synthesize(base / "session", TINY_SESSION, workers=1)
        config = ProcessConfig(training=TINY_TRAIN, workers=1, cache_dir=base / "cache")
        process_session(session.folder, base / "run", config)
    seconds = time.perf_counter() - t0
    log.info("kernels compiled and cached in %.0f s", seconds)
    return seconds
