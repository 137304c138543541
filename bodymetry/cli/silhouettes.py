"""``bodymetry silhouettes``: the capture stage on its own, scored where there is ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.table import Table

from bodymetry.capture.session import load_session
from bodymetry.cli.common import console, friendly_errors, labelled_progress
from bodymetry.studio.evaluate import SilhouetteRun, segment_and_score

__all__ = ["silhouettes"]


@click.command()
@click.argument("session_dir", metavar="SESSION", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Output folder (default: runs/<session name>/silhouettes).",
)
@click.option(
    "--method",
    type=click.Choice(["horprasert", "mog2", "none"]),
    default="horprasert",
    show_default=True,
    help="Background subtraction: Horprasert shadow suppression, OpenCV MOG2, or none.",
)
@click.option(
    "--read",
    "read_method",
    type=click.Choice(["sequential", "seek"]),
    default="sequential",
    show_default=True,
    help="Decode straight through (fast for H.264) or seek to each kept frame.",
)
@click.option("--no-overlays", is_flag=True, help="Write the masks only.")
@click.option("--strict", is_flag=True, help="Differing frame counts are an error.")
@click.option(
    "--no-shadow-eval",
    is_flag=True,
    help="With ground truth, skip re-rendering the true cast shadows (no shadow_false_positive).",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (results) on stdout.")
@friendly_errors
def silhouettes(
    session_dir: Path,
    out: Path | None,
    method: str,
    read_method: str,
    no_overlays: bool,
    strict: bool,
    no_shadow_eval: bool,
    as_json: bool,
) -> None:
    """Segment the person in every kept frame of SESSION (masks PNG + overlays)."""
    session = load_session(session_dir)
    out = out or Path("runs") / session.name / "silhouettes"
    # One bar per step (background models, then silhouettes); log lines off a terminal.
    with labelled_progress() as update:
        run = segment_and_score(
            session,
            out,
            method=method,
            read_method=read_method,
            overlays=not no_overlays,
            strict=strict,
            shadows=not no_shadow_eval,
            progress=update,
        )
    if as_json:
        click.echo(json.dumps(run.to_dict()))
        return
    console.print(_table(run, session.name))
    console.print(f"wrote masks and overlays to {out}/ in {run.seconds:.1f} s")


def _table(run: SilhouetteRun, name: str) -> Table:
    table = Table(title=f"silhouettes of {name} ({run.method})")
    table.add_column("camera")
    table.add_column("frames", justify="right")
    if run.ground_truth:
        table.add_column("IoU mean", justify="right")
        table.add_column("IoU min", justify="right")
        table.add_column("shadow FP", justify="right")
    table.add_column("flags")
    for camera, entry in run.cameras.items():
        row = [camera, str(entry["frames"])]
        if run.ground_truth:
            sfp = entry.get("shadow_false_positive")
            row += [
                f"{entry.get('iou_mean', float('nan')):.3f}",
                f"{entry.get('iou_min', float('nan')):.3f}",
                "-" if sfp is None else f"{100 * sfp:.2f} %",
            ]
        row.append(", ".join(f"{k} x{len(v)}" for k, v in entry["flags"].items()) or "-")
        table.add_row(*row)
    return table
