"""The review stage: every review output of a run in one pass over its frames.

``build_review(RUN)`` reads the run folder (``results.json``, the cameras of
``calibration.yaml``, the silhouettes and particles of ``frames/FFFFFF.npz``;
the session's videos only for the camera images), then for every kept frame
poses the fitted body and writes the frame to ``recording.rrd`` and
``recording.mcap``; the report
(``report.html``, ``measurements.csv``, optionally ``report.pdf``) reuses the
overlays of a few frames from the same pass. ``bodymetry process`` calls it
after ``results.json`` is written; a failure here never loses the results.

Each output is written to a temporary file and moved into place when
complete. A writer that fails is dropped (its previous file, if any, stays)
and the others go on; the failure is logged and listed in the summary.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.run_files import RECORDING_MCAP, RECORDING_RRD
from bodymetry.fileio import atomic_path
from bodymetry.log import Progress
from bodymetry.review.mcap_recording import McapWriter
from bodymetry.review.report import OverlayRow, build_report, overlay_row, select_overlay_frames
from bodymetry.review.rerun_recording import RerunWriter
from bodymetry.review.run_data import RunData, load_run, run_frame_views

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReviewSummary:
    """What :func:`build_review` wrote.

    Attributes
    ----------
    files : dict of str to Path
        Output name (``rrd``, ``mcap``, ``html``, ``csv``, ``pdf``) -> path written.
    errors : dict of str to str
        Output name -> why it was not written.
    frames : int
        Frames written to the recordings.
    seconds : float
        Wall time of the review stage.
    """

    files: dict[str, Path] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    frames: int = 0
    seconds: float = 0.0


class _Output:
    """A recording writer bound to a temporary file that replaces ``final`` on success."""

    def __init__(self, name: str, final: Path, factory: Callable[[Path], Any]) -> None:
        self.name = name
        self.final = final
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(final))
        self.writer = factory(self._tmp)

    def finish(self) -> None:
        self.writer.close()
        self._stack.close()  # moves the temporary file onto the final path

    def discard(self) -> None:
        with contextlib.suppress(Exception):
            self.writer.close()
        # Leaving the atomic block with an exception removes the temporary file.
        with contextlib.suppress(RuntimeError):
            self._stack.__exit__(RuntimeError, RuntimeError("discarded"), None)


def build_review(
    run: RunData | str | Path,
    *,
    recordings: bool = True,
    report: bool = True,
    pdf: bool = False,
    progress: Progress | None = None,
) -> ReviewSummary:
    """Write a run's review outputs into its folder.

    Parameters
    ----------
    run : RunData or path
        The run folder (or one already read).
    recordings : bool
        Write ``recording.rrd`` and ``recording.mcap``.
    report : bool
        Write ``report.html`` and ``measurements.csv``.
    pdf : bool
        Also write ``report.pdf``.
    progress : callable, optional
        ``progress("review", done, total)`` after each frame.

    Raises
    ------
    InputError
        When the run folder has no readable ``results.json``.
    """
    t0 = time.perf_counter()
    if not isinstance(run, RunData):
        run = load_run(run)
    body = shared_body_model()
    files: dict[str, Path] = {}
    errors: dict[str, str] = {}
    outputs = _start_recordings(run, body, errors) if recordings else []
    # Each person's overlay frames (person id -> frames): chosen from their own fits.
    overlay_frames = (
        {p.person_id: set(select_overlay_frames(p)) for p in run.person_runs()} if report else {}
    )
    overlays, done = _write_frames(
        run, body, outputs, errors, overlay_frames, every_frame=recordings, progress=progress
    )
    _finish_recordings(outputs, files, errors)
    if report:
        _write_report(run, body, overlays, pdf, files, errors)
    seconds = time.perf_counter() - t0
    log.info(
        "review of %s: %s in %.1f s%s",
        run.folder,
        ", ".join(p.name for p in files.values()) or "nothing written",
        seconds,
        f"; failed: {', '.join(errors)}" if errors else "",
    )
    return ReviewSummary(
        files=files, errors=errors, frames=done if recordings else 0, seconds=seconds
    )


def _start_recordings(run: RunData, body: BodyModel, errors: dict[str, str]) -> list[_Output]:
    """Open ``recording.rrd`` and ``recording.mcap`` (a writer that cannot start is
    logged and named in ``errors``)."""
    outputs: list[_Output] = []
    for name, filename, cls in (
        ("rrd", RECORDING_RRD, RerunWriter),
        ("mcap", RECORDING_MCAP, McapWriter),
    ):
        try:
            outputs.append(_Output(name, run.folder / filename, lambda p, c=cls: c(p, run, body)))
        except Exception as exc:
            log.exception("%s: could not start %s", run.folder, filename)
            errors[name] = f"{type(exc).__name__}: {exc}"
    return outputs


def _write_frames(
    run: RunData,
    body: BodyModel,
    outputs: list[_Output],
    errors: dict[str, str],
    overlay_frames: dict[int, set[int]],
    *,
    every_frame: bool,
    progress: Progress | None,
) -> tuple[list[OverlayRow], int]:
    """The pass over the frames: each person's view of each frame to every recording
    in ``outputs`` (a writer that fails is discarded, removed from ``outputs`` and
    named in ``errors``) and the overlays of each person's ``overlay_frames`` for
    the report.

    Every frame some person kept when ``every_frame``, else only the overlay
    frames. Returns the overlay rows and the number of frames passed.
    """
    overlays: list[OverlayRow] = []
    kept = {r.frame for p in run.person_runs() for r in p.frames}
    shown = set().union(*overlay_frames.values()) if overlay_frames else set()
    total = len(kept) if every_frame else len(shown)
    done = 0
    wanted = None if every_frame else sorted(shown)
    if progress:
        progress("review", 0, total)
    for views in run_frame_views(run, body, frames=wanted):
        for view in views:
            for out in list(outputs):
                try:
                    out.writer.add(view)
                except Exception as exc:
                    log.exception("%s: writing frame %d failed", out.final, view.frame)
                    errors[out.name] = f"frame {view.frame}: {type(exc).__name__}: {exc}"
                    out.discard()
                    outputs.remove(out)
            if view.frame in overlay_frames.get(view.person, ()):
                row = overlay_row(run.for_person(view.person), view)
                if row is not None:
                    overlays.append(row)
        done += 1
        if progress:
            progress("review", done, total)
    return overlays, done


def _finish_recordings(
    outputs: list[_Output], files: dict[str, Path], errors: dict[str, str]
) -> None:
    """Move the finished recordings into place (into ``files``; a failure into ``errors``)."""
    for out in outputs:
        try:
            out.finish()
            files[out.name] = out.final
        except Exception as exc:
            log.exception("%s: could not finish", out.final)
            errors[out.name] = f"{type(exc).__name__}: {exc}"
            out.discard()


def _write_report(
    run: RunData,
    body: BodyModel,
    overlays: list[OverlayRow],
    pdf: bool,
    files: dict[str, Path],
    errors: dict[str, str],
) -> None:
    """``report.html``, ``measurements.csv`` (and ``report.pdf``) into ``files``;
    a failure into ``errors``."""
    try:
        written = build_report(run, body, overlays=overlays, pdf=pdf)
        files["html"], files["csv"] = written.html, written.csv
        if written.pdf is not None:
            files["pdf"] = written.pdf
    except Exception as exc:
        log.exception("%s: could not write the report", run.folder)
        errors["report"] = f"{type(exc).__name__}: {exc}"
