"""What the review outputs are made of: a run folder read back, frame by frame.

A run folder (docs/outputs.md, schema :mod:`bodymetry.estimation.records`)
holds ``results.json``, the cameras the fit used (``calibration.yaml``) and,
per kept frame, the arrays the fit left (``frames/FFFFFF.npz``: observed and
model silhouettes, the last annealing layer; in a run of several persons each
person's are in ``persons/K/frames/``). The review reads these; it
does not segment or project again. Only the camera images come from the
session's videos (decoded, not processed); when the session folder has moved
away, the review has no images, with a warning.

Everything the review shows is at each camera's working resolution
(:mod:`bodymetry.estimation.resolution`, recorded in ``results.json``): the
recorded silhouettes are, :attr:`RunData.cameras` are the working cameras
(:meth:`RunResults.working_cameras` of the run's ``calibration.yaml``) and the
camera images are area-downscaled to it when read (:func:`frame_views`), so
overlays, recordings and report line up with what the fit saw.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import read_calibration
from bodymetry.calibration.session_calibration import CalibrationReport
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.capture.ingest import read_frame_sets
from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.skeleton import PART_PARENT
from bodymetry.estimation.records import FrameArrays, FrameRecord
from bodymetry.estimation.run_files import Evaluation, RunLayout, RunResults

log = logging.getLogger(__name__)

T = TypeVar("T")


@dataclass(frozen=True)
class RunData:
    """A processed run read back from its folder.

    Attributes
    ----------
    folder : Path
        The run folder.
    results : RunResults
        ``results.json``.
    cameras : CameraGroup or None
        The rig the run was fitted with, at its working resolution (None when
        the run has no cameras recorded).
    calibrated_cameras : CameraGroup or None
        The same rig at its own resolution (the run's ``calibration.yaml``).
    calibration_source : str
        Where the run's cameras came from (a file path), or why there are none.
    calibration_report : CalibrationReport or None
        ``calibration-report.json`` of the calibration, when there is one.
    calibration_quality : dict or None
        The ``quality:`` block of the calibration file, when it has one.
    evaluation : Evaluation or None
        ``evaluation.json`` written by ``bodymetry evaluate``, when present.
    session_folder : Path or None
        The session folder, when it still exists.
    person : int or None
        Whose frame files :attr:`layout` points at: None for a run of one person
        (``frames/``, ``meshes/``), the person's id in a view of a run of several
        (``persons/K/...``; :meth:`for_person`).

    A run of several persons is read once; :meth:`for_person` gives the run as
    one person sees it (their results, their frame files) without reading
    anything again, so that every reader of one person's numbers serves each
    person (:meth:`person_runs`).
    """

    folder: Path
    results: RunResults
    cameras: CameraGroup | None = None
    calibrated_cameras: CameraGroup | None = None
    calibration_source: str = ""
    calibration_report: CalibrationReport | None = None
    calibration_quality: dict[str, Any] | None = None
    evaluation: Evaluation | None = None
    session_folder: Path | None = None
    person: int | None = None
    # Whether ``results`` is already one person's view (their warnings added once).
    _viewed: bool = field(default=False, repr=False)

    @property
    def layout(self) -> RunLayout:
        """Where this run's (or this person's) files lie."""
        return RunLayout(self.folder).for_person(self.person)

    @property
    def person_ids(self) -> tuple[int, ...]:
        """The ids of the run's persons, in the order of ``results.json``."""
        return tuple(p.id for p in self.results.persons)

    @property
    def several(self) -> bool:
        """Whether this is a run of several persons (False for one person's view)."""
        return self.results.several

    @property
    def person_id(self) -> int:
        """The id of the run's first person (of a person's view: that person)."""
        return self.results.person.id

    def for_person(self, ident: int) -> RunData:
        """The run as person ``ident`` sees it: only their results (their warnings
        after the run's, :meth:`RunResults.for_person`) and their frame files.

        Raises
        ------
        KeyError
            When the run has no person ``ident``.
        """
        if self.results.persons == (self.results.person,) and ident == self.person_id:
            # One person (a run of one, or a view already): their warnings are in
            # ``results.warnings`` once, and their frame files stay where they are.
            if not self.results.person.warnings or self._viewed:
                return self
            return replace(self, results=self.results.for_person(ident), _viewed=True)
        return replace(self, results=self.results.for_person(ident), person=ident, _viewed=True)

    def person_runs(self) -> list[RunData]:
        """One view per person (:meth:`for_person`), in the order of ``results.json``."""
        return [self.for_person(i) for i in self.person_ids]

    @property
    def frames(self) -> tuple[FrameRecord, ...]:
        """Every kept frame's record, in frame order."""
        return self.results.frames

    @property
    def ok_frames(self) -> list[FrameRecord]:
        """The records of the frames that count in the summary (status ``ok``)."""
        return self.results.ok_frames

    @property
    def fitted_frames(self) -> list[FrameRecord]:
        """The records that carry a fit: the ``ok`` frames and those a quality gate
        left out of the summary but kept with their numbers."""
        return self.results.fitted_frames

    @property
    def fps(self) -> float:
        """Session frame rate (frames per second)."""
        return self.results.session.fps

    @property
    def camera_names(self) -> list[str]:
        names = self.results.session.cameras
        if names:
            return list(names)
        return [] if self.cameras is None else list(self.cameras.names)

    @property
    def ground_truth(self) -> SubjectTruth | None:
        return self.results.ground_truth

    @property
    def name(self) -> str:
        return self.results.session.name or self.folder.name

    def time_seconds(self, frame: int) -> float:
        """Time of a session frame from the start of the recording (seconds)."""
        return frame / self.fps


