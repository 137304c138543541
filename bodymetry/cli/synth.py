"""``bodymetry synth``: render a ground-truth session with the synthetic studio."""

from __future__ import annotations

from pathlib import Path

import click

from bodymetry.cli.common import console, friendly_errors, labelled_progress
from bodymetry.errors import InputError
from bodymetry.studio.looks import Look, look_usage
from bodymetry.studio.synth import SubjectSpec, SynthConfig, describe, synthesize

__all__ = ["synth"]


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise InputError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480") from exc
    return w, h


@click.command()
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--subject",
    default=None,
    help="seed:N | heldout:N | nu:v1,v2,... | independent:SEED[,body=K|edge=KEY]"
    "[,clothing=tight|shorts|loose|draped|skirt|dress|long_skirt][,ease=MM][,hair=0|1] "
    "(a body our model was not built from; "
    "edge=KEY picks one by percentile, e.g. female_height_p01 or girl_age6, docs/studio.md; "
    "default: from --seed).",
)
@click.option("--motion", default="mixed", show_default=True, help="Motion library name.")
@click.option("--frames", default=200, show_default=True, type=int, help="Frames to record.")
@click.option("--fps", default=60.0, show_default=True, type=float, help="Frame rate.")
@click.option(
    "--frame-step",
    default=25,
    show_default=True,
    type=int,
    help="Processing keeps every N-th frame.",
)
@click.option(
    "--cameras", default=4, show_default=True, type=int, help="Cameras around the volume."
)
@click.option("--size", default="640x480", show_default=True, help="Image size WIDTHxHEIGHT.")
@click.option(
    "--seed", default=0, show_default=True, type=int, help="Seeds the rig, motion, noise, subject."
)
@click.option(
    "--rig-seed",
    default=None,
    type=int,
    help="Seeds the camera rig alone (default: --seed); sessions of one lab share a rig.",
)
@click.option("--no-shadows", is_flag=True, help="No cast shadow from the key light.")
@click.option(
    "--calibration-frames", default=300, show_default=True, type=int, help="ChArUco clip length."
)
@click.option(
    "--background-frames", default=30, show_default=True, type=int, help="Empty-scene clip length."
)
@click.option(
    "--no-background-clip",
    is_flag=True,
    help="Write no empty-scene clips (background/), like most real recordings.",
)
@click.option(
    "--bystanders",
    default=0,
    show_default=True,
    type=int,
    help="People standing still in the room, each seen by one or two cameras.",
)
@click.option(
    "--people",
    default=1,
    show_default=True,
    type=int,
    help="Persons recorded, 1-3: the subject and others who walk past it, crossing it in "
    "some cameras; each has its own ground truth (ground_truth/persons/<k>/, "
    "docs/studio.md, 'People').",
)
@click.option(
    "--look",
    default=None,
    help="The subject's clothing, the room and the light as KEY=VALUE,... (any subset): "
    f"{look_usage()} (default: saturated, textured, hard; docs/studio.md, 'Looks').",
)
@click.option(
    "--crf", default=20, show_default=True, type=int, help="H.264 quality (lower: better, bigger)."
)
@click.option("--workers", default=None, type=int, help="Worker processes (default: all cores).")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
@friendly_errors
def synth(
    out: Path,
    subject: str | None,
    motion: str,
    frames: int,
    fps: float,
    frame_step: int,
    cameras: int,
    size: str,
    seed: int,
    rig_seed: int | None,
    no_shadows: bool,
    calibration_frames: int,
    background_frames: int,
    no_background_clip: bool,
    bystanders: int,
    people: int,
    look: str | None,
    crf: int,
    workers: int | None,
    overwrite: bool,
) -> None:
    """Render a ground-truth multi-camera session into OUT (the synthetic studio)."""
    config = SynthConfig(
        frames=frames,
        fps=fps,
        frame_step=frame_step,
        cameras=cameras,
        size=_parse_size(size),
        seed=seed,
        rig_seed=rig_seed,
        motion=motion,
        subject=SubjectSpec.parse(subject, seed),
        shadows=not no_shadows,
        background_frames=background_frames,
        calibration_frames=calibration_frames,
        crf=crf,
        background_clip=not no_background_clip,
        bystanders=bystanders,
        people=people,
        look=Look.parse(look),
    )
    with labelled_progress() as progress:

        def update(done: int, total: int) -> None:
            progress("rendering (images)", done, total)

        session = synthesize(out, config, workers=workers, on_progress=update, overwrite=overwrite)
    console.print(describe(session))
