"""The cohort of a study: one row per session and person, as ``cohort.csv``,
``cohort.parquet`` and ``cohort.html`` (docs/cohort.md).

A study folder (``bodymetry batch SESSIONS... --out STUDY``) holds one run folder
per session (``STUDY/<name>/``, as ``bodymetry process --out`` writes it) and
``STUDY/study.json`` (:class:`~bodymetry.estimation.records.StudyResults`): which
sessions are done, failed or pending, and why. The cohort reads the two: per
session the summary of its ``results.json`` (mean and standard deviation per
stage and measurement over the frames that passed the quality gate), how many
kept frames were used, the mean silhouette IoU and the run's warnings. A session
that measured several persons (``results.json`` format 3) is one row per person,
each with that person's numbers, caveats and warnings (after the run's).

A session without numbers (failed, pending, or a ``results.json`` that is
missing or unreadable) is a row too, with its status and reason; building the
cohort never fails on one session. ``cohort.parquet`` is written only when the
optional ``pyarrow`` is installed.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import logging
import math
import urllib.parse
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry import __version__
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS
from bodymetry.estimation.records import CORE_MEASUREMENTS, STAGES, Stat
from bodymetry.estimation.run_files import REPORT_HTML, RunLayout, RunResults, StudyResults
from bodymetry.estimation.uncertainty import StatedInterval
from bodymetry.fileio import atomic_path, write_text_atomic
from bodymetry.review import plots
from bodymetry.review.report import figure_uri, template_environment

__all__ = [
    "COHORT_CSV",
    "COHORT_HTML",
    "COHORT_PARQUET",
    "STUDY_JSON",
    "CohortFiles",
    "CohortRow",
    "cohort_columns",
    "cohort_rows",
    "measurement_keys",
    "write_cohort",
]

log = logging.getLogger(__name__)

#: What ``bodymetry batch`` writes into the study folder, read here.
STUDY_JSON = "study.json"
#: The cohort files written into the study folder.
COHORT_CSV = "cohort.csv"
COHORT_PARQUET = "cohort.parquet"
COHORT_HTML = "cohort.html"

#: Session statuses of ``study.json``.
DONE, FAILED, PENDING = "done", "failed", "pending"

#: Decimals per unit in the cohort table: millimetres to 0.1 mm, the rest to 0.01.
_DIGITS = {"mm": 1, "kg": 2, "l": 2}
_DEFAULT_DIGITS = 2
#: Decimals of the fraction of frames used and of the IoU.
_FRACTION_DIGITS = 3
#: The ends of a session value's 95 % interval, as cohort.csv names them.
INTERVAL_ENDS = ("low", "high")
_IOU_DIGITS = 4


@dataclass(frozen=True)
class CohortRow:
    """One person of one session of a study, as the cohort table shows it.

    Attributes
    ----------
    name : str
        The session's run folder inside the study folder.
    person : int or None
        The person's id in the session (0 for a session of one subject); None for
        a session without numbers.
    several : bool
        Whether the session measured several persons (the row is one of them).
    subject : str
        The session's name from ``results.json`` (the folder name without one).
    status : str
        ``"done"``, ``"failed"`` or ``"pending"`` (``study.json``); a ``done``
        session whose ``results.json`` is missing or unreadable is ``"failed"``.
    reason : str
        Why the session failed (one line), else empty.
    session_path : str
        The session folder that was processed.
    rig : str
        The discriminative models' key of its camera rig (empty when unknown).
    frames_kept : int or None
        Kept frames of the run (None without ``results.json``).
    frames_used : int or None
        Kept frames with status ``ok``: those in the summary.
    fraction_used : float or None
        ``frames_used / frames_kept`` (None without kept frames).
    stats : dict of str to dict of str to Stat
        Per stage (:data:`STAGES`) and measurement: mean, std and n over the
        used frames (``results.json`` summary; empty without one).
    iou_mean : float or None
        Mean silhouette IoU over the used frames (mean over cameras, then frames).
    intervals : dict of str to StatedInterval
        Per core measurement with one, the session value's 95 % interval
        (:mod:`bodymetry.estimation.uncertainty`).
    caveats : str
        The codes of the run's caveats (:mod:`bodymetry.estimation.caveats`),
        joined with ``"; "``: read its numbers with care.
    warnings : str
        The run's warnings, joined with ``"; "``.
    link : str or None
        ``<name>/report.html`` relative to the study folder, when that file exists
        (``#person-K``: the person's section, for a session of several).
    """

    name: str
    subject: str
    status: str
    person: int | None = None
    several: bool = False
    reason: str = ""
    session_path: str = ""
    rig: str = ""
    frames_kept: int | None = None
    frames_used: int | None = None
    fraction_used: float | None = None
    stats: Mapping[str, Mapping[str, Stat]] = field(default_factory=dict)
    iou_mean: float | None = None
    intervals: Mapping[str, StatedInterval] = field(default_factory=dict)
    caveats: str = ""
    warnings: str = ""
    link: str | None = None

    @property
    def label(self) -> str:
        """The row's name in tables and plots: the session, with the person when the
        session measured several."""
        return f"{self.name}, person {self.person}" if self.several else self.name

    @property
    def done(self) -> bool:
        """Whether the session has a readable ``results.json`` and is done."""
        return self.status == DONE

    def stat(self, stage: str, key: str) -> Stat | None:
        """A stage's statistics of a measurement (None when the run has none)."""
        s = self.stats.get(stage, {}).get(key)
        return s if s is not None and s.mean is not None else None


@dataclass(frozen=True)
class CohortFiles:
    """Paths written by :func:`write_cohort` (``parquet`` is None without pyarrow)."""

    csv: Path
    html: Path
    parquet: Path | None = None


# --- rows ---------------------------------------------------------------------------------
def cohort_rows(study_dir: Path, study: StudyResults) -> list[CohortRow]:
    """One row per session of ``study`` and person it measured, in the study's order
    (a session's persons in the order of its ``results.json``).

    Parameters
    ----------
    study_dir : Path
        The study folder: ``<name>/results.json`` per session.
    study : StudyResults
        ``study.json`` as read.

    Returns
    -------
    list of CohortRow
        Sessions without numbers (failed, pending, missing or unreadable
        ``results.json``) are rows with their status and reason; nothing here
        raises for one session.
    """
    study_dir = Path(study_dir)
    return [row for s in study.sessions for row in _rows(study_dir, s)]


def _rows(study_dir: Path, session: Any) -> list[CohortRow]:
    """A session's rows: one per person it measured, or one without numbers."""
    folder = study_dir / session.name
    layout = RunLayout(folder)
    report = folder / REPORT_HTML
    base = {
        "name": session.name,
        "subject": session.name,
        "status": session.status,
        "reason": _one_line(session.reason),
        "session_path": session.session_path,
        "rig": session.rig,
        # A relative link keeps the study folder movable as a whole.
        "link": f"{session.name}/{REPORT_HTML}" if report.is_file() else None,
    }
    if session.status != DONE and not layout.results.is_file():
        return [CohortRow(**base)]
    try:
        results = RunResults.read(layout.results)
    except InputError as exc:
        # A failed or pending session may have no usable results.json; only a
        # done one is expected to have it, so only there it changes the status.
        if session.status == DONE:
            log.warning("%s: %s", session.name, exc)
            base["status"] = FAILED
            base["reason"] = _one_line(f"results.json missing or unreadable: {exc}")
        return [CohortRow(**base)]
    base["subject"] = results.session.name or session.name
    return [_person_row(base, results.for_person(p.id), results.several) for p in results.persons]


def _person_row(base: dict[str, Any], results: RunResults, several: bool) -> CohortRow:
    """The row of one person (``results``: the run as that person sees it)."""
    ok = results.ok_frames
    kept = len(results.frames)
    ious = [r.mean_iou for r in ok if math.isfinite(r.mean_iou)]
    ident = results.person.id
    link = base["link"]
    return CohortRow(
        **{**base, "link": f"{link}#person-{ident}" if link and several else link},
        person=ident,
        several=several,
        frames_kept=kept,
        frames_used=len(ok),
        fraction_used=len(ok) / kept if kept else None,
        stats={stage: dict(stats) for stage, stats in results.summary.items()},
        # Plain mean of a non-empty list: numpy would warn on an empty one.
        iou_mean=float(sum(ious) / len(ious)) if ious else None,
        intervals=results.stated_intervals,
        caveats="; ".join(c.code for c in results.caveats),
        warnings="; ".join(_one_line(w) for w in results.warnings),
    )


def _one_line(text: str) -> str:
    # A reason or warning may span lines (tracebacks, OpenCV); a cell is one line.
    return " ".join(str(text).split())


def measurement_keys(rows: Sequence[CohortRow]) -> list[str]:
    """Every measurement of any row's summary: the core ones first, then the others in
    the order of docs/biometrics.md, then any unknown keys as found."""
    found: dict[str, None] = {}
    for row in rows:
        for stats in row.stats.values():
            found.update(dict.fromkeys(stats))
    known = [k for k in MEASUREMENTS if k in found and k not in CORE_MEASUREMENTS]
    others = [k for k in found if k not in MEASUREMENTS and k not in CORE_MEASUREMENTS]
    return [*CORE_MEASUREMENTS, *known, *others]


def cohort_columns(keys: Sequence[str]) -> list[str]:
    """Columns of ``cohort.csv`` for the measurements ``keys`` (docs/cohort.md)."""
    cols = [
        "session",
        "person",
        "subject",
        "status",
        "reason",
        "frames_kept",
        "frames_used",
        "fraction_used",
        "iou_mean",
    ]
    cols += [
        f"{stage}_{key}_{what}" for stage in STAGES for key in keys for what in ("mean", "std")
    ]
    cols += [f"session_{key}_{end}" for key in CORE_MEASUREMENTS for end in INTERVAL_ENDS]
    cols += ["caveats", "warnings", "report", "session_path", "rig"]
    return cols


def _digits(key: str) -> int:
    return _DIGITS.get(MEASUREMENTS.get(key, ""), _DEFAULT_DIGITS)


def _rounded(value: float | None, digits: int) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits)


