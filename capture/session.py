"""Session folders: ``session.yaml`` and the files it names (docs/session-format.md).

A session is one recording of one subject by a synchronized camera rig::

    recordings/demo/
      session.yaml            format: bodymetry-session/1 (this module reads it)
      calibration.yaml        the cameras (calibration/io.py reads it)
      videos/cam_00.mp4 ...   one synchronized video per camera
      background/cam_00.mp4   optional empty-scene clips
      calib/cam_00.mp4        optional ChArUco clips to solve calibration.yaml from
      ground_truth/           optional (synthetic sessions): subject.json, states.npz,
                              silhouettes/<camera>/<frame:06d>.png

:func:`load_session` validates everything and raises
:class:`bodymetry.errors.InputError` naming the file, the field (``cameras[1].video``),
what was expected and what was found. Paths in ``session.yaml`` are relative to
the session folder and may not leave it (no absolute paths, no ``..`` or symlinks
that resolve outside), so a session folder can be moved or shared as a whole.
"""

from __future__ import annotations

import os
import posixpath
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from bodymetry.calibration.io import read_calibration
from bodymetry.capture.ground_truth import GROUND_TRUTH_SILHOUETTES
from bodymetry.errors import InputError
from bodymetry.fileio import parse_yaml, write_text_atomic
from bodymetry.schema import (
    Fields,
    check_format,
    describe,
    dump_yaml,
    join_field,
    read_yaml_mapping,
)

if TYPE_CHECKING:
    from bodymetry.calibration.camera import CameraGroup

__all__ = [
    "DEFAULT_FRAME_STEP",
    "SESSION_FILE",
    "SESSION_FORMAT",
    "SESSION_MAX_BYTES",
    "BoardSpec",
    "Session",
    "SessionCamera",
    "load_session",
    "save_session",
    "session_from_data",
    "session_relative_path",
    "session_to_yaml",
]

SESSION_FORMAT = "bodymetry-session/1"
SESSION_FILE = "session.yaml"
#: The largest session.yaml read (a real one is a few kB; a larger file is the
#: wrong file, e.g. a video renamed).
SESSION_MAX_BYTES = 1_000_000
DEFAULT_CALIBRATION_FILE = "calibration.yaml"
DEFAULT_FRAME_STEP = 25


_TOP_REQUIRED = ("format", "name", "fps", "cameras")
_TOP_OPTIONAL = (
    "frame_step",
    "calibration",
    "calibration_clips",
    "board",
    "ground_truth",
    "subject",
)
_CAMERA_REQUIRED = ("name", "video")
_CAMERA_OPTIONAL = ("frame_offset", "background")
_BOARD_REQUIRED = ("type", "squares", "square_mm", "marker_mm", "dictionary")
_BOARD_OPTIONAL = ("legacy",)
_BOARD_TYPES = ("charuco",)

_SESSION_HEADER = "bodymetry session (docs/session-format.md); paths are relative to this folder"


