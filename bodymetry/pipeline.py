"""The run as one step graph: plain step functions with typed inputs and outputs.

A run of one session is these steps (docs/design.md, "The step graph"):

====================  ===========  =============================================================
step                  grain        does
====================  ===========  =============================================================
:func:`prepare`       session      checks the inputs, creates or resumes the run folder, resolves
                                   the cameras and their working resolution
:func:`plan`          session      which kept frames are recorded already; whether the run is
                                   finished (then nothing else runs)
:func:`backgrounds`   session      the empty-scene background model of each camera
:func:`segment`       frames       each kept frame's silhouettes (once per frame), at the working
                                   resolution, with the subject's landmarks
:func:`check_calibration`  session  shifts a camera whose calibration the landmarks contradict
:func:`plan_persons`  session      whom the run measures: every person capture tells apart and
                                   follows, ``--person N``, or the one subject
:func:`choose_person` person       each kept frame's silhouettes as one person's
:func:`train`         rig          the rig's discriminative models (cached; once per rig)
:func:`fit`           frame        one person's fit of one frame, written to the run folder
                                   (arrays and mesh, then the record that marks it done)
:func:`rescue`        person       the frames below the person's quality gate, again from
                                   their neighbours
:func:`register_cameras`  session  shifts a camera whose fitted bodies sit off its silhouettes
                                   in every frame; the frames are then fitted again
:func:`finish_person` person       the quality gate and the session stage of one person
:func:`finish`        session      ``results.json``, every person
:func:`review`        session      the recording, MCAP, report and CSV
====================  ===========  =============================================================

:func:`run_session` wires them, once, for both executors
(:mod:`bodymetry.executors`): ``bodymetry process`` runs it on a local process
pool, ``bodymetry batch`` on Dask (one call per session, all sessions at once).
The executor only decides where a step runs and at which grain frames are read
(one sequential pass on a workstation, a seek per frame on a cluster); the steps
and their order are the same, so ``process`` of a session and ``batch`` of it
write the same run.

Training and the fit work at each camera's working resolution
(:mod:`bodymetry.estimation.resolution`, chosen from the calibration by
:func:`prepare`): the models are trained with the working cameras, and the
observed silhouettes, segmented at the cameras' resolution, are downscaled to
it in :func:`segment` before the fit and the record.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.calibration.io import save_calibration
from bodymetry.cameras import resolve_cameras
from bodymetry.capture.background import BackgroundModel
from bodymetry.capture.ground_truth import SubjectTruth, match_person, person_folder
from bodymetry.capture.ingest import SyncReport, check_sync
from bodymetry.capture.landmarks import (
    LandmarkConfig,
    principal_point_offsets,
    shifted_camera,
    triangulate_landmarks,
)
from bodymetry.capture.people import Sighting
from bodymetry.capture.persons import track_ids
from bodymetry.capture.segmentation import background_models, segment_session
from bodymetry.capture.session import Session, load_session
from bodymetry.errors import InputError
from bodymetry.estimation.fit import (
    FrameFit,
    poor_fit_hint,
    preload,
    session_gate,
    shared_body_model,
)
from bodymetry.estimation.outline_check import check_outline
from bodymetry.estimation.records import FrameArrays, FrameRecord, SessionShape, summarize
from bodymetry.estimation.registration import (
    CameraShift,
    camera_shifts,
    read_registration,
    write_registration,
)
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import (
    SUMMARY_VERSION,
    PersonResults,
    RunLayout,
    RunResults,
    SessionInfo,
)
from bodymetry.estimation.session_shape import fit_session_shape, session_frame
from bodymetry.estimation.studio_accuracy import is_low_contrast, run_contrast
from bodymetry.estimation.training import cached_models_path, load_or_train, rig_key
from bodymetry.estimation.view_selection import (
    ABSENT,
    MIN_PIXELS,
    left_out_views,
    usable_camera_frames,
)
from bodymetry.executors import Executor
from bodymetry.frame_jobs import (
    FitJob,
    read_done_frames,
    rescue_poor_frames,
    run_fit_job,
    write_frame,
)
from bodymetry.log import Progress
from bodymetry.preflight import check_session
from bodymetry.review.build import build_review
from bodymetry.run_folder import prepare_run_folder

log = logging.getLogger(__name__)

__all__ = [
    "STEPS",
    "PersonPlan",
    "PreparedRun",
    "RigModels",
    "SegmentedFrame",
    "SessionPlan",
    "SessionRun",
    "apply_registration",
    "backgrounds",
    "camera_warnings",
    "check_calibration",
    "choose_person",
    "finish",
    "finish_person",
    "fit",
    "judged_agreement",
    "plan",
    "plan_persons",
    "prepare",
    "register_cameras",
    "rescue",
    "review",
    "run_session",
    "segment",
    "session_stage",
    "train",
]


# --- what the steps hand each other -------------------------------------------------------------
@dataclass(frozen=True)
class PreparedRun:
    """A session checked, its run folder ready and its cameras resolved.

    Attributes
    ----------
    session : Session
    layout : RunLayout
    cameras : CameraGroup
        The working rig (session order): the calibration's cameras at
        their working resolution, what training and the fit use.
    calibration_source : str
    resolution : WorkingResolution
        Each camera's working resolution (recorded in ``results.json``).
    calibrated : CameraGroup
        The calibration's cameras at the videos' resolution: what capture
        uses (its silhouettes and landmarks are at that resolution).
    warnings : tuple of str
        The up-front check's warnings (and the calibration check's).
    landmark_config : LandmarkConfig or None
        Set when :func:`check_calibration` or :func:`apply_registration` shifted
        cameras: the subject's landmarks are then triangulated again through them.
    unregistered : CameraGroup or None
        The working rig before :func:`apply_registration` shifted cameras (None:
        none shifted): the rig the discriminative models are trained and cached
        for, so that a resumed run finds the models its first part used.
    """

    session: Session
    layout: RunLayout
    cameras: CameraGroup
    calibration_source: str
    resolution: WorkingResolution
    calibrated: CameraGroup
    warnings: tuple[str, ...] = ()
    landmark_config: LandmarkConfig | None = None
    unregistered: CameraGroup | None = None

    @property
    def rig(self) -> CameraGroup:
        """The working rig the discriminative models are trained for."""
        return self.cameras if self.unregistered is None else self.unregistered

    def landmarks(
        self, views: Sequence[np.ndarray | None], recorded: np.ndarray | None
    ) -> np.ndarray | None:
        """A frame's 3D landmarks through the final cameras: ``recorded`` (capture's)
        unless the calibration check shifted cameras, then triangulated again."""
        if self.landmark_config is None or not views:
            return recorded
        if sum(v is not None for v in views) < 2:
            return None
        return triangulate_landmarks(self.calibrated, views, self.landmark_config)


@dataclass(frozen=True)
class SessionPlan:
    """What is left to do in a session's run folder.

    Attributes
    ----------
    report : SyncReport
        The session's videos and kept frames (probed once, reused by its steps).
    done : dict of int to FrameRecord
        Frames already recorded whole.
    finished : RunResults or None
        The recorded ``results.json`` when it holds every kept frame with these
        settings and the review is written: nothing is left to do.
    """

    report: SyncReport
    done: dict[int, FrameRecord]
    finished: RunResults | None = None

    @property
    def kept(self) -> tuple[int, ...]:
        """The session's kept frames."""
        return tuple(int(f) for f in self.report.kept)

    @property
    def pending(self) -> tuple[int, ...]:
        """The kept frames still to fit."""
        return tuple(f for f in self.kept if f not in self.done)