def _record(row: CohortRow, keys: Sequence[str]) -> dict[str, Any]:
    """A row's cells by column, rounded as in the CSV; None for missing values."""
    out: dict[str, Any] = {
        "session": row.name,
        "person": row.person,
        "subject": row.subject,
        "status": row.status,
        "reason": row.reason,
        "frames_kept": row.frames_kept,
        "frames_used": row.frames_used,
        "fraction_used": _rounded(row.fraction_used, _FRACTION_DIGITS),
        "iou_mean": _rounded(row.iou_mean, _IOU_DIGITS),
    }
    for stage in STAGES:
        for key in keys:
            s = row.stat(stage, key)
            out[f"{stage}_{key}_mean"] = _rounded(s.mean if s else None, _digits(key))
            out[f"{stage}_{key}_std"] = _rounded(s.std if s else None, _digits(key))
    for key in CORE_MEASUREMENTS:
        interval = row.intervals.get(key)
        for end in INTERVAL_ENDS:
            out[f"session_{key}_{end}"] = _rounded(
                getattr(interval, end) if interval else None, _digits(key)
            )
    out.update(
        {
            "caveats": row.caveats,
            "warnings": row.warnings,
            "report": row.link,
            "session_path": row.session_path,
            "rig": row.rig,
        }
    )
    return out


