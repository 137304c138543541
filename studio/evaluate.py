"""Silhouette quality against a studio session's ground truth.

- ``iou``: intersection over union of the computed and the true person mask
  (``ground_truth/silhouettes/<camera>/<frame:06d>.png``);
- ``shadow_false_positive``: the fraction of true cast-shadow pixels labelled
  person. The studio stores them as rendered
  (``ground_truth/shadows/<camera>/<frame:06d>.png``). Sessions rendered before
  it did are given shadows recomputed from ``ground_truth/states.npz``, posed
  and rendered again through the true cameras with the session's light and room
  (its look, ``ground_truth/studio.json``), without noise; an independent
  subject (``ground_truth/subject.json`` names it) is rebuilt from the committed
  bank. That re-render uses today's body model (and its skeleton), so after the
  model changes it no longer matches the video: a warning says so.

:func:`segment_and_score` runs the capture stage on a session (any session;
the scoring only where it has ground truth), writes the masks and
``silhouettes.json`` and returns a :class:`SilhouetteRun` (what ``bodymetry
silhouettes`` prints). It lives here, not in the capture stage, because the
scoring renders the studio's shadows and capture must not import the studio.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bodymetry.capture.background import SubtractionConfig
from bodymetry.capture.ground_truth import (
    GROUND_TRUTH_OCCLUDED,
    GROUND_TRUTH_SHADOWS,
    GROUND_TRUTH_SILHOUETTES,
    GROUND_TRUTH_STATES,
    GROUND_TRUTH_SUBJECT,
    StudioRecord,
    SubjectTruth,
    person_folder,
)
from bodymetry.capture.ingest import check_sync
from bodymetry.capture.overlays import save_silhouette_frame
from bodymetry.capture.segmentation import (
    SilhouetteFrame,
    background_models,
    segment_session,
)
from bodymetry.capture.session import Session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.contours import boundary_points
from bodymetry.fileio import load_npz, write_json_atomic
from bodymetry.log import Progress
from bodymetry.studio.independent import IndependentSpec, IndependentSubject
from bodymetry.studio.looks import Look, recorded_look
from bodymetry.studio.render import Studio

__all__ = [
    "SILHOUETTES_JSON",
    "GroundTruth",
    "SilhouetteRun",
    "SilhouetteScores",
    "iou",
    "load_ground_truth",
    "outline_errors",
    "outline_length",
    "segment_and_score",
]

log = logging.getLogger(__name__)

#: The stage's summary file in the output folder (:meth:`SilhouetteRun.to_dict`
#: plus ``per_frame``).
SILHOUETTES_JSON = "silhouettes.json"


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks (1.0 when both are empty)."""
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 1.0


def outline_length(mask: np.ndarray) -> int:
    """Length of the outline of an (H, W) bool mask, in pixel sides: the number of
    4-neighbour pairs with one pixel inside and one outside (the points of
    :func:`~bodymetry.estimation.contours.boundary_points`; the image border counts
    as outside)."""
    return len(boundary_points(np.pad(np.asarray(mask, bool), 1)))