@dataclass(frozen=True)
class SegmentedFrame:
    """One kept frame's silhouettes, as the fit needs them.

    Attributes
    ----------
    frame : int
    masks : tuple of (h_c, w_c) bool
        Observed silhouettes at the working resolution, camera order
        (:meth:`WorkingResolution.downscale` of capture's full-size masks).
    flags : tuple of tuple of str
        Capture's flags per camera (a view flagged ``unreliable`` is left out
        of the fit: :mod:`bodymetry.estimation.view_selection`).
    landmarks : (33, 3) float or None
        The subject's landmarks triangulated through the calibrated cameras.
    view_landmarks : tuple
        Each camera's 2D landmarks (empty without the learned segmenter).
    agreement : dict of str to float
        Capture's agreement of each judged view with the frame's other
        evidence (:func:`bodymetry.capture.fusion.view_agreement`; views not
        judged are absent), by camera name.
    persons : int or None
        Person-sized bodies in the capture volume
        (:attr:`bodymetry.capture.segmentation.SilhouetteFrame.persons`).
    people : tuple of Sighting
        Each person found, with their masks at the working resolution
        (:attr:`bodymetry.capture.segmentation.SilhouetteFrame.sightings`; empty
        where capture does not tell people apart); :func:`choose_person` turns
        the frame into one person's.
    unknown : tuple of ((h_c, w_c) bool or None)
        Per camera at the working resolution, the chosen person's pixels that
        someone nearer covers (neither person nor background to the fit); empty
        unless :func:`choose_person` set them.
    clothing : tuple of ((h_c, w_c) bool or None)
        Per camera at the working resolution, the silhouettes' pixels that are
        not skin (:attr:`SilhouetteFrame.clothing
        <bodymetry.capture.segmentation.SilhouetteFrame.clothing>`); empty
        where capture could not tell.
    contrast : float or None
        How plainly the silhouettes stand out from the empty scene
        (:attr:`SilhouetteFrame.contrast
        <bodymetry.capture.segmentation.SilhouetteFrame.contrast>`); None without
        an empty-scene clip, and for a person told apart from others (it is the
        frame's largest body's).
    """

    frame: int
    masks: tuple[np.ndarray, ...]
    flags: tuple[tuple[str, ...], ...]
    landmarks: np.ndarray | None
    view_landmarks: tuple
    agreement: dict[str, float] = field(default_factory=dict)
    persons: int | None = None
    people: tuple[Sighting, ...] = field(default=(), repr=False)
    unknown: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    clothing: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    contrast: float | None = None


@dataclass(frozen=True)
class RigModels:
    """The discriminative models of a rig, in the cache.

    Attributes
    ----------
    key : str
        :func:`bodymetry.estimation.training.rig_key`.
    path : Path
    reused : bool
        Found in the cache (not trained by this call).
    seconds : float
    """

    key: str
    path: Path
    reused: bool
    seconds: float


#: A tracked person is measured when seen in at least this share of the kept frames
#: (and in at least two): a crowd of one frame (a passer-by, a phantom of the
#: association) is named in a warning, not measured on one frame.
MIN_PERSON_SHARE = 0.3


@dataclass(frozen=True)
class PersonPlan:
    """Whom a run measures (:func:`plan_persons`).

    Attributes
    ----------
    ids : tuple of int
        The persons measured, by tracked identity; ``(0,)`` for the one subject.
    told_apart : bool
        Capture told them apart: each is fitted to their own pixels and landmarks
        (:func:`choose_person`). False: one subject per frame, as capture's
        silhouettes have it (anyone else in view may mix in; the run says so).
    warnings : tuple of str
        People followed but not measured (seen in too few kept frames).
    """

    ids: tuple[int, ...] = (0,)
    told_apart: bool = False
    warnings: tuple[str, ...] = ()

    @property
    def several(self) -> bool:
        """Whether the run measures more than one person (each in ``persons/K/``)."""
        return len(self.ids) > 1

    def layout_person(self, ident: int) -> int | None:
        """The :meth:`RunLayout.for_person` index of person ``ident``'s frame files
        (None: the run's own ``frames/``, as a run of one person keeps them)."""
        return ident if self.several else None


# --- the steps ------------------------------------------------------------------------------------
def prepare(
    session_path: str | Path,
    out: str | Path,
    config: ProcessConfig,
    restart: bool = False,
    progress: Progress | None = None,
) -> PreparedRun:
    """Check the session, create or resume the run folder, resolve the cameras and
    choose their working resolution (``config.working_person_px``).

    Every problem with the inputs and the output folder is listed before any
    long work, and before the run folder is created (a bad session leaves
    nothing behind).

    Raises
    ------
    InputError
        Listing every problem found.
    """
    report = check_session(session_path, Path(out))
    report.raise_if_failed()
    for warning in report.warnings:
        log.warning("%s", warning)
    session = load_session(session_path)
    if config.frame_step is not None and config.frame_step != session.frame_step:
        log.info(
            "%s: fitting every %d. frame (session.yaml says %d)",
            session.folder,
            config.frame_step,
            session.frame_step,
        )
        session = replace(session, frame_step=config.frame_step)
    layout = RunLayout(Path(out))
    prepare_run_folder(layout.folder, session, config, restart=restart)
    layout.frames_dir.mkdir(parents=True, exist_ok=True)
    resolved = resolve_cameras(session, layout.folder, progress)
    resolution = WorkingResolution.choose(resolved.cameras, config.working_person_px)
    return PreparedRun(
        session,
        layout,
        resolution.apply(resolved.cameras),
        resolved.source,
        resolution,
        resolved.cameras,
        tuple(str(w) for w in report.warnings),
    )


