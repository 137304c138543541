"""A tiny processed run with its review outputs, shared by the review tests.

A 2-camera 240x180 studio session (3 kept frames) fitted with tiny
discriminative models and the ``fast`` annealing preset, as in
tests/bodymetry/test_process.py; ``process_session`` writes the review
outputs at its end, so the fixture also exercises that wiring.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest
from tiny_run import TINY_TRAIN, tiny_session
from two_persons import two_person_copy

from bodymetry.capture.session import Session
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults
from bodymetry.process import process_session


@dataclass(frozen=True)
class ReviewRun:
    """The fixture: the session, the run folder, its results and progress calls."""

    session: Session
    folder: Path
    results: RunResults
    progress: list[tuple[str, int, int]]


@pytest.fixture(scope="session")
def review_run(tmp_path_factory) -> ReviewRun:
    base = tmp_path_factory.mktemp("review")
    session = tiny_session(base / "session", seed=3)
    calls: list[tuple[str, int, int]] = []
    results = process_session(
        session.folder,
        base / "run",
        ProcessConfig.preset(
            "fast", training=TINY_TRAIN, workers=1, cache_dir=base / "cache", pdf=True
        ),
        progress=lambda label, done, total: calls.append((label, done, total)),
    )
    return ReviewRun(session, base / "run", results, calls)


@pytest.fixture(scope="session")
def two_person_run(review_run, tmp_path_factory) -> Path:
    """The review run as a run of two persons (:func:`two_person_copy`), review files
    not yet written."""
    return two_person_copy(review_run, tmp_path_factory.mktemp("two") / "run")
