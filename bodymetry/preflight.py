"""One up-front check of a session (and a run folder) that lists every problem.

The stages validate their own inputs, but each stops at the first problem and
some run only after minutes of work (a calibration whose image size is not the
video's is found after the models were trained for it). :func:`check_session`
runs every check that needs no training or fitting, in seconds, and collects
what it finds instead of raising:

- ``session.yaml`` reads and is valid; every file it names exists and stays
  inside the session folder (the rules of :func:`~bodymetry.capture.session.load_session`);
- every camera's video opens and decodes its first kept frame; its fps is
  ``session.yaml``'s and its ``frame_offset`` is inside it (the rules of
  :func:`~bodymetry.capture.ingest.check_sync`); frame counts that differ
  across cameras are a warning (the session is cut to the shortest, as ingest does);
- a calibration exists, or ChArUco clips and a board to solve one from (the
  clips then decode at their video's size); the calibration reads, names every
  camera, and gives each camera its video's decoded image size (sizes may
  differ from camera to camera) and a principal point inside the image;
- every background clip decodes at its video's size;
- a camera whose first kept frames are all black is a warning (a covered lens);
- the output folder, when given, can be created and written, and is either
  empty or a bodymetry run (``results.json`` or ``frames/``), which is resumed.

Problems say which file is wrong and what was expected and found. Nothing is
written anywhere except a temporary file in the output folder, removed again
(with the folder, when the check created it).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bodymetry.calibration.io import read_calibration
from bodymetry.capture.background import read_clip
from bodymetry.capture.ingest import (
    VideoInfo,
    frame_count_mismatch,
    probe_video,
    size_mismatch,
    video_sync_problems,
)
from bodymetry.capture.person import SEGMENTER_REQUIREMENT, segmenter_available

# load_session stops at the first problem. To list every missing file, the
# session's structure is read without looking at files (session_from_data) and
# each path is then checked on its own (session_relative_path): the same rules and the
# same messages as load_session.
from bodymetry.capture.session import (
    DEFAULT_CALIBRATION_FILE,
    SESSION_FILE,
    Session,
    load_session,
    session_from_data,
    session_relative_path,
)
from bodymetry.errors import InputError
from bodymetry.estimation.run_files import RunLayout
from bodymetry.schema import Fields, join_field, read_yaml_mapping

__all__ = [
    "BLACK_FRAMES",
    "BLACK_MEAN",
    "PreflightReport",
    "Problem",
    "check_session",
]

#: A camera whose first ``BLACK_FRAMES`` kept frames all have a mean intensity
#: below ``BLACK_MEAN`` (0..255) is reported as black (a covered lens, no signal).
BLACK_MEAN = 2.0
BLACK_FRAMES = 3


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the inputs.

    Attributes
    ----------
    path : str
        The file (or folder) that is wrong, or that holds the wrong value.
    message : str
        What is wrong, with the expected and the actual value.
    """

    path: str
    message: str

    def __str__(self) -> str:
        # Messages from the stage validators already start with (or name) the file.
        return self.message if self.path in self.message else f"{self.path}: {self.message}"

    def to_json(self) -> dict[str, str]:
        return {"path": self.path, "message": self.message}


@dataclass(frozen=True)
class PreflightReport:
    """What :func:`check_session` found.

    Attributes
    ----------
    session : str
        The session checked, as given.
    problems : tuple of Problem
        What stops processing; every one found, not only the first.
    warnings : tuple of Problem
        What processing survives but the user should know (a black camera,
        frame counts that differ).
    """

    session: str
    problems: tuple[Problem, ...] = ()
    warnings: tuple[Problem, ...] = ()

    @property
    def ok(self) -> bool:
        """No problems (warnings allowed)."""
        return not self.problems

    def raise_if_failed(self) -> None:
        """Raise one :class:`InputError` listing every problem, one per line.

        Raises
        ------
        InputError
            The problem itself when there is one; else ``"N problem(s) in
            <session>:"`` and then one line per problem.
        """
        if len(self.problems) == 1:
            raise InputError(str(self.problems[0]))
        if self.problems:
            lines = [f"{len(self.problems)} problem(s) in {self.session}:"]
            lines += [f"  {p}" for p in self.problems]
            raise InputError("\n".join(lines))

    def to_json(self) -> dict[str, Any]:
        """Plain data for ``bodymetry check --json``."""
        return {
            "session": self.session,
            "ok": self.ok,
            "problems": [p.to_json() for p in self.problems],
            "warnings": [w.to_json() for w in self.warnings],
        }


