"""Logging set-up for the command line: rich handler on stderr, level by flag."""

from __future__ import annotations

import logging

from rich.console import Console
from rich.logging import RichHandler

#: Shared stderr console: progress bars and log lines go here, results to stdout.
console = Console(stderr=True)


def setup_logging(verbosity: int = 0) -> None:
    """Configure the root logger once.

    Parameters
    ----------
    verbosity
        0 shows warnings and progress, 1 info, 2 or more debug.
    """
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    logging.basicConfig(
        level=level,
        format="%(message)s",
        handlers=[RichHandler(console=console, show_path=False, rich_tracebacks=False)],
        force=True,
    )
