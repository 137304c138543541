"""``bodymetry estimate-image``: shape and measurements from one segmented photo."""

from __future__ import annotations

import json
from pathlib import Path

import click
import cv2

from bodymetry.cameras import load_rig
from bodymetry.cli.common import DEMO_SESSION, console, friendly_errors
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.resolution import DEFAULT_WORKING_PERSON_PX, WorkingResolution
from bodymetry.estimation.training import load_or_train
from bodymetry.estimation.uncalibrated import compare_photos, estimate_photo, read_mask

__all__ = ["estimate_image"]


@click.command("estimate-image")
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
@friendly_errors
def estimate_image(
    image: Path | None,
    mask: Path | None,
    height_mm: float,
    compare: tuple[Path, Path] | None,
    rig: Path | None,
    as_json: bool,
) -> None:
    """Body shape and measurements from one segmented photo, uncalibrated (paper Figure 2)."""
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
    calibrated = load_rig(rig or DEMO_SESSION)
    # The models `process` and `train` cache for this rig (its working cameras).
    cameras = WorkingResolution.choose(calibrated, DEFAULT_WORKING_PERSON_PX).apply(calibrated)
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
