"""Session ingest: open every camera's video, check that they agree, and yield
synchronized frame sets for the kept frames (every ``frame_step``-th session frame).

Session frame ``f`` is video frame ``f + frame_offset`` of each camera
(docs/session-format.md). :func:`check_sync` probes every video (fps, declared
frame count, size) and reports what does not agree:

- a video that is missing or cannot be opened, an fps that differs from
  ``session.yaml``'s, an image size that differs from the calibration, or a
  ``frame_offset`` past the end of the video: :class:`InputError` naming the
  camera and the file;
- frame counts that differ once the offsets are applied: a warning naming the
  camera(s); the session is cut to the frames every camera has (``strict=True``
  makes it an error).

The same rules without raising, for a check that lists every problem at once
(``bodymetry check``): :func:`video_sync_problems` (one camera),
:func:`size_mismatch` and :func:`frame_count_mismatch`.

:func:`read_frame_sets` decodes only what it must. H.264 seeks land on a
keyframe and decode forward from there (x264 puts one every 250 frames), so
for a step of 25 a seek per kept frame decodes about five times more than
reading straight through with ``grab()`` (which decodes without the colour
conversion) and converting only the kept frames (measured in
``benchmarks/bench_capture.py``: ``sequential`` is the default, ``seek`` is there
for sparse steps). Cameras decode in parallel threads (OpenCV releases the GIL).

A video that ends early (truncated copy, corrupt tail) is read as far as it
decodes; its later frames are flagged ``unreadable`` in every frame set
(:attr:`FrameSet.valid` is False and the image None) and a warning names the
camera and the last frame read.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bodymetry.capture.session import Session
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "READ_METHODS",
    "FrameSet",
    "SyncReport",
    "VideoInfo",
    "check_sync",
    "frame_count_mismatch",
    "probe_video",
    "read_frame_sets",
    "size_mismatch",
    "video_sync_problems",
]

#: How frames are fetched: decode straight through (``grab``) or seek to each kept frame.
READ_METHODS = ("sequential", "seek")

#: Relative fps difference tolerated between a video and ``session.yaml`` (container
#: time bases round 60 fps to 59.94... in some muxers).
FPS_TOLERANCE = 0.002


@dataclass(frozen=True)
class VideoInfo:
    """What a camera's video container declares.

    Attributes
    ----------
    camera : str
    path : Path
    fps : float
    frames : int
        Declared frame count (container metadata; a truncated file may hold fewer).
    size : (int, int)
        ``(width, height)``.
    frame_offset : int
        From ``session.yaml``: session frame ``f`` is video frame ``f + frame_offset``.
    """

    camera: str
    path: Path
    fps: float
    frames: int
    size: tuple[int, int]
    frame_offset: int = 0

    @property
    def session_frames(self) -> int:
        """Session frames this video covers (declared frames minus the offset)."""
        return max(self.frames - self.frame_offset, 0)


@dataclass(frozen=True)
class SyncReport:
    """The result of :func:`check_sync`.

    Attributes
    ----------
    videos : tuple of VideoInfo
        One per camera, in session order.
    n_frames : int
        Session frames every camera covers.
    kept : (K,) int
        Session frames to process: ``0, step, 2 step, ... < n_frames``.
    warnings : tuple of str
        Problems that do not stop processing (each names the camera).
    """

    videos: tuple[VideoInfo, ...]
    n_frames: int
    kept: np.ndarray
    warnings: tuple[str, ...] = ()

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(v.camera for v in self.videos)


@dataclass(frozen=True)
class FrameSet:
    """The images of one session frame, one per camera (session order).

    Attributes
    ----------
    frame : int
        Session frame index.
    images : tuple of ((H, W, 3) uint8 BGR or None), length C
        None where the camera's video could not be decoded at that frame.
    cameras : tuple of str
        Camera names, same order.
    flags : tuple of tuple of str
        Per camera: ``("unreadable",)`` when its image is None, else ``()``.
    """

    frame: int
    images: tuple[np.ndarray | None, ...]
    cameras: tuple[str, ...]
    flags: tuple[tuple[str, ...], ...] = field(default=())

    @property
    def valid(self) -> np.ndarray:
        """(C,) bool: the camera's image was decoded."""
        return np.array([im is not None for im in self.images], dtype=bool)


def _open(path: Path, camera: str):

    if not path.is_file():
        raise InputError(f"camera {camera!r}: video not found: {path}")
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise InputError(
            f"camera {camera!r}: cannot open the video {path} (not a video, truncated before "
            "its header/index could be read, or an unsupported codec)"
        )
    return cap