def plan(prepared: PreparedRun, config: ProcessConfig) -> SessionPlan:
    """The kept frames, those recorded whole already, and whether the run is finished.

    A run is finished when ``results.json`` holds every kept frame, was made
    with these settings (the session stage's and the review's included) and by
    this code's summary (:data:`SUMMARY_VERSION`), and the review files are
    written. Otherwise the frames recorded whole are reused and the rest redone.
    """
    report = check_sync(prepared.session)
    kept = {int(f) for f in report.kept}
    layout = prepared.layout
    done = read_done_frames(layout)
    if not layout.results.is_file():
        return SessionPlan(report, done)
    try:
        recorded = RunResults.read(layout.results)
    except InputError as exc:
        log.warning("%s; summarizing the run again", exc)
        return SessionPlan(report, done)
    # A run of several persons keeps each one's frames in persons/K/.
    layouts = [layout.for_person(p.id if recorded.several else None) for p in recorded.persons]
    finished = (
        all({r.frame for r in p.frames} == kept for p in recorded.persons)
        and all(set(read_done_frames(each)) == kept for each in layouts)
        and replace(recorded.config, workers=None) == replace(config, workers=None)
        and (not config.review or all(p.is_file() for p in layout.review_files))
    )
    if finished and recorded.summary_version != SUMMARY_VERSION:
        # A warning, not progress: the run's numbers change from what the file said.
        log.warning(
            "%s: summary made by an earlier bodymetry (summary version %d, now %d); "
            "making it again from the recorded frames (the per-frame fits stay as "
            "recorded; --restart fits them again)",
            layout.results,
            recorded.summary_version,
            SUMMARY_VERSION,
        )
        finished = False
    return SessionPlan(report, done, recorded if finished else None)


def backgrounds(
    prepared: PreparedRun, planned: SessionPlan, config: ProcessConfig, read_method: str
) -> list[BackgroundModel | None]:
    """Each camera's background model (None per camera where capture uses the segmenter alone).

    ``read_method`` is ``"sequential"`` or ``"seek"`` (the executor's way of
    reading video; both read the same frames).
    """
    if config.capture.method == "person":
        return [None] * len(prepared.session.cameras)
    median = not config.capture.uses_segmenter
    return list(
        background_models(prepared.session, planned.report, method=read_method, median=median)
    )


def segment(
    prepared: PreparedRun,
    planned: SessionPlan,
    models: Sequence[BackgroundModel | None],
    frames: Sequence[int],
    config: ProcessConfig,
    read_method: str,
) -> list[SegmentedFrame]:
    """The silhouettes of ``frames`` (capture), brought to the working resolution.

    Parameters
    ----------
    prepared : PreparedRun
    planned : SessionPlan
    models : sequence of (BackgroundModel or None)
        :func:`backgrounds`, camera order.
    frames : sequence of int
        Kept frames, in order (one sequential pass reads them all; the Dask
        executor segments one frame a task).
    config : ProcessConfig
    read_method : {"sequential", "seek"}
    """
    names = prepared.cameras.names
    return [
        SegmentedFrame(
            frame=sil.frame,
            # Held at the working resolution (a long session's full-size masks are large).
            masks=tuple(prepared.resolution.downscale(names, sil.masks)),
            flags=tuple(tuple(f) for f in sil.flags),
            landmarks=sil.landmarks,
            view_landmarks=tuple(sil.view_landmarks),
            agreement=judged_agreement(names, sil.agreement, sil.frame),
            persons=sil.persons,
            contrast=sil.contrast,
            people=tuple(_working(prepared.resolution, names, p, sil.masks) for p in sil.sightings),
            clothing=_working_masks(prepared.resolution, names, sil.clothing, sil.masks)
            if any(c is not None for c in sil.clothing)
            else (),
        )
        for sil in segment_session(
            prepared.session,
            config=config.capture,
            cameras=prepared.calibrated,
            report=planned.report,
            models=models,
            frames=list(frames),
            read_method=read_method,
            keep_images=False,
        )
    ]


def _working(
    resolution: WorkingResolution, names: Sequence[str], seen: Sighting, full: Sequence[np.ndarray]
) -> Sighting:
    """``seen`` with its masks and hidden pixels at the working resolution (None stays
    None); ``full``: the frame's masks at the cameras' own size."""

    return replace(
        seen,
        masks=_working_masks(resolution, names, seen.masks, full),
        hidden=_working_masks(resolution, names, seen.hidden, full) if seen.hidden else (),
    )


def _working_masks(
    resolution: WorkingResolution,
    names: Sequence[str],
    masks: Sequence[np.ndarray | None],
    full: Sequence[np.ndarray],
) -> tuple[np.ndarray | None, ...]:
    """Per camera masks at the cameras' own size brought to the working resolution
    (None stays None); ``full``: the frame's masks at the cameras' own size."""
    small = resolution.downscale(
        names, [np.zeros_like(f) if m is None else m for m, f in zip(masks, full, strict=True)]
    )
    return tuple(None if m is None else w for m, w in zip(masks, small, strict=True))


def judged_agreement(
    names: Sequence[str], agreement: Sequence[float | None], frame: int
) -> dict[str, float]:
    """Capture's per-camera agreement (:attr:`SilhouetteFrame.agreement
    <bodymetry.capture.segmentation.SilhouetteFrame.agreement>`) by camera name, the
    views it did not judge (None) left out; empty when capture judged nothing.

    Raises
    ------
    ValueError
        When ``agreement`` has neither one entry per camera nor none, or a value
        is not in [0, 1].
    """
    if not agreement:
        return {}
    if len(agreement) != len(names):
        raise ValueError(
            f"frame {frame}: capture's agreement has {len(agreement)} values for "
            f"{len(names)} cameras"
        )
    out = {n: float(a) for n, a in zip(names, agreement, strict=True) if a is not None}
    bad = {n: a for n, a in out.items() if not 0.0 <= a <= 1.0}
    if bad:
        raise ValueError(f"frame {frame}: capture's agreement outside [0, 1]: {bad}")
    return out


