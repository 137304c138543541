"""``bodymetry train``: the discriminative models for a camera rig."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.table import Table

from bodymetry.cameras import load_rig
from bodymetry.cli.common import cache_option, console, friendly_errors, labelled_progress
from bodymetry.estimation.resolution import DEFAULT_WORKING_PERSON_PX, WorkingResolution
from bodymetry.estimation.training import (
    HEADLINE_METRICS,
    TrainConfig,
    default_cache_dir,
    load_or_train,
    rig_key,
)

__all__ = ["train"]


@click.command()
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
    "--working-person-px",
    default=DEFAULT_WORKING_PERSON_PX,
    show_default=True,
    type=click.FloatRange(min=0),
    help="Train each camera at its working resolution, as `process` with the same "
    "working_person_px does (docs/discriminative.md); 0: full resolution.",
)
@cache_option
@click.option("--retrain", is_flag=True, help="Train even if a cached model fits the rig.")
@click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object with the test-set figures."
)
@friendly_errors
def train(
    source: Path,
    n_train: int,
    n_test: int,
    seed: int,
    workers: int | None,
    working_person_px: float,
    cache_dir: Path | None,
    retrain: bool,
    as_json: bool,
) -> None:
    """Train the discriminative models for the rig of SOURCE (a session or calibration.yaml)."""
    calibrated = load_rig(source)
    resolution = WorkingResolution.choose(calibrated, working_person_px or None)
    cameras = resolution.apply(calibrated)
    config = TrainConfig(n_train=n_train, n_test=n_test, seed=seed)
    cache = cache_dir or default_cache_dir()
    if retrain:
        stale = cache / "discriminative" / f"{rig_key(cameras, config)}.npz"
        stale.unlink(missing_ok=True)
    with labelled_progress() as update:
        models, reused = load_or_train(cameras, config, cache, workers=workers, progress=update)
    metrics = {k: v for k, v in models.metrics.items() if k not in ("selection",)}
    metrics["reused_cache"] = reused
    metrics["cache_key"] = models.key
    metrics["working_resolution"] = resolution.to_json()
    if as_json:
        click.echo(json.dumps(metrics))
        return
    table = Table(title=f"discriminative models for {source} ({'cached' if reused else 'trained'})")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key in HEADLINE_METRICS:
        table.add_row(key, f"{metrics[key]:.3f}")
    for name, choice in metrics["chosen"].items():
        table.add_row(f"chosen {name}", f"M={choice['M']}, λ={choice['lambda']:g}")
    console.print(table)