def probe_video(path: str | Path, camera: str = "?", frame_offset: int = 0) -> VideoInfo:
    """Read a video's container metadata (nothing is decoded but the first frame).

    Raises
    ------
    InputError
        Missing file, not openable, no decodable frame, or no frame rate.
    """

    path = Path(path)
    cap = _open(path, camera)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        frames = round(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if not cap.grab():
            raise InputError(f"camera {camera!r}: no frame of {path} could be decoded (corrupt?)")
    finally:
        cap.release()
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"camera {camera!r}: {path} declares no frame rate (got {fps})")
    if frames <= 0:
        raise InputError(f"camera {camera!r}: {path} declares no frame count (got {frames})")
    return VideoInfo(camera, path, fps, frames, (width, height), int(frame_offset))


def video_sync_problems(session: Session, info: VideoInfo) -> list[str]:
    """What :func:`check_sync` refuses about one camera's video, without raising.

    Parameters
    ----------
    session : Session
    info : VideoInfo
        From :func:`probe_video` (its ``camera`` and ``frame_offset`` are the session's).

    Returns
    -------
    list of str
        Empty when the video fits the session; else one message per problem (an
        fps other than ``session.yaml``'s beyond :data:`FPS_TOLERANCE`, a
        ``frame_offset`` at or past the end), each naming the camera and the file.
    """
    problems = []
    if abs(info.fps - session.fps) > FPS_TOLERANCE * session.fps:
        problems.append(
            f"camera {info.camera!r}: {info.path} runs at {info.fps:g} fps but session.yaml "
            f"says fps: {session.fps:g}; the cameras cannot be synchronized frame by frame"
        )
    if info.frame_offset >= info.frames:
        problems.append(
            f"camera {info.camera!r}: frame_offset {info.frame_offset} is past the end of "
            f"{info.path} ({info.frames} frames)"
        )
    return problems


def size_mismatch(
    info: VideoInfo, calibrated: tuple[int, int], calibration_file: str | Path
) -> str | None:
    """The message :func:`check_sync` raises when a video's size is not the calibration's.

    Parameters
    ----------
    info : VideoInfo
        The camera's video (its ``size`` is compared).
    calibrated : (int, int)
        ``(width, height)`` the calibration gives the camera.
    calibration_file : str or Path
        The calibration, as the message should name it.

    Returns
    -------
    str or None
        None when the sizes agree.
    """
    w, h = (int(v) for v in calibrated)
    if (w, h) == tuple(info.size):
        return None
    return (
        f"camera {info.camera!r}: {info.path} is {info.size[0]}x{info.size[1]} but "
        f"{calibration_file} says {w}x{h}"
    )


def frame_count_mismatch(videos: Sequence[VideoInfo]) -> str | None:
    """The warning :func:`check_sync` gives when frame counts differ after the offsets.

    Parameters
    ----------
    videos : sequence of VideoInfo
        One per camera, session order.

    Returns
    -------
    str or None
        None when every camera covers the same number of session frames; else a
        message naming the short camera(s) and how many frames will be used.
    """
    if not videos:
        return None
    counts = np.array([v.session_frames for v in videos])
    longest = int(counts.max())
    if (counts == longest).all():
        return None
    n_frames = int(counts.min())
    short = [v for v in videos if v.session_frames < longest]
    detail = "; ".join(
        f"camera {v.camera!r} has {v.session_frames} ({v.frames} in {v.path.name}"
        + (f" minus frame_offset {v.frame_offset}" if v.frame_offset else "")
        + ")"
        for v in short
    )
    return (
        f"frame counts differ after the offsets: {detail}, the others {longest}; "
        f"using the first {n_frames} session frames, which every camera has"
    )


