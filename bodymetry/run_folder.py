"""A run folder that describes itself: ``run.json``, written before anything else.

``run.json`` records the format, the session (its path and a fingerprint of
its content) and a fingerprint of the settings that change results. With it,
``bodymetry process --out RUN``:

- creates RUN when it does not exist, or uses it when it is empty;
- resumes RUN when it holds a run of the same session and settings (the
  frames already recorded are kept);
- refuses a non-empty folder that is not a run (another program's output, a
  typo), and a run of another session or other settings, unless ``restart``
  is given; a restart removes the run's own files only (never anything else).

The fingerprint of a session reads its small files whole (session.yaml, the
calibration) and, of every video, its size and the first and last MiB: enough
to tell another recording from this one without reading gigabytes.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

from bodymetry import __version__
from bodymetry.capture.session import SESSION_FILE, Session
from bodymetry.errors import InputError
from bodymetry.estimation.registration import RegistrationConfig
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import MANIFEST_FORMAT, RunLayout, RunManifest

log = logging.getLogger(__name__)

__all__ = [
    "config_fingerprint",
    "prepare_run_folder",
    "session_fingerprint",
]

_CHUNK = 1 << 20


def _hash_file_ends(h: Any, path: Path) -> None:
    size = path.stat().st_size
    h.update(f"{path.name}:{size}".encode())
    with path.open("rb") as f:
        h.update(f.read(_CHUNK))
        if size > 2 * _CHUNK:
            f.seek(size - _CHUNK)
            h.update(f.read(_CHUNK))


def session_fingerprint(session: Session) -> str:
    """A hash of what the session's measurements depend on (hex, 16 characters)."""
    h = hashlib.sha256()
    h.update((session.folder / SESSION_FILE).read_bytes())
    calib = session.calibration_path
    if calib is not None and calib.is_file():
        h.update(calib.read_bytes())
    for name in session.camera_names:
        video = session.video_path(name)
        if video.is_file():
            _hash_file_ends(h, video)
    return h.hexdigest()[:16]


#: Settings added after runs were made, at their defaults (the path into
#: ``ProcessConfig.to_json()``): left out of the hash there, so that earlier runs keep theirs.
_LATER_SETTINGS: dict[tuple[str, ...], object] = {("fit", "refinement", "thin_px"): 0.0}


def config_fingerprint(config: ProcessConfig) -> str:
    """A hash of the settings that change the results (not workers, cache or review)."""
    data = config.to_json()
    for path, default in _LATER_SETTINGS.items():
        *parents, key = path
        holder = data
        for name in parents:
            holder = holder.get(name, {})
        if holder.get(key) == default:
            holder.pop(key)
    relevant = {
        k: data[k] for k in ("quality", "fit", "training", "frame_step", "working_person_px")
    }
    if config.person is not None:  # absent otherwise: runs of one subject keep their hash
        relevant["person"] = config.person
    if config.largest:
        relevant["largest"] = True
    if config.registration != RegistrationConfig():  # the default keeps earlier runs' hash
        relevant["registration"] = data["registration"]
    return hashlib.sha256(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:16]


def _clear_run(layout: RunLayout) -> None:
    for path in layout.entries:
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()


def _is_old_run(layout: RunLayout) -> bool:
    return layout.results.is_file() or layout.frames_dir.is_dir()


def prepare_run_folder(
    out: Path, session: Session, config: ProcessConfig, *, restart: bool = False
) -> RunManifest:
    """Create, resume or (with ``restart``) reset the run folder ``out``; writes ``run.json``.

    Raises
    ------
    InputError
        When ``out`` is a file, a non-empty folder that is not a run, or a run of
        another session or other settings (without ``restart``), or cannot be written.
    """
    layout = RunLayout(Path(out))
    manifest = RunManifest(
        format=MANIFEST_FORMAT,
        session_path=str(session.folder.resolve()),
        session_fingerprint=session_fingerprint(session),
        config_fingerprint=config_fingerprint(config),
        bodymetry_version=__version__,
        created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    )
    folder = layout.folder
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a folder; choose another --out")
    entries = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    if entries:
        if layout.manifest.is_file():
            try:
                previous = RunManifest.read(layout.manifest)
            except InputError as exc:
                if not restart:
                    raise InputError(f"{exc}; pass --restart to start the run again") from exc
                previous = None
            if previous is not None:
                mismatch = []
                if previous.session_fingerprint != manifest.session_fingerprint:
                    mismatch.append(f"session {previous.session_path}")
                if previous.config_fingerprint != manifest.config_fingerprint:
                    mismatch.append("other settings")
                if not mismatch:
                    log.info("%s: resuming the run started %s", folder, previous.created)
                    return previous
                if not restart:
                    raise InputError(
                        f"{folder}: a run of {' and '.join(mismatch)}; pass --restart to "
                        "replace it, or choose another --out"
                    )
        elif _is_old_run(layout):
            if not restart:
                raise InputError(
                    f"{folder}: a run without run.json (an older bodymetry, or not a run); "
                    "pass --restart to replace it, or choose another --out"
                )
        else:
            raise InputError(
                f"{folder}: not empty and not a bodymetry run folder "
                f"({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''}); "
                "choose another --out"
            )
        log.warning("%s: --restart: removing the previous run's files", folder)
        _clear_run(layout)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        manifest.write(layout)
    except OSError as exc:
        raise InputError(
            f"{exc.filename or folder}: cannot write the run folder ({exc.strerror})"
        ) from exc
    return manifest