def _cell(value: Any) -> str:
    # Missing values are empty cells (a spreadsheet reads them as blanks, not zeros).
    if value is None:
        return ""
    return str(value)


def _csv_text(records: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for rec in records:
        writer.writerow([_cell(rec[c]) for c in columns])
    return buf.getvalue()


# --- parquet (optional) -------------------------------------------------------------------
def _pyarrow_available() -> bool:
    """Whether the optional ``pyarrow`` can be imported (tests replace this check)."""
    import importlib.util

    return importlib.util.find_spec("pyarrow") is not None


def _write_parquet(
    path: Path, records: Sequence[dict[str, Any]], columns: Sequence[str], keys: Sequence[str]
) -> Path:
    """``cohort.parquet``: the CSV's columns and values, typed (nullable)."""
    # Local import: pyarrow is an optional dependency; write_cohort calls this
    # only when _pyarrow_available() says it is installed.
    import pyarrow as pa
    import pyarrow.parquet as pq

    ints = {"person", "frames_kept", "frames_used"}
    floats = {"fraction_used", "iou_mean"} | {
        f"{stage}_{key}_{what}" for stage in STAGES for key in keys for what in ("mean", "std")
    }
    floats |= {f"session_{key}_{end}" for key in CORE_MEASUREMENTS for end in INTERVAL_ENDS}
    arrays = {}
    for col in columns:
        kind = pa.int64() if col in ints else pa.float64() if col in floats else pa.string()
        arrays[col] = pa.array([rec[col] for rec in records], type=kind)
    table = pa.table(arrays) if arrays else pa.table({})
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path


# --- HTML ---------------------------------------------------------------------------------
def _generative_values(rows: Sequence[CohortRow], key: str) -> list[tuple[str, float, float]]:
    """(row label, mean, std) of a measurement's generative stage, per row (session and
    person) that has one."""
    out = []
    for row in rows:
        s = row.stat("generative", key)
        if s is not None and s.mean is not None and math.isfinite(s.mean):
            out.append((row.label, s.mean, s.std or 0.0))
    return out


def distribution_figure(rows: Sequence[CohortRow]) -> Any:
    """One panel per core measurement: a box of the sessions' generative means with
    every session as a point (its frame-to-frame std as an error bar).

    Returns None when no session has a core measurement.
    """
    data = {key: _generative_values(rows, key) for key in CORE_MEASUREMENTS}
    if not any(data.values()):
        return None
    fig = plots.figure(11.0, 3.4)
    axes = fig.subplots(1, len(CORE_MEASUREMENTS), squeeze=False)[0]
    fig.subplots_adjust(left=0.06, right=0.99, top=0.88, bottom=0.1, wspace=0.3)
    color = plots.STAGE_COLORS["generative"]
    for ax, key in zip(axes, CORE_MEASUREMENTS, strict=True):
        ax.set_title(plots.label(key), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, axis="y")
        values = data[key]
        if not values:
            ax.text(0.5, 0.5, "no session", ha="center", va="center", transform=ax.transAxes)
            ax.set_xticks([])
            continue
        means = np.array([v[1] for v in values])
        stds = np.array([v[2] for v in values])
        ax.boxplot(
            means,
            positions=[0.0],
            widths=0.5,
            showfliers=False,
            medianprops={"color": "0.2"},
        )
        # Deterministic jitter: the same study draws the same figure.
        x = np.linspace(-0.15, 0.15, len(means)) if len(means) > 1 else np.zeros(1)
        ax.errorbar(
            x, means, yerr=stds, fmt="o", ms=4, color=color, ecolor=color, alpha=0.8, lw=0.8
        )
        ax.set_xticks([])
        ax.set_xlim(-0.6, 0.6)
        what = "person" if any(r.several for r in rows) else "session"
        ax.set_xlabel(f"{len(means)} {what}{'s' if len(means) != 1 else ''}", fontsize=8)
    return fig


def quality_figure(rows: Sequence[CohortRow]) -> Any:
    """Per session: the fraction of kept frames used and the mean silhouette IoU.

    Returns None when the study has no session.
    """
    if not rows:
        return None
    n = len(rows)
    height = max(2.2, 0.28 * n + 0.9)
    fig = plots.figure(11.0, height)
    ax_used, ax_iou = fig.subplots(1, 2, sharey=True)
    fig.subplots_adjust(
        left=0.2, right=0.98, top=1 - 0.45 / height, bottom=0.45 / height, wspace=0.08
    )
    y = np.arange(n)
    names = [r.label if r.done else f"{r.name} ({r.status})" for r in rows]
    used = [r.fraction_used if r.fraction_used is not None else 0.0 for r in rows]
    iou = [r.iou_mean if r.iou_mean is not None else 0.0 for r in rows]
    # Sessions without numbers stay listed (grey, zero length) so every row lines up.
    for ax, values, stage in ((ax_used, used, "discriminative"), (ax_iou, iou, "generative")):
        ax.barh(y, values, color=[plots.STAGE_COLORS[stage] if r.done else "0.75" for r in rows])
    ax_used.set_yticks(y, names, fontsize=7)
    ax_used.invert_yaxis()  # the study's order from the top
    for ax, title in (
        (ax_used, "fraction of kept frames used"),
        (ax_iou, "mean silhouette IoU (used frames)"),
    ):
        ax.set_xlim(0, 1)
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, axis="x")
    return fig


