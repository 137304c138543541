"""The files of a run folder and a study, each one typed class read and written here.

``bodymetry process`` writes a run folder (docs/outputs.md); ``evaluate``, the
review outputs, the report and ``batch`` read it. Every JSON file in it has its
class, and no other module parses these files:

==========================  ==================  ===========================================
file                        class               written by
==========================  ==================  ===========================================
``run.json``                :class:`RunManifest`  :func:`bodymetry.run_folder.prepare_run_folder`
``results.json``            :class:`RunResults`   :func:`bodymetry.pipeline.finish`
``evaluation.json``         :class:`Evaluation`   :func:`bodymetry.review.evaluation.evaluate_run`
``STUDY/study.json``        :class:`StudyResults` :func:`bodymetry.batch.run_batch`
==========================  ==================  ===========================================

The per-frame records and arrays are :mod:`bodymetry.estimation.records`; where
each file lies is :class:`RunLayout`. Each file carries a ``format`` number: an
older or foreign file gets a clear error naming it, not a ``KeyError``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.errors import InputError
from bodymetry.estimation.arm_evidence import arms_raised, raised_frames
from bodymetry.estimation.caveats import Caveat, run_caveats
from bodymetry.estimation.records import (
    COARSE_PIXELS,
    CORE_MEASUREMENTS,
    STAGES,
    FrameRecord,
    OutlineCheck,
    SessionGate,
    SessionShape,
    Stat,
)
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.studio_accuracy import (
    MeasuredAccuracy,
    coarse_pixels,
    is_low_contrast,
    like_accuracy,
    run_contrast,
)
from bodymetry.estimation.uncertainty import StatedInterval, stated_intervals
from bodymetry.fileio import read_json_object, write_json_atomic

__all__ = [
    "EVALUATION_FORMAT",
    "GT_STAGE",
    "MANIFEST_FORMAT",
    "MEASUREMENTS_CSV",
    "PERSONS_DIR",
    "RECORDING_MCAP",
    "RECORDING_RRD",
    "REPORT_HTML",
    "REPORT_PDF",
    "RESULTS_FORMAT",
    "RESULTS_FORMATS_READ",
    "STUDY_FORMAT",
    "SUMMARY_VERSION",
    "Evaluation",
    "PersonResults",
    "RigEntry",
    "RunLayout",
    "RunManifest",
    "RunResults",
    "SessionInfo",
    "StudyResults",
    "StudySession",
]

#: Version of ``results.json`` written by this code (1: before the typed schema;
#: 2: one subject, its ``frames`` and ``summary`` at the top level, still read).
RESULTS_FORMAT = 3
#: The results formats this code reads.
RESULTS_FORMATS_READ = (2, 3)
#: Version of the code that makes a run's summary from its recorded frames (the
#: session stage and the measurements it reports). A finished run whose
#: ``results.json`` holds another (files before it hold none: 0) has its summary made
#: again from the recorded frames when ``process`` meets it, so that an upgrade
#: reaches the numbers of runs already finished. Raise it when the summary changes
#: (1: the height read from the floor; 2: the weight read from the posed bodies;
#: 3: the floor trusted down to ``standing_height.MAX_SOLE_DEPTH`` only; 4: parts of the
#: model the camera does not resolve give no model-to-outline residual in the session
#: stage, ``SessionShapeConfig.thin_px``; 5: the outline check holds a run seen in low
#: contrast to ``OutlineConfig.loose_mm_low_contrast``; 6: unless its bare forearms and
#: shins lie inside the fitted body, and the crown compared with the
#: median of the trunk, head and lower limbs, ``outline_check.CROWN_REFERENCE``; 7: the
#: bare shins alone decide that, ``OutlineConfig.shins_inside_mm``, and in low contrast
#: the trunk is compared with whichever limbs the fit meets best; 8: bare shins far inside
#: the fitted body, ``OutlineConfig.legs_hidden_mm``, say a skirt hid the legs, and no
#: interval is stated for the height either; a run whose every frame is a poor fit says
#: what can cause it, ``fit.poor_fit_hint``; 9: a run at pixels coarser than the studio's
#: gets the ``coarse_pixels`` caveat and no interval, ``studio_accuracy.coarse_pixels``).
SUMMARY_VERSION = 9
#: Version of ``run.json``.
MANIFEST_FORMAT = 1
#: Version of ``evaluation.json`` (1: the generative stage was ``disc_generative``).
EVALUATION_FORMAT = 2
#: Review files written into the run folder (docs/review.md).
RECORDING_RRD = "recording.rrd"
RECORDING_MCAP = "recording.mcap"
REPORT_HTML = "report.html"
REPORT_PDF = "report.pdf"
MEASUREMENTS_CSV = "measurements.csv"
#: Where a run of several persons keeps each one's frame files (``persons/K/...``).
PERSONS_DIR = "persons"
#: The evaluation's extra stage: the generative fit started from the true pose
#: (the paper's "GT + Generative"), beside the run's :data:`STAGES`.
GT_STAGE = "gt_generative"


@dataclass(frozen=True)
class RunLayout:
    """Where a run folder keeps each record (docs/outputs.md).

    Attributes
    ----------
    folder : Path
    """

    folder: Path
    person: int | None = None

    def for_person(self, person: int | None) -> RunLayout:
        """The layout of one person's frame files (``persons/K/frames``, ``persons/K/meshes``);
        ``None``: the run's subject (``frames``, ``meshes``), as a one-person run keeps them."""
        return RunLayout(self.folder, person)

    @property
    def _person_root(self) -> Path:
        return self.folder if self.person is None else self.folder / PERSONS_DIR / str(self.person)

    @property
    def manifest(self) -> Path:
        """``run.json``: what the run is of (written first; see ``bodymetry.run_folder``)."""
        return self.folder / "run.json"

    @property
    def results(self) -> Path:
        return self.folder / "results.json"

    @property
    def frames_dir(self) -> Path:
        return self._person_root / "frames"

    @property
    def meshes_dir(self) -> Path:
        return self._person_root / "meshes"

    @property
    def calibration(self) -> Path:
        """The cameras the run was fitted with (copied or solved into the run)."""
        return self.folder / "calibration.yaml"

    @property
    def registration(self) -> Path:
        """``registration.json``: the cameras' offsets measured on the fitted bodies
        (:func:`bodymetry.pipeline.register_cameras`)."""
        return self.folder / "registration.json"

    @property
    def calibration_report(self) -> Path:
        return self.folder / "calibration-report.json"

    @property
    def evaluation(self) -> Path:
        """``evaluation.json`` (a run of several persons: each one's in ``persons/K/``)."""
        return self._person_root / "evaluation.json"

    @property
    def review_files(self) -> tuple[Path, ...]:
        """What the review always writes (``report.pdf`` only on request)."""
        return tuple(
            self.folder / n for n in (RECORDING_RRD, RECORDING_MCAP, REPORT_HTML, MEASUREMENTS_CSV)
        )

    @property
    def entries(self) -> tuple[Path, ...]:
        """Everything a run writes into its folder (a restart removes these, nothing else)."""
        return (
            self.manifest,
            self.results,
            self.evaluation,
            self.folder / "frames",
            self.folder / "meshes",
            self.folder / PERSONS_DIR,
            self.calibration,
            self.registration,
            self.calibration_report,
            *self.review_files,
            self.folder / REPORT_PDF,
        )

    def frame_record(self, frame: int) -> Path:
        return self.frames_dir / f"{frame:06d}.json"

    def frame_arrays(self, frame: int) -> Path:
        return self.frames_dir / f"{frame:06d}.npz"

    def frame_mesh(self, frame: int) -> Path:
        return self.meshes_dir / f"{frame:06d}.ply"

    def recorded_frames(self) -> list[int]:
        """Frames that have a record, in order."""
        if not self.frames_dir.is_dir():
            return []
        return sorted(int(p.stem) for p in self.frames_dir.glob("*.json") if p.stem.isdigit())


