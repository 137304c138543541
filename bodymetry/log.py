"""Logging set-up for the command line: stderr, level by flag, progress shown by default."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.logging import RichHandler

__all__ = ["PROGRESS_LOGGER", "Progress", "console", "setup_logging"]

#: A long step's progress callback: ``progress(label, done, total)``.
Progress = Callable[[str, int, int], None]

#: Shared stderr console: progress bars and log lines go here, results to stdout.
console = Console(stderr=True)

#: The logger of progress lines (``bodymetry.cli.common.LogProgress``, used when
#: stderr is no terminal): shown at the default verbosity, like the bars.
PROGRESS_LOGGER = "bodymetry.progress"


class _StderrHandler(logging.StreamHandler):
    """Plain lines on whatever ``sys.stderr`` is when a record is emitted.

    For a stderr that is no terminal (a log file, CI): one record, one line,
    never wrapped at 80 columns as rich would; resolving ``sys.stderr`` late
    follows a redirection made after set-up (test runners swap it).
    """

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        # StreamHandler.__init__ assigns the stream; the property decides.
        pass


def setup_logging(verbosity: int = 0) -> None:
    """Configure the root logger (again: a later call replaces the handlers).

    Parameters
    ----------
    verbosity
        0 shows warnings and progress, 1 info, 2 or more debug.
    """
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    if console.is_terminal:
        handler: logging.Handler = RichHandler(
            console=console, show_path=False, rich_tracebacks=False
        )
        handler.setFormatter(logging.Formatter("%(message)s"))
    else:
        handler = _StderrHandler()
        handler.setFormatter(
            logging.Formatter("%(asctime)s %(levelname)s %(message)s", "%Y-%m-%d %H:%M:%S")
        )
    logging.basicConfig(level=level, handlers=[handler], force=True)
    # Progress lines are INFO records: shown at the default verbosity too.
    logging.getLogger(PROGRESS_LOGGER).setLevel(min(level, logging.INFO))
