"""``bodymetry view``, ``report`` and ``evaluate``: what to do with a processed run."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import click
import rich.markup
from rich.table import Table

from bodymetry.cli.common import console, friendly_errors, labelled_progress
from bodymetry.errors import InputError
from bodymetry.estimation.run_files import GT_STAGE, RECORDING_MCAP, RECORDING_RRD, Evaluation
from bodymetry.review.build import build_review
from bodymetry.review.cohort import STUDY_JSON, write_cohort

# The evaluation's entry point, imported in this one place (it may move between packages).
from bodymetry.review.evaluation import evaluate_persons

__all__ = ["evaluate", "report", "view"]


def _launch_viewer(args: list[str]) -> int:
    """Run the Rerun viewer (the ``rerun`` executable of the rerun-sdk package)."""
    exe = Path(sys.executable).with_name("rerun")
    rerun = str(exe) if exe.is_file() else shutil.which("rerun")
    if rerun is None:
        raise InputError("the Rerun viewer (`rerun`, from the rerun-sdk package) is not installed")
    return subprocess.call([rerun, *args])


@click.command()
@click.argument("run", type=click.Path(path_type=Path))
@click.option("--web", is_flag=True, help="Serve the web viewer (open the printed address).")
@click.option("--mcap", "use_mcap", is_flag=True, help="Open recording.mcap instead of the .rrd.")
@click.option(
    "--port", default=None, type=click.IntRange(1, 65535), help="Web viewer port (with --web)."
)
@friendly_errors
def view(run: Path, web: bool, use_mcap: bool, port: int | None) -> None:
    """Open the recording of RUN (a run folder or a .rrd / .mcap file) in the Rerun viewer."""
    path = run / (RECORDING_MCAP if use_mcap else RECORDING_RRD) if run.is_dir() else run
    if not path.is_file():
        hint = (
            "run `bodymetry report` or `bodymetry process` (without --no-review) first"
            if run.is_dir()
            else "expected a run folder, a .rrd or a .mcap file"
        )
        raise InputError(f"{path}: not found; {hint}")
    if path.suffix.lower() not in (".rrd", ".mcap"):
        raise InputError(f"{path}: expected a .rrd or .mcap recording")
    if port is not None and not web:
        raise InputError("--port: only with --web")
    args = [str(path)]
    if web:
        args.insert(0, "--web-viewer")
        if port is not None:
            args[1:1] = ["--web-viewer-port", str(port)]
    rc = _launch_viewer(args)
    if rc:
        raise click.exceptions.Exit(rc)


@click.command()
@click.argument("run", type=click.Path(path_type=Path))
@click.option("--pdf", is_flag=True, help="Also write report.pdf.")
@click.option(
    "--recordings",
    is_flag=True,
    help="Also rewrite recording.rrd and recording.mcap (reads every frame's images again).",
)
@friendly_errors
def report(run: Path, pdf: bool, recordings: bool) -> None:
    """Rebuild report.html and measurements.csv of RUN from its results.json (no refitting).

    When RUN is a study folder of `bodymetry batch` (it holds study.json), rebuild
    its cohort instead: cohort.csv, cohort.html and, with pyarrow, cohort.parquet.
    """
    if (run / STUDY_JSON).is_file():
        _report_study(run, pdf=pdf, recordings=recordings)
        return
    with labelled_progress() as update:
        summary = build_review(run, recordings=recordings, pdf=pdf, progress=update)
    for name, path in summary.files.items():
        console.print(
            f"wrote {path}" if name != "csv" else f"wrote {path} (one row per person and frame)"
        )
    for name, why in summary.errors.items():
        console.print(f"[bold red]{name} failed:[/] {rich.markup.escape(why)}", highlight=False)
    if summary.errors:
        sys.exit(1)


def _report_study(study: Path, pdf: bool, recordings: bool) -> None:
    """``bodymetry report STUDY``: the cohort of a study folder (docs/cohort.md)."""
    if pdf or recordings:
        # The options rebuild one run's outputs; a study has a run folder per session.
        raise InputError(
            f"{study}: a study folder (study.json); --pdf and --recordings apply to one "
            f"run: `bodymetry report {study / '<session>'} --pdf`"
        )
    files = write_cohort(study)
    console.print(f"wrote {files.csv} (one row per session and person)")
    if files.parquet is not None:
        console.print(f"wrote {files.parquet}")
    else:
        console.print("cohort.parquet not written: pyarrow is not installed")
    console.print(f"wrote {files.html}")


@click.command()
@click.argument("run", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--workers", default=None, type=int, help="Frames fitted in parallel (default: all cores)."
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print one JSON object per person, a line each (also in RUN/evaluation.json, or "
    "RUN/persons/K/evaluation.json for a run of several persons).",
)
@friendly_errors
def evaluate(run: Path, workers: int | None, as_json: bool) -> None:
    """The paper's Figure 3 for a processed session with ground truth (RUN/evaluation.json).

    A run of several persons scores each against the studio person where they stood
    (RUN/persons/K/evaluation.json)."""
    with labelled_progress() as update:
        evaluations = evaluate_persons(run, workers=workers, progress=update)
    for ev in evaluations:
        if as_json:
            click.echo(json.dumps(ev.to_json()))
        else:
            _print_evaluation(ev)


def _print_evaluation(ev: Evaluation) -> None:
    who = "" if ev.person is None else f" person {ev.person} (studio person {ev.truth_person})"
    table = Table(title=f"{ev.session}{who} ({ev.frames} frames): Figure 3")
    table.add_column("biometric")
    table.add_column("actual", justify="right")
    # The session's one value is ± its standard error; the others ± their spread.
    titles = {
        "discriminative": ("discriminative", "std"),
        "generative": ("disc. + generative", "std"),
        "session": ("session", "s.e."),
        GT_STAGE: ("GT + generative", "std"),
    }
    stages = [s for s in ev.stages if all(s in row for row in ev.table.values())]
    for stage in stages:
        title, spread = titles[stage]
        table.add_column(f"{title} mean", justify="right")
        table.add_column(spread, justify="right")
    for key, row in ev.table.items():
        cells = [key, f"{ev.actual[key]:.1f}"]
        for stage in stages:
            cells += [f"{row[stage].mean:.1f}", f"{row[stage].std:.1f}"]
        table.add_row(*cells)
    console.print(table)
    mpjpe = ", ".join(f"{titles[s][0]} {mm:.0f} mm" for s, mm in ev.mpjpe_mm.items())
    console.print(f"MPJPE: {mpjpe}; silhouette IoU of the fit {ev.silhouette_iou_mean:.3f}")