@dataclass(frozen=True)
class SessionInfo:
    """The session a run measured.

    Attributes
    ----------
    path : str
        The session folder (absolute, as processed).
    name : str
    cameras : tuple of str
    fps : float
    frame_step : int
    """

    path: str
    name: str
    cameras: tuple[str, ...]
    fps: float
    frame_step: int

    def to_json(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "name": self.name,
            "cameras": list(self.cameras),
            "fps": self.fps,
            "frame_step": self.frame_step,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SessionInfo:
        return cls(
            str(data.get("path", "")),
            str(data.get("name", "")),
            tuple(data.get("cameras", ())),
            float(data.get("fps") or 25.0),
            int(data.get("frame_step", 1)),
        )


@dataclass(frozen=True)
class PersonResults:
    """One person of a run: their kept frames, summary and session stage.

    Attributes
    ----------
    id : int
        Their identity, tracked across the kept frames (0, 1, ...; docs/capture.md,
        "Persons and occlusion"). A run of one subject has the one person 0.
    frames : tuple of FrameRecord
        Every kept frame, in frame order, as this person's fit recorded it.
    summary : dict of str to dict of str to Stat
        Per stage and measurement, over their ``ok`` frames.
    told_apart : bool
        Capture told this person apart from the others in view (their own pixels
        and landmarks were fitted); False for the subject of a one-subject run,
        where anyone else in view may have mixed into the numbers.
    camera_frames : dict of str to int
        Per camera, the kept frames in which it saw a usable silhouette of them.
    warnings : tuple of str
        What the user should know about this person's numbers.
    ground_truth : SubjectTruth or None
        The studio person's true measurements (matched by position for a run of
        several persons), when the session has them.
    quality_gate : SessionGate or None
        The gate their frames' statuses were set by.
    session_shape : SessionShape or None
        Their session stage; None when it was disabled.
    """

    id: int
    frames: tuple[FrameRecord, ...]
    summary: dict[str, dict[str, Stat]]
    told_apart: bool = False
    camera_frames: dict[str, int] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    ground_truth: SubjectTruth | None = None
    quality_gate: SessionGate | None = None
    session_shape: SessionShape | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "id": self.id,
            "told_apart": self.told_apart,
            "frames": [r.to_json() for r in self.frames],
            "summary": {
                stage: {k: s.to_json() for k, s in stats.items()}
                for stage, stats in self.summary.items()
            },
            "camera_frames": self.camera_frames,
            "warnings": list(self.warnings),
        }
        if self.quality_gate is not None:
            out["quality_gate"] = self.quality_gate.to_json()
        if self.session_shape is not None:
            out["session_shape"] = self.session_shape.to_json()
        if self.ground_truth is not None:
            out["ground_truth"] = self.ground_truth.to_json()
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str, default_id: int = 0) -> PersonResults:
        """One person's object (or, for format 2, the whole file's top level)."""
        if not isinstance(data.get("frames"), list):
            raise InputError(
                f"{where}: no 'frames' list; not a results file of `bodymetry process`"
            )
        frames = tuple(
            sorted(
                (
                    FrameRecord.from_json(f, f"{where}: frames[{i}]")
                    for i, f in enumerate(data["frames"])
                ),
                key=lambda r: r.frame,
            )
        )
        ident = data.get("id", default_id)
        if isinstance(ident, bool) or not isinstance(ident, int) or ident < 0:
            raise InputError(f"{where}: 'id' must be a whole number >= 0, got {ident!r}")
        return cls(
            id=ident,
            frames=frames,
            summary={
                stage: {k: Stat.from_json(v) for k, v in stats.items()}
                for stage, stats in data.get("summary", {}).items()
            },
            told_apart=bool(data.get("told_apart", False)),
            camera_frames={k: int(v) for k, v in data.get("camera_frames", {}).items()},
            warnings=tuple(str(w) for w in data.get("warnings", [])) if "id" in data else (),
            ground_truth=(
                SubjectTruth.from_json(data["ground_truth"], f"{where}: ground_truth")
                if data.get("ground_truth") is not None
                else None
            ),
            quality_gate=(
                SessionGate.from_json(data["quality_gate"], f"{where}: quality_gate")
                if data.get("quality_gate") is not None
                else None
            ),
            session_shape=(
                SessionShape.from_json(data["session_shape"], f"{where}: session_shape")
                if data.get("session_shape") is not None
                else None
            ),
        )