@dataclass
class _Findings:
    """What the checks collect as they go."""

    problems: list[Problem] = field(default_factory=list)
    warnings: list[Problem] = field(default_factory=list)
    #: Files already reported missing or unreadable: later checks skip them
    #: instead of reporting them again.
    bad: set[Path] = field(default_factory=set)
    #: What load_session refused, listed at the end unless a check covered it.
    refused: InputError | None = None

    def problem(self, path: Path | str, message: str | Exception, *, bad: bool = False) -> None:
        self.problems.append(Problem(str(path), str(message)))
        if bad:
            self.bad.add(Path(path))

    def warn(self, path: Path | str, message: str) -> None:
        self.warnings.append(Problem(str(path), str(message)))

    def mentions(self, message: str) -> bool:
        """Whether a finding already covers ``message`` (same text or same file and field)."""
        place = _place(message)
        return any(
            str(p) == message or p.message == message or _place(p.message) == place
            for p in (*self.problems, *self.warnings)
        )


def _place(message: str) -> str:
    """``"<file>: <field>"`` of a validator message ``"<file>: <field>: <what>"``."""
    return ": ".join(message.split(": ")[:2])


def check_session(
    session_path: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    *,
    need_calibration: bool = True,
) -> PreflightReport:
    """Check a session (and the run folder it will be processed into) before any work.

    Parameters
    ----------
    session_path : path
        The session folder or its ``session.yaml``.
    out : path, optional
        The run folder ``process`` will write (checked when given).
    need_calibration : bool
        A session with neither a calibration nor clips to solve one from is a
        problem (True) or a warning (False, for work that needs no cameras).

    Returns
    -------
    PreflightReport
        Every problem and warning found. Bad inputs never raise: call
        :meth:`PreflightReport.raise_if_failed` to stop on them.
    """
    findings = _Findings()
    session = _load(findings, Path(session_path))
    if session is not None:
        videos = _check_videos(findings, session)
        message = frame_count_mismatch(list(videos.values()))
        if message is not None:
            findings.warn(session.folder / SESSION_FILE, message)
        _check_calibration(findings, session, videos, need_calibration)
        _check_clip_sizes(
            findings,
            session,
            videos,
            "background clip",
            session.background_path,
            "record the empty scene with the same camera and settings",
        )
        no_clip = [c.name for c in session.cameras if session.background_path(c.name) is None]
        if no_clip and not segmenter_available():
            findings.warn(
                session.folder / SESSION_FILE,
                f"no background clip for camera(s) {', '.join(no_clip)} and the person "
                "segmenter is not installed: their silhouettes come from the median of the "
                "session's frames, which loses a person who stands still (install it: "
                f"pip install --no-deps {SEGMENTER_REQUIREMENT})",
            )
        refused = findings.refused
        if refused is not None and not findings.mentions(str(refused)):
            # Whatever load_session refused is listed, even if no check here covers it.
            findings.problem(session.folder / SESSION_FILE, refused)
    if out is not None:
        _check_out(findings, Path(out))
    return PreflightReport(
        session=str(session_path),
        problems=tuple(findings.problems),
        warnings=tuple(findings.warnings),
    )


# --------------------------------------------------------------------------
# session.yaml and the files it names
# --------------------------------------------------------------------------
def _load(findings: _Findings, path: Path) -> Session | None:
    """The session, or its structure when files are missing; None when unreadable."""
    try:
        return load_session(path)
    except InputError as exc:
        first = exc
    yaml_path = (path / SESSION_FILE if path.is_dir() else path).absolute()
    try:
        data = read_yaml_mapping(yaml_path, "session file")
    except InputError:
        # No session.yaml, or not YAML: nothing more can be checked.
        findings.problem(yaml_path, first)
        return None
    folder = yaml_path.parent
    fields = Fields(yaml_path)
    data = dict(data)
    given_calibration = data.get("calibration") is not None
    if not given_calibration and (folder / DEFAULT_CALIBRATION_FILE).is_file():
        data["calibration"] = DEFAULT_CALIBRATION_FILE  # what load_session does
    no_calibration = data.get("calibration") is None and data.get("calibration_clips") is None
    if no_calibration:
        # A placeholder, so that the rest is still read; _check_calibration
        # reports the missing calibration.
        data["calibration"] = DEFAULT_CALIBRATION_FILE
    try:
        session = session_from_data(data, fields, folder, check_files=False)
    except InputError as exc:
        # A malformed session.yaml: its cameras are unknown, nothing more to check.
        findings.problem(yaml_path, exc)
        if not findings.mentions(str(first)):
            findings.problem(yaml_path, first)
        return None
    if no_calibration:
        session = dataclasses.replace(session, calibration_file=None)
    _check_paths(findings, session, fields)
    findings.refused = first
    return session