def outline_errors(mask: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """How far a silhouette's outline lies from the true one, in pixels.

    IoU depends on the body as much as on the segmentation: the same error along
    the outline costs a thin body more (its outline is longer per pixel of area;
    the studio's held-out subject of 47 kg has 45 % more outline per area than
    the 91 kg one before the re-bake, and the same segmentation lost 0.01 of
    IoU on it). Dividing the disagreeing pixels by the true outline's length
    gives a figure in pixels that does not.

    Parameters
    ----------
    mask, truth : (H, W) bool

    Returns
    -------
    error_px : float
        Pixels that disagree (added plus missed) per pixel of true outline: the
        mean absolute offset of the outline where the errors are thin bands.
    bias_px : float
        Added minus missed per pixel of true outline: the mean signed offset
        (+: the silhouette lies outside the true one). NaN both when ``truth`` is empty.
    """
    mask, truth = np.asarray(mask, bool), np.asarray(truth, bool)
    length = outline_length(truth)
    if length == 0:
        return float("nan"), float("nan")
    added = np.count_nonzero(mask & ~truth)
    missed = np.count_nonzero(truth & ~mask)
    return (added + missed) / length, (added - missed) / length


@dataclass
class GroundTruth:
    """Lazy access to a studio session's true person and shadow masks."""

    session: Session
    with_shadows: bool = True

    def __post_init__(self) -> None:
        self._studio = None
        self._states = None
        self._model = None
        self._independent: IndependentSubject | None = None
        self._cameras = None
        self._shadow_cache: dict[tuple[str, int], np.ndarray | None] = {}

    def has_silhouettes(self) -> bool:
        gt = self.session.ground_truth_path
        return gt is not None and (gt / "silhouettes").is_dir()

    def has_states(self) -> bool:
        gt = self.session.ground_truth_path
        return gt is not None and (gt / GROUND_TRUTH_STATES).is_file()

    def person(self, camera: str, frame: int, index: int = 0) -> np.ndarray | None:
        """(H, W) bool true silhouette (the visible pixels) of person ``index`` (0: the
        subject), or None when the session has none for that frame or person."""
        if self.session.ground_truth is None:
            return None
        if index == 0:
            return _read_mask(self.session.ground_truth_silhouette_path(camera, frame))
        return self._person_mask(GROUND_TRUTH_SILHOUETTES, camera, frame, index)

    def occluded(self, camera: str, frame: int, index: int = 0) -> np.ndarray | None:
        """(H, W) bool pixels of person ``index``'s whole projection that another person
        hides, or None when the session has no such mask (a one-person session)."""
        if self.session.ground_truth is None:
            return None
        return self._person_mask(GROUND_TRUTH_OCCLUDED, camera, frame, index)

    def persons(self) -> int:
        """Persons the studio recorded (1 without a studio record or before people)."""
        gt = self.session.ground_truth_path
        studio = None if gt is None else StudioRecord.read(gt)
        return 1 if studio is None else studio.people

    def person_truth(self, index: int = 0) -> SubjectTruth | None:
        """Person ``index``'s ``subject.json`` (biometrics and description), or None."""
        gt = self.session.ground_truth_path
        return None if gt is None else SubjectTruth.read(person_folder(gt, index))

    def person_states(self, index: int = 0) -> dict[str, np.ndarray] | None:
        """Person ``index``'s true states (``frame``, ``tau``, ``theta``, ``joints``;
        the subject's also ``nu`` and ``board_poses``), or None."""
        gt = self.session.ground_truth_path
        if gt is None:
            return None
        path = person_folder(gt, index) / GROUND_TRUTH_STATES
        return load_npz(path) if path.is_file() else None

    def _person_mask(self, kind: str, camera: str, frame: int, index: int) -> np.ndarray | None:
        """A ``silhouettes`` or ``occluded`` mask of a person's folder, or None."""
        self.session.camera(camera)  # an unknown camera is an error, not a missing mask
        folder = person_folder(self.session.ground_truth_path, index)
        return _read_mask(folder / kind / camera / f"{int(frame):06d}.png")

    @property
    def look(self) -> Look:
        """The look the session was rendered with (the default without a studio record)."""
        gt = self.session.ground_truth_path
        return Look() if gt is None else recorded_look(gt)

    def _setup(self) -> None:
        gt = self.session.ground_truth_path
        self._states = load_npz(gt / GROUND_TRUTH_STATES)
        studio = StudioRecord.read(gt)
        shadows = studio.shadows if studio is not None else True
        look = self.look
        self._independent = None
        if "nu" in self._states:
            self._model = BodyModel.load(n_shape=len(self._states["nu"]))
        else:
            self._model = BodyModel.load()
            self._independent = IndependentSubject(independent_spec(gt), model=self._model)
        # The light of studio/synth.py (_render_camera): a soft light's shadow is wider
        # and its "more than half of the full shadow" region different from a hard one's.
        self._studio = Studio.from_model(
            self._model,
            shadows=shadows,
            light=look.build_light(),
            room=look.build_room(),
        )
        self._cameras = self.session.calibration()  # indexed by camera name

    def shadow(self, camera: str, frame: int) -> np.ndarray | None:
        """(H, W) bool true cast-shadow pixels (not person), or None without states."""
        key = (camera, int(frame))
        if key not in self._shadow_cache:
            self._shadow_cache[key] = self._render_shadow(camera, int(frame))
        return self._shadow_cache[key]

    def _render_shadow(self, camera: str, frame: int) -> np.ndarray | None:
        gt = self.session.ground_truth_path
        if gt is None:
            return None
        stored = gt / GROUND_TRUTH_SHADOWS
        if stored.is_dir():
            self.session.camera(camera)  # an unknown camera is an error, not a missing mask
            return _read_mask(stored / camera / f"{frame:06d}.png")
        if not self.has_states():
            return None
        if self._studio is None:
            log.warning(
                "%s has no stored shadow masks (rendered before the studio wrote them): its "
                "shadows are re-rendered with today's body model and are wrong where the model "
                "changed since; render the session again for a trustworthy shadow figure",
                gt,
            )
            self._setup()
        s = self._states
        rows = np.flatnonzero(s["frame"] == frame)
        if rows.size == 0:
            return None
        r = int(rows[0])
        if self._independent is not None:
            vertices = self._independent.pose(s["tau"][r][None], s["theta"][r][None])[0][0]
        else:
            state = BodyState(s["tau"][r], s["theta"][r], s["nu"][None])
            vertices = self._model.pose(state).vertices[0]
        out = self._studio.render_frame(self._cameras[camera], vertices, effects=False)
        return out.shadow_mask & ~out.person_mask


def _read_mask(path: Path) -> np.ndarray | None:
    """(H, W) bool mask of a PNG (non-zero pixels), or None when there is no file."""
    if not path.is_file():
        return None
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise InputError(f"{path}: not a readable PNG mask")
    return mask > 0


def independent_spec(ground_truth: Path) -> IndependentSpec:
    """The independent subject named by a session's ``ground_truth/subject.json``.

    Raises
    ------
    InputError
        When the subject is not an independent one (its states should hold ν).
    """
    subject = SubjectTruth.read(ground_truth)
    text = str(subject.details.get("subject", "")) if subject else ""
    if subject is None or subject.source != "independent" or not text.startswith("independent:"):
        raise InputError(
            f"{ground_truth}: the states have no shape ν and {GROUND_TRUTH_SUBJECT} names no "
            "independent subject"
        )
    return IndependentSpec.parse(text.partition(":")[2])


def load_ground_truth(session: Session) -> GroundTruth | None:
    """The session's ground truth, or None when it has no silhouettes."""
    gt = GroundTruth(session)
    return gt if gt.has_silhouettes() else None


class SilhouetteScores:
    """Accumulates IoU and shadow false positives over :class:`SilhouetteFrame` s.

    Parameters
    ----------
    ground_truth : GroundTruth
    shadows : bool
        Also score cast shadows (re-renders each frame; slower).
    """

    def __init__(self, ground_truth: GroundTruth, shadows: bool = True) -> None:
        self.gt = ground_truth
        self.shadows = shadows and ground_truth.has_states()
        self.ious: dict[str, list[float]] = {}
        self.outlines: dict[str, list[tuple[float, float]]] = {}
        self.shadow_hits: dict[str, int] = {}
        self.shadow_total: dict[str, int] = {}
        self.shadow_fractions: dict[str, list[float]] = {}

    def update(self, sf: SilhouetteFrame) -> None:
        """Score one frame of the capture stage."""
        for name, mask in zip(sf.cameras, sf.masks, strict=True):
            truth = self.gt.person(name, sf.frame)
            if truth is None:
                continue
            if truth.shape != mask.shape:
                raise InputError(
                    f"camera {name!r}: ground-truth silhouette of frame {sf.frame} is "
                    f"{truth.shape[1]}x{truth.shape[0]}, the video {mask.shape[1]}x{mask.shape[0]}"
                )
            self.ious.setdefault(name, []).append(iou(mask, truth))
            if truth.any():
                self.outlines.setdefault(name, []).append(outline_errors(mask, truth))
            if self.shadows:
                shadow = self.gt.shadow(name, sf.frame)
                if shadow is not None:
                    hits = int(np.count_nonzero(mask & shadow))
                    total = int(np.count_nonzero(shadow))
                    self.shadow_hits[name] = self.shadow_hits.get(name, 0) + hits
                    self.shadow_total[name] = self.shadow_total.get(name, 0) + total
                    if total:
                        self.shadow_fractions.setdefault(name, []).append(hits / total)

    def summary(self) -> dict[str, dict]:
        """Per camera: ``iou_mean``, ``iou_min``, ``outline_error_px`` and
        ``outline_bias_px`` (means over the frames with a person in the truth,
        :func:`outline_errors`; None without one), ``shadow_false_positive`` (pooled
        over frames: true shadow pixels labelled person / true shadow pixels;
        None when not scored), ``shadow_false_positive_max`` (worst frame), ``frames``."""
        out = {}
        for name, values in self.ious.items():
            total = self.shadow_total.get(name, 0)
            fractions = self.shadow_fractions.get(name, [])
            outline = np.array(self.outlines.get(name, []), float).reshape(-1, 2)
            error, bias = (
                (round(float(v), 4) for v in outline.mean(axis=0)) if len(outline) else (None, None)
            )
            out[name] = {
                "iou_mean": round(float(np.mean(values)), 4),
                "iou_min": round(float(np.min(values)), 4),
                "outline_error_px": error,
                "outline_bias_px": bias,
                "shadow_false_positive": (
                    round(self.shadow_hits[name] / total, 4) if total else None
                ),
                "shadow_false_positive_max": round(max(fractions), 4) if fractions else None,
                "frames": len(values),
            }
        return out


@dataclass
class SilhouetteRun:
    """What :func:`segment_and_score` did: the figures ``bodymetry silhouettes`` prints.

    Attributes
    ----------
    session, out : str
        The session folder and the output folder.
    method : str
        Background subtraction (:data:`bodymetry.capture.background.METHODS`).
    frames : int
        Kept frames segmented.
    frame_step : int
        The session's kept-frame step.
    session_frames : int
        Session frames every camera covers.
    background : dict
        Per camera, where its background model came from (clip or session median).
    warnings : list of str
        Synchronisation problems that did not stop the stage.
    seconds : float
        Wall time of the stage.
    ground_truth : bool
        Whether the masks were scored against the session's true silhouettes.
    cameras : dict
        Per camera: ``frames``, the :meth:`SilhouetteScores.summary` entries (with
        ground truth) and ``flags`` (flag -> frames that raised it).
    per_frame : list of dict
        Per kept frame: ``frame`` and ``flags`` (camera -> flags); written to the
        file only, not part of :meth:`to_dict`.
    """

    session: str
    out: str
    method: str
    frames: int
    frame_step: int
    session_frames: int
    background: dict[str, str]
    warnings: list[str]
    seconds: float
    ground_truth: bool
    cameras: dict[str, dict[str, Any]]
    per_frame: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The summary as JSON-ready data (without ``per_frame``)."""
        return {
            "session": self.session,
            "out": self.out,
            "method": self.method,
            "frames": self.frames,
            "frame_step": self.frame_step,
            "session_frames": self.session_frames,
            "background": dict(self.background),
            "warnings": list(self.warnings),
            "seconds": self.seconds,
            "ground_truth": self.ground_truth,
            "cameras": {name: dict(entry) for name, entry in self.cameras.items()},
        }


def segment_and_score(
    session: Session,
    out: str | Path,
    *,
    method: str = "horprasert",
    read_method: str = "sequential",
    overlays: bool = True,
    strict: bool = False,
    shadows: bool = True,
    progress: Progress | None = None,
) -> SilhouetteRun:
    """Segment every kept frame of ``session`` into ``out`` and score it where it has ground truth.

    Writes ``out/masks/<camera>/<frame>.png`` (and overlays) per kept frame, and
    ``out/silhouettes.json`` (:meth:`SilhouetteRun.to_dict` plus ``per_frame``).

    Parameters
    ----------
    session : Session
    out : path
        Output folder (created).
    method : {"horprasert", "mog2", "none"}
        Background subtraction.
    read_method : {"sequential", "seek"}
        Decode straight through or seek to each kept frame.
    overlays : bool
        Also write the overlay images.
    strict : bool
        Differing frame counts between cameras are an error, not a warning.
    shadows : bool
        With ground truth, also score cast shadows (re-renders the true shadows; slower).
    progress : callable, optional
        ``progress(label, done, total)``: "background models" once, then
        "silhouettes" after each frame.

    Returns
    -------
    SilhouetteRun

    Raises
    ------
    InputError
        Unreadable or unsynchronised videos (with ``strict``), ground truth of
        another image size.
    """
    t0 = time.perf_counter()
    out = Path(out)
    report = check_sync(session, strict=strict)
    gt = load_ground_truth(session)
    scores = SilhouetteScores(gt, shadows=shadows) if gt is not None else None
    total = len(report.kept)
    if progress is not None:
        progress("background models", 0, total)
    models = background_models(session, report, method=read_method)
    frames = segment_session(
        session,
        subtraction=SubtractionConfig(method=method),
        report=report,
        models=models,
        read_method=read_method,
    )
    flags, per_frame = _save_and_score(session, out, frames, scores, overlays, progress, total)
    cameras = _camera_entries(session, per_frame, flags, scores)
    run = SilhouetteRun(
        session=str(session.folder),
        out=str(out),
        method=method,
        frames=len(per_frame),
        frame_step=session.frame_step,
        session_frames=report.n_frames,
        background={m.camera: m.source for m in models},
        warnings=list(report.warnings),
        seconds=round(time.perf_counter() - t0, 2),
        ground_truth=scores is not None,
        cameras=cameras,
        per_frame=per_frame,
    )
    write_json_atomic(out / SILHOUETTES_JSON, {**run.to_dict(), "per_frame": per_frame})
    return run


def _save_and_score(
    session: Session,
    out: Path,
    frames: Iterable[SilhouetteFrame],
    scores: SilhouetteScores | None,
    overlays: bool,
    progress: Progress | None,
    total: int,
) -> tuple[dict[str, dict[str, list[int]]], list[dict[str, Any]]]:
    """Write each segmented frame's masks, score it and collect its flags.

    Parameters
    ----------
    frames : iterable of SilhouetteFrame
        The segmented kept frames (``segment_session``'s generator: segmenting
        starts as the loop runs, after the first progress call).
    scores : SilhouetteScores or None
        Updated with each frame (None: no ground truth).
    total : int
        Kept frames (for ``progress``).

    Returns
    -------
    flags : dict camera -> flag -> list of frame
    per_frame : list of dict
        ``{"frame": int, "flags": {camera: [flag, ...]}, "agreement": {camera:
        float or None}}`` per frame (``agreement`` where capture judged the views).
    """
    if progress is not None:
        progress("silhouettes", 0, total)
    flags: dict[str, dict[str, list[int]]] = {name: {} for name in session.camera_names}
    per_frame: list[dict[str, Any]] = []
    for sf in frames:
        save_silhouette_frame(out, sf, overlays=overlays)
        if scores is not None:
            scores.update(sf)
        for name, f in zip(sf.cameras, sf.flags, strict=True):
            for flag in f:
                flags[name].setdefault(flag, []).append(sf.frame)
        entry: dict[str, Any] = {
            "frame": sf.frame,
            "flags": dict(zip(sf.cameras, map(list, sf.flags), strict=True)),
        }
        if sf.agreement:
            entry["agreement"] = {
                n: None if a is None else round(a, 4)
                for n, a in zip(sf.cameras, sf.agreement, strict=True)
            }
        per_frame.append(entry)
        if progress is not None:
            progress("silhouettes", len(per_frame), total)
    return flags, per_frame


def _camera_entries(
    session: Session,
    per_frame: list[dict[str, Any]],
    flags: dict[str, dict[str, list[int]]],
    scores: SilhouetteScores | None,
) -> dict[str, dict[str, Any]]:
    """Per camera: frames segmented, its scores (where there is ground truth) and its flags."""
    summary = scores.summary() if scores is not None else {}
    cameras: dict[str, dict[str, Any]] = {}
    for name in session.camera_names:
        entry: dict[str, Any] = {"frames": len(per_frame)}
        entry.update(summary.get(name, {}))
        entry["flags"] = flags[name]
        cameras[name] = entry
    return cameras
