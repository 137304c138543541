"""What the command modules share: user errors as one line, progress bars, logging.

Kept small and free of stage imports: the command group imports it for
``bodymetry --help``.
"""

from __future__ import annotations

import contextlib
import functools
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click
import rich.markup
from rich.progress import BarColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

from bodymetry.errors import BodymetryError
from bodymetry.log import console, setup_logging

__all__ = ["DEMO_SESSION", "console", "friendly_errors", "labelled_progress", "setup_logging"]

#: The bundled demo recording (a studio session with ground truth).
DEMO_SESSION = Path(__file__).resolve().parents[2] / "recordings" / "demo"


def friendly_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Report a :class:`BodymetryError` raised by ``func`` as one line and exit with 2.

    Other exceptions are bugs and propagate with their traceback.
    """

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


#: ``--cache``: the trained-model cache folder (train and process share it).
cache_option = click.option(
    "--cache",
    "cache_dir",
    default=None,
    type=click.Path(file_okay=False, path_type=Path),
    help="Model cache folder (default: $BODYMETRY_CACHE or ~/.cache/bodymetry).",
)


def frames_progress(**kwargs: Any) -> Progress:
    """A rich progress display counting frames (``kwargs`` go to ``Progress``)."""
    return Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        "{task.completed}/{task.total} frames",
        TimeRemainingColumn(),
        console=console,
        **kwargs,
    )