def _paths(session: Session) -> Iterable[tuple[str, str, str, bool]]:
    """(relative path, field, what, is a folder) of every file ``session.yaml`` names."""
    for i, cam in enumerate(session.cameras):
        where = join_field("cameras", i)
        yield cam.video, join_field(where, "video"), f"video of camera {cam.name!r}", False
        if cam.background is not None:
            yield (
                cam.background,
                join_field(where, "background"),
                f"background clip of camera {cam.name!r}",
                False,
            )
    if session.calibration_file is not None:
        yield session.calibration_file, "calibration", "calibration file", False
    for name, clip in session.calibration_clips.items():
        yield (
            clip,
            join_field("calibration_clips", name),
            f"calibration clip of camera {name!r}",
            False,
        )
    if session.ground_truth is not None:
        yield session.ground_truth, "ground_truth", "ground-truth folder", True


def _check_paths(findings: _Findings, session: Session, fields: Fields) -> None:
    for relative, field_name, what, directory in _paths(session):
        try:
            session_relative_path(
                fields, relative, field_name, session.folder, what, directory=directory
            )
        except InputError as exc:
            findings.problem(session.path(relative), exc, bad=True)


# --------------------------------------------------------------------------
# Videos
# --------------------------------------------------------------------------
def _decode(path: Path, frames: list[int]) -> list[np.ndarray]:
    """The video frames ``frames`` (increasing) of ``path``, as far as they decode."""
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    images: list[np.ndarray] = []
    try:
        position = 0
        for wanted in frames:
            # Straight through with grab(): cheaper than a seek for a few early frames.
            while position < wanted:
                if not cap.grab():
                    return images
                position += 1
            ok, image = cap.read()
            position += 1
            if not ok or image is None:
                return images
            images.append(image)
    finally:
        cap.release()
    return images


def _check_videos(findings: _Findings, session: Session) -> dict[str, VideoInfo]:
    """Probe and decode every camera's video; returns those that decode, by camera."""
    videos: dict[str, VideoInfo] = {}
    for cam in session.cameras:
        path = session.video_path(cam.name)
        if path in findings.bad:
            continue
        try:
            info = probe_video(path, cam.name, cam.frame_offset)
        except InputError as exc:
            findings.problem(path, exc, bad=True)
            continue
        sync = video_sync_problems(session, info)
        for message in sync:
            findings.problem(path, message)
        if cam.frame_offset >= info.frames:
            continue
        kept = [
            cam.frame_offset + k * session.frame_step
            for k in range(BLACK_FRAMES)
            if cam.frame_offset + k * session.frame_step < info.frames
        ]
        images = _decode(path, kept)
        if not images:
            findings.problem(
                path,
                f"camera {cam.name!r}: the first kept frame of {path} (video frame "
                f"{cam.frame_offset}) does not decode (corrupt, or an unsupported codec?)",
                bad=True,
            )
            continue
        height, width = images[0].shape[:2]
        means = tuple(float(im.mean()) for im in images)
        # The decoded size is what the pipeline gets, whatever the container declares.
        videos[cam.name] = dataclasses.replace(info, size=(width, height))
        if max(means) < BLACK_MEAN:
            findings.warn(
                path,
                f"camera {cam.name!r}: the first {len(means)} kept frame(s) of {path} are black "
                f"(mean intensity {max(means):.1f} < {BLACK_MEAN:g} of 255): a covered lens "
                "or no signal? The camera will see no one",
            )
    return videos


def _decoded_size(
    findings: _Findings, path: Path, camera: str, what: str
) -> tuple[int, int] | None:
    """(width, height) of the first frame of a clip; None (reported) when it does not decode."""
    try:
        first = read_clip(path, camera, max_frames=1, what=what)[0]
    except InputError as exc:
        findings.problem(path, str(exc), bad=True)
        return None
    return first.shape[1], first.shape[0]