# --------------------------------------------------------------------------
# Dataclasses
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class BoardSpec:
    """The ChArUco board waved in the calibration clips.

    Attributes
    ----------
    squares : (int, int)
        Chessboard squares ``(x, y)`` = (columns, rows), as OpenCV's ``CharucoBoard``.
    square_mm, marker_mm : float
        Printed square side and marker side, millimetres (measure the print!).
    dictionary : str
        OpenCV ArUco dictionary name, e.g. ``"DICT_5X5_100"``.
    legacy : bool
        OpenCV's legacy ChArUco layout (boards made before OpenCV 4.6 with an even
        number of rows).
    type : str
        Board kind; only ``"charuco"``.
    """

    squares: tuple[int, int]
    square_mm: float
    marker_mm: float
    dictionary: str
    legacy: bool = False
    type: str = "charuco"

    def __post_init__(self) -> None:
        object.__setattr__(self, "squares", (int(self.squares[0]), int(self.squares[1])))
        object.__setattr__(self, "square_mm", float(self.square_mm))
        object.__setattr__(self, "marker_mm", float(self.marker_mm))
        object.__setattr__(self, "legacy", bool(self.legacy))

    @property
    def square_m(self) -> float:
        """Square side in metres."""
        return self.square_mm / 1000.0

    @property
    def marker_m(self) -> float:
        """Marker side in metres."""
        return self.marker_mm / 1000.0

    @property
    def n_markers(self) -> int:
        """Number of ArUco markers on the board."""
        return (self.squares[0] * self.squares[1]) // 2

    def create_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object, lengths in metres (object points in metres)."""

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, dictionary)
        board.setLegacyPattern(self.legacy)
        return board


@dataclass(frozen=True)
class SessionCamera:
    """One camera of a session.

    Attributes
    ----------
    name : str
        Camera name; matches ``calibration.yaml``.
    video : str
        The camera's video, POSIX path relative to the session folder.
    frame_offset : int
        Frames to skip at the start of this video so that it lines up with the
        others: session frame ``f`` is video frame ``f + frame_offset`` (>= 0).
    background : str or None
        Optional empty-scene clip (same camera, same settings), relative path.
    """

    name: str
    video: str
    frame_offset: int = 0
    background: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame_offset", int(self.frame_offset))


@dataclass(frozen=True)
class Session:
    """A validated session folder (see :func:`load_session`).

    Paths are kept as written (relative to ``folder``); use :meth:`path`,
    :meth:`video_path` etc. for absolute ones.

    Attributes
    ----------
    folder : Path
        The session folder (absolute after :func:`load_session`).
    name : str
        Session name.
    fps : float
        Frame rate of the videos (frames per second).
    cameras : tuple of SessionCamera
        In the order every per-camera array uses (camera axis first).
    frame_step : int
        Every ``frame_step``-th session frame is processed (paper: 25).
    calibration_file : str or None
        The ``calibration:`` key: path of the ``calibration.yaml``.
    calibration_clips : mapping of str to str
        Camera name -> ChArUco clip, to solve the calibration from.
    board : BoardSpec or None
        The board in the calibration clips.
    ground_truth : str or None
        Folder with ground truth (synthetic sessions).
    subject : mapping or str or None
        Free-form notes about the subject.
    """

    folder: Path
    name: str
    fps: float
    cameras: tuple[SessionCamera, ...]
    frame_step: int = DEFAULT_FRAME_STEP
    calibration_file: str | None = None
    calibration_clips: Mapping[str, str] = field(default_factory=dict)
    board: BoardSpec | None = None
    ground_truth: str | None = None
    subject: Mapping[str, Any] | str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "folder", Path(self.folder))
        object.__setattr__(self, "fps", float(self.fps))
        object.__setattr__(self, "frame_step", int(self.frame_step))
        object.__setattr__(self, "cameras", tuple(self.cameras))
        object.__setattr__(self, "calibration_clips", dict(self.calibration_clips))

    # -- lookups ---------------------------------------------------------------
    @property
    def camera_names(self) -> tuple[str, ...]:
        """Camera names in session order."""
        return tuple(cam.name for cam in self.cameras)

    def camera(self, name: str) -> SessionCamera:
        """The camera called ``name``."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise KeyError(f"session {self.name!r} has no camera {name!r}; it has {self.camera_names}")

    def path(self, relative: str) -> Path:
        """Absolute path of a path written relative to the session folder."""
        return self.folder / relative

    def video_path(self, camera: str) -> Path:
        """The video of ``camera``."""
        return self.path(self.camera(camera).video)

    def background_path(self, camera: str) -> Path | None:
        """The empty-scene clip of ``camera``, or None."""
        bg = self.camera(camera).background
        return None if bg is None else self.path(bg)

    def calibration_clip_path(self, camera: str) -> Path:
        """The ChArUco calibration clip of ``camera``."""
        if camera not in self.calibration_clips:
            raise KeyError(f"session {self.name!r} has no calibration clip for camera {camera!r}")
        return self.path(self.calibration_clips[camera])

    @property
    def calibration_path(self) -> Path | None:
        """The ``calibration.yaml`` (None when the session has none yet)."""
        return None if self.calibration_file is None else self.path(self.calibration_file)

    @property
    def ground_truth_path(self) -> Path | None:
        """The ground-truth folder, or None."""
        return None if self.ground_truth is None else self.path(self.ground_truth)

    def ground_truth_silhouette_path(self, camera: str, frame: int) -> Path:
        """``ground_truth/silhouettes/<camera>/<frame:06d>.png`` (frame = session frame)."""
        if self.ground_truth is None:
            raise KeyError(f"session {self.name!r} has no ground truth")
        self.camera(camera)
        return self.path(self.ground_truth) / GROUND_TRUTH_SILHOUETTES / camera / f"{frame:06d}.png"

    def kept_frames(self, n_frames: int) -> np.ndarray:
        """Session frame indices processed out of ``n_frames``: 0, step, 2 step, ... (K,) int."""
        return np.arange(0, max(int(n_frames), 0), self.frame_step, dtype=np.int64)

    def calibration(self) -> CameraGroup:
        """The cameras from ``calibration_file``, ordered like :attr:`cameras`.

        Raises
        ------
        InputError
            No calibration file yet, a malformed one, or missing cameras.
        """
        if self.calibration_file is None:
            raise InputError(
                f"{self.folder / SESSION_FILE}: calibration: the session has no calibration "
                "file yet; solve one from its calibration clips (`bodymetry calibrate`)"
            )
        group = read_calibration(self.path(self.calibration_file)).cameras
        _check_calibration_names(
            Fields(self.folder / SESSION_FILE), self.calibration_file, group, self.camera_names
        )
        return group.subset(self.camera_names)


