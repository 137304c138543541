"""Fixtures shared by the end-to-end tests of ``bodymetry`` (process and batch)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from tiny_run import tiny_process_config

from bodymetry.calibration.camera import CameraGroup
from bodymetry.calibration.io import load_calibration, save_calibration
from bodymetry.capture.landmarks import shifted_camera
from bodymetry.capture.session import Session
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults
from bodymetry.process import process_session
from bodymetry.studio.synth import synthesize
from bodymetry.warmup import TINY_SESSION


@dataclasses.dataclass(frozen=True)
class MovedCameraRun:
    """A 4-camera tiny session whose camera 1 the calibration puts 5 px too low, processed.

    Attributes
    ----------
    session : Session
        The session; its calibration file holds the moved camera.
    calibration : CameraGroup
        The cameras as rendered (camera 1 where it belongs).
    config : ProcessConfig
        The settings of the run (its model cache holds the rig's trained models).
    out : Path
        The run folder; tests that change it copy it first.
    results : RunResults
        What ``process_session`` returned.
    """

    session: Session
    calibration: CameraGroup
    config: ProcessConfig
    out: Path
    results: RunResults


@pytest.fixture(scope="session")
def moved_camera(tmp_path_factory) -> MovedCameraRun:
    """Rendered and processed once: the registration tests of process and batch share it
    (each render and run costs ~16 s on 2 cores)."""
    base = tmp_path_factory.mktemp("moved_camera")
    session = synthesize(base / "session", dataclasses.replace(TINY_SESSION, cameras=4), workers=1)
    calibration = load_calibration(session.calibration_path)
    off = CameraGroup(
        [shifted_camera(c, 0.0, 5.0) if c.name == "cam_01" else c for c in calibration]
    )
    save_calibration(session.calibration_path, off)
    config = tiny_process_config(base / "cache")
    out = base / "run"
    results = process_session(session.folder, out, config)
    return MovedCameraRun(session, calibration, config, out, results)
