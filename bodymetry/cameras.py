"""The one place that decides which cameras a run uses.

:func:`resolve_cameras` takes the session's ``calibration.yaml`` when it has
one, else a calibration solved earlier into the run folder (a resumed run),
else solves one from the session's ChArUco clips. Either way the run folder
gets its own ``calibration.yaml`` (a copy, or the solution with its
``calibration-report.json``), so that everything reading the run afterwards
(``evaluate``, the review, ``report``) reads the cameras the fit used from
the run itself: :func:`run_cameras`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from bodymetry.calibration.camera import CameraGroup
from bodymetry.calibration.io import load_calibration
from bodymetry.calibration.session_calibration import (
    REPORT_FILE,
    calibrate_session,
    write_calibration,
)
from bodymetry.capture.session import Session, load_session
from bodymetry.errors import InputError
from bodymetry.estimation.run_files import RunLayout
from bodymetry.fileio import write_bytes_atomic
from bodymetry.log import Progress

log = logging.getLogger(__name__)

__all__ = ["ResolvedCameras", "load_rig", "resolve_cameras"]

#: ``calibration_source`` of a calibration solved from the session's clips.
SOLVED = "solved from the session's ChArUco clips"


@dataclass(frozen=True)
class ResolvedCameras:
    """The cameras of a run and where they came from.

    Attributes
    ----------
    cameras : CameraGroup
        The rig, in session camera order.
    source : str
        The calibration file the session gave, or :data:`SOLVED`.
    """

    cameras: CameraGroup
    source: str


def resolve_cameras(
    session: Session,
    run_dir: Path,
    progress: Progress | None = None,
) -> ResolvedCameras:
    """The session's cameras, recorded into ``run_dir/calibration.yaml``.

    Parameters
    ----------
    session : Session
    run_dir : Path
        The run folder (created if missing). The session folder is never modified.
    progress : callable, optional
        ``progress(label, done, total)`` while solving from clips.

    Raises
    ------
    InputError
        When the session has neither a calibration file nor clips to solve one from.
    """
    layout = RunLayout(Path(run_dir))
    layout.folder.mkdir(parents=True, exist_ok=True)
    given = session.calibration_path
    if given is not None and given.is_file():
        cameras = session.calibration()
        # The run keeps a byte copy: it stays readable if the session moves.
        write_bytes_atomic(layout.calibration, given.read_bytes())
        report = given.with_name(REPORT_FILE)
        if report.is_file():
            write_bytes_atomic(layout.calibration_report, report.read_bytes())
        elif layout.calibration_report.is_file():
            layout.calibration_report.unlink()
        return ResolvedCameras(cameras, str(given))
    if layout.calibration.is_file() and layout.calibration_report.is_file():
        return ResolvedCameras(
            load_calibration(layout.calibration).subset(session.camera_names), SOLVED
        )
    if session.calibration_clips and session.board is not None:
        log.info("%s: no calibration.yaml; solving it from the ChArUco clips", session.folder)
        result, _ = calibrate_session(
            session,
            on_progress=(lambda label, d, t: progress(f"calibration: {label}", d, t))
            if progress
            else None,
        )
        write_calibration(result, layout.calibration, overwrite=True)
        return ResolvedCameras(result.cameras.subset(session.camera_names), SOLVED)
    raise InputError(
        f"{session.folder}: no calibration.yaml and no ChArUco clips to solve one from "
        "(see docs/session-format.md)"
    )


def load_rig(path: Path) -> CameraGroup:
    """The cameras named by a command-line argument: a session folder, its
    ``session.yaml``, or a ``calibration.yaml`` (``train``, ``estimate-image``).

    Raises
    ------
    InputError
        For any other file, or when the file is not valid.
    """
    path = Path(path)
    if path.is_dir() or path.name == "session.yaml":
        return load_session(path).calibration()
    if path.suffix.lower() in (".yaml", ".yml"):
        return load_calibration(path)
    raise InputError(f"{path}: expected a session folder, session.yaml or calibration.yaml")