# --------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------
def session_relative_path(
    fields: Fields,
    value: Any,
    field_name: str,
    folder: Path | None,
    what: str,
    *,
    directory: bool = False,
) -> str:
    """Validate a path written relative to the session folder.

    Parameters
    ----------
    fields
        Names the source in error messages.
    value
        The parsed value (must be a string).
    field_name
        The field, for messages (``cameras[0].video``).
    folder
        The session folder: when given, the path must exist there (inside it,
        links resolved) and be a folder or a file as ``directory`` says; when
        None only the spelling is checked.
    what
        What the path names, for messages (``"calibration file"``).
    directory
        Whether the path must name a folder (else a file).

    Returns
    -------
    str
        The path as written.

    Raises
    ------
    InputError
        Backslashes, absolute paths, paths leaving the folder, missing files.
    """
    text = fields.string(value, field_name)
    if "\\" in text:
        raise fields.error(
            field_name,
            f"use forward slashes in paths (relative to the session folder), got {text!r}",
        )
    if PurePosixPath(text).is_absolute() or PureWindowsPath(text).drive:
        raise fields.error(
            field_name,
            f"expected a path relative to the session folder, got the absolute path {text!r}",
        )
    norm = posixpath.normpath(text)
    if norm == ".." or norm.startswith("../"):
        raise fields.error(
            field_name,
            f"path {text!r} leaves the session folder; keep every file of a session inside it",
        )
    if folder is None:
        return text
    root = folder.resolve()
    full = folder / text
    resolved = full.resolve()
    if not resolved.is_relative_to(root):
        raise fields.error(
            field_name,
            f"path {text!r} resolves to {resolved}, outside the session folder {root} "
            "(a symbolic link?); keep every file of a session inside it",
        )
    if not full.exists():
        raise fields.error(field_name, f"{what} not found: {full}")
    if directory and not full.is_dir():
        raise fields.error(field_name, f"{what} must be a folder, found a file: {full}")
    if not directory and not full.is_file():
        raise fields.error(field_name, f"{what} must be a file, found a folder: {full}")
    return text


