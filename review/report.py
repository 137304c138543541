"""The measurement report of a run: ``report.html``, ``measurements.csv``, ``report.pdf``.

``report.html`` is one self-contained file (images embedded as base64, no
external resources): the session and subject summary, the measurements per
stage (mean ± std, and the paper's Figure 3 layout beside the ground truth
when the session has one; the GT + Generative column when ``bodymetry
evaluate`` wrote ``evaluation.json``), per-frame plots, silhouette overlays of
a few frames in every camera, front and side renders of the fitted body, the
calibration quality and a per-frame table. ``report.pdf`` (``--pdf``) has the
same content, composed with matplotlib (no system libraries needed).
``measurements.csv`` has one row per person and kept frame (a ``person`` column).
A run of several persons has one section per person ("Person K": headline
cards, frames and fit, tables, plots, overlays in the person's colour, body,
frames), the run's warnings once above them; a run of one person looks as it
always did.

Everything is rebuilt from the run folder (``bodymetry report RUN``):
``results.json``, the cameras of ``calibration.yaml`` and, for the overlays,
the silhouettes recorded in ``frames/FFFFFF.npz``. Only the camera images
under the overlays come from the session's videos; without them the
silhouettes are drawn on grey, and without either the overlays are left out
with a note.
"""

from __future__ import annotations

import base64
import csv
import datetime as _dt
import io
import logging
import math
import re
import textwrap
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import jinja2
import markupsafe
import numpy as np

from bodymetry import __version__
from bodymetry.calibration.camera import Camera
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.caveats import VALIDATED
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.outline_check import OutlineConfig
from bodymetry.estimation.records import CORE_MEASUREMENTS, STAGES, SessionGate, SessionShape, Stat
from bodymetry.estimation.run_files import (
    GT_STAGE,
    MEASUREMENTS_CSV,
    REPORT_HTML,
    REPORT_PDF,
    RunResults,
)
from bodymetry.estimation.studio_accuracy import LIKE_HEIGHT, LIKE_WEIGHT, LOW_CONTRAST, MIN_LIKE
from bodymetry.estimation.uncertainty import (
    COVERAGE,
    MEASURED_AMONG,
    MEASURED_COVERAGE,
    MEASURED_SESSIONS,
)
from bodymetry.estimation.view_selection import left_out_views
from bodymetry.fileio import atomic_path, write_text_atomic
from bodymetry.review import plots
from bodymetry.review.accuracy import SESSION_ACCURACY
from bodymetry.review.accuracy import SOURCE as ACCURACY_SOURCE
from bodymetry.review.mcap_recording import overlay_silhouettes
from bodymetry.review.person_colors import person_hex, person_overlap_rgb
from bodymetry.review.run_data import FrameView, RunData, frame_views, load_run, run_frame_views

log = logging.getLogger(__name__)
#: The stated interval's coverage as the report writes it ("95").
_COVERAGE_PERCENT = round(100 * COVERAGE)

#: Frames shown with silhouette overlays (evenly spaced, plus the worst fit).
OVERLAY_FRAMES = 3
#: Width of one overlay tile in the report (pixels).
OVERLAY_WIDTH = 320
#: Characters per line of the PDF summary page's text (9 pt across an A4 landscape page).
SUMMARY_LINE_CHARS = 150


@dataclass(frozen=True)
class ReportFiles:
    """Paths written by :func:`build_report` (``pdf`` is None without ``--pdf``)."""

    html: Path
    csv: Path
    pdf: Path | None = None


@dataclass(frozen=True)
class OverlayRow:
    """Silhouette overlays of one frame in every camera.

    Attributes
    ----------
    frame : int
    caption : str
    images : list of (H, W, 3) uint8 RGB, one per camera (downscaled)
    cameras : list of str
    person : int
        Whose fit the overlays show (drawn in their colour).
    """

    frame: int
    caption: str
    images: list[np.ndarray] = field(default_factory=list)
    cameras: list[str] = field(default_factory=list)
    person: int = 0


def select_overlay_frames(run: RunData, n: int = OVERLAY_FRAMES) -> list[int]:
    """Frames to show with overlays: ``n`` evenly spaced fitted frames and the worst fit."""
    ok = run.fitted_frames
    if not ok:
        return []
    idx = np.unique(np.linspace(0, len(ok) - 1, min(n, len(ok))).round().astype(int))
    frames = [ok[i].frame for i in idx]
    worst = min(ok, key=lambda r: np.nan_to_num(r.mean_iou, nan=np.inf))
    if worst.frame not in frames:
        frames.append(worst.frame)
    return sorted(frames)


def _size_text(camera: Camera, working: Camera) -> str:
    """``"1080×1920"``, or ``"1080×1920 (working 360×640)"`` when the run worked below it."""
    text = f"{camera.size[0]}×{camera.size[1]}"
    if working.size != camera.size:
        text += f" (working {working.size[0]}×{working.size[1]})"
    return text


