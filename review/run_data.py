"""What the review outputs are made of: a run folder read back, and per-frame geometry.

A run folder (docs/outputs.md) holds ``results.json`` and, for runs of this
version, ``frames/FFFFFF.npz`` (the last annealing layer's particles). The
review stage needs, besides, the cameras (the session's calibration, or the
one solved into the run folder) and, for images and observed silhouettes, the
session's videos. Everything but ``results.json`` is optional: what is missing
(an older run without particles, a session folder moved away) is left out of
the review with a warning.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry.calibration.camera import Camera
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PART_PARENT

log = logging.getLogger(__name__)

#: Review files written into the run folder.
RECORDING_RRD = "recording.rrd"
RECORDING_MCAP = "recording.mcap"
REPORT_HTML = "report.html"
REPORT_PDF = "report.pdf"
MEASUREMENTS_CSV = "measurements.csv"

#: The two fitting stages, as keyed in ``results.json``.
STAGES = ("discriminative", "generative")


@dataclass(frozen=True)
class RunData:
    """A processed run read back from its folder.

    Attributes
    ----------
    folder : Path
        The run folder.
    results : dict
        ``results.json`` (schema: docs/outputs.md).
    cameras : list of Camera
        The cameras the run was fitted with (empty when they cannot be found).
    calibration_source : str
        Where the cameras came from (a file path), or why there are none.
    calibration_report : dict or None
        ``calibration-report.json`` of a solved calibration, when there is one.
    calibration_quality : dict or None
        The ``quality:`` block of the calibration file, when it has one.
    evaluation : dict or None
        ``evaluation.json`` written by ``bodymetry evaluate``, when present.
    session_folder : Path or None
        The session folder, when it still exists.
    """

    folder: Path
    results: dict[str, Any]
    cameras: list[Camera] = field(default_factory=list)
    calibration_source: str = ""
    calibration_report: dict[str, Any] | None = None
    calibration_quality: dict[str, Any] | None = None
    evaluation: dict[str, Any] | None = None
    session_folder: Path | None = None

    @property
    def frames(self) -> list[dict[str, Any]]:
        """Every kept frame's record, in frame order."""
        return sorted(self.results.get("frames", []), key=lambda r: r["frame"])

    @property
    def ok_frames(self) -> list[dict[str, Any]]:
        """The records of the frames that count in the summary (status ``ok``)."""
        return [r for r in self.frames if r.get("status") == "ok"]

    @property
    def fitted_frames(self) -> list[dict[str, Any]]:
        """The records that carry a fit: the ``ok`` frames and those a quality gate
        left out of the summary but kept with their numbers."""
        return [r for r in self.frames if stage_state(r) is not None]

    @property
    def fps(self) -> float:
        """Session frame rate (frames per second; 25 when the run does not say)."""
        fps = self.results.get("session", {}).get("fps")
        return float(fps) if fps else 25.0

    @property
    def camera_names(self) -> list[str]:
        names = self.results.get("session", {}).get("cameras")
        return list(names) if names else [c.name for c in self.cameras]

    @property
    def ground_truth(self) -> dict[str, Any] | None:
        return self.results.get("ground_truth")

    @property
    def name(self) -> str:
        return str(self.results.get("session", {}).get("name", self.folder.name))

    def time_seconds(self, frame: int) -> float:
        """Time of a session frame from the start of the recording (seconds)."""
        return frame / self.fps


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable JSON file ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def _optional_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        return _read_json(path)
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
        When the folder has no readable ``results.json`` or it lacks ``frames``.
    """
    folder = Path(folder)
    path = folder / "results.json"
    if not folder.is_dir():
        raise InputError(f"{folder}: no such run folder; run `bodymetry process` first")
    if not path.is_file():
        raise InputError(f"{path}: not found; run `bodymetry process` first")
    results = _read_json(path)
    if not isinstance(results.get("frames"), list):
        raise InputError(f"{path}: no 'frames' list; not a results file of `bodymetry process`")
    session_folder = None
    session_path = results.get("session", {}).get("path")
    if session_path and Path(session_path).is_dir():
        session_folder = Path(session_path)
    elif session_path:
        log.warning(
            "%s: session folder %s not found; the review has no camera images", path, session_path
        )
    cameras, source, quality, cal_report = _run_cameras(folder, session_folder)
    return RunData(
        folder=folder,
        results=results,
        cameras=cameras,
        calibration_source=source,
        calibration_report=cal_report,
        calibration_quality=quality,
        evaluation=_optional_json(folder / "evaluation.json"),
        session_folder=session_folder,
    )


def _run_cameras(
    folder: Path, session_folder: Path | None
) -> tuple[list[Camera], str, dict | None, dict | None]:
    """The cameras of a run, as ``estimation.pipeline`` found them (never solves).

    Returns cameras, their source, the calibration's quality block and the
    solved calibration's report (when the calibration was solved from clips).
    """
    from bodymetry.calibration.io import read_calibration
    from bodymetry.capture.session import load_session

    candidates: list[tuple[Path, Path | None]] = []
    names: Sequence[str] | None = None
    if session_folder is not None:
        try:
            session = load_session(session_folder)
        except InputError as exc:
            log.warning("%s; the review has no camera images", exc)
            session = None
        if session is not None:
            names = session.camera_names
            if session.calibration_path is not None and session.calibration_path.is_file():
                candidates.append((session.calibration_path, session.calibration_path.parent))
    candidates.append((folder / "calibration.yaml", folder))
    for path, report_dir in candidates:
        if not path.is_file():
            continue
        try:
            calib = read_calibration(path)
        except InputError as exc:
            log.warning("%s; the review has no cameras", exc)
            continue
        group = calib.cameras.subset(names) if names else calib.cameras
        report = _optional_json(report_dir / "calibration-report.json") if report_dir else None
        return list(group), str(path), calib.quality, report
    log.warning("%s: no calibration found; the review has no camera views", folder)
    return [], "no calibration found", None, None


def stage_state(record: dict[str, Any], stage: str = "generative") -> np.ndarray | None:
    """The fitted state of a frame record as a vector ``[τ, θ, ν]`` (3 + 37 + n,), or None.

    Frames left out of the summary by a quality gate may still carry their fit;
    the review shows it (that is the frame a person wants to look at).
    """
    state = (record.get(stage) or {}).get("state")
    if not state:
        return None
    vector = np.concatenate([state["tau"], state["theta"], state["nu"]]).astype(float)
    return vector if np.all(np.isfinite(vector)) else None


def load_particles(folder: Path, frame: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The last annealing layer of a frame: particles (N, 49) and weights (N,), or None.

    Runs written before the particles were saved have no ``frames/FFFFFF.npz``.
    """
    from bodymetry.fileio import load_npz

    path = folder / "frames" / f"{frame:06d}.npz"
    if not path.is_file():
        return None
    try:
        arrays = load_npz(path)
        return np.asarray(arrays["particles"], float), np.asarray(arrays["weights"], float)
    except (InputError, KeyError) as exc:
        log.warning("%s: unreadable particles (%s); left out of the review", path, exc)
        return None