def _optional(read: Callable[[Path], T], path: Path) -> T | None:
    """``read(path)`` of an optional file: None when it is missing or unreadable (a warning)."""
    if not path.is_file():
        return None
    try:
        return read(path)
    except InputError as exc:
        log.warning("%s; left out of the review", exc)
        return None


def load_run(folder: str | Path) -> RunData:
    """Read a run folder for review.

    Parameters
    ----------
    folder : path
        A folder written by ``bodymetry process``.

    Raises
    ------
    InputError
        When the folder has no readable ``results.json`` of this version.
    """
    layout = RunLayout(Path(folder))
    if not layout.folder.is_dir():
        raise InputError(f"{layout.folder}: no such run folder; run `bodymetry process` first")
    if not layout.results.is_file():
        raise InputError(f"{layout.results}: not found; run `bodymetry process` first")
    results = RunResults.read(layout.results)
    session_folder = None
    session_path = results.session.path
    if session_path and Path(session_path).is_dir():
        session_folder = Path(session_path)
    elif session_path:
        log.warning(
            "%s: session folder %s not found; the review has no camera images",
            layout.results,
            session_path,
        )
    cameras: CameraGroup | None = None
    calibrated: CameraGroup | None = None
    quality = None
    source = "no calibration recorded in the run"
    if layout.calibration.is_file():
        try:
            calib = read_calibration(layout.calibration)
            names = results.session.cameras
            calibrated = calib.cameras.subset(names) if names else calib.cameras
            quality = calib.quality
            cameras = results.working_cameras(calibrated)
            source = results.calibration_source or str(layout.calibration)
        except InputError as exc:
            cameras, calibrated = None, None
            log.warning("%s; the review has no cameras", exc)
    else:
        log.warning("%s: no calibration.yaml; the review has no camera views", layout.folder)
    return RunData(
        folder=layout.folder,
        results=results,
        cameras=cameras,
        calibrated_cameras=calibrated,
        calibration_source=source,
        calibration_report=_optional(CalibrationReport.read, layout.calibration_report),
        calibration_quality=quality,
        evaluation=_optional(Evaluation.read, layout.evaluation),
        session_folder=session_folder,
    )