def needs_every_frame(config: ProcessConfig) -> bool:
    """Whether every kept frame is segmented before any frame is fitted: for the
    calibration check (its landmarks) or to follow people through the frames
    (:func:`plan_persons`, where the segmenter tells them apart); otherwise only
    the pending frames are."""
    return config.person is not None or (
        config.capture.uses_segmenter
        and (config.capture.landmarks.refine_calibration or not config.largest)
    )


def check_calibration(
    prepared: PreparedRun, segmented: Sequence[SegmentedFrame], config: ProcessConfig
) -> PreparedRun:
    """Check the cameras against the subject's landmarks in all kept frames; shift the
    principal point of a camera that is systematically off
    (:func:`bodymetry.capture.landmarks.principal_point_offsets`).

    A shifted camera is written to the run's ``calibration.yaml`` (the session's
    file is never modified) and named in a warning (``results.json``). Without
    landmarks (no segmenter) or with ``capture.landmarks.refine_calibration``
    off, the run keeps the calibration as given. In frames with more than one
    person in view, each person's own landmarks are used where capture told
    them apart (:attr:`SegmentedFrame.people`); other such frames are left out
    (a warning says so), and with no other frame the calibration is kept as
    given.
    """
    cfg = config.capture.landmarks
    if not cfg.refine_calibration:
        return prepared
    # Each view's landmarks are its most prominent person's: with two people in the
    # capture volume they may be different people in different views, and their
    # residuals say nothing about the cameras (on the real two-person Pose2Sim
    # recording they shifted a camera by 30 px). Where capture told the people
    # apart, each person's own landmarks are used instead.
    frames: list = []
    crowded = []
    for s in segmented:
        if (s.persons or 0) <= 1:
            if s.view_landmarks:
                frames.append(s.view_landmarks)
        elif s.people:
            frames.extend(p.landmarks for p in s.people)
        else:
            crowded.append(s.frame)
    if crowded:
        notes = (
            f"calibration check: {len(crowded)} kept frames have more than one person in "
            "view, whose landmarks may be different people in different cameras; "
            + (
                "they were left out of the check"
                if frames
                else "the calibration was not checked and is used as given"
            ),
        )
        log.warning("%s", notes[0])
        prepared = replace(prepared, warnings=(*prepared.warnings, *notes))
    if not frames:
        return prepared
    cameras, offsets = principal_point_offsets(prepared.calibrated, frames, cfg)
    for offset in offsets:
        log.info("%s", offset.describe())
    applied = [o for o in offsets if o.applied]
    if not applied:
        return prepared
    warnings = tuple(
        f"{o.describe()}: the calibration does not fit this video, so its principal point "
        "was shifted by that offset for this run (RUN/calibration.yaml; "
        "--set capture.landmarks.refine_calibration=false keeps the calibration as given)"
        for o in applied
    )
    for text in warnings:
        log.warning("%s", text)
    save_calibration(prepared.layout.calibration, cameras)
    return replace(
        prepared,
        calibrated=cameras,
        cameras=prepared.resolution.apply(cameras),
        warnings=(*prepared.warnings, *warnings),
        landmark_config=cfg,
    )


def plan_persons(
    prepared: PreparedRun, segmented: Sequence[SegmentedFrame], config: ProcessConfig
) -> PersonPlan:
    """Whom the run measures: every person capture tells apart and follows through
    enough kept frames, ``process --person N``'s one, or else the one subject.

    Identities are given over all kept frames
    (:func:`bodymetry.capture.persons.track_ids`). Where capture tells no people
    apart (one person in view, an empty-scene clip whose hull split is too coarse
    to measure, ``--largest``), the run measures one subject per frame, as today.

    Raises
    ------
    InputError
        For ``--person N`` when capture told no people apart, or the recording
        has no person ``N``.
    """
    chosen = config.person
    ordered = sorted(segmented, key=lambda s: s.frame)
    from_segmenter = [[p for p in s.people if p.source != "hull"] for s in ordered]
    if chosen is None and (config.largest or not any(from_segmenter)):
        return PersonPlan()
    if chosen is not None and not any(s.people for s in ordered):
        raise InputError(
            f"--person {chosen}: capture told no people apart in this recording (one person "
            "in view, no calibrated rig, or a session with an empty-scene clip, where people "
            "are not told apart yet); run without --person to measure the subject"
        )
    if chosen is not None and not any(from_segmenter):
        # Measured on two-person studio sessions, the hull's split gives each person
        # masks too coarse to measure (mean IoU 0.70 against their truth; the fits
        # failed the quality gate or read kilograms off): no numbers rather than
        # wrong ones.
        raise InputError(
            f"--person {chosen}: with an empty-scene clip people are told apart by "
            "splitting the multi-view hull, which is not yet accurate enough to measure "
            'one of them (docs/capture.md, "Persons and occlusion"); run without --person'
        )
    ids = track_ids([s.people for s in ordered])
    known = 1 + max((i for frame in ids for i in frame), default=-1)
    if chosen is not None:
        if chosen >= known:
            raise InputError(
                f"--person {chosen}: capture followed {known} "
                f"{'person' if known == 1 else 'people'} through this recording (0 to {known - 1})"
            )
        return PersonPlan((chosen,), told_apart=True)
    seen = {i: sum(i in frame for frame in ids) for i in range(known)}
    need = max(2, math.ceil(MIN_PERSON_SHARE * len(ordered)))
    measured = tuple(i for i, n in seen.items() if n >= need)
    warnings = tuple(
        f"person {i} was seen in only {n} of {len(ordered)} kept frames and is not measured "
        f"(at least {need} wanted)"
        for i, n in seen.items()
        if n < need
    )
    if len(measured) < 2:
        # One person followed through the recording: the one subject, measured as
        # capture's silhouettes have them (a one-person run is unchanged).
        return PersonPlan(warnings=warnings)
    log.info("measuring %d people: %s", len(measured), ", ".join(map(str, measured)))
    return PersonPlan(measured, told_apart=True, warnings=warnings)