@dataclass(frozen=True)
class RunResults:
    """``results.json``: a whole run, one :class:`PersonResults` per person measured.

    The per-person attributes (``frames``, ``summary``, ``ground_truth``,
    ``camera_frames``, ``quality_gate``, ``session_shape``) read the run's first
    person: a run of one subject is the case of one person, and
    :meth:`for_person` gives the run as one of its persons sees it, so that every
    reader of one person's numbers serves each person of a run.

    Attributes
    ----------
    session : SessionInfo
    config : ProcessConfig
        The settings the run used; read back by ``evaluate``.
    persons : tuple of PersonResults
        Everyone the run measured, by id (at least one).
    timing_seconds : dict of str to float
    calibration_source : str
        Where the run's cameras came from (a file, or "solved from the clips").
    warnings : tuple of str
        What the user should know about the run (also logged); each person's
        own warnings are in :attr:`PersonResults.warnings`.
    working_resolution : WorkingResolution or None
        The resolution each camera was trained and fitted at (the recorded
        silhouettes are at it); None for runs recorded before working
        resolutions, which worked at the cameras' own resolution.
    models : str
        The discriminative models' cache key (recorded inside ``config`` in the file).
    models_reused : bool
        The models came from the cache (not trained by this run).
    summary_version : int
        :data:`SUMMARY_VERSION` of the code that made the summary (0: a file from
        before the version was recorded).
    """

    session: SessionInfo
    config: ProcessConfig
    persons: tuple[PersonResults, ...]
    timing_seconds: dict[str, float] = field(default_factory=dict)
    calibration_source: str = ""
    warnings: tuple[str, ...] = ()
    working_resolution: WorkingResolution | None = None
    models: str = ""
    models_reused: bool = False
    summary_version: int = SUMMARY_VERSION

    def __post_init__(self) -> None:
        if not self.persons:
            raise ValueError("a run has at least one person")
        ids = [p.id for p in self.persons]
        if len(set(ids)) != len(ids):
            raise ValueError(f"person ids repeat: {ids}")

    @classmethod
    def of_subject(cls, session: SessionInfo, config: ProcessConfig, **fields: Any) -> RunResults:
        """A run of one subject (person 0) from the person's attributes (``frames``,
        ``summary``, ...) and the run's, each as a keyword."""
        person_keys = {f for f in PersonResults.__dataclass_fields__ if f != "id"} - {"warnings"}
        mine = {k: fields.pop(k) for k in list(fields) if k in person_keys}
        mine.setdefault("frames", ())
        mine.setdefault("summary", {})
        return cls(session, config, (PersonResults(0, **mine),), **fields)

    @property
    def person(self) -> PersonResults:
        """The run's first person (the one person of a run of one subject)."""
        return self.persons[0]

    def for_person(self, ident: int) -> RunResults:
        """The run with ``ident`` its only person (its warnings added to the run's).

        Raises
        ------
        KeyError
            When the run has no person ``ident``.
        """
        for p in self.persons:
            if p.id == ident:
                return replace(self, persons=(p,), warnings=(*self.warnings, *p.warnings))
        raise KeyError(f"the run has no person {ident} (it has {[p.id for p in self.persons]})")

    def with_person(self, **changes: Any) -> RunResults:
        """The run with its first person's attributes changed (``frames=...``, ...)."""
        return replace(self, persons=(replace(self.person, **changes), *self.persons[1:]))

    @property
    def several(self) -> bool:
        """Whether the run measured more than one person."""
        return len(self.persons) > 1

    @property
    def frames(self) -> tuple[FrameRecord, ...]:
        return self.person.frames

    @property
    def summary(self) -> dict[str, dict[str, Stat]]:
        return self.person.summary

    @property
    def ground_truth(self) -> SubjectTruth | None:
        return self.person.ground_truth

    @property
    def camera_frames(self) -> dict[str, int]:
        return self.person.camera_frames

    @property
    def quality_gate(self) -> SessionGate | None:
        return self.person.quality_gate

    @property
    def session_shape(self) -> SessionShape | None:
        return self.person.session_shape

    @property
    def ok_frames(self) -> list[FrameRecord]:
        return [r for r in self.frames if r.ok]

    @property
    def outline(self) -> OutlineCheck | None:
        """The session stage's outline check (None without the stage or the check)."""
        return None if self.session_shape is None else self.session_shape.outline

    @property
    def caveats(self) -> tuple[Caveat, ...]:
        """Why the first person's numbers deserve less trust than they look
        (:func:`bodymetry.estimation.caveats.run_caveats`; derived from the records,
        so an older ``results.json`` gets them too); :meth:`for_person` for another's."""
        outline = self.outline
        shape = self.session_shape
        # Soles the floor reading did not trust (a file made before the bound read every
        # depth from the floor, as its summary says; `process` makes it again).
        floor = (
            shape.floor_mm
            if shape is not None and shape.ok and shape.floor_height and not shape.floor_applied
            else None
        )
        return run_caveats(
            self.frames,
            self.session.cameras,
            () if outline is None else outline.warnings,
            told_apart=self.person.told_apart or self.config.person is not None,
            headline=self.headline_values,
            raised=self.arm_raised_frames,
            sole_depth_mm=None if floor is None or not math.isfinite(floor) else floor,
            mm_per_px=None if outline is None else outline.mm_per_px,
        )

    @property
    def outline_contrast(self) -> float | None:
        """How plainly capture saw the first person stand out from the empty scene
        (:func:`~bodymetry.estimation.studio_accuracy.run_contrast`, 3 decimals; None
        without an empty-scene clip)."""
        contrast = run_contrast(self.frames)
        return None if contrast is None else round(contrast, 3)

    @cached_property
    def arm_raised_frames(self) -> tuple[int, ...] | None:
        """The first person's measured frames with an arm raised
        (:func:`~bodymetry.estimation.arm_evidence.raised_frames`: it poses the body of
        every frame), judged once for :attr:`caveats` and :attr:`studio_accuracy`."""
        return raised_frames(self.frames)

    @property
    def among_others(self) -> bool:
        """Whether capture counted someone besides the first person in any of their
        frames (:attr:`~bodymetry.estimation.records.FrameRecord.crowded`)."""
        return any(r.crowded for r in self.frames)

    @cached_property
    def studio_accuracy(self) -> dict[str, MeasuredAccuracy]:
        """The studio's accuracy on bodies like the first person's measured one, per core
        measurement with enough like sessions
        (:func:`bodymetry.estimation.studio_accuracy.like_accuracy`; derived, like
        :attr:`caveats`, once: the report's cards, :attr:`stated_intervals` and
        ``results.json`` all read it); for a person measured among others
        (:attr:`among_others`), the larger of that and the studio's two-person
        sessions' error."""
        arms = arms_raised(self.arm_raised_frames)
        low = is_low_contrast(self.outline_contrast)
        return like_accuracy(
            self.headline_values, arms, among_others=self.among_others, low_contrast=low
        )

    @property
    def stated_intervals(self) -> dict[str, StatedInterval]:
        """The first person's 95 % interval per core measurement with a session value
        and a :attr:`studio_accuracy` (:mod:`bodymetry.estimation.uncertainty`; derived,
        like :attr:`caveats`); none for one the outline check says the silhouettes
        overstate (:attr:`intervals_withheld`)."""
        session = self.summary.get("session", {})
        withheld = self.intervals_withheld
        values = {k: s.mean for k, s in session.items() if s.mean is not None and k not in withheld}
        errors = {k: s.std for k, s in session.items() if s.std is not None}
        frames = max((s.n for s in session.values()), default=0)
        return stated_intervals(values, errors, frames, self.studio_accuracy)

    @property
    def intervals_withheld(self) -> dict[str, str]:
        """Per core measurement with no stated interval because the outline check found
        loose clothing, hair or legs hidden, which (``"loose clothing"``, ``"hair or
        headwear"``, ``"legs hidden"``;
        :attr:`~bodymetry.estimation.records.OutlineCheck.overstated`): the studio's
        accuracy, of tight clothing and bare heads, does not apply; nor, for all of
        them, where its working pixels were coarser than the studio's
        (:data:`COARSE_PIXELS`, :func:`~bodymetry.estimation.studio_accuracy.coarse_pixels`)."""
        shape = self.session_shape
        outline = None if shape is None else shape.outline
        if outline is None:
            return {}
        # Pixels coarser than the studio's: its accuracy does not apply to any of them.
        coarse = (
            dict.fromkeys(CORE_MEASUREMENTS, COARSE_PIXELS)
            if coarse_pixels(outline.mm_per_px)
            else {}
        )
        return {**coarse, **outline.overstated}

    @property
    def headline_values(self) -> dict[str, float]:
        """The first person's measurements as the run states them: per measurement the
        session stage's value, else the generative frames' mean (missing when neither)."""
        out: dict[str, float] = {}
        for stage in ("generative", "session"):  # the session's value wins where it has one
            for key, stat in self.summary.get(stage, {}).items():
                if stat.mean is not None:
                    out[key] = stat.mean
        return out

    def working_cameras(self, cameras: CameraGroup) -> CameraGroup:
        """The rig the run was trained and fitted with, from its calibrated one.

        The one place a reader of a run turns the run's ``calibration.yaml``
        into the cameras of its recorded silhouettes.

        Raises
        ------
        InputError
            When the calibration does not match the recorded working resolution.
        """
        resolution = self.working_resolution or WorkingResolution.full(cameras)
        return resolution.apply(cameras)

    @property
    def fitted_frames(self) -> list[FrameRecord]:
        return [r for r in self.frames if r.fitted]

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": RESULTS_FORMAT,
            "summary_version": self.summary_version,
            "session": self.session.to_json(),
            "config": {
                **self.config.to_json(),
                "models": self.models,
                "models_reused": self.models_reused,
            },
            "calibration_source": self.calibration_source,
            "persons": [
                # Caveats and the studio's accuracy are derived from the records (read back
                # by recomputing):
                # written for scripts and viewers that read the file without bodymetry.
                {
                    **p.to_json(),
                    "caveats": [c.to_json() for c in view.caveats],
                    "outline_contrast": view.outline_contrast,
                    "studio_accuracy": {k: a.to_json() for k, a in view.studio_accuracy.items()},
                    "intervals": {k: i.to_json() for k, i in view.stated_intervals.items()},
                    "intervals_withheld": view.intervals_withheld,
                }
                for p, view in ((p, self.for_person(p.id)) for p in self.persons)
            ],
            "timing_seconds": self.timing_seconds,
            "warnings": list(self.warnings),
        }
        if self.working_resolution is not None:
            out["working_resolution"] = self.working_resolution.to_json()
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "results.json") -> RunResults:
        """Read ``results.json`` content; InputError naming ``where`` for old or foreign files.

        A format-2 file (one subject, its frames at the top level) reads as a run of
        one person 0."""
        fmt = data.get("format")
        if fmt is None:
            raise InputError(
                f"{where}: written by an older bodymetry (no 'format' key); "
                "run `bodymetry process` again to update it"
            )
        if fmt not in RESULTS_FORMATS_READ:
            raise InputError(
                f"{where}: results format {fmt!r}, this bodymetry reads formats "
                f"{', '.join(map(str, RESULTS_FORMATS_READ))}"
            )
        if not isinstance(data.get("session"), Mapping):
            raise InputError(
                f"{where}: no 'session' object; not a results file of `bodymetry process`"
            )
        if fmt == 2:
            persons = (PersonResults.from_json(data, where),)
        else:
            raw = data.get("persons")
            if not isinstance(raw, list) or not raw:
                raise InputError(
                    f"{where}: no 'persons' list; not a results file of `bodymetry process`"
                )
            persons = tuple(
                PersonResults.from_json(
                    p if isinstance(p, Mapping) else {}, f"{where}: persons[{i}]", i
                )
                for i, p in enumerate(raw)
            )
            if len({p.id for p in persons}) != len(persons):
                raise InputError(f"{where}: person ids repeat: {[p.id for p in persons]}")
        config = data.get("config")
        if not isinstance(config, Mapping):
            raise InputError(
                f"{where}: no 'config' object; not a results file of `bodymetry process`"
            )
        return cls(
            session=SessionInfo.from_json(data["session"]),
            config=ProcessConfig.from_json(dict(config), f"{where}: config"),
            models=str(config.get("models", "")),
            models_reused=bool(config.get("models_reused", False)),
            summary_version=int(data.get("summary_version", 0)),
            persons=persons,
            timing_seconds=dict(data.get("timing_seconds", {})),
            calibration_source=str(data.get("calibration_source", "")),
            warnings=tuple(str(w) for w in data.get("warnings", [])),
            working_resolution=(
                WorkingResolution.from_json(
                    data["working_resolution"], f"{where}: working_resolution"
                )
                if data.get("working_resolution") is not None
                else None
            ),
        )

    @classmethod
    def read(cls, path: Path) -> RunResults:
        return cls.from_json(read_json_object(path), str(path))

    def write(self, layout: RunLayout) -> None:
        """Write ``results.json`` (atomically: a reader never sees half a file)."""
        write_json_atomic(layout.results, self.to_json())


