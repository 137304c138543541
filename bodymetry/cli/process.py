"""``bodymetry process``: measure the person in a session (the whole pipeline)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import rich.markup
from rich.table import Table

from bodymetry.cli.common import (
    DEMO_SESSION,
    EXIT_CAVEATS,
    EXIT_NO_FRAMES,
    cache_option,
    console,
    friendly_errors,
    labelled_progress,
    quality_option,
)
from bodymetry.errors import InputError
from bodymetry.estimation.fit import FitConfig, poor_fit_hint
from bodymetry.estimation.records import COARSE_PIXELS, CORE_MEASUREMENTS, STAGES
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import (
    MEASUREMENTS_CSV,
    RECORDING_MCAP,
    RECORDING_RRD,
    REPORT_HTML,
    REPORT_PDF,
    RunResults,
)
from bodymetry.process import process_session

__all__ = ["process"]


@click.command()
@click.argument("session", required=False, type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Run folder (default: runs/<session name>). An existing run resumes.",
)
@quality_option
@click.option(
    "--workers", default=None, type=int, help="Frames fitted in parallel (default: all cores)."
)
@click.option(
    "--frame-step",
    default=None,
    type=click.IntRange(1),
    help="Fit every N-th frame instead of the session's frame_step (e.g. 10 for a "
    "100-frame clip); recorded in results.json.",
)
@click.option("--seed", default=0, show_default=True, type=int, help="Seeds the particle filter.")
@click.option(
    "--person",
    default=None,
    type=click.IntRange(0),
    help="Measure only person N of a recording with several people (numbered from 0 in "
    "the order capture first sees them; docs/capture.md). Default: every person capture "
    "tells apart, each with their own table, else the one subject.",
)
@click.option(
    "--largest",
    is_flag=True,
    help="Measure one subject per frame, the largest body, even where capture tells "
    "people apart (the run says so when several people are in view).",
)
@click.option(
    "--min-iou",
    default=0.9,
    show_default=True,
    type=click.FloatRange(0.0, 1.0),
    help="Frames whose fit overlaps the silhouettes less (mean IoU) are marked 'poor fit' "
    "and left out of the summary.",
)
@cache_option
@click.option(
    "--no-review",
    is_flag=True,
    help="Skip the review outputs (recording.rrd, recording.mcap, report.html, measurements.csv).",
)
@click.option("--pdf", is_flag=True, help="Also write the report as report.pdf.")
@click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override any setting of the run's config (repeatable), e.g. "
    "--set annealing.n_particles=120, --set refinement.iterations=20, "
    "--set training.n_train=1000, --set density=1010 (docs/outputs.md lists them).",
)
@click.option(
    "--show-config",
    is_flag=True,
    help="Print the resulting config as JSON and exit (nothing is run).",
)
@click.option(
    "--restart",
    is_flag=True,
    help="OUT holds a run of another session or other settings: replace it (its own "
    "files only) instead of refusing.",
)
@friendly_errors
def process(
    session: Path | None,
    out: Path | None,
    quality: str,
    workers: int | None,
    frame_step: int | None,
    seed: int,
    person: int | None,
    largest: bool,
    min_iou: float,
    cache_dir: Path | None,
    no_review: bool,
    pdf: bool,
    overrides: tuple[str, ...],
    show_config: bool,
    restart: bool,
) -> None:
    """Measure the person in SESSION (default: the demo recording): silhouettes,
    discriminative estimate, generative refinement, biometrics per kept frame,
    then the review outputs (docs/review.md)."""
    if no_review and pdf:
        raise InputError("--pdf: the report is part of the review; drop --no-review")
    config = ProcessConfig.preset(
        quality,
        fit=FitConfig.preset(quality, seed=seed, min_iou=min_iou),
        workers=workers,
        cache_dir=cache_dir,
        review=not no_review,
        pdf=pdf,
        frame_step=frame_step,
        person=person,
        largest=largest,
    ).with_overrides(overrides)
    if show_config:
        click.echo(json.dumps(config.to_json(), indent=2))
        return
    session = session or DEMO_SESSION
    out = out or Path("runs") / session.resolve().name
    with labelled_progress() as update:
        results = process_session(session, out, config, progress=update, restart=restart)
    views = [results.for_person(p.id) for p in results.persons]
    for view in views:
        _print_summary(view, results.several)
    # The run's own warnings once, under the tables (each person's are under theirs).
    for warning in results.warnings:
        console.print(f"[bold yellow]warning:[/] {rich.markup.escape(warning)}")
    console.print(
        f"wrote {out / 'results.json'} and "
        f"{'persons/*/frames/' if results.several else 'frames/'} (per-frame records)"
    )
    if config.review:
        _print_review_files(out)
    # In a run of several persons each line names its person.
    who = {v.person.id: f"person {v.person.id}: " if results.several else "" for v in views}
    if not any(view.ok_frames for view in views):
        # The run itself worked (results.json says why each frame failed), but
        # there is no measurement: a script must not mistake it for success.
        for view in views:
            message = who[view.person.id] + no_frames_message(view, out)
            console.print(
                f"[bold red]error:[/] {rich.markup.escape(message)}",
                highlight=False,
                soft_wrap=True,
            )
        sys.exit(EXIT_NO_FRAMES)
    caveats = [(who[view.person.id], caveat) for view in views for caveat in view.caveats]
    unmeasured = [view for view in views if not view.ok_frames]
    for view in unmeasured:
        message = who[view.person.id] + no_frames_message(view, out)
        console.print(
            f"[bold yellow]caveat (unmeasured):[/] {rich.markup.escape(message)}",
            highlight=False,
            soft_wrap=True,
        )
    if caveats:
        # Measured, but the numbers stand on thin or ambiguous evidence: say so, and
        # let a script tell it from a clean run.
        for who, caveat in caveats:
            console.print(
                f"[bold yellow]caveat ({caveat.code}):[/] "
                f"{rich.markup.escape(who + caveat.message)}",
                highlight=False,
                soft_wrap=True,
            )
    if caveats or unmeasured:
        sys.exit(EXIT_CAVEATS)


def no_frames_message(results: RunResults, run: Path) -> str:
    """Why no frame of a run was measured: its frames' statuses, summarized on one line.

    Statuses are grouped by their kind (the text before a ``:``, so "poor fit: mean
    silhouette IoU 0.41 < 0.90" counts as "poor fit"), most frequent first, with
    the first frames of each.
    """
    frames = results.frames
    if not frames:
        return f"no frame was measured: the session has no kept frame (see {run / 'results.json'})"
    kinds: dict[str, list[int]] = {}
    for f in frames:
        kinds.setdefault(f.status_kind, []).append(f.frame)
    parts = []
    for kind, numbers in sorted(kinds.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        shown = ", ".join(str(n) for n in numbers[:3]) + (", ..." if len(numbers) > 3 else "")
        parts.append(f"{len(numbers)} {kind} (frame{'s' if len(numbers) > 1 else ''} {shown})")
    hint = poor_fit_hint(frames)
    return (
        f"no frame of {len(frames)} could be measured: {'; '.join(parts)}"
        f"{'; ' + hint if hint else ''}; "
        f"per frame in {run / 'results.json'}"
    )


def _print_review_files(run: Path) -> None:
    names = (RECORDING_RRD, RECORDING_MCAP, REPORT_HTML, REPORT_PDF, MEASUREMENTS_CSV)
    written = [n for n in names if (run / n).is_file()]
    if written:
        console.print(f"review: {', '.join(written)} in {run}/ (open with `bodymetry view {run}`)")


def _print_summary(results: RunResults, several: bool = False) -> None:
    """The table of one person's measurements (``results``: the run as they see it,
    :meth:`RunResults.for_person`), their warnings and their failed frames."""
    frames = results.frames
    failed = [f for f in frames if not f.ok]
    name = results.session.name
    n_ok = len(frames) - len(failed)
    share = f" ({100 * n_ok / len(frames):.0f} %)" if frames else ""
    who = f" person {results.person.id}" if several else ""
    table = Table(title=f"{name}{who}: {n_ok} of {len(frames)} kept frames measured{share}")
    table.add_column("measurement")
    truth = results.ground_truth
    if truth:
        table.add_column("actual", justify="right")
    for stage in STAGES:
        # The session stage is one value with its standard error, not a mean over frames.
        spread = "± s.e." if stage == "session" else "mean ± std"
        table.add_column(f"{stage} {spread}", justify="right")
    # The session value's 95 % interval: its standard error and the studio's error on
    # like bodies together (docs/outputs.md, "The 95 % interval").
    intervals = results.stated_intervals
    if intervals:
        table.add_column("95 % interval", justify="right")
    for key in (*CORE_MEASUREMENTS, "chest_mm", "waist_mm", "hip_mm"):
        row = [key]
        if truth:
            actual = truth.get(key)
            row.append("-" if actual is None else f"{actual:.1f}")
        for stage in STAGES:
            s = results.summary.get(stage, {}).get(key)
            row.append("-" if s is None or s.mean is None else f"{s.mean:.1f} ± {s.std:.1f}")
        if intervals:
            i = intervals.get(key)
            row.append("-" if i is None else f"{i.low:.1f} to {i.high:.1f}")
        table.add_row(*row)
    console.print(table)
    # A measurement whose interval the outline check's finding voids says so (its row
    # reads "-"; the caveat below says what was found).
    withheld: dict[str, list[str]] = {}
    for key, finding in results.intervals_withheld.items():
        withheld.setdefault(finding, []).append(key)
    for finding, keys in withheld.items():
        studio = (
            "measured at finer pixels"
            if finding == COARSE_PIXELS
            else "of tight clothing and bare heads"
        )
        console.print(
            f"no 95 % interval for {', '.join(keys)}: {finding} (the studio's accuracy is {studio})"
        )
    shape = results.session_shape
    if shape is not None and not shape.ok:
        console.print(f"session shape: {rich.markup.escape(shape.status)}")
    # This person's warnings (cameras, the outline check), under their table.
    for warning in results.person.warnings:
        console.print(f"[bold yellow]warning:[/] {rich.markup.escape(warning)}")
    for f in failed:
        console.print(f"frame {f.frame}: {f.status}")