def _board_from_data(fields: Fields, value: Any, field_name: str) -> BoardSpec:
    board = fields.mapping(value, field_name)
    fields.keys(board, field_name, _BOARD_REQUIRED, _BOARD_OPTIONAL)
    kind = fields.string(board["type"], join_field(field_name, "type"))
    if kind not in _BOARD_TYPES:
        raise fields.error(
            join_field(field_name, "type"),
            f"unknown board type {kind!r}; supported: {', '.join(_BOARD_TYPES)}",
        )
    sq_field = join_field(field_name, "squares")
    squares = board["squares"]
    if not isinstance(squares, list) or len(squares) != 2:
        raise fields.error(
            sq_field, f"expected [x, y], the number of squares per side, got {describe(squares)}"
        )
    sx = fields.integer(squares[0], join_field(sq_field, 0), minimum=2)
    sy = fields.integer(squares[1], join_field(sq_field, 1), minimum=2)
    square = fields.number(board["square_mm"], join_field(field_name, "square_mm"), positive=True)
    marker = fields.number(board["marker_mm"], join_field(field_name, "marker_mm"), positive=True)
    if not marker < square:
        raise fields.error(
            join_field(field_name, "marker_mm"),
            f"the marker ({marker!r} mm) must be smaller than the square ({square!r} mm)",
        )
    dict_field = join_field(field_name, "dictionary")
    name = fields.string(board["dictionary"], dict_field)

    known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
    if name not in known:
        raise fields.error(
            dict_field, f"unknown ArUco dictionary {name!r}; expected one of {', '.join(known)}"
        )
    size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0]
    n_markers = (sx * sy) // 2
    if n_markers > size:
        raise fields.error(
            dict_field,
            f"a {sx}x{sy} board has {n_markers} markers but {name} holds only {size}",
        )
    legacy = False
    if "legacy" in board:
        legacy = fields.boolean(board["legacy"], join_field(field_name, "legacy"))
    return BoardSpec(
        squares=(sx, sy),
        square_mm=square,
        marker_mm=marker,
        dictionary=name,
        legacy=legacy,
        type=kind,
    )


def _camera_from_data(
    fields: Fields, value: Any, field_name: str, folder: Path | None
) -> SessionCamera:
    cam = fields.mapping(value, field_name)
    fields.keys(cam, field_name, _CAMERA_REQUIRED, _CAMERA_OPTIONAL)
    name = fields.string(cam["name"], join_field(field_name, "name"))
    video = session_relative_path(
        fields, cam["video"], join_field(field_name, "video"), folder, f"video of camera {name!r}"
    )
    offset = 0
    if "frame_offset" in cam:
        offset = fields.integer(
            cam["frame_offset"], join_field(field_name, "frame_offset"), minimum=0
        )
    background = None
    if cam.get("background") is not None:
        background = session_relative_path(
            fields,
            cam["background"],
            join_field(field_name, "background"),
            folder,
            f"background clip of camera {name!r}",
        )
    return SessionCamera(name=name, video=video, frame_offset=offset, background=background)


def _check_calibration_names(
    fields: Fields, calibration_file: str, group: CameraGroup, names: tuple[str, ...]
) -> None:
    missing = [n for n in names if n not in group]
    if missing:
        raise fields.error(
            "calibration",
            f"{calibration_file} has no camera named {', '.join(map(repr, missing))}; "
            f"it has {list(group.names)} and the session's cameras[].name are {list(names)} "
            "(names must match)",
        )


def session_from_data(data: Any, fields: Fields, folder: Path, *, check_files: bool) -> Session:
    """Validate parsed ``session.yaml`` content.

    Parameters
    ----------
    data
        The parsed YAML document.
    fields
        Names the source in error messages.
    folder
        The session folder (paths in the file are relative to it).
    check_files
        When true every named file must exist inside ``folder`` and the
        calibration must name the session's cameras; when false only the
        structure is checked (what :func:`save_session` writes, or a check that
        lists every missing file itself with :func:`session_relative_path`).

    Returns
    -------
    Session
        The session; problems are reported in file order, the first one raised.

    Raises
    ------
    InputError
        For every problem, naming the source, the field, expected and actual.
    """
    _check_top_level(data, fields)
    files = folder if check_files else None
    name = fields.string(data["name"], "name")
    fps = fields.number(data["fps"], "fps", positive=True)
    frame_step = DEFAULT_FRAME_STEP
    if data.get("frame_step") is not None:
        frame_step = fields.integer(data["frame_step"], "frame_step", minimum=1)
    cameras = _cameras_from_list(fields, data["cameras"], files)
    names = tuple(cam.name for cam in cameras)
    calibration_file = _calibration_file_from_data(fields, data, folder, check_files=check_files)
    clips = _clips_from_data(fields, data, names, files)
    board = _board_for_calibration(fields, data, calibration_file, clips)
    ground_truth = None
    if data.get("ground_truth") is not None:
        ground_truth = session_relative_path(
            fields,
            data["ground_truth"],
            "ground_truth",
            files,
            "ground-truth folder",
            directory=True,
        )
    subject = _subject_from_data(fields, data)
    session = Session(
        folder=folder,
        name=name,
        fps=fps,
        cameras=tuple(cameras),
        frame_step=frame_step,
        calibration_file=calibration_file,
        calibration_clips=clips,
        board=board,
        ground_truth=ground_truth,
        subject=subject,
    )
    if check_files and calibration_file is not None:
        group = read_calibration(folder / calibration_file).cameras
        _check_calibration_names(fields, calibration_file, group, names)
    return session


