"""``ProcessConfig``: everything ``bodymetry process`` does, in one validated tree.

The quality presets (:data:`bodymetry.estimation.fit.PRESETS`) set the fit's
annealing and refinement; any field can then be overridden from the command
line with ``--set KEY=VALUE`` (e.g. ``--set annealing.n_particles=120``,
``--set training.n_train=500``, ``--set workers=2``). The whole tree is
recorded in ``results.json`` (``config``), so a run says exactly how it was
made, and ``evaluate`` refits with the same settings.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from bodymetry.capture.segmentation import CaptureConfig
from bodymetry.errors import InputError
from bodymetry.estimation.fit import PRESETS, FitConfig
from bodymetry.estimation.registration import RegistrationConfig
from bodymetry.estimation.resolution import DEFAULT_WORKING_PERSON_PX
from bodymetry.estimation.session_shape import SessionShapeConfig
from bodymetry.estimation.training import TrainConfig, default_cache_dir
from bodymetry.settings import apply_overrides, from_jsonable, to_jsonable

__all__ = ["OVERRIDE_ALIASES", "ProcessConfig"]

#: Short ``--set`` keys: the fit's settings without the ``fit.`` prefix.
OVERRIDE_ALIASES: dict[str, str] = {f.name: f"fit.{f.name}" for f in fields(FitConfig)}


@dataclass(frozen=True)
class ProcessConfig:
    """What ``bodymetry process`` does.

    Attributes
    ----------
    quality : str
        The preset the fit settings started from (``fast``, ``default``, ``best``).
    capture : CaptureConfig
        How silhouettes are made (background subtraction, the learned person
        segmenter, the multi-view check).
    fit : FitConfig
        Per-frame fit: seed, density, quality gate, annealing, refinement.
    training : TrainConfig
        Discriminative training for a new rig (paper §6: 3000 + 597 examples).
    registration : RegistrationConfig
        Whether and when the fitted bodies shift a camera that sits off the
        observed silhouettes in every frame, and the frames are fitted again
        (:mod:`bodymetry.estimation.registration`).
    session_shape : SessionShapeConfig
        The session stage after the per-frame fits: one shape for the session
        (``--set session_shape.enabled=false`` skips it). It changes no
        frame's fit, so it is not part of the run folder's settings
        fingerprint: a finished run resumed with another setting redoes only
        the summary.
    frame_step : int or None
        Fit every ``frame_step``-th frame instead of the session's own
        ``frame_step`` (for clips too short for the default of 25); None keeps
        the session's.
    working_person_px : float or None
        Each camera's working resolution (:mod:`bodymetry.estimation.resolution`):
        a camera in which a standing 1.8 m person at the world origin would be
        at least twice this tall (pixels) is trained and fitted at ``1/k`` of
        its resolution, ``k = floor(person_px / working_person_px)``. None
        (``--set working_person_px=null``) keeps every camera at full resolution.
    workers : int or None
        Worker processes (None: one per core).
    cache_dir : Path or None
        Trained models (None: ``$BODYMETRY_CACHE`` or ``~/.cache/bodymetry``).
    review : bool
        Write the review outputs (recording, MCAP, report) after the results.
    pdf : bool
        Also write ``report.pdf``.
    person : int or None
        Measure this person of a multi-person recording (``--person N``; the
        identities capture follows through the frames, numbered from 0 in the
        order they are first seen: :func:`bodymetry.capture.persons.track_ids`).
        None: every person capture tells apart (each with their own fits,
        session stage and summary), else the one subject.
    largest : bool
        Measure one subject per frame, the largest body (the most prominent
        person without an empty-scene clip), even where capture tells people
        apart (``--largest``; a run with several people in view says so).
    """

    quality: str = "default"
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    training: TrainConfig = field(default_factory=TrainConfig)
    session_shape: SessionShapeConfig = field(default_factory=SessionShapeConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    frame_step: int | None = None
    working_person_px: float | None = DEFAULT_WORKING_PERSON_PX
    workers: int | None = None
    cache_dir: Path | None = None
    review: bool = True
    pdf: bool = False
    person: int | None = None
    largest: bool = False

    def __post_init__(self) -> None:
        if self.quality not in PRESETS:
            raise InputError(f"quality: expected one of {', '.join(PRESETS)}, got {self.quality!r}")
        if self.frame_step is not None and self.frame_step < 1:
            raise InputError(f"frame_step: expected >= 1, got {self.frame_step}")
        if self.working_person_px is not None and not self.working_person_px > 0:
            raise InputError(
                f"working_person_px: expected a height in pixels > 0 or null, "
                f"got {self.working_person_px}"
            )
        if self.workers is not None and self.workers < 1:
            raise InputError(f"workers: expected >= 1, got {self.workers}")
        if self.person is not None and self.person < 0:
            raise InputError(f"person: expected a person number >= 0, got {self.person}")
        if self.largest and self.person is not None:
            raise InputError(
                f"largest: measures one subject, person: measures person {self.person}; choose one"
            )
        if self.pdf and not self.review:
            raise InputError("pdf: a PDF report needs the review outputs (review=true)")

    @classmethod
    def preset(cls, quality: str = "default", **kwargs: Any) -> ProcessConfig:
        """The config of a quality preset; ``kwargs`` set other top-level fields."""
        if quality not in PRESETS:
            raise InputError(f"quality: expected one of {', '.join(PRESETS)}, got {quality!r}")
        fit = kwargs.pop("fit", None) or FitConfig.preset(quality)
        return cls(quality=quality, fit=fit, **kwargs)

    def with_overrides(self, overrides: Iterable[str]) -> ProcessConfig:
        """A copy with ``KEY=VALUE`` overrides (``annealing.x`` means ``fit.annealing.x``)."""
        return apply_overrides(self, overrides, OVERRIDE_ALIASES)

    @property
    def workers_or_cores(self) -> int:
        return self.workers or os.cpu_count() or 1

    @property
    def models_cache(self) -> Path:
        return self.cache_dir or default_cache_dir()

    def to_json(self) -> dict[str, Any]:
        return to_jsonable(self)

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str = "config") -> ProcessConfig:
        """Read a recorded config (``results.json``'s ``config`` without its extra keys)."""
        known = {f.name for f in fields(cls)}
        return from_jsonable(cls, {k: v for k, v in data.items() if k in known}, where)