def choose_person(
    prepared: PreparedRun,
    segmented: Sequence[SegmentedFrame],
    config: ProcessConfig,
    chosen: int,
) -> list[SegmentedFrame]:
    """Every kept frame as person ``chosen`` of the capture sees it (in frame order).

    The people capture found in each frame are given identities across the
    frames (:func:`bodymetry.capture.persons.track_ids`, as in
    :func:`plan_persons`), and each frame's silhouettes, flags and landmarks
    become those of the chosen person, with the pixels of theirs that someone
    nearer covers as ``unknown`` (neither person nor background to the fit): a
    view where most of them is hidden is flagged ``occluded`` and one whose
    detection mixed them with someone else ``mixed`` (both left out of that
    frame's fit), one that shows nothing of them ``empty``, and a frame without
    them has no silhouette (its record says so).
    """
    ordered = sorted(segmented, key=lambda s: s.frame)
    ids = track_ids([s.people for s in ordered])
    names = prepared.cameras.names
    out = []
    for seg, frame_ids in zip(ordered, ids, strict=True):
        if chosen not in frame_ids:
            masks = tuple(np.zeros_like(m) for m in seg.masks)
            out.append(
                replace(
                    seg, masks=masks, flags=(("empty", ABSENT),) * len(names), landmarks=None,
                    view_landmarks=(), agreement={}, people=(), contrast=None,
                )
            )  # fmt: skip
            continue
        person = seg.people[frame_ids.index(chosen)]
        masks = tuple(
            np.zeros_like(m) if mine is None else mine
            for m, mine in zip(seg.masks, person.masks, strict=True)
        )
        mixed = person.mixed or (False,) * len(names)
        flags = tuple(
            ("empty",) if mine is None else ("occluded",) if hidden else ("mixed",) if mix else ()
            for mine, hidden, mix in zip(person.masks, person.occluded, mixed, strict=True)
        )
        unknown = tuple(
            None if mine is None or u is None or not u.any() else u
            for mine, u in zip(person.masks, person.hidden or (None,) * len(names), strict=True)
        )
        views = list(person.landmarks)
        landmarks = (
            triangulate_landmarks(prepared.calibrated, views, config.capture.landmarks)
            if sum(v is not None for v in views) >= 2
            else None
        )
        out.append(
            replace(
                seg, masks=masks, flags=flags, landmarks=landmarks,
                view_landmarks=tuple(views), agreement={}, people=(), contrast=person.contrast,
                unknown=unknown if any(u is not None for u in unknown) else (),
            )
        )  # fmt: skip
    log.info(
        "person %d: in %d of %d kept frames", chosen, sum(chosen in f for f in ids), len(ordered)
    )
    return out


def rig_of(prepared: PreparedRun, config: ProcessConfig) -> str:
    """The cache key of the run's rig (:func:`bodymetry.estimation.training.rig_key`)."""
    return rig_key(prepared.rig, config.training)


def train(
    prepared: PreparedRun,
    config: ProcessConfig,
    progress: Progress | None = None,
    workers: int | None = None,
) -> RigModels:
    """Load the rig's models from the cache, training them first if needed.

    The training set is rendered at the working cameras' sizes
    (:attr:`PreparedRun.cameras`), and the cache key is theirs. ``workers``
    (default ``config.workers``) render it in parallel; in a daemon process
    (a worker of a cluster started with ``dask worker``, which may not start
    processes) it renders in this process.
    """
    if mp.current_process().daemon:
        workers = 1
    t0 = time.perf_counter()
    models, reused = load_or_train(
        prepared.rig,
        config.training,
        config.cache_dir,
        workers=workers if workers is not None else config.workers,
        progress=(lambda label, d, t: progress(f"training: {label}", d, t)) if progress else None,
    )
    path = cached_models_path(models.key, config.cache_dir)
    return RigModels(models.key, path, reused, time.perf_counter() - t0)


def fit_job_of(
    prepared: PreparedRun, models: RigModels, seg: SegmentedFrame, config: ProcessConfig
) -> FitJob:
    """The fit's job for one segmented frame, through the run's final cameras."""
    return FitJob(
        seg.frame,
        list(seg.masks),
        [list(f) for f in seg.flags],
        prepared.cameras,
        models.path,
        config.fit,
        prepared.landmarks(seg.view_landmarks, seg.landmarks),
        agreement=seg.agreement,
        persons=seg.persons,
        contrast=seg.contrast,
        unknown=list(seg.unknown),
        clothing=list(seg.clothing),
    )


def fit(
    prepared: PreparedRun,
    models: RigModels,
    seg: SegmentedFrame,
    config: ProcessConfig,
    person: int | None = None,
) -> FrameRecord:
    """Fit one frame and write it (:func:`bodymetry.frame_jobs.write_frame`) into the
    frame files of ``person`` (:meth:`PersonPlan.layout_person`; None: the run's own).

    Returns the record as written (rounded as in the file), so that a fresh
    run and a resumed one summarize exactly the same numbers.
    """
    layout = prepared.layout.for_person(person)
    return write_frame(layout, run_fit_job(fit_job_of(prepared, models, seg, config)))


def rescue(
    prepared: PreparedRun,
    models: RigModels,
    records: dict[int, FrameRecord],
    config: ProcessConfig,
    run_jobs: Callable[[Sequence[FitJob]], list[FrameFit]],
    progress: Progress | None = None,
    person: int | None = None,
) -> dict[int, FrameRecord]:
    """The frames below the session's quality gate, fitted again from their neighbours
    (:func:`bodymetry.frame_jobs.rescue_poor_frames`); ``run_jobs`` fits a round's jobs
    on the executor's workers. ``person``: as in :func:`fit`."""
    return rescue_poor_frames(
        prepared.layout.for_person(person),
        records,
        prepared.cameras,
        models.path,
        config.fit,
        config.fit.rescue_neighbours,
        progress,
        run_jobs,
    )