#: Version of ``study.json`` written by ``bodymetry batch``.
STUDY_FORMAT = 1


@dataclass(frozen=True)
class StudySession:
    """One session of a study (``bodymetry batch``).

    Attributes
    ----------
    name : str
        Its run folder's name inside the study folder (unique in the study).
    session_path : str
        The session folder.
    status : str
        ``"done"`` (results.json written), ``"failed"`` or ``"pending"``.
    reason : str
        Why it failed (one line), else empty.
    rig : str
        The discriminative models' key of its camera rig (empty when unknown).
    """

    name: str
    session_path: str
    status: str
    reason: str = ""
    rig: str = ""

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "study.json") -> StudySession:
        try:
            return cls(
                name=str(data["name"]),
                session_path=str(data["session_path"]),
                status=str(data["status"]),
                reason=str(data.get("reason", "")),
                rig=str(data.get("rig", "")),
            )
        except (KeyError, TypeError) as exc:
            raise InputError(f"{where}: malformed session entry ({exc})") from exc


@dataclass(frozen=True)
class RigEntry:
    """One camera rig of a study: its models and the sessions on it.

    Attributes
    ----------
    sessions : tuple of str
        The study's session names on this rig, sorted.
    trained : bool or None
        Whether this call trained the models (False: from the cache; None: every
        session on the rig was finished already, nothing was loaded).
    seconds : float or None
        Time to train or load the models.
    """

    sessions: tuple[str, ...]
    trained: bool | None = None
    seconds: float | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"trained": self.trained, "sessions": list(self.sessions)}
        if self.seconds is not None:
            out["seconds"] = self.seconds
        return out

    @classmethod
    def from_json(cls, data: Any, where: str = "rig") -> RigEntry:
        try:
            seconds = data.get("seconds")
            return cls(
                tuple(str(s) for s in data["sessions"]),
                None if data.get("trained") is None else bool(data["trained"]),
                None if seconds is None else float(seconds),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed rig entry ({exc})") from exc


@dataclass(frozen=True)
class StudyResults:
    """``study.json``: what ``bodymetry batch`` did, read by the cohort report.

    Attributes
    ----------
    sessions : tuple of StudySession
        In the order given on the command line.
    rigs : dict of str to RigEntry
        Per rig key.
    timing_seconds : dict of str to float
    """

    sessions: tuple[StudySession, ...]
    rigs: dict[str, RigEntry] = field(default_factory=dict)
    timing_seconds: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": STUDY_FORMAT,
            "sessions": [s.to_json() for s in self.sessions],
            "rigs": {k: r.to_json() for k, r in self.rigs.items()},
            "timing_seconds": self.timing_seconds,
        }

    def write(self, path: Path) -> None:
        """Write ``STUDY/study.json`` (atomically)."""
        write_json_atomic(path, self.to_json())

    @classmethod
    def read(cls, path: Path) -> StudyResults:
        """Read ``STUDY/study.json``; InputError naming the file when it is not one."""
        data = read_json_object(path)
        if data.get("format") != STUDY_FORMAT or not isinstance(data.get("sessions"), list):
            raise InputError(
                f"{path}: not a study.json of `bodymetry batch` (format {STUDY_FORMAT})"
            )
        return cls(
            sessions=tuple(
                StudySession.from_json(s, f"{path}: sessions[{i}]")
                for i, s in enumerate(data["sessions"])
            ),
            rigs={
                k: RigEntry.from_json(r, f"{path}: rigs.{k}")
                for k, r in dict(data.get("rigs", {})).items()
            },
            timing_seconds=dict(data.get("timing_seconds", {})),
        )