def _check_top_level(data: Any, fields: Fields) -> None:
    """The document is a mapping with the session format and only known keys."""
    if not isinstance(data, dict):
        raise fields.error("", f"expected a mapping at the top level, got {describe(data)}")
    fields.mapping(data, "")
    check_format(fields, data, SESSION_FORMAT)
    fields.keys(data, "", _TOP_REQUIRED, _TOP_OPTIONAL)


def _cameras_from_list(fields: Fields, value: Any, files: Path | None) -> list[SessionCamera]:
    """The ``cameras`` list: at least one, unique names (a duplicate is reported before
    its files are looked at); files checked inside ``files`` when given."""
    if not isinstance(value, list):
        raise fields.error("cameras", f"expected a list of cameras, got {describe(value)}")
    if not value:
        raise fields.error("cameras", "expected at least one camera, got an empty list")
    cameras: list[SessionCamera] = []
    first: dict[str, int] = {}
    for i, item in enumerate(value):
        # Names first, so that a duplicate is reported before its files are looked at.
        if isinstance(item, dict) and isinstance(item.get("name"), str) and item["name"] in first:
            raise fields.error(
                join_field(join_field("cameras", i), "name"),
                f"duplicate camera name {item['name']!r} (also cameras[{first[item['name']]}])",
            )
        cam = _camera_from_data(fields, item, join_field("cameras", i), files)
        first[cam.name] = i
        cameras.append(cam)
    return cameras


def _calibration_file_from_data(
    fields: Fields, data: dict[str, Any], folder: Path, *, check_files: bool
) -> str | None:
    """The ``calibration`` path as written; when files are checked and none is written,
    ``calibration.yaml`` if the folder holds one; else None."""
    files = folder if check_files else None
    if data.get("calibration") is not None:
        return session_relative_path(
            fields, data["calibration"], "calibration", files, "calibration file"
        )
    if check_files and (folder / DEFAULT_CALIBRATION_FILE).is_file():
        return session_relative_path(
            fields, DEFAULT_CALIBRATION_FILE, "calibration", files, "calibration file"
        )
    return None


def _clips_from_data(
    fields: Fields, data: dict[str, Any], names: tuple[str, ...], files: Path | None
) -> dict[str, str]:
    """``calibration_clips``: one clip path per session camera (or none at all)."""
    clips: dict[str, str] = {}
    if data.get("calibration_clips") is None:
        return clips
    clips_value = fields.mapping(data["calibration_clips"], "calibration_clips")
    for cam_name, clip in clips_value.items():
        clip_field = join_field("calibration_clips", cam_name)
        if cam_name not in names:
            raise fields.error(
                clip_field,
                f"no session camera is called {cam_name!r}; cameras are {list(names)}",
            )
        clips[cam_name] = session_relative_path(
            fields, clip, clip_field, files, f"calibration clip of camera {cam_name!r}"
        )
    missing = [n for n in names if n not in clips]
    if missing:
        raise fields.error(
            "calibration_clips",
            f"no clip for camera(s) {', '.join(map(repr, missing))}; every camera needs one",
        )
    return clips