def overlay_row(run: RunData, view: FrameView) -> OverlayRow | None:
    """The overlay tiles of a frame (None when it has neither images nor silhouettes)."""
    if not view.images and not view.observed:
        return None
    tiles, names = [], []
    for c, cam in enumerate(run.cameras or ()):
        image = view.images[c] if c < len(view.images) else None
        observed = view.observed[c] if c < len(view.observed) else None
        model = view.model[c] if view.model is not None else None
        if image is None and observed is None:
            continue
        bgr = overlay_silhouettes(image, observed, model, view.person)
        h, w = bgr.shape[:2]
        scale = OVERLAY_WIDTH / w
        small = cv2.resize(bgr, (OVERLAY_WIDTH, round(h * scale)), interpolation=cv2.INTER_AREA)
        iou = view.record.silhouette_iou.get(cam.name, float("nan"))
        text = cam.name + (f"  IoU {iou:.2f}" if np.isfinite(iou) else "")
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        box = small[2 : 10 + th, 2 : 10 + tw]
        box[:] = (0.35 * box).astype(np.uint8)  # a dark box keeps the label readable
        cv2.putText(
            small,
            text,
            (6, 6 + th),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
        tiles.append(small[:, :, ::-1].copy())
        names.append(cam.name)
    if not tiles:
        return None
    iou = view.record.mean_iou
    caption = f"frame {view.frame} (t = {run.time_seconds(view.frame):.2f} s)"
    if np.isfinite(iou):
        caption += f", mean IoU {iou:.2f}"
    return OverlayRow(view.frame, caption, tiles, names, view.person)


def compute_overlays(
    run: RunData, body: BodyModel, frames: Sequence[int] | None = None
) -> list[OverlayRow]:
    """Overlay rows: recorded silhouettes over the session's images.

    ``frames`` of the run's first person; None: each person's own
    :func:`select_overlay_frames` (the camera images of a frame decoded once).
    """
    if frames is not None:
        views = ([v] for v in frame_views(run, body, frames=frames))
        wanted = {run.person_id: set(frames)}
    else:
        wanted = {p.person_id: set(select_overlay_frames(p)) for p in run.person_runs()}
        views = run_frame_views(run, body, frames=sorted(set().union(*wanted.values())))
    rows = []
    for frame_views_ in views:
        for view in frame_views_:
            if view.frame in wanted.get(view.person, ()):
                row = overlay_row(run.for_person(view.person), view)
                if row is not None:
                    rows.append(row)
    return rows


# --- tables -------------------------------------------------------------------------------
def _stat(summary: dict[str, dict[str, Stat]], stage: str, key: str) -> tuple[float, float] | None:
    s = summary.get(stage, {}).get(key)
    if s is None or s.mean is None:
        return None
    return s.mean, s.std or 0.0


def figure3_columns(run: RunData) -> list[dict[str, str]]:
    """The stage columns of the Figure 3 table: ``key`` (of :func:`figure3_rows`),
    ``title`` and ``spread`` (what the ± is): Discriminative, Disc. + Generative,
    then the session's one shape when the run has it, then GT + Generative after
    ``bodymetry evaluate``."""
    cols = [
        {"key": "discriminative", "title": "Discriminative", "spread": "Std"},
        {"key": "generative", "title": "Disc. + Generative", "spread": "Std"},
    ]
    if "session" in run.results.summary:
        cols.append({"key": "session", "title": "Session (one shape)", "spread": "S.e."})
    if run.evaluation is not None:
        cols.append({"key": GT_STAGE, "title": "GT + Generative", "spread": "Std"})
    return cols


def figure3_rows(run: RunData) -> list[dict[str, Any]]:
    """The paper's Figure 3 rows: Actual, Discriminative, Disc. + Generative, Session,
    GT + Generative.

    Each row: ``key``, ``label``, ``actual`` (float or None) and per stage of
    :data:`STAGES` and :data:`GT_STAGE`: (mean, std), the session's (value,
    standard error), or None.
    """
    summary = run.results.summary
    truth = run.ground_truth
    table = run.evaluation.table if run.evaluation is not None else {}
    rows = []
    for key in CORE_MEASUREMENTS:
        gt_gen = table.get(key, {}).get(GT_STAGE)
        rows.append(
            {
                "key": key,
                "label": plots.label(key),
                "actual": truth.get(key) if truth else None,
                **{stage: _stat(summary, stage, key) for stage in STAGES},
                GT_STAGE: (gt_gen.mean, gt_gen.std) if gt_gen is not None else None,
            }
        )
    return rows


def measurement_rows(run: RunData) -> list[dict[str, Any]]:
    """Every measurement: actual, mean ± std per frame stage, the session's value ±
    standard error, n, and the errors of the generative mean and the session value."""
    summary = run.results.summary
    truth = run.ground_truth
    rows = []
    for key in MEASUREMENTS:
        disc = _stat(summary, "discriminative", key)
        gen = _stat(summary, "generative", key)
        if disc is None and gen is None:
            continue
        actual = truth.get(key) if truth else None
        error = None
        if actual is not None and gen is not None and actual:
            error = 100.0 * (gen[0] - actual) / actual
        session = _stat(summary, "session", key)
        session_error = None
        if actual is not None and session is not None and actual:
            session_error = 100.0 * (session[0] - actual) / actual
        rows.append(
            {
                "key": key,
                "label": plots.label(key),
                "actual": actual,
                "discriminative": disc,
                "generative": gen,
                "n": summary.get("generative", {}).get(key, Stat(None, None, 0)).n,
                "error_pct": error,
                "session": session,
                "session_error_pct": session_error,
            }
        )
    return rows


def csv_columns(run: RunData) -> list[str]:
    """Columns of ``measurements.csv``."""
    keys = _measurement_keys(run)
    cols = ["person", "frame", "time_s", "status", "flags"]
    cols += [f"{stage}_{key}" for stage in STAGES for key in keys]
    cols += [f"iou_{name}" for name in run.camera_names]
    cols += ["iou_mean", "session_iou_mean", "final_log_likelihood", "seconds_total"]
    return cols


def _measurement_keys(run: RunData) -> list[str]:
    # Every person is measured with the same model: the first fitted frame of any says.
    fitted = [r for p in run.person_runs() for r in p.fitted_frames]
    present = (
        set(fitted[0].estimates["generative"].biometrics) if fitted else set(CORE_MEASUREMENTS)
    )
    return [k for k in MEASUREMENTS if k in present]


def write_measurements_csv(run: RunData, path: str | Path) -> Path:
    """``measurements.csv``: one row per person and kept frame (failed frames with empty
    values), person by person; the ``person`` column is the person's id (0 for a run
    of one subject)."""
    path = Path(path)
    keys = _measurement_keys(run)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(csv_columns(run))
    records = [(p.person_id, r) for p in run.person_runs() for r in p.frames]
    for person, r in records:
        flags = ";".join(f"{cam}:{flag}" for cam, fl in sorted(r.flags.items()) for flag in fl)
        row: list[Any] = [person, r.frame, f"{run.time_seconds(r.frame):.4f}", r.status, flags]
        for stage in STAGES:
            est = r.estimates.get(stage)
            values = est.biometrics if est is not None else {}
            row += [_fmt_csv(values.get(k)) for k in keys]
        row += [_fmt_csv(r.silhouette_iou.get(name)) for name in run.camera_names]
        lls = r.annealing.layer_log_likelihood if r.annealing is not None else ()
        session = r.estimates.get("session")
        row += [
            _fmt_csv(r.mean_iou),
            _fmt_csv(session.mean_iou if session is not None else None),
            _fmt_csv(lls[-1] if lls else None),
            _fmt_csv(r.seconds.get("total")),
        ]
        writer.writerow(row)
    write_text_atomic(path, buf.getvalue())
    return path


def _fmt_csv(value: Any) -> str:
    # Missing and non-finite values (NaN is how the records keep a JSON null) are empty cells.
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def calibration_summary(run: RunData) -> dict[str, Any]:
    """Calibration quality for the report: source, overall RMS, per-camera figures."""
    out: dict[str, Any] = {
        "source": run.calibration_source,
        "solved": False,
        "rms_px": None,
        "frames_used": None,
        "cameras": [],
    }
    report = run.calibration_report
    quality = run.calibration_quality or {}
    per_camera = {}
    if report is not None:
        out["solved"] = True
        out["rms_px"] = report.rms_px
        out["frames_used"] = report.frames_used
        out["outliers_rejected"] = report.outliers_rejected
        per_camera = report.cameras
    elif quality:
        out["rms_px"] = quality.get("overall", {}).get("rms_px")
        per_camera = {k: v for k, v in quality.items() if k != "overall" and isinstance(v, dict)}
    # The calibration's own cameras (its pixels), with the working size beside
    # the image size when the run worked below it.
    for cam, work in zip(run.calibrated_cameras or (), run.cameras or (), strict=True):
        fig = per_camera.get(cam.name, {})
        out["cameras"].append(
            {
                "name": cam.name,
                "size": _size_text(cam, work),
                "fx": cam.K[0, 0],
                "fy": cam.K[1, 1],
                "cx": cam.K[0, 2],
                "cy": cam.K[1, 2],
                "centre": cam.center,
                "distance_m": float(np.linalg.norm(cam.center[:2])),
                "rms_px": fig.get("rms_px"),
                "boards": fig.get("boards_detected"),
                "corners": fig.get("corners_used"),
            }
        )
    return out


# --- report ------------------------------------------------------------------------------
def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _jpeg_uri(rgb: np.ndarray, quality: int = 85) -> str:
    ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover
        raise RuntimeError("JPEG encoding failed")
    return _data_uri(buf.tobytes(), "image/jpeg")


def body_renders(run: RunData, body: BodyModel) -> dict[str, dict[str, np.ndarray]]:
    """Front and side renders of the fitted canonical body (the session's one shape
    when the run has it, else the mean ν over fitted frames), and of the true body
    when the ground truth has its shape."""
    ok = run.ok_frames or run.fitted_frames
    renders: dict[str, dict[str, np.ndarray]] = {}
    shape = run.results.session_shape
    if shape is not None and shape.ok and len(shape.nu) == body.n_shape:
        renders["fitted (session shape)"] = plots.body_views(body, np.asarray(shape.nu, float))
    elif ok:
        nu = np.mean([r.estimates["generative"].state.nu[0] for r in ok], axis=0)
        if len(nu) == body.n_shape:
            renders["fitted (mean shape)"] = plots.body_views(body, nu)
    truth_nu = run.ground_truth.nu if run.ground_truth else None
    if truth_nu is not None and len(truth_nu) == body.n_shape:
        renders["actual (ground truth)"] = plots.body_views(body, np.asarray(truth_nu, float))
    return renders


@dataclass
class _Content:
    """Everything the HTML and PDF reports show, computed once."""

    context: dict[str, Any]
    figures: dict[str, Any]
    overlays: list[OverlayRow]
    renders: dict[str, dict[str, np.ndarray]]
    #: Per person (one for a run of one person): the person's own context, figures,
    #: overlays and renders; ``context`` above holds the run's and the first person's.
    persons: list[_Content] = field(default_factory=list)


def prior_pull_text(shape: SessionShape | None) -> str:
    """How far the shape prior moved the core session values, in words
    (``"height -0.4 mm, arm span +0.2 mm, weight +0.05 kg"``; ``""`` when the stage
    was not accepted or was recorded before the pull was)."""
    if shape is None or not shape.ok:
        return ""
    parts = []
    for key in CORE_MEASUREMENTS:
        pull, unit = shape.prior_pull.get(key, math.nan), MEASUREMENTS[key]
        if math.isfinite(pull):
            digits = 2 if unit == "kg" else 1
            parts.append(f"{plots.LABELS[key].lower()} {pull:+.{digits}f} {unit}")
    return ", ".join(parts)


def session_unavailable(shape: SessionShape | None) -> str:
    """Why a run has no session estimate: ``""`` when its session stage was accepted,
    else the stage's status (``"rejected: ..."``, ``"skipped: ..."``, ``"failed: ..."``)
    or ``"the session stage was not run"``."""
    if shape is None:
        return "the session stage was not run"
    return "" if shape.ok else shape.status


def headline_cards(run: RunData) -> list[dict[str, Any]]:
    """The Subject section's cards: one per core measurement that has a per-frame mean.

    The headline value is the session estimate ± its standard error when the
    session stage was accepted, with the per-frame mean ± std below it; without
    the session stage, the per-frame mean ± std and why the session estimate is
    unavailable.

    Returns
    -------
    list of dict
        Each: ``key``, ``label``, ``unit``; ``mean``, ``std`` and ``n`` of the
        disc. + generative stage over the frames; ``session`` as (value,
        standard error) or None; ``unavailable`` (why ``session`` is None, ``""``
        when it is not); ``actual`` (float or None), ``accuracy`` (the
        measured accuracy of the session values, or None) and ``interval`` (the
        session value's 95 % interval, :mod:`bodymetry.estimation.uncertainty`, or
        None where none is stated), ``no_interval`` (the outline check's finding,
        loose clothing or hair, where that is why none is stated; ``""`` otherwise).
    """
    summary = run.results.summary
    truth = run.ground_truth
    why = session_unavailable(run.results.session_shape)
    # The studio's figures for bodies like this one where it scored enough of them.
    like = run.results.studio_accuracy
    intervals = run.results.stated_intervals
    withheld = run.results.intervals_withheld
    cards = []
    for key in CORE_MEASUREMENTS:
        gen = _stat(summary, "generative", key)
        if gen is None:
            continue
        session = _stat(summary, "session", key)
        cards.append(
            {
                "key": key,
                "label": plots.LABELS[key],
                "unit": MEASUREMENTS[key],
                "mean": gen[0],
                "std": gen[1],
                "n": summary["generative"][key].n,
                "session": session,
                "unavailable": "" if session else why or "no session value for this measurement",
                "actual": truth.get(key) if truth else None,
                "accuracy": like.get(key) or SESSION_ACCURACY.get(key),
                "interval": intervals.get(key) if session else None,
                # The outline check's finding that leaves it without one.
                "no_interval": withheld.get(key, "") if session else "",
            }
        )
    return cards


def per_frame_rows(run: RunData) -> list[dict[str, Any]]:
    """The Frames table: per kept frame its ``frame``, ``status``, ``flags`` (text),
    the core measurements' ``values`` of its final estimate (None when missing),
    ``iou`` (mean, None when not finite) and ``seconds``."""
    rows = []
    for r in run.frames:
        gen = r.estimate()
        iou = r.mean_iou
        rows.append(
            {
                "frame": r.frame,
                "status": r.status,
                "flags": "; ".join(
                    [f"{cam}: {', '.join(fl)}" for cam, fl in sorted(r.flags.items()) if fl]
                    + ([f"{r.persons} people in view"] if (r.persons or 0) > 1 else [])
                ),
                "values": [
                    None if gen is None else gen.biometrics.get(k) for k in CORE_MEASUREMENTS
                ],
                "iou": iou if np.isfinite(iou) else None,
                "seconds": r.seconds.get("total"),
            }
        )
    return rows


def left_out_rows(run: RunData) -> list[dict[str, str]]:
    """The "Views left out" list: per camera whose view capture flagged ``unreliable``,
    ``occluded`` or ``mixed`` in some kept frames (left out of those frames' fits), its
    ``camera``, ``reason`` (the flag), ``frames`` (how many and which) and
    ``agreement`` (the range of capture's agreement, "" when none was recorded);
    empty when no view was left out."""
    return [
        {
            "camera": view.camera,
            "reason": view.reason,
            "frames": f"{len(view.frames)} of {view.kept} kept frames "
            f"({', '.join(map(str, view.frames))})",
            "agreement": view.agreement_text,
        }
        for view in left_out_views(run.frames, run.camera_names)
    ]


def _clothing_share(shape: SessionShape | None) -> float | None:
    """The share of the session stage's silhouette pixels capture called clothing,
    hair or shoes (:attr:`SessionShape.clothing_share`); None where it told nowhere."""
    if shape is None or not math.isfinite(shape.clothing_share):
        return None
    return shape.clothing_share


def _session_facts(run: RunData) -> dict[str, Any]:
    """The session's folder, cameras, image sizes, frame rate and step."""
    session = run.results.session
    return {
        "path": session.path,
        "cameras": ", ".join(run.camera_names),
        "n_cameras": len(run.camera_names),
        "fps": session.fps,
        "frame_step": session.frame_step,
        # Every distinct camera size, in camera order (rigs may mix camera models).
        "image_size": (
            ", ".join(
                dict.fromkeys(
                    _size_text(c, w)
                    for c, w in zip(run.calibrated_cameras or (), run.cameras or (), strict=True)
                )
            )
            or "?"
        ),
    }


def _frame_counts(run: RunData) -> dict[str, int]:
    """Kept, ok (in the measurements), fitted and failed frames."""
    frames = run.frames
    return {
        "kept": len(frames),
        "ok": len(run.ok_frames),
        "fitted": len(run.fitted_frames),
        "failed": len(frames) - len(run.ok_frames),
    }


def _recorded_settings(results: RunResults) -> dict[str, Any]:
    """The report's ``gate`` (the quality gate) and ``config`` (quality preset,
    seed, density, particles, layers, models) from the run's recorded settings."""
    # The settings as the run recorded them: a run made with other settings
    # than today's defaults reports its own.
    config = results.config
    fit = config.fit
    return {
        "gate": results.quality_gate or SessionGate(fit.min_iou, fit.min_iou, None),
        "config": {
            "quality": config.quality,
            "seed": fit.seed,
            "density": fit.density,
            "particles": fit.annealing.n_particles,
            "layers": fit.annealing.n_layers,
            "models": results.models,
        },
    }


def _figures(
    run: RunData, body: BodyModel | None
) -> tuple[dict[str, Any], dict[str, dict[str, np.ndarray]]]:
    """The report's matplotlib figures (per-frame measurements, fit quality, body)
    and the body renders they were made from."""
    figures = {}
    if run.fitted_frames:
        figures["measurements"] = plots.measurement_plots(run)
        figures["fit"] = plots.fit_quality_plots(run)
    renders = body_renders(run, body) if body is not None else {}
    if renders:
        figures["body"] = plots.body_figure(renders)
    return figures, renders


def _person_content(
    run: RunData, body: BodyModel | None, overlays: list[OverlayRow], several: bool
) -> _Content:
    """One person's part of the report (``run``: the person's view of the run)."""
    results = run.results
    truth = run.ground_truth
    ident = run.person_id
    figures, renders = _figures(run, body)
    person = results.person
    context = {
        "id": ident,
        "frames": _frame_counts(run),
        "gate": _recorded_settings(results)["gate"],
        "failed": [r for r in run.frames if not r.ok],
        "left_out": left_out_rows(run),
        "truth": truth,
        "truth_source": truth.source if truth else None,
        "headline": headline_cards(run),
        "session_unavailable": session_unavailable(results.session_shape),
        "figure3": figure3_rows(run),
        "figure3_columns": figure3_columns(run),
        "session_shape": results.session_shape,
        "prior_pull": prior_pull_text(results.session_shape),
        "outline": results.outline,
        # The outline check runs with its defaults (no run setting changes them).
        "legs_hidden_mm": OutlineConfig().legs_hidden_mm,
        "clothing_share": _clothing_share(results.session_shape),
        "contrast": results.outline_contrast,
        "low_contrast": LOW_CONTRAST,
        "among_others": results.among_others,
        # A run of several persons shows its own warnings once, above the persons.
        "warnings": list(person.warnings if several else results.warnings),
        "caveats": list(results.caveats),
        "measurements": measurement_rows(run),
        "per_frame": per_frame_rows(run),
        "overlay_note": _overlay_note(run, overlays),
        "sfx": f"-p{ident}" if several else "",
        "who": f" (person {ident})" if several else "",
        "summary_title": f"Person {ident}" if several else "Subject",
        "person_color": person_hex(ident) if several else "",
        "model_color": person_hex(ident),
        "overlap_color": "#{:02x}{:02x}{:02x}".format(*person_overlap_rgb(ident)),
        "meshes_dir": f"{run.layout.meshes_dir.relative_to(run.folder).as_posix()}/",
    }
    return _Content(context, figures, overlays, renders)


def _content(run: RunData, body: BodyModel | None, overlays: list[OverlayRow]) -> _Content:
    """The report's template context, figures and renders (``body`` None: no renders):
    the run's, and each person's (:attr:`_Content.persons`; the first person's also
    at the top, as a run of one person shows them)."""
    persons = [
        _person_content(p, body, [o for o in overlays if o.person == p.person_id], run.several)
        for p in run.person_runs()
    ]
    first = persons[0]
    results = run.results
    context = {
        "title": f"bodymetry report: {run.name}",
        "name": run.name,
        "generated": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "version": __version__,
        "session": _session_facts(run),
        **_recorded_settings(results),
        "timing": results.timing_seconds,
        "accuracy_source": ACCURACY_SOURCE,
        "like_min": MIN_LIKE,
        "interval_coverage": _COVERAGE_PERCENT,
        "interval_measured": ", ".join(
            f"{round(100 * share)} % of {plots.LABELS[key].lower()}s"
            for key, share in MEASURED_COVERAGE.items()
        ),
        "interval_sessions": MEASURED_SESSIONS,
        "interval_among": ", ".join(
            f"{inside} of {stated} {plots.LABELS[key].lower()}s"
            for key, (inside, stated) in MEASURED_AMONG.items()
        ),
        "like_height": round(100 * LIKE_HEIGHT),
        "like_weight": round(100 * LIKE_WEIGHT),
        "validated_range": VALIDATED.describe(),
        "has_evaluation": run.evaluation is not None,
        "core_labels": [plots.label(k) for k in CORE_MEASUREMENTS],
        "calibration": calibration_summary(run),
        "run_folder": str(run.folder.resolve()),
        **first.context,
        "several": run.several,
        "warnings": list(results.warnings) if run.several else first.context["warnings"],
    }
    return _Content(context, first.figures, first.overlays, first.renders, persons)


def _overlay_note(run: RunData, overlays: list[OverlayRow]) -> str:
    """Why the report has no overlays ("" when it has some)."""
    if overlays:
        return ""
    if not run.fitted_frames:
        return "No fitted frame to show."
    if not run.cameras:
        return "Overlays need the run's cameras (calibration.yaml), which were not found."
    if run.session_folder is None:
        return (
            "Overlays need the recorded silhouettes (frames/*.npz) or the session's videos, "
            "which were not found."
        )
    return "No recorded silhouettes or camera images for the frames shown."


def template_environment() -> jinja2.Environment:
    """The Jinja2 environment of the review's HTML pages (``review/templates/``).

    Autoescaped, strict about undefined names, with the ``num`` (:func:`_num`),
    ``breakable`` (:func:`breakable`) and ``ordinal`` (:func:`ordinal`) filters;
    shared by ``report.html`` and the cohort's ``cohort.html``.
    """
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("bodymetry.review", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["num"] = _num
    env.filters["breakable"] = breakable
    env.filters["ordinal"] = ordinal
    return env


def breakable(text: Any) -> markupsafe.Markup:
    """``text`` (a file path, a model key) escaped for HTML, with a line-break
    opportunity (``<wbr>``) after every ``/`` and ``_`` and none inside the
    pieces between them (a piece with a hyphen is kept on one line): a long
    path wraps at its separators instead of overflowing or breaking a name."""
    pieces = [piece for piece in re.split(r"(?<=[/_])", str(text)) if piece]
    html = [
        f'<span class="nw">{markupsafe.escape(piece)}</span>'
        if "-" in piece
        else str(markupsafe.escape(piece))
        for piece in pieces
    ]
    return markupsafe.Markup("<wbr>".join(html))


def ordinal(n: Any) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ``11th``, ``22nd``...: ``str(n)`` for a non-integer."""
    try:
        k = int(n)
    except (TypeError, ValueError):
        return str(n)
    if k != n:
        return str(n)
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def figure_uri(fig: Any) -> str:
    """A matplotlib figure as a PNG ``data:`` URI (the pages embed every image)."""
    return _data_uri(plots.png_bytes(fig), "image/png")


def render_html(content: _Content) -> str:
    """The report as one self-contained HTML page."""
    env = template_environment()
    persons = []
    for person in content.persons or [content]:
        persons.append(
            {
                **person.context,
                "images": {name: figure_uri(fig) for name, fig in person.figures.items()},
                "overlays": [
                    {
                        "caption": row.caption,
                        "tiles": [_jpeg_uri(t) for t in row.images],
                        "cameras": row.cameras,
                    }
                    for row in person.overlays
                ],
            }
        )
    template = env.get_template("report.html.j2")
    return template.render(
        **content.context,
        images=persons[0]["images"],
        overlays=persons[0]["overlays"],
        persons=persons,
    )


def _num(value: Any, digits: int = 1) -> str:
    """A number for the report (``–`` when missing)."""
    if value is None:
        return "–"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not np.isfinite(v):
        return "–"
    return f"{v:,.{digits}f}".replace(",", " ")


def build_report(
    run: RunData | str | Path,
    body: BodyModel | None = None,
    *,
    overlays: Iterable[OverlayRow] | None = None,
    pdf: bool = False,
) -> ReportFiles:
    """Write ``report.html`` and ``measurements.csv`` (and ``report.pdf``) into the run folder.

    Parameters
    ----------
    run : RunData or path
        The run (a folder is read with :func:`review.run_data.load_run`).
    body : BodyModel, optional
        For the body renders and overlays (default: the shared model).
    overlays : iterable of OverlayRow, optional
        Precomputed overlays (the review stage collects them while it writes the
        recordings); computed from the session when not given.
    pdf : bool
        Also write ``report.pdf``.
    """
    if not isinstance(run, RunData):
        run = load_run(run)
    if body is None:
        body = shared_body_model()
    rows = compute_overlays(run, body) if overlays is None else list(overlays)
    content = _content(run, body, rows)
    csv_path = write_measurements_csv(run, run.folder / MEASUREMENTS_CSV)
    html_path = run.folder / REPORT_HTML
    write_text_atomic(html_path, render_html(content))
    log.info("wrote %s and %s", html_path, csv_path)
    pdf_path = None
    if pdf:
        pdf_path = write_pdf(content, run.folder / REPORT_PDF)
        log.info("wrote %s", pdf_path)
    return ReportFiles(html=html_path, csv=csv_path, pdf=pdf_path)


# --- PDF ----------------------------------------------------------------------------------
def write_pdf(content: _Content, path: str | Path) -> Path:
    """The report as a PDF (A4 landscape-ish pages composed with matplotlib)."""
    # Local: the PDF backend takes about a second to import and only --pdf needs it.
    from matplotlib.backends.backend_pdf import PdfPages

    path = Path(path)
    ctx = content.context
    metadata = {"Title": ctx["title"], "Creator": f"bodymetry {ctx['version']}"}
    with atomic_path(path) as tmp, PdfPages(tmp, metadata=metadata) as pdf:
        # One set of pages per person (a run of one person: today's pages).
        for person in content.persons or [content]:
            mine = _Content(
                {**ctx, **person.context},
                person.figures,
                person.overlays,
                person.renders,
            )
            if ctx["several"]:
                mine.context["title"] = f"{ctx['title']}, person {person.context['id']}"
            _person_pages(pdf, mine)
    return path


def _person_pages(pdf: Any, content: _Content) -> None:
    """A person's pages: summary, per-frame plots, overlays, body and calibration."""
    pdf.savefig(_summary_page(content.context))
    for name in ("measurements", "fit"):
        if name in content.figures:
            pdf.savefig(content.figures[name])
    if content.overlays:
        fig = plots.image_grid(
            [(f"frame {row.frame}", row.images) for row in content.overlays],
            content.overlays[0].cameras,
        )
        person = content.overlays[0].person
        colours = "dark red, both orange" if person == 0 else "in the person's colour"
        fig.suptitle(
            f"Silhouette overlays: observed only light blue, model only {colours}",
            fontsize=10,
        )
        pdf.savefig(fig)
    pdf.savefig(_body_and_calibration_page(content))


def _summary_page(ctx: dict[str, Any]) -> Any:
    """The PDF's first page: the run in a few lines, the Figure 3 table and every
    measurement."""
    fig = plots.figure(11.69, 8.27)
    fig.set_layout_engine("none")
    fig.text(0.04, 0.95, ctx["title"], fontsize=16, weight="bold")
    for i, line in enumerate(_summary_lines(ctx)):
        fig.text(0.04, 0.90 - 0.022 * i, line, fontsize=9)
    _figure3_table(fig, ctx)
    _measurements_table(fig, ctx)
    return fig


def _headline_lines(ctx: dict[str, Any]) -> list[str]:
    """The headline cards in words: the session values ± standard error, then the
    per-frame means ± std (or why there is no session value)."""
    cards = ctx["headline"]
    if not cards:
        return []
    lines = []
    if any(h["session"] for h in cards):
        lines.append(
            "Session estimate ± standard error: "
            + ", ".join(
                f"{h['label'].lower()} {_pm(h['session'])} {h['unit']}"
                for h in cards
                if h["session"]
            )
            + "."
        )
    lines.append(
        "Per-frame mean ± std (disc. + generative): "
        + ", ".join(f"{h['label'].lower()} {_pm((h['mean'], h['std']))} {h['unit']}" for h in cards)
        + "."
    )
    stated = [h for h in cards if h["interval"]]
    if stated:
        lines.append(
            f"{_COVERAGE_PERCENT} % interval (standard error and the studio's error on "
            "like bodies combined): "
            + ", ".join(
                f"{h['label'].lower()} {_num(h['interval'].low)} to {_num(h['interval'].high)} "
                f"{h['unit']}"
                for h in stated
            )
            + "."
        )
    missing = [h for h in cards if not h["session"]]
    if missing:
        lines.append(f"Session estimate unavailable ({missing[0]['unavailable']}).")
    return lines


def _summary_lines(ctx: dict[str, Any]) -> list[str]:
    """The summary page's lines: session, frames and settings, the headline
    values, calibration, provenance and the measured accuracy (long lines wrapped)."""
    s = ctx["session"]
    f = ctx["frames"]
    c = ctx["config"]
    lines = [
        f"Session {s['path']}: {s['n_cameras']} cameras ({s['image_size']}), {s['fps']} fps, "
        f"every {ordinal(s['frame_step'])} frame kept.",
        f"{f['ok']} of {f['kept']} kept frames in the measurements ({f['failed']} left out); "
        f"quality {c['quality']}, {c['particles']} particles x {c['layers']} layers, "
        f"seed {c['seed']}, density {c['density']} kg/m³.",
        *_left_out_lines(ctx),
        *_headline_lines(ctx),
        f"Calibration: {ctx['calibration']['source']}.",
        f"Generated {ctx['generated']} by bodymetry {ctx['version']}.",
    ]
    measured = [h for h in ctx["headline"] if h["session"] and h["accuracy"]]
    if measured:
        lines.append(
            "Measured accuracy of the session values (RMS / worst error): "
            + ", ".join(
                f"{h['label'].lower()} {_num(h['accuracy'].rms)} / {_num(h['accuracy'].worst)} "
                f"{h['unit']} ({h['accuracy'].sessions} {h['accuracy'].scope})"
                for h in measured
            )
            + "."
        )
        lines.append(
            f"Figures of sessions of bodies like this one: the studio's sessions whose subject's "
            f"true height lies within {ctx['like_height']} % and weight within "
            f"{ctx['like_weight']} % of the measured ones (python -m benchmarks studio_accuracy); "
            f"otherwise {ctx['accuracy_source']}."
        )
        lines.append(f"The body model was validated on {ctx['validated_range']}.")
    return [part for line in lines for part in textwrap.wrap(line, SUMMARY_LINE_CHARS)]


def _left_out_lines(ctx: dict[str, Any]) -> list[str]:
    """The views left out (unreliable, occluded or mixed), in one line (none when no view was)."""
    if not ctx["left_out"]:
        return []
    views = "; ".join(
        f"{v['camera']} ({v['reason']}) in {v['frames']}"
        + (f", agreement {v['agreement']}" if v["agreement"] else "")
        for v in ctx["left_out"]
    )
    return [f"Views left out of the fit (capture's silhouette checks): {views}."]


def _figure3_table(fig: Any, ctx: dict[str, Any]) -> None:
    """The Figure 3 table in the upper half of the summary page."""
    ax = fig.add_axes((0.04, 0.49, 0.92, 0.2))
    ax.set_axis_off()
    ax.set_title(
        "Basic biometric measurements (paper, Figure 3): mean / std over frames", fontsize=10
    )
    header = ["Biometric", "Actual"]
    for col in ctx["figure3_columns"]:
        header += [col["title"], col["spread"].lower()]
    cells = []
    for row in ctx["figure3"]:
        line = [row["label"], _num(row["actual"])]
        for col in (c["key"] for c in ctx["figure3_columns"]):
            value = row[col]
            line += [_num(value[0]), _num(value[1])] if value else ["–", "–"]
        cells.append(line)
    table = ax.table(cellText=cells, colLabels=header, loc="upper center", cellLoc="right")
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.scale(1, 1.4)


def _measurements_table(fig: Any, ctx: dict[str, Any]) -> None:
    """Every measurement (per stage, the session's value and the errors) in the
    lower half of the summary page."""
    ax2 = fig.add_axes((0.04, 0.04, 0.92, 0.42))
    ax2.set_axis_off()
    ax2.set_title("All measurements (mean ± std over fitted frames)", fontsize=10)
    has_session = ctx["session_shape"] is not None and ctx["session_shape"].ok
    rows = [
        [
            r["label"],
            _num(r["actual"]),
            _pm(r["discriminative"]),
            _pm(r["generative"]),
            *([_pm(r["session"])] if has_session else []),
            str(r["n"]),
            "–" if r["error_pct"] is None else f"{r['error_pct']:+.1f} %",
            *(
                ["–" if r["session_error_pct"] is None else f"{r['session_error_pct']:+.1f} %"]
                if has_session
                else []
            ),
        ]
        for r in ctx["measurements"]
    ]
    if rows:
        t2 = ax2.table(
            cellText=rows,
            colLabels=[
                "Measurement",
                "Actual",
                "Discriminative",
                "Disc. + generative",
                *(["Session ± s.e."] if has_session else []),
                "n",
                "Error",
                *(["Session error"] if has_session else []),
            ],
            loc="upper center",
            cellLoc="right",
        )
        t2.auto_set_font_size(False)
        t2.set_fontsize(8)
        t2.scale(1, 1.25)


def _pm(value: tuple[float, float] | None) -> str:
    return "–" if value is None else f"{_num(value[0])} ± {_num(value[1])}"


def _body_and_calibration_page(content: _Content) -> Any:
    ctx = content.context
    fig = plots.figure(11.69, 8.27)
    fig.set_layout_engine("none")
    fig.text(0.04, 0.95, "Fitted body and calibration", fontsize=14, weight="bold")
    views = [
        (f"{who}: {view}", img) for who, v in content.renders.items() for view, img in v.items()
    ]
    # Box widths proportional to the image widths: every render at the same scale.
    total = sum(img.shape[1] for _, img in views) or 1
    x = 0.04
    for title, image in views:
        width = 0.92 * image.shape[1] / total
        ax = fig.add_axes((x, 0.40, width, 0.50))
        ax.imshow(image)
        ax.set_title(title, fontsize=8)
        ax.set_axis_off()
        x += width
    cal = ctx["calibration"]
    ax = fig.add_axes((0.04, 0.04, 0.92, 0.3))
    ax.set_axis_off()
    rms = cal.get("rms_px")
    ax.set_title(
        f"Calibration ({'solved from ChArUco clips' if cal['solved'] else 'given'}; "
        f"reprojection RMS {'–' if rms is None else f'{rms:.3f} px'})",
        fontsize=10,
    )
    if cal["cameras"]:
        rows = [
            [
                cam["name"],
                cam["size"],
                _num(cam["fx"]),
                _num(cam["fy"]),
                f"{_num(cam['cx'])}, {_num(cam['cy'])}",
                ", ".join(_num(x, 2) for x in cam["centre"]),
                "–" if cam["rms_px"] is None else f"{cam['rms_px']:.3f}",
            ]
            for cam in cal["cameras"]
        ]
        t = ax.table(
            cellText=rows,
            colLabels=["Camera", "Size", "fx", "fy", "cx, cy", "Centre (m)", "RMS px"],
            loc="upper center",
            cellLoc="right",
        )
        t.auto_set_font_size(False)
        t.set_fontsize(8)
        t.scale(1, 1.3)
    return fig