@dataclass(frozen=True)
class FrameView:
    """Everything the review shows for one kept frame.

    Attributes
    ----------
    record : dict
        The frame's record from ``results.json``.
    images : list of ((H, W, 3) uint8 BGR or None), length C
        Camera images (empty list when the session's videos are not available).
    observed : list of ((H, W) bool or None), length C
        Observed silhouettes (empty list when not available).
    model : (C, H, W) bool or None
        The fitted model's silhouette in every camera (None for a failed frame).
    vertices : (V, 3) float32 or None
        The fitted body at full resolution, metres, world frame.
    keypoints : (K, 3) float or None
        Joints and extra keypoints (order of ``BodyModel.keypoint_names``).
    particles : (N, 49) float or None
        The last annealing layer's particles ``[τ, θ, ν]``.
    weights : (N,) float or None
    """

    record: dict[str, Any]
    images: list[np.ndarray | None] = field(default_factory=list)
    observed: list[np.ndarray | None] = field(default_factory=list)
    model: np.ndarray | None = None
    vertices: np.ndarray | None = None
    keypoints: np.ndarray | None = None
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None

    @property
    def frame(self) -> int:
        return int(self.record["frame"])

    @property
    def ok(self) -> bool:
        """Whether the frame was fitted and counts in the summary."""
        return self.record.get("status") == "ok"


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
    body: BodyModel, record: dict[str, Any], cameras: Sequence[Camera]
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The fitted body of a frame record: full mesh, keypoints and model silhouettes.

    Returns
    -------
    vertices : (V, 3) float32 or None
    keypoints : (K, 3) float or None
    model : (C, H, W) bool or None
        The level of detail projected in every camera (as the fit's IoU).
    """
    from bodymetry.estimation.projection import project_silhouettes

    vector = stage_state(record)
    if vector is None:
        return None, None, None
    state = BodyState.from_vector(vector[None])
    posed = body.pose(state)
    model = None
    if cameras and len({c.size for c in cameras}) == 1:
        lod = body.pose(state, lod=True).vertices[0]
        model = project_silhouettes(lod, body.faces(lod=True), list(cameras))
    return posed.vertices[0].astype(np.float32), posed.keypoints[0], model


def frame_views(
    run: RunData, body: BodyModel, *, images: bool = True, frames: Sequence[int] | None = None
) -> Iterator[FrameView]:
    """Yield a :class:`FrameView` per kept frame (or per frame of ``frames``), in order.

    With ``images`` and a reachable session, the camera images and observed
    silhouettes are recomputed by the capture stage (as the fit saw them).
    """
    records = {r["frame"]: r for r in run.frames}
    wanted = sorted(records) if frames is None else [f for f in sorted(frames) if f in records]
    sil_iter = _silhouettes(run, wanted) if images else iter(())
    pending = {}
    for frame in wanted:
        record = records[frame]
        imgs: list[np.ndarray | None] = []
        observed: list[np.ndarray | None] = []
        sil = pending.pop(frame, None)
        while sil is None:
            nxt = next(sil_iter, None)
            if nxt is None:
                break
            if nxt.frame == frame:
                sil = nxt
            else:
                pending[nxt.frame] = nxt
        if sil is not None:
            imgs = list(sil.images) if sil.images else [None] * len(sil.masks)
            observed = list(sil.masks)
        vertices, keypoints, model = pose_frame(body, record, run.cameras)
        cloud = load_particles(run.folder, frame) if vertices is not None else None
        yield FrameView(
            record=record,
            images=imgs,
            observed=observed,
            model=model,
            vertices=vertices,
            keypoints=keypoints,
            particles=None if cloud is None else cloud[0],
            weights=None if cloud is None else cloud[1],
        )


def _silhouettes(run: RunData, frames: Sequence[int]) -> Iterator[Any]:
    """Silhouette frames (with images) of the run's session, or nothing when unavailable."""
    if run.session_folder is None or not frames:
        return
    from bodymetry.capture.session import load_session
    from bodymetry.capture.silhouette import segment_session

    try:
        session = load_session(run.session_folder)
        yield from segment_session(session, frames=list(frames), keep_images=True)
    except (InputError, OSError, ValueError) as exc:
        log.warning(
            "%s: could not read the session's images (%s); the review shows none",
            run.session_folder,
            exc,
        )
