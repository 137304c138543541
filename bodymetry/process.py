"""``bodymetry process``: from a session folder to a run folder of measurements.

The step graph of :mod:`bodymetry.pipeline` on a :class:`~bodymetry.executors.LocalExecutor`:
the session's steps in this process, the frame fits on a pool of worker
processes. Every finished frame is written to the run folder atomically, its
arrays and mesh before its record (``frames/FFFFFF.json``, which marks it
done), so a killed run resumes from the frames it finished; a finished run is
returned as recorded. The layout and schema of the run folder are
:mod:`bodymetry.estimation.records` (docs/outputs.md).
"""

from __future__ import annotations

from pathlib import Path

from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults
from bodymetry.executors import LocalExecutor
from bodymetry.log import Progress
from bodymetry.pipeline import run_session

__all__ = ["process_session"]


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
        For bad inputs, before any long work (:func:`bodymetry.pipeline.prepare`).
    """
    config = config or ProcessConfig()
    with LocalExecutor(config.workers_or_cores) as executor:
        run = run_session(session_path, out, config, executor, progress, restart=restart)
    return run.results