def check_sync(session: Session, *, strict: bool = False, check_sizes: bool = True) -> SyncReport:
    """Probe every camera's video and check that they can be synchronized.

    Parameters
    ----------
    session : Session
    strict : bool
        Make differing frame counts an error instead of a warning.
    check_sizes : bool
        Compare each video's image size with the calibration's (when the session
        has a calibration file).

    Returns
    -------
    SyncReport

    Raises
    ------
    InputError
        Missing or unreadable video; fps different from ``session.yaml``; a
        ``frame_offset`` at or past the end of the video; an image size that is
        not the calibration's; (``strict``) frame counts that differ.
    """
    videos = []
    for cam in session.cameras:
        info = probe_video(session.video_path(cam.name), cam.name, cam.frame_offset)
        problems = video_sync_problems(session, info)
        if problems:
            raise InputError(problems[0])
        videos.append(info)
    if check_sizes and session.calibration_file is not None:
        calib = session.calibration()
        for info, cam in zip(videos, calib, strict=True):
            problem = size_mismatch(info, cam.size, session.calibration_file)
            if problem is not None:
                raise InputError(problem)
    counts = np.array([v.session_frames for v in videos])
    n_frames = int(counts.min())
    warnings: list[str] = []
    msg = frame_count_mismatch(videos)
    if msg is not None:
        if strict:
            raise InputError(f"{session.folder / 'session.yaml'}: {msg}")
        warnings.append(msg)
        log.warning("%s", msg)
    kept = session.kept_frames(n_frames)
    return SyncReport(tuple(videos), n_frames, kept, tuple(warnings))


class _CameraReader:
    """Reads one camera's kept frames, in increasing order, by grab or by seek."""

    def __init__(self, info: VideoInfo, method: str) -> None:
        self.info = info
        self.method = method
        self.cap = _open(info.path, info.camera)
        self.position = 0  # index of the next frame grab() returns
        self.ended_at: int | None = None  # first video frame that did not decode

    def read(self, video_frame: int) -> np.ndarray | None:

        if self.ended_at is not None and video_frame >= self.ended_at:
            return None
        if self.method == "seek" and video_frame != self.position:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, video_frame)
            self.position = video_frame
        while self.position < video_frame:
            if not self.cap.grab():
                self.ended_at = self.position
                return None
            self.position += 1
        if not self.cap.grab():
            self.ended_at = self.position
            return None
        self.position += 1
        ok, image = self.cap.retrieve()
        if not ok or image is None:
            self.ended_at = self.position - 1
            return None
        return image

    def close(self) -> None:
        self.cap.release()


def read_frame_sets(
    session: Session,
    report: SyncReport | None = None,
    *,
    frames: Sequence[int] | None = None,
    method: str = "sequential",
    threads: int | None = None,
) -> Iterator[FrameSet]:
    """Yield the synchronized images of the kept frames.

    Parameters
    ----------
    session : Session
    report : SyncReport, optional
        From :func:`check_sync` (computed when not given).
    frames : sequence of int, optional
        Session frames to read (increasing); default ``report.kept``.
    method : {"sequential", "seek"}
        Decode straight through or seek to each frame (see the module notes).
    threads : int, optional
        Decoding threads (default: one per camera, at most 4).

    Yields
    ------
    FrameSet
        In increasing frame order. A camera whose video stops decoding early
        gives None images from there on, flagged ``unreadable``, with one warning.
    """
    if method not in READ_METHODS:
        raise InputError(f"read method {method!r}: expected one of {', '.join(READ_METHODS)}")
    report = report or check_sync(session)
    wanted = np.asarray(report.kept if frames is None else frames, dtype=np.int64)
    if wanted.size and (np.any(np.diff(wanted) <= 0) or wanted[0] < 0):
        raise InputError(f"frames must be increasing and >= 0, got {wanted.tolist()[:10]}...")
    readers = [_CameraReader(info, method) for info in report.videos]
    names = report.camera_names
    warned: set[int] = set()
    n_threads = max(1, min(threads or min(len(readers), 4), len(readers)))
    pool = ThreadPoolExecutor(n_threads) if n_threads > 1 else None
    try:
        for f in wanted.tolist():

            def fetch(c: int, f: int = f) -> np.ndarray | None:
                return readers[c].read(f + report.videos[c].frame_offset)

            if pool is None:
                images = [fetch(c) for c in range(len(readers))]
            else:
                images = list(pool.map(fetch, range(len(readers))))
            for c, image in enumerate(images):
                if image is None and c not in warned:
                    warned.add(c)
                    r = readers[c]
                    log.warning(
                        "camera %r: %s stopped decoding at video frame %s of %d declared "
                        "(truncated or corrupt); session frames from %d on are flagged "
                        "'unreadable' for this camera",
                        names[c],
                        r.info.path,
                        r.ended_at,
                        r.info.frames,
                        f,
                    )
            yield FrameSet(
                frame=int(f),
                images=tuple(images),
                cameras=names,
                flags=tuple(("unreadable",) if im is None else () for im in images),
            )
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
        for r in readers:
            r.close()
