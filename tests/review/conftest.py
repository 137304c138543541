"""A tiny processed run with its review outputs, shared by the review tests.

A 2-camera 240x180 studio session (3 kept frames) fitted with tiny
discriminative models and the ``fast`` annealing preset, as in
tests/estimation/test_pipeline.py; ``process_session`` writes the review
outputs at its end, so the fixture also exercises that wiring.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import pytest

from capture.session import Session
from capture.studio.synth import SynthConfig, synthesize
from estimation.pipeline import ProcessConfig, process_session
from estimation.training import TrainConfig

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


@dataclass(frozen=True)
class ReviewRun:
    """The fixture: the session, the run folder, its results and progress calls."""

    session: Session
    folder: Path
    results: dict
    progress: list[tuple[str, int, int]]


@pytest.fixture(scope="session")
def review_run(tmp_path_factory) -> ReviewRun:
    base = tmp_path_factory.mktemp("review")
    session = synthesize(
        base / "session",
        SynthConfig(
            frames=5,
            frame_step=2,
            cameras=2,
            size=(240, 180),
            seed=3,
            motion="apose",
            background_frames=3,
            calibration_frames=30,
        ),
        workers=1,
    )
    calls: list[tuple[str, int, int]] = []
    results = process_session(
        session.folder,
        base / "run",
        ProcessConfig(quality="fast"),
        workers=1,
        cache_dir=base / "cache",
        progress=lambda label, done, total: calls.append((label, done, total)),
        train_config=TINY_TRAIN,
        pdf=True,
    )
    return ReviewRun(session, base / "run", results, calls)


@pytest.fixture(autouse=True)
def _restore_root_logger():
    """The CLI configures the root logger (basicConfig(force=True)); undo it after each test."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
