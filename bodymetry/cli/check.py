"""``bodymetry check``: list every problem with a session before any long work."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import rich.markup

from bodymetry.cli.common import console, friendly_errors
from bodymetry.preflight import check_session

__all__ = ["check"]

#: Exit status when problems were found (that of every bad-input error).
_EXIT_PROBLEMS = 2


@click.command()
@click.argument("session", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Also check the run folder `bodymetry process --out` would write.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the findings as JSON on stdout.")
@friendly_errors
def check(session: Path, out: Path | None, as_json: bool) -> None:
    """Check SESSION (and --out) and list every problem found, before any training or fitting."""
    report = check_session(session, out)
    if as_json:
        click.echo(json.dumps(report.to_json(), indent=2))
        if not report.ok:
            sys.exit(_EXIT_PROBLEMS)
        return
    for warning in report.warnings:
        _print("[yellow]warning:[/]", str(warning))
    if not report.ok:
        # Printed here, one per line: the shared error handler folds a message onto one line.
        _print("[bold red]error:[/]", f"{len(report.problems)} problem(s) in {session}:")
        for problem in report.problems:
            _print("  -", str(problem))
        sys.exit(_EXIT_PROBLEMS)
    n = len(report.warnings)
    click.echo(f"{session}: ok" + (f" ({n} warning{'s' if n != 1 else ''})" if n else ""))


def _print(head: str, text: str) -> None:
    # Text, not markup (paths and messages hold brackets: cameras[1].video), on one
    # line whatever the terminal width.
    console.print(f"{head} {rich.markup.escape(text)}", highlight=False, soft_wrap=True)
