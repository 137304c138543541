"""``bodymetry compile``: compile the numeric kernels now, not in the first run."""

from __future__ import annotations

import click

from bodymetry.cli.common import friendly_errors
from bodymetry.warmup import compile_kernels

__all__ = ["compile_"]


@click.command("compile")
@friendly_errors
def compile_() -> None:
    """Compile and cache the numeric kernels now (make does it at install), not in the first run."""
    click.echo("compiling bodymetry's kernels: a tiny studio session end to end (once, ~45 s)")
    seconds = compile_kernels()
    click.echo(f"kernels compiled and cached ({seconds:.0f} s)")
