"""Session folders from other tools' recordings: Pose2Sim, anipose / FreeMoCap, plain folders.

:func:`import_recording` reads a recording in another tool's layout and writes
a bodymetry session folder (docs/session-format.md): ``session.yaml``,
``calibration.yaml`` and the videos under ``videos/``. docs/import.md says what
each importer reads; in short:

* **Pose2Sim project**: ``Config.toml``, ``videos/``, and a calibration folder
  (a name holding ``calib``, here or one level up as in Pose2Sim's batch
  layout) with a Pose2Sim / anipose ``.toml`` (preferred: what Pose2Sim's own
  triangulation reads) or a Qualisys ``.qca.txt`` (read with
  ``binning_factor`` from ``Config.toml``).
* **anipose / FreeMoCap**: videos in ``videos-raw/``, ``synchronized_videos/``,
  ``videos/`` or the folder itself, and ``calibration/calibration.toml`` or a
  ``*calibration*.toml`` beside them (translations in millimetres unless the
  file says otherwise).
* **plain folder** of videos, with ``--calibration FILE`` (``.qca.txt``, ``.toml``
  or our ``calibration.yaml``).

Videos and calibration cameras are paired by :func:`match_cameras`; each
camera's image size becomes the size its video decodes to (:func:`fit_size`).
Nothing is written before everything has been read and checked.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
import shutil
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodymetry.calibration.anipose import import_anipose_toml
from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import (
    CALIBRATION_MAX_BYTES,
    Calibration,
    read_calibration,
    save_calibration,
)
from bodymetry.calibration.qualisys import natural_key, read_qca
from bodymetry.capture.background import read_clip
from bodymetry.capture.ingest import FPS_TOLERANCE, probe_video
from bodymetry.capture.session import (
    DEFAULT_CALIBRATION_FILE,
    DEFAULT_FRAME_STEP,
    SESSION_FILE,
    Session,
    SessionCamera,
    load_session,
    save_session,
)
from bodymetry.errors import InputError
from bodymetry.fileio import read_text_limited

__all__ = [
    "MIN_KEPT_FRAMES",
    "SIZE_SLACK_PX",
    "VIDEO_EXTENSIONS",
    "ImportResult",
    "Recording",
    "default_frame_step",
    "find_recording",
    "fit_size",
    "import_recording",
    "match_cameras",
    "read_any_calibration",
]

log = logging.getLogger(__name__)

#: File name endings taken as videos (case-insensitive).
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv")
#: A video may decode up to this many pixels narrower / wider (and shorter /
#: taller) than its calibration says and keep the intrinsics: H.264 and HEVC
#: code whole 16-pixel blocks and crop the rest at the right and bottom edges
#: (1080 lines are coded as 1088), so the principal point does not move.
SIZE_SLACK_PX = 16
#: The default frame step keeps at least this many frames of a short clip.
MIN_KEPT_FRAMES = 10
#: The largest Pose2Sim Config.toml or anipose config.toml read.
CONFIG_MAX_BYTES = 1_000_000

_VIDEO_FOLDERS = ("videos", "videos-raw", "synchronized_videos", "videos_raw")
_UNITS_BY_KIND = {"pose2sim": "m", "anipose": "mm"}


# --------------------------------------------------------------------------
# Camera name matching
# --------------------------------------------------------------------------
def _normalized(name: str) -> str:
    """Lower case, Pose2Sim's ``int_`` / ``_img`` folder decoration removed, only
    letters and digits, leading zeros of numbers dropped: ``int_cam01_img`` ->
    ``cam1``, ``cam_01`` -> ``cam1``, ``Cam-1`` -> ``cam1``."""
    text = name.lower()
    text = re.sub(r"^int_", "", text)
    text = re.sub(r"_img$", "", text)
    text = re.sub(r"[^a-z0-9]", "", text)
    return re.sub(r"\d+", lambda m: str(int(m.group(0))), text)


def _number(name: str) -> str | None:
    """The last number in the normalized name (``Miqus_1_28519`` -> ``28519``), or None."""
    numbers = re.findall(r"\d+", _normalized(name))
    return numbers[-1] if numbers else None


def _match_by(
    key: Callable[[str], str | None],
    videos: list[str],
    cameras: list[str],
    pairs: dict[str, str],
    *,
    suffix: bool = False,
) -> None:
    """Pair the names whose keys are equal (or, with ``suffix``, whose video key ends
    with the camera key) when the pairing is one to one; move them to ``pairs``."""
    vkeys = {v: key(v) for v in videos}
    ckeys = {c: key(c) for c in cameras}
    for v in list(videos):
        if not vkeys[v]:
            continue
        if suffix:
            hits = [c for c in cameras if ckeys[c] and vkeys[v].endswith(ckeys[c])]
        else:
            hits = [c for c in cameras if ckeys[c] == vkeys[v]]
        if len(hits) != 1:
            continue
        c = hits[0]
        if suffix:
            back = [w for w in videos if vkeys[w] and vkeys[w].endswith(ckeys[c])]
        else:
            back = [w for w in videos if vkeys[w] == ckeys[c]]
        if back == [v]:
            pairs[v] = c
    for v, c in pairs.items():
        if v in videos:
            videos.remove(v)
        if c in cameras:
            cameras.remove(c)


def match_cameras(
    videos: Sequence[str], cameras: Sequence[str], *, calibration: str | os.PathLike[str] = ""
) -> dict[str, str]:
    """Pair video names (file stems) with calibration camera names.

    The rule (docs/import.md), applied in rounds to the names still unpaired; a
    round pairs a video and a camera only when each is the other's only match:

    1. the same name;
    2. the same normalized name: lower case, Pose2Sim's ``int_`` prefix and
       ``_img`` suffix removed, only letters and digits, numbers without
       leading zeros (``cam01`` = ``cam_01`` = ``int_cam01_img`` = ``CAM-1``);
    3. the same last number in the normalized names (``cam01`` = ``1``,
       ``Camera_000_synchronized`` = ``cam_0``, ``trial_Miqus_1_28519`` = ``28519``);
    4. the normalized video name ends with the normalized camera name
       (anipose's ``vid-camA`` = ``A``).

    Calibration cameras left without a video are allowed (a QTM rig's marker
    cameras film no video); a video left without a camera is an error.

    Parameters
    ----------
    videos
        Video file stems.
    cameras
        Camera names of the calibration.
    calibration
        The calibration file, named in the error.

    Returns
    -------
    dict
        Video name -> camera name, in the order of ``videos``.

    Raises
    ------
    InputError
        Some video has no camera, listing the unmatched videos and cameras.
    """
    left_v, left_c = list(videos), list(cameras)
    pairs: dict[str, str] = {}
    _match_by(lambda s: s, left_v, left_c, pairs)
    _match_by(_normalized, left_v, left_c, pairs)
    _match_by(_number, left_v, left_c, pairs)
    _match_by(_normalized, left_v, left_c, pairs, suffix=True)
    if left_v:
        where = f"{calibration}: " if str(calibration) else ""
        raise InputError(
            f"{where}cannot match the videos to the calibration's cameras: videos without a "
            f"camera {left_v}; cameras without a video {left_c} (all cameras: {list(cameras)}). "
            "Names match when equal after dropping case, separators and leading zeros "
            "(cam01 = cam_01 = int_cam01_img), or by their last number (cam01 = 1); "
            "rename the video files after the camera names"
        )
    return {v: pairs[v] for v in videos}


# --------------------------------------------------------------------------
# Sizes and frame step
# --------------------------------------------------------------------------
def fit_size(
    camera: Camera, decoded: tuple[int, int], video: Path, calibration: Path
) -> tuple[Camera, str | None]:
    """Give ``camera`` the size its video decodes to.

    Parameters
    ----------
    camera
        As calibrated.
    decoded
        ``(width, height)`` of the video's decoded frames.
    video, calibration
        Named in the messages.

    Returns
    -------
    camera : Camera
        With ``size = decoded``; K, distortion and pose unchanged.
    warning : str or None
        When the sizes differ by at most :data:`SIZE_SLACK_PX` per side (a
        codec's crop or pad at the right / bottom edge): the intrinsics are kept.

    Raises
    ------
    InputError
        A larger difference (another resolution, a rotated or scaled video),
        naming both sizes and both files.
    """
    w, h = (int(v) for v in decoded)
    cw, ch = camera.size
    if (w, h) == (cw, ch):
        return camera, None
    said = f"{calibration.name} says {cw}x{ch} for camera {camera.name!r}"
    if abs(w - cw) <= SIZE_SLACK_PX and abs(h - ch) <= SIZE_SLACK_PX:
        message = (
            f"{video} decodes as {w}x{h} but {said}: kept the intrinsics (a crop or pad of "
            f"{abs(w - cw)}x{abs(h - ch)} px at the right / bottom edge, as video codecs do) "
            f"and wrote the decoded size {w}x{h}"
        )
        return dataclasses.replace(camera, size=(w, h)), message
    hint = "another resolution than the one calibrated"
    if (w, h) == (ch, cw):
        hint = "a rotated video (portrait vs landscape)?"
    elif math.isclose(w / h, cw / ch, rel_tol=0.01):
        hint = (
            f"the same aspect scaled by {w / cw:.3g} (a resized or binned video? a Qualisys "
            "calibration of binned video needs binning_factor in Pose2Sim's Config.toml)"
        )
    raise InputError(
        f"{video} decodes as {w}x{h} (aspect {w / h:.3f}) but {said} (aspect {cw / ch:.3f}): "
        f"{hint}; the calibration does not fit this video"
    )


def default_frame_step(n_frames: int) -> int:
    """The session format's default (25), or less so a short clip keeps
    :data:`MIN_KEPT_FRAMES` frames (100 frames -> 10, keeping frames 0, 10, ..., 90)."""
    return max(1, min(DEFAULT_FRAME_STEP, int(n_frames) // MIN_KEPT_FRAMES))


def _decoded_size(path: Path, camera: str) -> tuple[int, int]:
    """(width, height) of a video's first decoded frame."""
    first = read_clip(path, camera, max_frames=1, what="video")[0]
    return int(first.shape[1]), int(first.shape[0])


# --------------------------------------------------------------------------
# Finding a recording's parts
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Recording:
    """What :func:`find_recording` found in a source folder.

    Attributes
    ----------
    kind : str
        ``"pose2sim"``, ``"anipose"`` (anipose or FreeMoCap) or ``"plain"``.
    folder : Path
        The source folder.
    videos : tuple of Path
        The videos, in natural order of their names.
    calibration : Path or None
        The calibration file found (None for a plain folder without one).
    binning_factor : int
        Pose2Sim's Qualisys binning factor (1 elsewhere).
    config : Path or None
        Pose2Sim's ``Config.toml`` or anipose's ``config.toml``.
    """

    kind: str
    folder: Path
    videos: tuple[Path, ...]
    calibration: Path | None
    binning_factor: int = 1
    config: Path | None = None


def _videos_in(folder: Path) -> list[Path]:
    files = [
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in VIDEO_EXTENSIONS
    ]
    return sorted(files, key=lambda p: natural_key(p.name))


def _read_toml(path: Path, what: str) -> dict:
    try:
        return tomllib.loads(read_text_limited(path, CONFIG_MAX_BYTES, what))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the {what}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from exc


def _pose2sim_binning(config: Path) -> int:
    data = _read_toml(config, "Pose2Sim Config.toml")
    section = data.get("calibration", {})
    for key in ("convert", "qualisys"):
        section = section.get(key, {}) if isinstance(section, dict) else {}
    value = section.get("binning_factor", 1) if isinstance(section, dict) else 1
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(
            f"{config}: calibration.convert.qualisys.binning_factor: expected an integer >= 1, "
            f"got {value!r}"
        )
    return value


def _pose2sim_calibration(folder: Path) -> Path | None:
    """Pose2Sim's calibration folder (a name holding 'calib', here or one level up),
    its TOML when there is one (what Pose2Sim triangulates with), else its .qca.txt."""
    for base in (folder, folder.parent):
        dirs = (
            sorted(p for p in base.iterdir() if p.is_dir() and "calib" in p.name.lower())
            if base.is_dir()
            else []
        )
        for calib_dir in dirs:
            tomls = sorted(calib_dir.glob("*.toml"))
            qcas = sorted(calib_dir.glob("*.qca.txt"))
            for found, what in ((tomls, "calibration TOML"), (qcas, "Qualisys .qca.txt")):
                if len(found) > 1:
                    raise InputError(
                        f"{calib_dir}: {len(found)} {what} files ({[p.name for p in found]}); "
                        "choose one with --calibration FILE"
                    )
                if found:
                    if tomls and qcas:
                        log.info(
                            "%s: using %s (what Pose2Sim triangulates with), not %s",
                            calib_dir,
                            tomls[0].name,
                            qcas[0].name,
                        )
                    return found[0]
    return None


def find_recording(source: str | os.PathLike[str], calibration: Path | None = None) -> Recording:
    """Recognize the layout of ``source`` and find its videos and calibration.

    Parameters
    ----------
    source
        The folder: a Pose2Sim project (``Config.toml``), an anipose / FreeMoCap
        session, or a plain folder of videos.
    calibration
        A calibration file to use instead of the one the layout names.

    Raises
    ------
    InputError
        No such folder, no videos, or no calibration.
    """
    folder = Path(source)
    if not folder.is_dir():
        raise InputError(
            f"{folder}: source folder not found"
            if not folder.exists()
            else f"{folder}: expected a folder (a recording), found a file"
        )
    binning = 1
    config: Path | None = None
    if (folder / "Config.toml").is_file():
        kind, config = "pose2sim", folder / "Config.toml"
        binning = _pose2sim_binning(config)
        video_dir = folder / "videos"
        if not video_dir.is_dir():
            raise InputError(
                f"{folder}: a Pose2Sim project (Config.toml) without a videos/ folder; "
                "import each trial folder (the one holding videos/)"
            )
        found = calibration or _pose2sim_calibration(folder)
    else:
        video_dir = next((folder / d for d in _VIDEO_FOLDERS if (folder / d).is_dir()), folder)
        tomls = [folder / "calibration" / "calibration.toml"] + sorted(
            p for p in folder.glob("*.toml") if "calibration" in p.name.lower()
        )
        tomls = [p for p in tomls if p.is_file()]
        if len(tomls) > 1:
            raise InputError(
                f"{folder}: {len(tomls)} calibration TOML files ({[str(p) for p in tomls]}); "
                "choose one with --calibration FILE"
            )
        kind = "anipose" if tomls or video_dir != folder else "plain"
        if (folder / "config.toml").is_file():
            kind, config = "anipose", folder / "config.toml"
        found = calibration or (tomls[0] if tomls else None)
    videos = _videos_in(video_dir)
    if not videos:
        raise InputError(f"{video_dir}: no videos ({', '.join(VIDEO_EXTENSIONS)}) in the folder")
    if found is None:
        raise InputError(
            f"{folder}: no calibration found (looked for a Pose2Sim calibration folder, "
            "calibration/calibration.toml, *calibration*.toml); pass --calibration FILE "
            "(.qca.txt, .toml or calibration.yaml)"
        )
    return Recording(kind, folder, tuple(videos), Path(found), binning, config)


def read_any_calibration(
    path: Path,
    *,
    units: str | None = None,
    default_units: str | None = None,
    binning_factor: int = 1,
) -> tuple[CameraGroup, dict]:
    """Read a calibration by its name: ``.qca.txt`` (Qualisys), ``.toml`` (anipose /
    FreeMoCap / Pose2Sim) or ``.yaml`` / ``.yml`` (ours).

    Parameters
    ----------
    path
        The file.
    units
        Unit of a TOML's translations (``m``, ``cm``, ``mm``); default: the file's
        ``metadata.units``, else ``default_units``, else an error.
    default_units
        The layout's usual unit (Pose2Sim writes metres, anipose and FreeMoCap mm).
    binning_factor
        For a ``.qca.txt``.

    Returns
    -------
    cameras : CameraGroup
    quality : dict
        Figures to keep in ``calibration.yaml`` (per camera name).
    """
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    name = path.name.lower()
    if name.endswith((".qca.txt", ".qca")):
        qca = read_qca(path, binning_factor=binning_factor)
        quality = {
            n: {"qtm_avg_residual_mm": r} for n, r in qca.residuals_mm.items() if math.isfinite(r)
        }
        return qca.cameras, quality
    if name.endswith(".toml"):
        chosen = units
        if chosen is None:
            try:
                meta = tomllib.loads(
                    read_text_limited(path, CALIBRATION_MAX_BYTES, "calibration TOML file")
                ).get("metadata", {})
            except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
                meta = {}  # import_anipose_toml reports it, naming the file
            if not (isinstance(meta, dict) and "units" in meta) and default_units is not None:
                chosen = default_units
                log.info(
                    "%s: the file does not say its unit; reading translations in %s "
                    "(this layout's; --units to change)",
                    path,
                    chosen,
                )
        try:
            return import_anipose_toml(path, units=chosen), {}
        except InputError as exc:
            if "metadata.units" in str(exc) and units is None:
                raise InputError(f"{exc} (on the command line: --units mm, cm or m)") from exc
            raise
    if name.endswith((".yaml", ".yml")):
        return read_calibration(path).cameras, {}
    raise InputError(
        f"{path}: unknown calibration format; expected a Qualisys .qca.txt, an anipose / "
        "FreeMoCap / Pose2Sim .toml or a bodymetry calibration.yaml"
    )


# --------------------------------------------------------------------------
# The import
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class ImportResult:
    """What :func:`import_recording` wrote.

    Attributes
    ----------
    session : Session
        The session as loaded back from ``out``.
    kind : str
        The source's layout (:attr:`Recording.kind`).
    calibration_source : Path
        The calibration file read.
    links : str
        How the videos were placed: ``"hardlink"``, ``"copy"`` or a mix (``"hardlink, copy"``).
    frames : int
        Frames of the shortest video (the session's length).
    warnings : tuple of str
        Everything logged as a warning (sizes, fps of Config.toml, world up).
    """

    session: Session
    kind: str
    calibration_source: Path
    links: str
    frames: int
    warnings: tuple[str, ...]


def _check_out(out: Path, source: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is a file; OUT must be a folder")
    src, dst = source.resolve(), out.resolve()
    if dst == src or src.is_relative_to(dst):
        raise InputError(f"{out}: OUT may not be the source folder or hold it; choose a new folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise InputError(
                f"{out}: the folder is not empty; pass --overwrite to replace the session "
                "in it, or choose an empty or new folder"
            )
        if not (out / SESSION_FILE).is_file():
            raise InputError(
                f"{out}: the folder is not empty and holds no {SESSION_FILE}; --overwrite "
                "replaces a session, not other files: choose an empty or new folder"
            )


def _place(src: Path, dst: Path, copy: bool) -> str:
    """Hard-link (or copy) ``src`` to ``dst``; returns how."""
    if dst.exists() or dst.is_symlink():
        if not copy and dst.exists() and os.path.samefile(src, dst):
            return "hardlink"  # already linked by an earlier import
        dst.unlink()
    if not copy:
        try:
            os.link(src, dst)
            return "hardlink"
        except OSError as exc:
            log.info("%s: cannot hard-link here (%s); copying", src, exc.strerror or exc)
    tmp = dst.with_name(f".{dst.name}.tmp")
    shutil.copy2(src, tmp)
    os.replace(tmp, dst)
    return "copy"


def _world_up_warning(group: CameraGroup, calibration: Path) -> str | None:
    """Cameras mostly stand upright: world z should point up in most images
    (negative image y). A calibration whose z points down in most is not z up."""
    down = [cam.name for cam in group if (cam.R @ np.array([0.0, 0.0, 1.0]))[1] > 0]
    if len(down) * 2 > len(group):
        return (
            f"{calibration}: world z points down in the images of {down}; bodymetry expects "
            "z up with the floor at z = 0 (an anipose board frame?): measurements that need "
            "the floor will be wrong"
        )
    return None


def import_recording(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    calibration: str | os.PathLike[str] | None = None,
    frame_step: int | None = None,
    copy: bool = False,
    overwrite: bool = False,
    units: str | None = None,
) -> ImportResult:
    """Write a session folder ``out`` from a recording in another tool's layout.

    Parameters
    ----------
    source
        A Pose2Sim project, an anipose / FreeMoCap session or a folder of videos.
    out
        The session folder to write: new, empty, or (with ``overwrite``) a session.
    calibration
        A calibration file to use instead of the layout's (``.qca.txt``,
        ``.toml`` or ``calibration.yaml``); required for a plain folder.
    frame_step
        Process every ``frame_step``-th frame; default :func:`default_frame_step`
        of the shortest video.
    copy
        Copy the videos; by default they are hard-linked (no space used), and
        copied where a hard link is impossible (another file system). Symbolic
        links are not used: the session format refuses links that resolve
        outside the session folder.
    overwrite
        Replace the session in a non-empty ``out`` (its ``session.yaml``,
        ``calibration.yaml`` and the videos of the same names; other files stay).
    units
        Unit of a TOML calibration's translations when the file does not say.

    Returns
    -------
    ImportResult

    Raises
    ------
    InputError
        Any problem with the source, the calibration, the matching, the sizes,
        the frame rates or ``out``; nothing is written then.
    """
    out = Path(out)
    source = Path(source)
    calib = Path(calibration) if calibration is not None else None
    if frame_step is not None and (isinstance(frame_step, bool) or int(frame_step) < 1):
        raise InputError(f"--frame-step: expected an integer >= 1, got {frame_step!r}")
    rec = find_recording(source, calib)
    _check_out(out, source, overwrite)
    log.info(
        "%s: a %s recording; %d video(s); calibration %s",
        source,
        rec.kind,
        len(rec.videos),
        rec.calibration,
    )
    group, quality = _read_calibration(rec, units)
    pairs = _match_videos(rec, group)
    group_out, fps, frames, warnings = _fit_cameras(rec, group, pairs)
    rate = _common_rate(rec, fps, warnings)
    shortest = min(frames)
    if frame_step is None:
        frame_step = _default_step_logged(shortest)
    up = _world_up_warning(group_out, rec.calibration)
    if up:
        warnings.append(up)
    for warning in warnings:
        log.warning("%s", warning)

    # Everything is read and checked: write.
    links = _write_session(out, source, rec, group_out, quality, pairs, rate, int(frame_step), copy)
    return ImportResult(
        load_session(out), rec.kind, rec.calibration, links, shortest, tuple(warnings)
    )


def _read_calibration(rec: Recording, units: str | None) -> tuple[CameraGroup, dict]:
    """The recording's calibration (:func:`read_any_calibration`) with its layout's
    default units and binning factor.

    Returns
    -------
    group : CameraGroup
    quality : dict
        Quality per calibration camera name, where the file states it.
    """
    return read_any_calibration(
        rec.calibration,
        units=units,
        default_units=_UNITS_BY_KIND.get(rec.kind),
        binning_factor=rec.binning_factor,
    )


def _match_videos(rec: Recording, group: CameraGroup) -> dict[str, str]:
    """Match the videos (by file stem) to the calibration's cameras (:func:`match_cameras`).

    Returns
    -------
    dict video stem -> calibration camera name
        Calibration cameras without a video are logged and left out.

    Raises
    ------
    InputError
        Two videos share a stem (e.g. different extensions), or no match.
    """
    stems = [p.stem for p in rec.videos]
    duplicates = sorted({s for s in stems if stems.count(s) > 1})
    if duplicates:
        raise InputError(
            f"{rec.videos[0].parent}: several videos share the name(s) {duplicates} "
            "(different extensions?); keep one video per camera"
        )
    pairs = match_cameras(stems, group.names, calibration=rec.calibration)
    unused = [n for n in group.names if n not in pairs.values()]
    if unused:
        log.info("%s: cameras without a video, left out: %s", rec.calibration, unused)
    return pairs


def _fit_cameras(
    rec: Recording, group: CameraGroup, pairs: dict[str, str]
) -> tuple[CameraGroup, list[tuple[str, float]], list[int], list[str]]:
    """Each video's camera, renamed after the video and fitted to its decoded size.

    Parameters
    ----------
    pairs : dict video stem -> calibration camera name

    Returns
    -------
    cameras : CameraGroup
        The rig, in video order.
    fps : list of (name, float)
        Each video's frame rate.
    frames : list of int
        Each video's frame count.
    warnings : list of str
        Size warnings of :func:`fit_size`.
    """
    warnings: list[str] = []
    cameras: list[Camera] = []
    fps: list[tuple[str, float]] = []
    frames: list[int] = []
    for video in rec.videos:
        name = video.stem
        info = probe_video(video, name)
        fps.append((name, info.fps))
        frames.append(info.frames)
        cam = dataclasses.replace(group[pairs[name]], name=name)
        cam, warning = fit_size(cam, _decoded_size(video, name), video, rec.calibration)
        if warning:
            warnings.append(warning)
        cameras.append(cam)
        log.info("camera %r: %s <-> calibration camera %r", name, video.name, pairs[name])
    return CameraGroup(cameras), fps, frames, warnings


def _common_rate(rec: Recording, fps: list[tuple[str, float]], warnings: list[str]) -> float:
    """The videos' one frame rate; appends a warning to ``warnings`` where a Pose2Sim
    project declares another.

    Raises
    ------
    InputError
        The videos run at different rates (beyond :data:`FPS_TOLERANCE`).
    """
    rate = fps[0][1]
    off = [f"{n}: {f:g}" for n, f in fps if abs(f - rate) > FPS_TOLERANCE * rate]
    if off:
        raise InputError(
            f"{rec.videos[0].parent}: the videos run at different frame rates "
            f"({', '.join(f'{n}: {f:g}' for n, f in fps)} fps); a session needs one"
        )
    if rec.kind == "pose2sim" and rec.config is not None:
        declared = _read_toml(rec.config, "Pose2Sim Config.toml").get("project", {})
        declared = declared.get("frame_rate") if isinstance(declared, dict) else None
        numeric = isinstance(declared, (int, float)) and not isinstance(declared, bool)
        if numeric and abs(declared - rate) > FPS_TOLERANCE * rate:
            warnings.append(
                f"{rec.config}: project.frame_rate = {declared:g} but the videos run at "
                f"{rate:g} fps; using the videos' rate"
            )
    return rate


def _default_step_logged(shortest: int) -> int:
    """:func:`default_frame_step` of the shortest video's frame count, logged."""
    frame_step = default_frame_step(shortest)
    kept = len(range(0, shortest, frame_step))
    if frame_step < DEFAULT_FRAME_STEP:
        log.info(
            "frame_step %d: the shortest video has %d frames, so every %d-th frame keeps "
            "%d (the default %d would keep %d); --frame-step N to choose",
            frame_step,
            shortest,
            frame_step,
            kept,
            DEFAULT_FRAME_STEP,
            len(range(0, shortest, DEFAULT_FRAME_STEP)),
        )
    else:
        log.info("frame_step %d: keeps %d of %d frames", frame_step, kept, shortest)
    return frame_step


def _write_session(
    out: Path,
    source: Path,
    rec: Recording,
    group: CameraGroup,
    quality: dict,
    pairs: dict[str, str],
    rate: float,
    frame_step: int,
    copy: bool,
) -> str:
    """Write the session folder: the videos (linked or copied), ``calibration.yaml``
    and ``session.yaml``.

    Parameters
    ----------
    group : CameraGroup
        The fitted cameras, in video order.
    quality : dict
        The source calibration's quality per calibration camera name.
    pairs : dict video stem -> calibration camera name

    Returns
    -------
    str
        How the videos were placed (``"hard link"``, ``"copy"``, comma-joined).
    """
    out.mkdir(parents=True, exist_ok=True)
    (out / "videos").mkdir(exist_ok=True)
    how = []
    session_cams = []
    for video, cam in zip(rec.videos, group, strict=True):
        relative = f"videos/{video.name}"
        how.append(_place(video, out / relative, copy))
        session_cams.append(SessionCamera(name=cam.name, video=relative))
    qca = rec.calibration.name.lower().endswith((".qca.txt", ".qca"))
    world = {
        "frame": "Qualisys (QTM) world: z up, metres"
        if qca
        else "the source calibration's world frame (bodymetry expects z up, metres)",
        "note": f"imported by `bodymetry import` from {rec.calibration.name} ({rec.kind})",
    }
    save_calibration(
        out / DEFAULT_CALIBRATION_FILE,
        Calibration(
            cameras=group,
            world=world,
            quality={v: quality[c] for v, c in pairs.items() if c in quality} or None,
        ),
    )
    session = Session(
        folder=out,
        name=source.resolve().name,
        fps=rate,
        cameras=tuple(session_cams),
        frame_step=frame_step,
        calibration_file=DEFAULT_CALIBRATION_FILE,
    )
    save_session(session)
    links = ", ".join(dict.fromkeys(how))
    log.info("wrote the session %s (%d cameras, videos: %s)", out, len(group), links)
    return links