def load_frame_arrays(where: Path | RunLayout, frame: int) -> FrameArrays | None:
    """A frame's recorded arrays (silhouettes, particles), or None when missing or unreadable.

    Parameters
    ----------
    where : Path or RunLayout
        A run folder (its ``frames/``: a run of one person) or a person's layout
        (:attr:`RunData.layout`: ``persons/K/frames/`` in a run of several).
    frame : int
    """
    layout = where if isinstance(where, RunLayout) else RunLayout(Path(where))
    path = layout.frame_arrays(frame)
    if not path.is_file():
        return None
    try:
        return FrameArrays.load(path)
    except InputError as exc:
        log.warning("%s; left out of the review", exc)
        return None


@dataclass(frozen=True)
class FrameView:
    """Everything the review shows for one kept frame.

    Attributes
    ----------
    record : FrameRecord
        The frame's record.
    images : list of ((h, w, 3) uint8 BGR or None), length C
        Camera images at the working resolution (empty list when the
        session's videos are not available).
    observed : list of ((h, w) bool or None), length C
        Observed silhouettes as the fit saw them (empty list when not recorded).
    model : list of ((h, w) bool or None), length C, or None
        The fitted model's silhouette in every camera (None for a failed frame).
    vertices : (V, 3) float32 or None
        The fitted body at full resolution, metres, world frame.
    keypoints : (K, 3) float or None
        Joints and extra keypoints (order of ``BodyModel.keypoint_names``).
    particles : (N, 40 + n_shape) float or None
        The last annealing layer's particles ``[τ, θ, ν]``.
    weights : (N,) float or None
    landmarks : (33, 3) float or None
        The subject's body landmarks capture triangulated (world frame; NaN rows
        not seen), when the person segmenter ran.
    session_vertices : (V_lod, 3) float32 or None
        The session stage's body in this frame (the session's one shape in the
        frame's refined pose), its level of detail (``body.faces(lod=True)``:
        it is drawn beside the full-resolution fitted body and would double the
        recordings); None without one.
    person : int
        Whose fit this is (the person's id; 0 for a run of one subject).
    clothing : list of ((h, w) bool or None), length C
        The observed silhouettes' pixels capture found not to be skin
        (clothing, hair, shoes; :mod:`bodymetry.capture.skin`); empty list
        when not recorded.
    """

    record: FrameRecord
    images: list[np.ndarray | None] = field(default_factory=list)
    observed: list[np.ndarray | None] = field(default_factory=list)
    model: list[np.ndarray | None] | None = None
    vertices: np.ndarray | None = None
    keypoints: np.ndarray | None = None
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    session_vertices: np.ndarray | None = None
    person: int = 0
    clothing: list[np.ndarray | None] = field(default_factory=list)

    @property
    def frame(self) -> int:
        return self.record.frame

    @property
    def ok(self) -> bool:
        """Whether the frame was fitted and counts in the summary."""
        return self.record.ok


def skeleton_segments(keypoints: np.ndarray) -> np.ndarray:
    """Bones as segments from each joint to its parent's joint.

    Parameters
    ----------
    keypoints : (K, 3) float
        Joints first (order of ``skeleton.JOINTS``), then extra keypoints
        (knuckles) which hang from the wrists.

    Returns
    -------
    (S, 2, 3) float
    """
    segments = [
        (keypoints[parent], keypoints[child])
        for child, parent in enumerate(PART_PARENT)
        if parent >= 0
    ]
    n_joints = len(PART_PARENT)
    # Knuckles (after the joints) hang from the wrists (joints 5 and 8).
    for k, wrist in zip(range(n_joints, len(keypoints)), (5, 8), strict=False):
        segments.append((keypoints[wrist], keypoints[k]))
    return np.asarray(segments, float)


