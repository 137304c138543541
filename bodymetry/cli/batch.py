"""``bodymetry batch``: measure every session of a study on Dask (docs/batch.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.table import Table

from bodymetry.batch import dashboard_link, dask_client, find_sessions, run_batch
from bodymetry.cli.common import (
    cache_option,
    console,
    friendly_errors,
    labelled_progress,
    quality_option,
)
from bodymetry.estimation.records import CORE_MEASUREMENTS
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.review.cohort import cohort_rows

__all__ = ["EXIT_SESSIONS_FAILED", "batch"]

#: Exit status when at least one session of the study failed (the others are done).
EXIT_SESSIONS_FAILED = 4


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--out",
    "study",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Study folder: one run folder per session, study.json, cohort.csv, cohort.html.",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="A running Dask scheduler (tcp://host:8786); default: a local cluster.",
)
@click.option(
    "--workers",
    default=None,
    type=click.IntRange(1),
    help="Worker processes of the local cluster (default: one per core).",
)
@quality_option
@click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override any setting, as for `bodymetry process` (repeatable).",
)
@cache_option
@click.option("--no-review", is_flag=True, help="Skip each session's review outputs.")
@click.option(
    "--restart",
    is_flag=True,
    help="Replace run folders of other sessions or settings instead of failing them.",
)
@friendly_errors
def batch(
    sessions: tuple[Path, ...],
    study: Path,
    scheduler: str | None,
    workers: int | None,
    quality: str,
    overrides: tuple[str, ...],
    cache_dir: Path | None,
    no_review: bool,
    restart: bool,
) -> None:
    """Measure every session of a study on Dask (this machine or a cluster) into STUDY/,
    with the cohort table and report.

    SESSIONS are session folders, folders of session folders, or text files
    listing them. A rerun skips finished frames and sessions; a failed session
    is reported and the others go on (exit status 4 when any failed).
    """
    found = find_sessions(sessions)
    config = ProcessConfig.preset(
        quality, cache_dir=cache_dir.resolve() if cache_dir else None, review=not no_review
    ).with_overrides(overrides)
    console.print(f"{len(found)} session(s) -> {study}/")
    with dask_client(scheduler, workers) as client:
        link = dashboard_link(client)
        console.print(f"Dask dashboard: {link}" if link else "Dask: no dashboard (needs bokeh)")
        with labelled_progress() as update:
            outcome = run_batch(found, study, config, client, update, restart=restart)
    _print_study(outcome.study, study)
    if not outcome.ok:
        sys.exit(EXIT_SESSIONS_FAILED)


def _print_study(study, folder: Path) -> None:
    table = Table(title=f"study {folder}")
    for col in ("session", "status", "rig", "detail"):
        table.add_column(col)
    # A done session whose numbers stand on thin or ambiguous evidence says so.
    # A session of several persons: each person's caveats, with whose they are.
    caveats: dict[str, str] = {}
    for row in cohort_rows(folder, study):
        if row.caveats:
            mine = f"person {row.person}: {row.caveats}" if row.several else row.caveats
            caveats[row.name] = "; ".join(filter(None, (caveats.get(row.name), mine)))
    for entry in study.sessions:
        found = caveats.get(entry.name)
        detail = entry.reason or (f"caveats: {found}" if found else "")
        table.add_row(entry.name, entry.status, entry.rig[:8], detail)
    console.print(table)
    with_caveats = sum(1 for text in caveats.values() if text)
    if with_caveats:
        console.print(
            f"{with_caveats} session(s) measured with caveats: read their reports "
            "(the cohort's 'caveats' column)"
        )
    trained = sum(1 for r in study.rigs.values() if r.trained)
    console.print(
        f"{len(study.rigs)} rig(s), {trained} trained now; cohort: {folder / 'cohort.csv'}, "
        f"{folder / 'cohort.html'} ({', '.join(CORE_MEASUREMENTS)} per session)"
    )
