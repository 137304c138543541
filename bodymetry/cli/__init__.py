"""The ``bodymetry`` command line: a thin layer over the stage packages.

One module per command group (``model``, ``synth``, ``train``, ``image``,
``calibrate``, ``silhouettes``, ``process``, ``runs``); :mod:`.common` holds what
they share. The group loads a command's module only when that command runs (or
its own ``--help`` is asked for), so ``bodymetry --help`` does not import the
stage packages.

Every command runs under one error handler (:func:`.common.reported_errors`):
an error reaching the command line is printed as one line naming the file or
option, with exit status 2 for bad input (:class:`bodymetry.errors.BodymetryError`,
``OSError``, malformed JSON / YAML / text, OpenCV failures) and 1 for anything
else (a bug); ``-v`` adds the traceback. ``process`` exits with 3 when no frame
could be measured. Warnings are shown as log lines (numeric ones at debug
level). docs/cli.md lists the exit statuses.
"""

from __future__ import annotations

import click

from bodymetry import __version__
from bodymetry.cli.common import DEMO_SESSION, reported_errors, setup_logging, warnings_to_log
from bodymetry.cli.lazy import LazyGroup

__all__ = ["COMMANDS", "DEMO_SESSION", "BodymetryGroup", "main"]

#: Command name -> ("module:attribute" of its click command, the first line of its help).
#: The help line is what ``bodymetry --help`` lists without importing the module;
#: tests/bodymetry/test_cli.py checks that it matches the command's docstring.
COMMANDS: dict[str, tuple[str, str]] = {
    "batch": (
        "bodymetry.cli.batch:batch",
        "Measure every session of a study on Dask (this machine or a cluster) into STUDY/, "
        "with the cohort table and report.",
    ),
    "calibrate": (
        "bodymetry.cli.calibrate:calibrate",
        "Solve the cameras of SESSION from its ChArUco calibration clips.",
    ),
    "check": (
        "bodymetry.cli.check:check",
        "Check SESSION (and --out) and list every problem found, before any training or fitting.",
    ),
    "compile": (
        "bodymetry.cli.compile:compile_",
        "Compile and cache the numeric kernels now (make does it at install), "
        "not in the first run.",
    ),
    "estimate-image": (
        "bodymetry.cli.image:estimate_image",
        "Body shape and measurements from one segmented photo, uncalibrated (paper Figure 2).",
    ),
    "evaluate": (
        "bodymetry.cli.runs:evaluate",
        "The paper's Figure 3 for a processed session with ground truth (RUN/evaluation.json).",
    ),
    "import": (
        "bodymetry.cli.import_:import_",
        "Make a session folder OUT from a Pose2Sim, anipose / FreeMoCap or plain recording SOURCE.",
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


class BodymetryGroup(LazyGroup):
    """The command group: lazily loaded commands, run under the one error handler."""

    def invoke(self, ctx: click.Context) -> object:
        # Here, not per command: an error anywhere (loading a command's module
        # included) is reported the same way, and -v is parsed by now.
        with reported_errors(ctx.params.get("verbose") or 0), warnings_to_log():
            return super().invoke(ctx)


@click.group(
    cls=BodymetryGroup,
    lazy_subcommands=COMMANDS,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.version_option(__version__, prog_name="bodymetry")
@click.option(
    "-v",
    "--verbose",
    count=True,
    help="More log output (-v info and tracebacks of errors, -vv debug).",
)
def main(verbose: int) -> None:
    """Body pose, shape and measurements from synchronized multi-camera video."""
    setup_logging(verbose)