def pose_frame(
    body: BodyModel, record: FrameRecord, stage: str = "generative", lod: bool = False
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A stage's body of a frame record: full-resolution vertices and keypoints.

    Returns
    -------
    vertices : (V, 3) float32 or None
    keypoints : (K, 3) float or None
    """
    estimate = record.estimate(stage)
    if estimate is None:
        return None, None
    posed = body.pose(estimate.state, lod=lod)
    return posed.vertices[0].astype(np.float32), posed.keypoints[0]


def frame_views(
    run: RunData, body: BodyModel, *, images: bool = True, frames: Sequence[int] | None = None
) -> Iterator[FrameView]:
    """Yield a :class:`FrameView` per kept frame (or per frame of ``frames``) of the
    run's first person, in order (``run.for_person(K)`` for another person,
    :func:`run_frame_views` for every person at once).

    Silhouettes and particles are read from the person's ``FFFFFF.npz``; with
    ``images`` and a reachable session, the camera images are decoded from its
    videos.
    """
    first = run.for_person(run.person_id)
    for views in run_frame_views(first, body, images=images, frames=frames):
        yield views[0]


def run_frame_views(
    run: RunData, body: BodyModel, *, images: bool = True, frames: Sequence[int] | None = None
) -> Iterator[list[FrameView]]:
    """Yield, per frame that some person kept (or per such frame of ``frames``), in
    order, one :class:`FrameView` per person who kept it (in the order of
    ``results.json``).

    The camera images of a frame are decoded once and shared by its views; each
    person's silhouettes and particles come from their own frame files
    (:attr:`RunData.layout`).
    """
    persons = run.person_runs()
    records = [{r.frame: r for r in p.frames} for p in persons]
    kept = sorted(set().union(*records))
    wanted = kept if frames is None else sorted(set(frames) & set(kept))
    image_sets = _images(run, wanted) if images else iter(())
    for frame in wanted:
        shared = next(image_sets, []) if images else []
        yield [
            _frame_view(p, body, mine[frame], shared)
            for p, mine in zip(persons, records, strict=True)
            if frame in mine
        ]


def _frame_view(
    run: RunData, body: BodyModel, record: FrameRecord, images: list[np.ndarray | None]
) -> FrameView:
    """One person's view of a frame (``run``: that person's view of the run)."""
    arrays = load_frame_arrays(run.layout, record.frame) or FrameArrays()
    names = run.camera_names
    vertices, keypoints = pose_frame(body, record)
    observed = [arrays.observed.get(n) for n in names] if arrays.observed else []
    model = [arrays.model.get(n) for n in names] if arrays.model and vertices is not None else None
    return FrameView(
        record=record,
        images=images,
        observed=observed,
        model=model,
        vertices=vertices,
        keypoints=keypoints,
        particles=arrays.particles if vertices is not None else None,
        weights=arrays.weights if vertices is not None else None,
        landmarks=arrays.landmarks,
        session_vertices=pose_frame(body, record, "session", lod=True)[0],
        person=run.person_id,
        clothing=arrays.clothing_of(names) if arrays.clothing else [],
    )


def _images(run: RunData, frames: Sequence[int]) -> Iterator[list[np.ndarray | None]]:
    """The camera images of each of ``frames`` (in order), or empty lists when unavailable."""
    sets: Iterator[Any] = iter(())
    if run.session_folder is not None and frames:
        try:
            session = load_session(run.session_folder)
            sets = read_frame_sets(session, frames=list(frames))
        except (InputError, OSError, ValueError) as exc:
            log.warning(
                "%s: could not read the session's images (%s); the review shows none",
                run.session_folder,
                exc,
            )
    for _ in frames:
        try:
            frame_set = next(sets, None)
        except (InputError, OSError, ValueError) as exc:
            log.warning("%s: reading images failed (%s)", run.session_folder, exc)
            frame_set, sets = None, iter(())
        if frame_set is None:
            yield []
        elif run.cameras is not None:
            yield [
                _working_image(image, cam)
                for image, cam in zip(frame_set.images, run.cameras, strict=True)
            ]
        else:  # no recorded cameras: the images as decoded
            yield list(frame_set.images)


def _working_image(image: np.ndarray | None, camera: Camera) -> np.ndarray | None:
    """A camera image (H, W, 3) area-downscaled to ``camera.size`` (the working camera);
    unchanged when it already has that size."""
    if image is None or image.shape[1::-1] == tuple(camera.size):
        return image
    return cv2.resize(image, camera.size, interpolation=cv2.INTER_AREA)