def register_cameras(
    prepared: PreparedRun,
    config: ProcessConfig,
    records: dict[int | None, dict[int, FrameRecord]],
) -> PreparedRun:
    """Measure each camera's offset between the fitted bodies and the observed
    silhouettes over every fitted frame (:func:`bodymetry.estimation.registration.camera_shifts`)
    and shift the cameras that are off (:func:`apply_registration`).

    ``records``: per person's layout (:meth:`PersonPlan.layout_person`), their
    frames' records. The offsets are written to ``RUN/registration.json``; when a
    camera is shifted, every frame's record is removed first, so that the caller
    fits them all again through the shifted cameras (and a run stopped in between
    measures again from fresh fits). Runs once: with ``registration.json`` written,
    the run is returned as it is (:func:`apply_registration` applied it).
    Pixels another person hides (``unknown``) count for neither silhouette.
    """
    cfg = config.registration
    layout = prepared.layout
    if not cfg.enabled or layout.registration.is_file():
        return prepared
    names = [cam.name for cam in prepared.cameras]
    pairs: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {n: [] for n in names}
    positions = []
    for person, frames in records.items():
        where = layout.for_person(person)
        for frame, record in sorted(frames.items()):
            if not record.fitted or "generative" not in record.estimates:
                continue
            positions.append(record.estimates["generative"].state.tau[0])
            try:
                arrays = FrameArrays.load(where.frame_arrays(frame))
            except InputError as exc:
                log.warning("%s; left out of the camera registration", exc)
                continue
            for name in names:
                observed, model = arrays.observed.get(name), arrays.model.get(name)
                if observed is None or model is None:
                    continue
                unknown = arrays.unknown.get(name)
                if unknown is not None:
                    observed, model = observed & ~unknown, model & ~unknown
                pairs[name].append((observed, model))
    if not positions:
        return prepared
    centre = np.median(np.asarray(positions), axis=0)
    shifts = camera_shifts(prepared.cameras, [pairs[n] for n in names], centre, cfg)
    for shift in shifts:
        log.info("camera registration: %s", shift.describe())
    if any(s.applied for s in shifts):
        for person, frames in records.items():
            where = layout.for_person(person)
            for frame in frames:
                where.frame_record(frame).unlink(missing_ok=True)
    write_registration(layout.registration, shifts)
    return _registered(prepared, config, shifts)


def apply_registration(prepared: PreparedRun, config: ProcessConfig) -> PreparedRun:
    """A resumed run with the registration :func:`register_cameras` recorded
    (``RUN/registration.json``) applied; without it (or with
    ``registration.enabled`` off) the run as it is."""
    layout = prepared.layout
    if not config.registration.enabled or not layout.registration.is_file():
        return prepared
    return _registered(prepared, config, read_registration(layout.registration))


def _registered(
    prepared: PreparedRun, config: ProcessConfig, shifts: Sequence[CameraShift]
) -> PreparedRun:
    """The run with the principal points of the cameras ``shifts`` applies to moved,
    written to the run's ``calibration.yaml`` and named in a warning (``results.json``)."""
    layout = prepared.layout
    by_name = {s.camera: s for s in shifts if s.applied}
    if not by_name:
        return prepared
    scales = prepared.resolution.scales
    shifted = []
    for cam in prepared.calibrated:
        s = by_name.get(cam.name)
        if s is None:
            shifted.append(cam)
            continue
        # The offsets are working-resolution pixels; the working camera is the calibrated
        # one scaled by 1/k (Camera.scaled), so a working pixel is exactly k of its own
        # (not the ratio of the rounded image sizes).
        k = scales[cam.name].factor
        shifted.append(shifted_camera(cam, s.dx * k, s.dy * k))
    calibrated = CameraGroup(shifted)
    warnings = tuple(
        f"{by_name[name].describe()}: its principal point was shifted by that offset and "
        "every frame fitted again (RUN/calibration.yaml, RUN/registration.json; "
        "--set registration.enabled=false keeps the cameras as the calibration check left them)"
        for name in sorted(by_name)
    )
    for text in warnings:
        log.warning("%s", text)
    save_calibration(layout.calibration, calibrated)
    return replace(
        prepared,
        calibrated=calibrated,
        cameras=prepared.resolution.apply(calibrated),
        warnings=(*prepared.warnings, *warnings),
        landmark_config=config.capture.landmarks,
        unregistered=prepared.rig,
    )


def session_stage(
    prepared: PreparedRun,
    config: ProcessConfig,
    records: Sequence[FrameRecord],
    progress: Progress | None = None,
    person: int | None = None,
) -> tuple[SessionShape | None, list[FrameRecord]]:
    """One shape for the session (:mod:`bodymetry.estimation.session_shape`).

    Reads the accepted frames' silhouettes back from the run folder (the
    ``frames/FFFFFF.npz`` written with their records; ``person``: as in
    :func:`fit`), so it runs the same after a resumed run. The frame records on disk
    are left as they are: the ``session`` estimates live in ``results.json``.

    Returns
    -------
    SessionShape or None
        None when ``config.session_shape.enabled`` is off.
    list of FrameRecord
        ``records`` with each accepted frame's ``session`` estimate added when
        the stage was accepted (unchanged otherwise).
    """
    if not config.session_shape.enabled:
        return None, list(records)
    ok = [r for r in records if r.ok]
    layout = prepared.layout.for_person(person)
    log.info("%s: session shape from %d accepted frames", prepared.session.folder, len(ok))
    try:
        arrays = [FrameArrays.load(layout.frame_arrays(r.frame)) for r in ok]
        worn, seen = np.sum([a.clothing_pixels() for a in arrays], axis=0) if arrays else (0, 0)
        clothing_share = worn / seen if seen else math.nan
        frames = [session_frame(r, a, prepared.cameras) for r, a in zip(ok, arrays, strict=True)]
        shape = fit_session_shape(
            shared_body_model(),
            prepared.cameras,
            frames,
            config.fit.refinement,
            config.session_shape,
            config.fit.density,
            progress,
        )
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        log.warning("%s: the session shape failed: %s", prepared.session.folder, exc)
        failed = SessionShape(status=f"failed: {exc}", frames=tuple(r.frame for r in ok))
        return failed, list(records)
    if not shape.summary.ok:
        log.warning("%s: session shape %s", prepared.session.folder, shape.summary.status)
    # The outline check at the states the summary reports: the shared shape
    # when accepted, else each frame's own fit.
    checked = [
        (f.masks, shape.estimates[f.frame].vector() if f.frame in shape.estimates else f.start)
        for f in frames
    ]
    outline = check_outline(
        shared_body_model(),
        prepared.cameras,
        checked,
        config.session_shape.refinement(config.fit.refinement),
        alignments=[shape.alignments.get(f.frame) for f in frames],
        clothing=[f.clothing for f in frames],
        # Low contrast moves the captured outline by part: the check needs more.
        low_contrast=bool(is_low_contrast(run_contrast(ok))),
    )
    out = [
        replace(r, estimates={**r.estimates, "session": shape.estimates[r.frame]})
        if r.frame in shape.estimates
        else r
        for r in records
    ]
    return replace(shape.summary, outline=outline, clothing_share=float(clothing_share)), out


