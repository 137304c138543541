"""``bodymetry import``: a session folder from a Pose2Sim, anipose / FreeMoCap or plain recording.

The work is :func:`bodymetry.importers.import_recording` (docs/import.md).
"""

from __future__ import annotations

from pathlib import Path

import click

from bodymetry.cli.common import friendly_errors
from bodymetry.importers import import_recording

__all__ = ["import_"]


@click.command(name="import")
@click.argument("source", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option(
    "--calibration",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Calibration to use (.qca.txt, anipose/Pose2Sim .toml or calibration.yaml) "
    "instead of the one SOURCE's layout names; required for a plain folder of videos.",
)
@click.option(
    "--frame-step",
    type=click.IntRange(1),
    default=None,
    help="Process every N-th frame (default 25, less for a short clip so >= 10 frames are kept).",
)
@click.option(
    "--units",
    type=click.Choice(["m", "cm", "mm"]),
    default=None,
    help="Unit of a TOML calibration's translations when the file does not say "
    "(default: m for Pose2Sim, mm for anipose / FreeMoCap).",
)
@click.option(
    "--copy", is_flag=True, help="Copy the videos (default: hard links, copies where impossible)."
)
@click.option("--overwrite", is_flag=True, help="Replace the session in a non-empty OUT.")
@friendly_errors
def import_(
    source: Path,
    out: Path,
    calibration: Path | None,
    frame_step: int | None,
    units: str | None,
    copy: bool,
    overwrite: bool,
) -> None:
    """Make a session folder OUT from a Pose2Sim, anipose / FreeMoCap or plain recording SOURCE.

    SOURCE is a Pose2Sim project (Config.toml, videos/, a calibration folder with
    a Qualisys .qca.txt or a calibration .toml), an anipose / FreeMoCap session
    (videos and an anipose calibration TOML) or a folder of videos (with
    --calibration). Videos are paired with calibration cameras by name
    (docs/import.md); each camera gets its video's decoded image size.
    """
    result = import_recording(
        source,
        out,
        calibration=calibration,
        frame_step=frame_step,
        copy=copy,
        overwrite=overwrite,
        units=units,
    )
    session = result.session
    kept = len(session.kept_frames(result.frames))
    click.echo(
        f"{out}: session {session.name!r} from a {result.kind} recording: "
        f"{len(session.cameras)} cameras ({', '.join(session.camera_names)}), "
        f"{session.fps:g} fps, frame_step {session.frame_step} (keeps {kept} of "
        f"{result.frames} frames), videos as {result.links}; "
        f"next: bodymetry check {out}"
    )