def _pm(stat: Stat | None, digits: int) -> dict[str, Any] | None:
    if stat is None:
        return None
    return {"mean": stat.mean, "std": stat.std or 0.0, "digits": digits}


def _html_context(
    study_dir: Path, study: StudyResults, rows: Sequence[CohortRow], keys: Sequence[str]
) -> dict[str, Any]:
    # Counts of sessions count each session once, whatever the persons it measured.
    first_rows = list({r.name: r for r in reversed(rows)}.values())[::-1]
    done = [r for r in first_rows if r.done]
    sessions = []
    for r in rows:
        sessions.append(
            {
                "name": r.name,
                "label": r.label,
                "person": r.person if r.several else None,
                "subject": r.subject,
                "status": r.status,
                "reason": r.reason,
                "done": r.done,
                "frames_kept": r.frames_kept,
                "frames_used": r.frames_used,
                "fraction": r.fraction_used,
                "iou": r.iou_mean,
                "core": [_pm(r.stat("generative", k), _digits(k)) for k in CORE_MEASUREMENTS],
                "all": [_pm(r.stat("generative", k), _digits(k)) for k in keys],
                "caveats": r.caveats,
                "warnings": r.warnings,
                # Quoted: a folder name with spaces or '#' is still one link.
                "link": urllib.parse.quote(r.link) if r.link else None,
            }
        )
    cohort = []
    for key in CORE_MEASUREMENTS:
        values = [v[1] for v in _generative_values(rows, key)]
        if values:
            s = Stat.of(values)
            cohort.append(
                {
                    "label": plots.LABELS.get(key, key),
                    "unit": MEASUREMENTS.get(key, ""),
                    "mean": s.mean,
                    "std": s.std,
                    "n": s.n,
                    "min": min(values),
                    "max": max(values),
                    "digits": _digits(key),
                }
            )
    return {
        "title": f"bodymetry cohort: {study_dir.resolve().name}",
        "generated": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "version": __version__,
        "study_folder": str(study_dir.resolve()),
        "counts": {
            "sessions": len(first_rows),
            "done": len(done),
            "failed": sum(r.status == FAILED for r in first_rows),
            "pending": sum(r.status == PENDING for r in first_rows),
            "persons": sum(r.done for r in rows),
            "several": any(r.several for r in rows),
            "frames_used": sum(r.frames_used or 0 for r in rows),
            "frames_kept": sum(r.frames_kept or 0 for r in rows),
        },
        "cohort": cohort,
        "core_labels": [plots.label(k) for k in CORE_MEASUREMENTS],
        "all_labels": [plots.label(k) for k in keys],
        "sessions": sessions,
        "rigs": [
            {
                "key": key,
                "trained": bool(info.trained),
                "seconds": info.seconds,
                "sessions": ", ".join(info.sessions),
            }
            for key, info in study.rigs.items()
        ],
        "timing": study.timing_seconds,
    }