def _check_clip_sizes(
    findings: _Findings,
    session: Session,
    videos: dict[str, VideoInfo],
    kind: str,
    clip_path: Callable[[str], Path | None],
    why: str,
) -> None:
    """Each camera's ``kind`` clip (``clip_path(camera)``, None: none) has its video's size."""
    for cam in session.cameras:
        path = clip_path(cam.name)
        if path is None or path in findings.bad:
            continue
        size = _decoded_size(findings, path, cam.name, kind)
        video = videos.get(cam.name)
        if size is not None and video is not None and size != video.size:
            findings.problem(
                path,
                f"camera {cam.name!r}: the {kind} {path} is {size[0]}x{size[1]} but "
                f"its video {video.path.name} is {video.size[0]}x{video.size[1]}; {why}",
            )


# --------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------
def _check_calibration(
    findings: _Findings, session: Session, videos: dict[str, VideoInfo], need_calibration: bool
) -> None:
    yaml_path = session.folder / SESSION_FILE
    if session.calibration_file is None:
        if session.calibration_clips and session.board is not None:
            # Clips to solve the calibration from must decode at their camera's size.
            _check_clip_sizes(
                findings,
                session,
                videos,
                "calibration clip",
                session.calibration_clip_path,
                "cameras solved from it would not fit the video",
            )
            return
        message = (
            f"{yaml_path}: calibration: the session has no calibration: give "
            "'calibration: calibration.yaml' (the solved cameras), or "
            "'calibration_clips' and 'board' to solve one from (docs/session-format.md)"
        )
        if need_calibration:
            findings.problem(yaml_path, message)
        else:
            findings.warn(yaml_path, message)
        return
    path = session.path(session.calibration_file)
    if path in findings.bad:
        return
    try:
        names = read_calibration(path).cameras.names
        # Also checks that it names every session camera (the message load_session gives).
        group = session.calibration()
    except InputError as exc:
        findings.problem(path, exc, bad=True)
        return
    for cam in group:
        index = names.index(cam.name)
        video = videos.get(cam.name)
        if video is not None:
            where = f"{session.calibration_file} (cameras[{index}].size)"
            message = size_mismatch(video, cam.size, where)
            if message is not None:
                findings.problem(path, message)
        # Camera and read_calibration refuse non-positive focal lengths; a principal
        # point outside the image is valid there but means K is of another image size.
        w, h = cam.size
        cx, cy = float(cam.K[0, 2]), float(cam.K[1, 2])
        if not (0.0 <= cx <= w and 0.0 <= cy <= h):
            findings.problem(
                path,
                f"{path}: {join_field(join_field('cameras', index), 'K')}: the principal "
                f"point of camera {cam.name!r} (cx={cx:g}, cy={cy:g}) lies outside its "
                f"{w}x{h} image (expected 0 <= cx <= {w}, 0 <= cy <= {h}); is K for "
                "another image size?",
            )


# --------------------------------------------------------------------------
# The output folder
# --------------------------------------------------------------------------
def _check_out(findings: _Findings, out: Path) -> None:
    """``out`` is an empty or absent folder, or a run; and it can be written."""
    if out.exists() and not out.is_dir():
        findings.problem(out, f"--out {out}: expected a run folder, found a file")
        return
    if out.is_dir():
        try:
            entries = [p.name for p in out.iterdir()]
        except OSError as exc:
            findings.problem(out, f"--out {out}: cannot list the folder: {exc}")
            return
        layout = RunLayout(out)
        markers = (layout.results, layout.frames_dir, layout.manifest)
        if entries and not any(m.exists() for m in markers):
            shown = ", ".join(sorted(entries)[:5]) + (", ..." if len(entries) > 5 else "")
            findings.problem(
                out,
                f"--out {out}: the folder holds {len(entries)} item(s) ({shown}) but is not a "
                "bodymetry run folder (no results.json or frames/); choose another --out",
            )
            return
    # Folders this check creates, deepest first, removed again afterwards.
    created: list[Path] = []
    parent = out
    while not parent.exists():
        created.append(parent)
        parent = parent.parent
    try:
        try:
            if created:
                out.mkdir(parents=True)
        except OSError as exc:
            findings.problem(
                out,
                f"--out {out}: cannot create the run folder ({exc.strerror or exc}); "
                "choose another --out",
            )
            return
        try:
            # The same kind of write a run does: a new file in the folder.
            with tempfile.NamedTemporaryFile(dir=out, prefix=".bodymetry-check-"):
                pass
        except OSError as exc:
            findings.problem(
                out,
                f"--out {out}: cannot write in the run folder ({exc.strerror or exc}); "
                "choose another --out",
            )
    finally:
        for folder in created:
            # Not created, or someone else put something in it meanwhile: leave it.
            with contextlib.suppress(OSError):
                folder.rmdir()
