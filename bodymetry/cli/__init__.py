"""The ``bodymetry`` command line: a thin layer over the stage packages.

One module per command group (``model``, ``synth``, ``train``, ``image``,
``calibrate``, ``silhouettes``, ``process``, ``runs``); :mod:`.common` holds what
they share. The group loads a command's module only when that command runs (or
its own ``--help`` is asked for), so ``bodymetry --help`` does not import the
stage packages.

Errors the user can fix (:class:`bodymetry.errors.BodymetryError`) are printed
as one line naming the file or option and exit with status 2; anything else is
a bug and keeps its traceback.
"""

from __future__ import annotations

import click

from bodymetry import __version__
from bodymetry.cli.common import DEMO_SESSION, setup_logging
from bodymetry.cli.lazy import LazyGroup

__all__ = ["COMMANDS", "DEMO_SESSION", "main"]

#: Command name -> ("module:attribute" of its click command, the first line of its help).
#: The help line is what ``bodymetry --help`` lists without importing the module;
#: tests/bodymetry/test_cli.py checks that it matches the command's docstring.
COMMANDS: dict[str, tuple[str, str]] = {
    "calibrate": (
        "bodymetry.cli.calibrate:calibrate",
        "Solve the cameras of SESSION from its ChArUco calibration clips.",
    ),
    "check": (
        "bodymetry.cli.check:check",
        "Check SESSION (and --out) and list every problem found, before any training or fitting.",
    ),
    "estimate-image": (
        "bodymetry.cli.image:estimate_image",
        "Body shape and measurements from one segmented photo, uncalibrated (paper Figure 2).",
    ),
    "evaluate": (
        "bodymetry.cli.runs:evaluate",
        "The paper's Figure 3 for a processed session with ground truth (RUN/evaluation.json).",
    ),
    "model": (
        "bodymetry.cli.model:model",
        "The SCAPE body model: bake it, inspect it, export meshes.",
    ),
    "process": (
        "bodymetry.cli.process:process",
        "Measure the person in SESSION (default: the demo recording): silhouettes, "
        "discriminative estimate, generative refinement, biometrics per kept frame, "
        "then the review outputs (docs/review.md).",
    ),
    "report": (
        "bodymetry.cli.runs:report",
        "Rebuild report.html and measurements.csv of RUN from its results.json (no refitting).",
    ),
    "silhouettes": (
        "bodymetry.cli.silhouettes:silhouettes",
        "Segment the person in every kept frame of SESSION (masks PNG + overlays).",
    ),
    "synth": (
        "bodymetry.cli.synth:synth",
        "Render a ground-truth multi-camera session into OUT (the synthetic studio).",
    ),
    "train": (
        "bodymetry.cli.train:train",
        "Train the discriminative models for the rig of SOURCE (a session or calibration.yaml).",
    ),
    "view": (
        "bodymetry.cli.runs:view",
        "Open the recording of RUN (a run folder or a .rrd / .mcap file) in the Rerun viewer.",
    ),
}


@click.group(
    cls=LazyGroup,
    lazy_subcommands=COMMANDS,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.version_option(__version__, prog_name="bodymetry")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """Body pose, shape and measurements from synchronized multi-camera video."""
    setup_logging(verbose)
