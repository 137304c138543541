"""Calibrate a session from its ChArUco clips: detection, solve, files.

``calibrate_session`` is what ``bodymetry calibrate SESSION`` runs: it detects
the board in every camera's clip (cameras in parallel threads; OpenCV releases
the GIL), solves the cameras (:func:`calibration.solve.calibrate_cameras`) and
returns a :class:`~calibration.solve.CalibrationResult`;
``write_calibration`` writes ``calibration.yaml`` and ``calibration-report.json``
(:class:`CalibrationReport`, the one reader and writer of that file).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2

from bodymetry.calibration.charuco import (
    DEFAULT_UPSCALE,
    CameraDetections,
    board_geometry,
    detect_clip,
)
from bodymetry.calibration.io import save_calibration
from bodymetry.calibration.solve import CalibrationOptions, CalibrationResult, calibrate_cameras
from bodymetry.errors import InputError
from bodymetry.fileio import read_json_object, write_json_atomic

__all__ = [
    "REPORT_FILE",
    "CalibrationReport",
    "auto_step",
    "calibrate_session",
    "calibration_clip_lengths",
    "detect_session",
    "parse_floor_frames",
    "write_calibration",
]

#: Name of the report written beside calibration.yaml.
REPORT_FILE = "calibration-report.json"


@dataclass(frozen=True)
class CalibrationReport:
    """``calibration-report.json``: how a calibration was solved and how good it is.

    Attributes
    ----------
    calibration : str
        The ``calibration.yaml`` it describes.
    rms_px : float
        Final reprojection RMS over every camera (pixels).
    frames_used, observations, outliers_rejected : int
    cameras : dict of str to dict
        Per camera its figures (``frames_read``, ``boards_detected``,
        ``corners_used``, ``rms_px``, intrinsics notes, ...).
    world : dict
        How the world frame was set (floor board, axes).
    solver : dict
        The solver's settings and convergence.
    session : str or None
        The session folder, when it was calibrated from its clips by ``bodymetry calibrate``.
    """

    calibration: str
    rms_px: float
    frames_used: int
    observations: int
    outliers_rejected: int
    cameras: dict[str, dict[str, Any]]
    world: dict[str, Any] = field(default_factory=dict)
    solver: dict[str, Any] = field(default_factory=dict)
    session: str | None = None

    @classmethod
    def of(
        cls, result: CalibrationResult, calibration: Path, session: str | None = None
    ) -> CalibrationReport:
        return cls.from_json(
            {"calibration": str(calibration), **result.report(), "session": session}
        )

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "calibration": self.calibration,
            "rms_px": self.rms_px,
            "frames_used": self.frames_used,
            "observations": self.observations,
            "outliers_rejected": self.outliers_rejected,
            "world": self.world,
            "solver": self.solver,
            "cameras": self.cameras,
        }
        if self.session is not None:
            out["session"] = self.session
        return out

    @classmethod
    def from_json(cls, data: Any, where: str = REPORT_FILE) -> CalibrationReport:
        try:
            return cls(
                calibration=str(data["calibration"]),
                rms_px=float(data["rms_px"]),
                frames_used=int(data["frames_used"]),
                observations=int(data["observations"]),
                outliers_rejected=int(data["outliers_rejected"]),
                cameras={str(k): dict(v) for k, v in dict(data["cameras"]).items()},
                world=dict(data.get("world") or {}),
                solver=dict(data.get("solver") or {}),
                session=None if data.get("session") is None else str(data["session"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: not a calibration report of bodymetry ({exc})") from exc

    @classmethod
    def read(cls, path: Path) -> CalibrationReport:
        return cls.from_json(read_json_object(path, what="calibration report"), str(path))

    def write(self, path: Path) -> None:
        write_json_atomic(path, self.to_json())


#: Detection aims at about this many sampled frames per clip by default.
TARGET_SAMPLES = 300


def auto_step(n_frames: int, target: int = TARGET_SAMPLES) -> int:
    """Sampling step giving at most ``target`` frames of an ``n_frames`` clip."""
    return max(1, math.ceil(n_frames / target)) if n_frames > 0 else 1


def parse_floor_frames(text: str | None, fps: float) -> tuple[int, int] | None:
    """``"START:END"`` (clip frames, END exclusive), ``"none"``, or None (the first second)."""
    if text is None or text == "":
        return (0, max(1, round(fps)))
    if text.strip().lower() == "none":
        return None
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError as exc:
        raise InputError(
            f"--floor-frames {text!r}: expected START:END in clip frames (e.g. 0:60) or 'none'"
        ) from exc
    if not 0 <= a < b:
        raise InputError(f"--floor-frames {text!r}: need 0 <= START < END")
    return (a, b)


def _clip_length(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
    finally:
        cap.release()


def calibration_clip_lengths(session) -> dict[str, int]:
    """Frames in each camera's calibration clip, after checking every clip can be used.

    Raises
    ------
    InputError
        No board description, a camera without a clip, or clips that cannot be
        read (all of them named, before any detection starts).
    """
    if session.board is None:
        raise InputError(
            f"{session.folder / 'session.yaml'}: board: the session describes no calibration "
            "board, so its calibration clips cannot be used"
        )
    missing = [c for c in session.camera_names if c not in session.calibration_clips]
    if missing:
        raise InputError(
            f"{session.folder / 'session.yaml'}: cameras {missing} have no calibration clip"
        )
    paths = {c: session.calibration_clip_path(c) for c in session.camera_names}
    # Every clip is checked before any detection starts, and every bad one is named.
    lengths = {c: _clip_length(p) if p.is_file() else -1 for c, p in paths.items()}
    bad = [
        f"{paths[c]} ({'not found' if n < 0 else 'no readable frames'})"
        for c, n in lengths.items()
        if n <= 0
    ]
    if bad:
        raise InputError(
            f"{session.folder / 'session.yaml'}: calibration clips cannot be read: {'; '.join(bad)}"
        )
    return lengths


def detect_session(
    session,
    *,
    step: int | None = None,
    upscale: int = DEFAULT_UPSCALE,
    refine: bool = True,
    workers: int | None = None,
    on_progress: Callable[[str, int, int], None] | None = None,
) -> list[CameraDetections]:
    """Detect the board in every camera's calibration clip.

    Parameters
    ----------
    session : capture.session.Session
    step : sample every ``step``-th frame (None: about 300 frames per clip)
    upscale : detection upscale factor (:func:`calibration.charuco.detect_image`)
    refine : place the corners with :class:`calibration.charuco.CornerRefiner`
    workers : threads (None: one per camera, at most the CPU count)
    on_progress : ``on_progress(camera, done, total)`` after each sampled frame

    Raises
    ------
    InputError
        No board description, a camera without a clip, unreadable clips.
    """
    lengths = calibration_clip_lengths(session)
    names = list(session.camera_names)
    paths = {c: session.calibration_clip_path(c) for c in names}
    if step is None:
        step = auto_step(max(lengths.values()))
    board = session.board.create_board()

    def one(name: str) -> CameraDetections:
        def cb(done: int, total: int) -> None:
            if on_progress is not None:
                on_progress(name, done, total)

        return detect_clip(
            paths[name], board, name, step=step, upscale=upscale, refine=refine, on_frame=cb
        )

    n_workers = workers or min(len(names), os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=max(1, n_workers)) as pool:
        return list(pool.map(one, names))


def calibrate_session(
    session,
    *,
    floor_frames: tuple[int, int] | str | None = "auto",
    step: int | None = None,
    options: CalibrationOptions | None = None,
    workers: int | None = None,
    on_progress: Callable[[str, int, int], None] | None = None,
    detections: list[CameraDetections] | None = None,
) -> tuple[CalibrationResult, list[CameraDetections]]:
    """Solve a session's cameras from its ChArUco clips.

    ``floor_frames``: clip frames ``(start, end)`` where the board lies on the
    floor; ``"auto"``: the first second of the clips; None: no floor board
    (the world is then the first camera's frame). ``detections``: reuse
    :func:`detect_session`'s output instead of detecting again.
    """
    if floor_frames == "auto":
        floor_frames = (0, max(1, round(session.fps)))
    opts = options or CalibrationOptions()
    opts = CalibrationOptions(**{**opts.__dict__, "floor_frames": floor_frames})
    if detections is None:
        detections = detect_session(session, step=step, workers=workers, on_progress=on_progress)
    geom = board_geometry(session.board.create_board(), session.board.square_m)
    result = calibrate_cameras(detections, geom, opts)
    frames = detections[0].frames
    result.solver["detection_step"] = int(frames[1] - frames[0]) if len(frames) > 1 else 1
    return result, detections


def write_calibration(
    result: CalibrationResult,
    out: Path,
    *,
    overwrite: bool = False,
    session: str | None = None,
) -> Path:
    """Write ``out`` (calibration.yaml) and ``calibration-report.json`` beside it
    (naming ``session`` when given).

    Refuses to replace an existing ``out`` unless ``overwrite``. Returns the
    report path.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise InputError(
            f"{out} exists; pass --overwrite to replace it or --out to write elsewhere"
        )
    report_path = out.with_name(REPORT_FILE)
    save_calibration(out, result.cameras, {"world": result.world, "quality": result.quality()})
    CalibrationReport.of(result, out, session).write(report_path)
    return report_path