def _board_for_calibration(
    fields: Fields, data: dict[str, Any], calibration_file: str | None, clips: dict[str, str]
) -> BoardSpec | None:
    """The ``board``; required with calibration clips. The session must have a
    calibration file or clips (and a board) to solve one from."""
    board = None
    if data.get("board") is not None:
        board = _board_from_data(fields, data["board"], "board")
    if clips and board is None:
        raise fields.error(
            "board", "missing key 'board': calibration_clips need a description of the board"
        )
    if calibration_file is None and not clips:
        raise fields.error(
            "calibration",
            "the session has no calibration: give 'calibration: calibration.yaml', or "
            "'calibration_clips' and 'board' to solve one from",
        )
    return board


def _subject_from_data(fields: Fields, data: dict[str, Any]) -> dict[str, Any] | str | None:
    """Free notes on the subject: a mapping, a string or nothing."""
    subject = data.get("subject")
    if subject is not None and not isinstance(subject, (dict, str)):
        raise fields.error(
            "subject", f"expected notes (a mapping or a string), got {describe(subject)}"
        )
    if isinstance(subject, dict):
        fields.mapping(subject, "subject")
    return subject


def load_session(path: str | os.PathLike[str]) -> Session:
    """Read and validate a session.

    Parameters
    ----------
    path
        The session folder, or its ``session.yaml``.

    Returns
    -------
    Session
        With ``folder`` absolute. The calibration file (when present) has been
        read and checked to name every session camera.

    Raises
    ------
    InputError
        For every problem, naming the file, the field, expected and actual:
        malformed YAML, missing keys, wrong types, fps <= 0, frame_step < 1,
        duplicate cameras, unknown format version, paths that leave the session
        folder, missing files, calibration camera names that do not match.
    """
    path = Path(path)
    yaml_path = path / SESSION_FILE if path.is_dir() else path
    if not yaml_path.exists():
        if not path.exists():
            raise InputError(f"{path}: session folder not found")
        raise InputError(f"{yaml_path}: session file not found (a session folder holds one)")
    yaml_path = yaml_path.absolute()
    data = read_yaml_mapping(yaml_path, "session file", SESSION_MAX_BYTES)
    return session_from_data(data, Fields(yaml_path), yaml_path.parent, check_files=True)


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------
def _session_to_data(session: Session) -> dict[str, Any]:
    data: dict[str, Any] = {
        "format": SESSION_FORMAT,
        "name": session.name,
        "fps": session.fps,
        "frame_step": session.frame_step,
    }
    cams = []
    for cam in session.cameras:
        entry: dict[str, Any] = {"name": cam.name, "video": cam.video}
        if cam.frame_offset:
            entry["frame_offset"] = cam.frame_offset
        if cam.background is not None:
            entry["background"] = cam.background
        cams.append(entry)
    data["cameras"] = cams
    if session.calibration_file is not None:
        data["calibration"] = session.calibration_file
    if session.calibration_clips:
        data["calibration_clips"] = dict(session.calibration_clips)
    if session.board is not None:
        b = session.board
        data["board"] = {
            "type": b.type,
            "squares": list(b.squares),
            "square_mm": b.square_mm,
            "marker_mm": b.marker_mm,
            "dictionary": b.dictionary,
            "legacy": b.legacy,
        }
    if session.ground_truth is not None:
        data["ground_truth"] = session.ground_truth
    if session.subject is not None:
        data["subject"] = (
            dict(session.subject) if isinstance(session.subject, Mapping) else session.subject
        )
    return data


def session_to_yaml(session: Session) -> str:
    """The text of ``session.yaml`` for ``session`` (validated, files not checked)."""
    try:
        text = dump_yaml(_session_to_data(session), header=_SESSION_HEADER)
    except TypeError as exc:
        raise ValueError(f"session {session.name!r} cannot be written: {exc}") from exc
    session_from_data(
        parse_yaml(text),
        Fields(f"session {session.name!r} to be written"),
        session.folder,
        check_files=False,
    )
    return text


def save_session(session: Session, folder: str | os.PathLike[str] | None = None) -> Path:
    """Write ``session.yaml`` atomically into ``folder`` (default ``session.folder``).

    The content is validated as :func:`load_session` would (paths relative and
    inside the folder, names unique, ...) but the files it names need not exist
    yet. Returns the path written.
    """
    target = Path(session.folder if folder is None else folder) / SESSION_FILE
    write_text_atomic(target, session_to_yaml(session))
    return target