def camera_warnings(
    records: Sequence[FrameRecord], names: Sequence[str], bound: float | None = None
) -> list[str]:
    """The run's warnings about its cameras: one per camera that saw no person in any
    kept frame, and one per camera whose view was left out as ``unreliable`` in some
    (:meth:`~bodymetry.estimation.view_selection.LeftOutView.describe`, quoting ``bound``,
    capture's agreement bound, when given)."""
    n_kept = len(records)
    seen = {n: sum(r.person_pixels.get(n, 0) >= MIN_PIXELS for r in records) for n in names}
    out = [
        f"camera {name!r} saw no person in any of the {n_kept} kept frames (covered, black "
        "or pointing away?); it contributed nothing to the measurements"
        for name, n in seen.items()
        if n == 0 and n_kept > 0
    ]
    return out + [view.describe(bound) for view in left_out_views(records, names)]


def finish_person(
    prepared: PreparedRun,
    config: ProcessConfig,
    records: dict[int, FrameRecord],
    persons: PersonPlan,
    ident: int,
    progress: Progress | None = None,
) -> PersonResults:
    """One person's results: their recorded frames held to their quality gate, their
    session stage (:func:`session_stage`), warnings and ground truth."""
    session = prepared.session
    name = f"{session.folder}" + (f" person {ident}" if persons.told_apart else "")
    gate, gated = session_gate([records[f] for f in sorted(records)], config.fit)
    shape, gated = session_stage(prepared, config, gated, progress, persons.layout_person(ident))
    ordered = tuple(gated)
    if gate.threshold < gate.min_iou:
        log.info(
            "%s: quality gate %.2f (the good frames score %.2f; min_iou %.2f; deficits x%.2f "
            "for the body's width)",
            name,
            gate.threshold,
            gate.reference,
            gate.min_iou,
            gate.width_scale,
        )
    warnings = camera_warnings(
        ordered, session.camera_names, bound=config.capture.fusion.min_agreement
    )
    if not any(r.ok for r in ordered):
        hint = poor_fit_hint(ordered)
        warnings.append(
            f"no frame of the {len(ordered)} kept frames was measured"
            + (f": {hint}" if hint else "")
        )
    if shape is not None and shape.outline is not None:
        warnings.extend(shape.outline.warnings)
    truth = _truth(session, ordered, warnings, ident if persons.told_apart else None)
    for text in warnings:
        log.warning("%s: %s", name, text)
    return PersonResults(
        id=ident,
        frames=ordered,
        summary=summarize(ordered, shape),
        told_apart=persons.told_apart,
        # A view left out of a frame (too few pixels, unreadable, unreliable) does not count.
        camera_frames=usable_camera_frames(ordered, session.camera_names),
        warnings=tuple(warnings),
        ground_truth=truth,
        quality_gate=gate,
        session_shape=shape,
    )


def finish(
    prepared: PreparedRun,
    config: ProcessConfig,
    models: RigModels,
    persons: Sequence[PersonResults],
    timing: dict[str, float],
    warnings: Sequence[str] = (),
) -> RunResults:
    """Write ``results.json``: every person's results (:func:`finish_person`) and the
    run's own (``warnings``: :attr:`PersonPlan.warnings`)."""
    session = prepared.session
    for text in warnings:
        log.warning("%s: %s", session.folder, text)
    shapes = [p.session_shape.seconds for p in persons if p.session_shape is not None]
    if shapes:
        timing = {**timing, "session_shape": sum(shapes)}
    results = RunResults(
        session=SessionInfo(
            path=str(session.folder.resolve()),
            name=session.name,
            cameras=tuple(session.camera_names),
            fps=session.fps,
            frame_step=session.frame_step,
        ),
        config=config,
        models=models.key,
        models_reused=models.reused,
        persons=tuple(persons),
        timing_seconds={k: round(v, 1) for k, v in timing.items()},
        calibration_source=prepared.calibration_source,
        warnings=(*prepared.warnings, *warnings),
        working_resolution=prepared.resolution,
    )
    results.write(prepared.layout)
    return results


def _truth(
    session: Session, records: Sequence[FrameRecord], warnings: list[str], person: int | None
) -> SubjectTruth | None:
    """A person's ground truth: the session's subject's, or for a person capture told
    apart (``person``) the studio person whose root their fits follow
    (:func:`bodymetry.capture.ground_truth.match_person`); None (and a warning
    in ``warnings``) where that is not clear: no comparison rather than one with
    somebody else's numbers."""
    folder = session.ground_truth_path
    if folder is None:
        return None
    if person is None:
        return SubjectTruth.read(folder)
    positions = {r.frame: r.estimates["generative"].state.tau[0] for r in records if r.fitted}
    index, distance = match_person(folder, positions)
    if index is None:
        warnings.append(
            f"person {person} is matched to none of the studio's people (nearest "
            f"root {distance:.2f} m away on average, or two about as near): the run is not "
            "compared with the ground truth"
        )
        return None
    log.info("person %d is the studio's person %d (%.2f m)", person, index, distance)
    return SubjectTruth.read(person_folder(folder, index))


def review(prepared: PreparedRun, config: ProcessConfig, progress: Progress | None = None) -> None:
    """The review outputs of the finished run (``config.review``), from its folder.

    A failure here is logged, never raised: ``results.json`` is safe on disk.
    """
    if not config.review:
        return
    try:
        build_review(prepared.layout.folder, pdf=config.pdf, progress=progress)
    except Exception:  # results.json is written; the review is extra
        log.exception("%s: building the review outputs failed", prepared.layout.folder)


#: The steps in graph order (docs/design.md draws them).
STEPS: tuple[Callable, ...] = (
    prepare,
    plan,
    backgrounds,
    segment,
    check_calibration,
    apply_registration,
    plan_persons,
    choose_person,
    train,
    fit,
    rescue,
    register_cameras,
    finish_person,
    finish,
    review,
)


# --- the graph ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SessionRun:
    """What :func:`run_session` did for one session.

    Attributes
    ----------
    results : RunResults
        The run's results (as recorded, when it was finished already).
    rig : str
        The rig's cache key.
    models : RigModels or None
        The rig's models; None when the run was finished already (nothing ran).
    """

    results: RunResults
    rig: str
    models: RigModels | None

    @property
    def ran(self) -> bool:
        """Whether anything was computed (False: the run was finished already)."""
        return self.models is not None