@dataclass(frozen=True)
class RunManifest:
    """``run.json``: what a run folder is of, written before anything else
    (:func:`bodymetry.run_folder.prepare_run_folder`).

    Attributes
    ----------
    format : int
    session_path : str
        The session folder (absolute).
    session_fingerprint : str
        :func:`bodymetry.run_folder.session_fingerprint` of the session.
    config_fingerprint : str
        :func:`bodymetry.run_folder.config_fingerprint` of the settings.
    bodymetry_version : str
    created : str
        ISO 8601 time (UTC) the run folder was started.
    """

    format: int
    session_path: str
    session_fingerprint: str
    config_fingerprint: str
    bodymetry_version: str
    created: str

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def write(self, layout: RunLayout) -> None:
        write_json_atomic(layout.manifest, self.to_json())

    @classmethod
    def read(cls, path: Path) -> RunManifest:
        data = read_json_object(path)
        try:
            return cls(**{k: data[k] for k in cls.__dataclass_fields__})
        except (KeyError, TypeError) as exc:
            raise InputError(f"{path}: not a bodymetry run.json ({exc})") from exc


@dataclass(frozen=True)
class Evaluation:
    """``evaluation.json``: the paper's Figure 3 for a run with ground truth
    (``bodymetry evaluate``).

    Attributes
    ----------
    run : str
        The run folder (absolute).
    session : str
        The session's name.
    frames : int
        The frames evaluated (the run's ``ok`` frames).
    frames_failed : int
    actual : dict of str to float
        The true value of each of :data:`CORE_MEASUREMENTS`.
    table : dict of str to dict of str to Stat
        Per measurement, per stage (:data:`STAGES` the run has, then
        :data:`GT_STAGE`): mean and spread over the frames (the session
        stage's ``std`` is its standard error).
    mpjpe_mm : dict of str to float
        Mean per-joint position error per stage.
    silhouette_iou_mean : float
    person : int or None
        The run's person evaluated, for a run of several persons (None: the run's
        one person).
    truth_person : int
        The studio's person their truth is (0: the session's subject), matched
        by where they stood for a person capture told apart.
    """

    run: str
    session: str
    frames: int
    frames_failed: int
    actual: dict[str, float]
    table: dict[str, dict[str, Stat]]
    mpjpe_mm: dict[str, float]
    silhouette_iou_mean: float
    person: int | None = None
    truth_person: int = 0

    @property
    def stages(self) -> tuple[str, ...]:
        """The stages evaluated, in pipeline order (:data:`STAGES`, then :data:`GT_STAGE`)."""
        present = {s for row in self.table.values() for s in row}
        return tuple(s for s in (*STAGES, GT_STAGE) if s in present)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": EVALUATION_FORMAT,
            "run": self.run,
            "session": self.session,
            "frames": self.frames,
            "frames_failed": self.frames_failed,
            "table": {
                key: {"actual": self.actual[key], **{s: v.to_json() for s, v in row.items()}}
                for key, row in self.table.items()
            },
            "mpjpe_mm": self.mpjpe_mm,
            "silhouette_iou_mean": self.silhouette_iou_mean,
            "person": self.person,
            "truth_person": self.truth_person,
        }

    def write(self, layout: RunLayout) -> None:
        """Write it where ``layout`` keeps it (:meth:`RunLayout.for_person`)."""
        write_json_atomic(layout.evaluation, self.to_json())

    @classmethod
    def read(cls, path: Path) -> Evaluation:
        """Read ``evaluation.json``; InputError naming the file for an old or foreign one."""
        data = read_json_object(path)
        if data.get("format") != EVALUATION_FORMAT:
            raise InputError(
                f"{path}: not an evaluation.json of this bodymetry (format "
                f"{data.get('format')!r}, expected {EVALUATION_FORMAT}); run `bodymetry evaluate` "
                "again"
            )
        try:
            table = {
                str(key): {str(s): Stat.from_json(v) for s, v in dict(row).items() if s != "actual"}
                for key, row in dict(data["table"]).items()
            }
            actual = {str(k): float(row["actual"]) for k, row in dict(data["table"]).items()}
            return cls(
                run=str(data["run"]),
                session=str(data["session"]),
                frames=int(data["frames"]),
                frames_failed=int(data["frames_failed"]),
                actual=actual,
                table=table,
                mpjpe_mm={str(k): float(v) for k, v in dict(data["mpjpe_mm"]).items()},
                silhouette_iou_mean=float(data["silhouette_iou_mean"]),
                person=None if data.get("person") is None else int(data["person"]),
                truth_person=int(data.get("truth_person", 0)),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{path}: malformed evaluation ({exc})") from exc