def render_cohort_html(
    study_dir: Path, study: StudyResults, rows: Sequence[CohortRow], keys: Sequence[str]
) -> str:
    """``cohort.html``: one self-contained page (plots embedded as PNG data URIs)."""
    figures = {"distribution": distribution_figure(rows), "quality": quality_figure(rows)}
    images = {name: figure_uri(fig) for name, fig in figures.items() if fig is not None}
    context = _html_context(study_dir, study, rows, keys)
    return template_environment().get_template("cohort.html.j2").render(**context, images=images)


# --- entry point --------------------------------------------------------------------------
def write_cohort(study_dir: Path) -> CohortFiles:
    """Write ``cohort.csv``, ``cohort.html`` (and ``cohort.parquet`` with pyarrow) into
    the study folder, from ``study.json`` and each session's ``results.json``.

    Parameters
    ----------
    study_dir : Path
        The study folder of ``bodymetry batch``.

    Returns
    -------
    CohortFiles

    Raises
    ------
    InputError
        ``study.json`` is missing, unreadable, or not of this format (one
        session's missing or unreadable ``results.json`` is a row, not an error).
    """
    study_dir = Path(study_dir)
    study = StudyResults.read(study_dir / STUDY_JSON)
    rows = cohort_rows(study_dir, study)
    keys = measurement_keys(rows)
    columns = cohort_columns(keys)
    records = [_record(r, keys) for r in rows]
    csv_path = study_dir / COHORT_CSV
    write_text_atomic(csv_path, _csv_text(records, columns))
    parquet_path = None
    if _pyarrow_available():
        parquet_path = _write_parquet(study_dir / COHORT_PARQUET, records, columns, keys)
    else:
        log.info("pyarrow is not installed: no %s (cohort.csv has the same table)", COHORT_PARQUET)
    html_path = study_dir / COHORT_HTML
    write_text_atomic(html_path, render_cohort_html(study_dir, study, rows, keys))
    log.info(
        "cohort of %d sessions (%d persons measured): wrote %s",
        len({r.name for r in rows}),
        sum(r.done for r in rows),
        ", ".join(str(p) for p in (csv_path, parquet_path, html_path) if p is not None),
    )
    return CohortFiles(csv=csv_path, html=html_path, parquet=parquet_path)