def run_session(
    session_path: str | Path,
    out: str | Path,
    config: ProcessConfig,
    executor: Executor,
    progress: Progress | None = None,
    *,
    restart: bool = False,
) -> SessionRun:
    """Run the step graph of one session on ``executor``; the one wiring of the steps.

    Parameters
    ----------
    session_path : path
        A session folder (docs/session-format.md).
    out : path
        The run folder; frames already recorded there are not fitted again, and
        a finished run (:func:`plan`) is returned as recorded.
    config : ProcessConfig
    executor : LocalExecutor or DaskExecutor
        Where the steps run (:mod:`bodymetry.executors`).
    progress : callable, optional
        ``progress(label, done, total)`` (``frames``; on a local executor also the
        steps' own: ``rescue``, ``training: ...``, the session stage's).
    restart : bool
        Replace a run of another session or other settings in ``out``.

    Raises
    ------
    InputError
        For bad inputs, before any long work (:func:`prepare`).
    """
    ex = executor
    t0 = time.perf_counter()
    # Progress callbacks stay in this process: a remote step gets none.
    local = None if ex.remote else progress
    prep_f = ex.submit(prepare, session_path, out, config, restart, local)
    prepared: PreparedRun = prep_f.result()
    plan_f = ex.submit(plan, prep_f, config)
    planned: SessionPlan = plan_f.result()
    if planned.finished is not None:
        log.info("%s: finished already (%s)", prepared.session.folder, prepared.layout.results)
        return SessionRun(planned.finished, planned.finished.models, None)
    # The fit's models and kernels load while the frames are segmented (a local
    # pool's forked workers inherit them; the session stage needs them too).
    ex.warm_up(preload, prepared.cameras, config.fit.refinement)
    every = needs_every_frame(config)
    frames = planned.kept if every else planned.pending
    segmented = {}
    if frames:
        bg_f = ex.submit(backgrounds, prep_f, plan_f, config, ex.read_method)
        chunks = ex.frame_chunks(frames)
        segmented = _per_frame(
            ex,
            chunks,
            [
                ex.submit(segment, prep_f, plan_f, bg_f, chunk, config, ex.read_method)
                for chunk in chunks
            ],
        )
    if every:
        prep_f = ex.submit(check_calibration, prep_f, list(segmented.values()), config)
    # A resumed run fits through the cameras its registration shifted.
    prep_f = ex.submit(apply_registration, prep_f, config)
    prepared = prep_f.result()
    # Whom to measure (an unknown --person is bad input: said before training).
    persons = (
        ex.submit(plan_persons, prep_f, list(segmented.values()), config).result()
        if every
        else PersonPlan()
    )
    # Per person, each kept frame's silhouettes as theirs and the frames left to fit.
    frames_of: dict[int, dict] = {}
    done: dict[int, dict[int, FrameRecord]] = {}
    for ident in persons.ids:
        layout_person = persons.layout_person(ident)
        done[ident] = (
            dict(planned.done)
            if layout_person is None
            else read_done_frames(prepared.layout.for_person(layout_person))
        )
        if persons.told_apart:
            chosen_f = ex.submit(choose_person, prep_f, list(segmented.values()), config, ident)
            frames_of[ident] = {f: ex.item(chosen_f, i) for i, f in enumerate(sorted(segmented))}
        else:
            frames_of[ident] = segmented
    t_sil = time.perf_counter() - t0
    ex.wait_warm()  # before training poses the body model here
    rig = rig_of(prepared, config)
    models_f = ex.shared(rig, train, prep_f, config, local)
    models: RigModels = models_f.result()
    t1 = time.perf_counter()

    def fit_all(prep_f) -> list[FrameRecord]:
        """Fit every person's frames not yet done, then rescue their poor ones."""
        jobs = [
            (ident, (prep_f, models_f, frames_of[ident][f], config, persons.layout_person(ident)))
            for ident in persons.ids
            for f in planned.kept
            if f not in done[ident]
        ]
        fits = ex.submit_many(fit, [args for _, args in jobs])
        new = _gathered(ex, fits, [i for i, _ in jobs], done, len(planned.kept), progress)
        for ident in persons.ids:
            done[ident] = ex.submit(
                rescue, prep_f, models_f, done[ident], config, ex.job_runner(), local,
                persons.layout_person(ident),
            ).result()  # fmt: skip
        return new

    new = fit_all(prep_f)
    registered_f = ex.submit(
        register_cameras,
        prep_f,
        config,
        {persons.layout_person(ident): done[ident] for ident in persons.ids},
    )
    registered = registered_f.result()
    if prepared.unregistered is None and registered.unregistered is not None:
        # A camera was shifted: every frame again, through the registered cameras.
        prep_f, prepared = registered_f, registered
        for ident in persons.ids:
            done[ident] = {}
        new += fit_all(prep_f)
    cpu = sum(r.seconds.get("total", 0.0) for r in new)
    timing = {"training": models.seconds, "fitting_cpu": cpu}
    if not ex.remote:  # wall times of this session's own work (on Dask, steps interleave)
        timing |= {"silhouettes": t_sil, "fitting": time.perf_counter() - t1}
    people = [
        ex.submit(finish_person, prep_f, config, done[ident], persons, ident, local).result()
        for ident in persons.ids
    ]
    timing["total"] = time.perf_counter() - t0
    results = ex.submit(finish, prep_f, config, models_f, people, timing, persons.warnings).result()
    ex.submit(review, prep_f, config, local).result()
    return SessionRun(results, rig, models)


def _per_frame(ex: Executor, chunks: Sequence[tuple[int, ...]], chunk_fs: Sequence) -> dict:
    """Per frame, a future of its :class:`SegmentedFrame` from its chunk's list."""
    return {
        frame: ex.item(chunk_f, i)
        for chunk_f, chunk in zip(chunk_fs, chunks, strict=True)
        for i, frame in enumerate(chunk)
    }


def _gathered(
    ex: Executor,
    fits: Sequence,
    owners: Sequence[int],
    done: dict[int, dict[int, FrameRecord]],
    n_kept: int,
    progress: Progress | None,
) -> list[FrameRecord]:
    """The new records once the fits are in, each added to its person's ``done``
    (``owners``: the person of each fit); ``progress("frames", ...)`` as each fit ends,
    over every person's kept frames."""
    owner = dict(zip(fits, owners, strict=True))
    new: list[FrameRecord] = []
    total = n_kept * len(done)

    def report() -> None:
        if progress:
            progress("frames", sum(len(d) for d in done.values()), total)

    report()
    for future in ex.as_completed(fits):
        record = future.result()
        new.append(record)
        done[owner[future]][record.frame] = record
        report()
    return new
