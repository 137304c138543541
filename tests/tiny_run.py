"""A tiny studio session and tiny discriminative models, shared by the end-to-end tests.

A 2-camera 240x180 studio session with 5 frames (3 kept) and training settings
small enough that ``process_session`` runs in seconds.
"""

from __future__ import annotations

from pathlib import Path

from bodymetry.capture.session import Session
from bodymetry.estimation.training import TrainConfig
from bodymetry.studio.synth import SynthConfig, synthesize

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


def tiny_session(folder: Path, seed: int, frames: int = 5, rig_seed: int | None = None) -> Session:
    """Render the tiny A-pose studio session into ``folder`` (every 2nd frame kept).

    Sessions with one ``rig_seed`` share their cameras (one rig); by default the
    rig follows ``seed``.
    """
    return synthesize(
        folder,
        SynthConfig(
            frames=frames,
            frame_step=2,
            cameras=2,
            size=(240, 180),
            seed=seed,
            rig_seed=rig_seed,
            motion="apose",
            background_frames=3,
            calibration_frames=30,
        ),
        workers=1,
    )


def tiny_train_overrides() -> list[str]:
    """``--set`` arguments that make ``bodymetry process`` train :data:`TINY_TRAIN`."""
    return [
        f"training.{name}={list(value) if isinstance(value, tuple) else value}"
        for name, value in TINY_TRAIN.__dict__.items()
    ]
