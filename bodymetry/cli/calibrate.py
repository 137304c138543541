"""``bodymetry calibrate``: solve a session's cameras from its ChArUco clips."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from bodymetry.calibration.session_calibration import (
    calibrate_session,
    calibration_clip_lengths,
    detect_session,
    parse_floor_frames,
    write_calibration,
)
from bodymetry.capture.session import DEFAULT_CALIBRATION_FILE, load_session
from bodymetry.cli.common import console, friendly_errors, labelled_progress
from bodymetry.errors import InputError

__all__ = ["calibrate"]


@click.command()
@click.argument("session_dir", metavar="SESSION", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="calibration.yaml to write (default: the session's calibration path).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing calibration file.")
@click.option(
    "--floor-frames",
    default=None,
    help="Clip frames START:END where the board lies still on the floor, face up (it "
    "defines the world: origin, z up); 'none' for no floor (world = first camera). "
    "Default: the first second.",
)
@click.option(
    "--step", default=None, type=click.IntRange(1), help="Detect every N-th frame (default: auto)."
)
@click.option("--workers", default=None, type=click.IntRange(1), help="Detection threads.")
@friendly_errors
def calibrate(
    session_dir: Path,
    out: Path | None,
    overwrite: bool,
    floor_frames: str | None,
    step: int | None,
    workers: int | None,
) -> None:
    """Solve the cameras of SESSION from its ChArUco calibration clips."""
    session = load_session(session_dir)
    out = out or session.calibration_path or (session.folder / DEFAULT_CALIBRATION_FILE)
    if out.exists() and not overwrite:
        raise InputError(
            f"{out} exists; pass --overwrite to replace it or --out to write elsewhere"
        )
    floor = parse_floor_frames(floor_frames, session.fps)
    calibration_clip_lengths(session)  # every unusable clip named before any progress bar
    with labelled_progress() as progress:

        def update(name: str, done: int, total: int) -> None:
            progress(f"detecting {name} (frames)", done, total)

        detections = detect_session(session, step=step, workers=workers, on_progress=update)
    with console.status("solving (intrinsics, camera graph, bundle adjustment)"):
        result, _ = calibrate_session(session, floor_frames=floor, detections=detections)
    report_path = write_calibration(result, out, overwrite=overwrite, session=str(session.folder))
    table = Table(title=f"calibration of {session.name}: RMS {result.rms_px:.3f} px")
    for col in ("camera", "frames read", "boards detected", "corners used", "RMS px"):
        table.add_column(col, justify="left" if col == "camera" else "right")
    for name, fig in result.per_camera.items():
        table.add_row(
            name,
            str(fig["frames_read"]),
            str(fig["boards_detected"]),
            str(fig["corners_used"]),
            f"{fig['rms_px']:.3f}",
        )
    console.print(table)
    console.print(f"world: {result.world.get('frame')}")
    console.print(f"wrote {out} and {report_path}")
