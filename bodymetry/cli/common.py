"""What the command modules share: errors as one line, progress, logging.

Kept small and free of stage imports (numpy, cv2 and yaml included): the
command group imports it for ``bodymetry --help``.

Exit status of every command (docs/cli.md):

* 0: done;
* 1: an internal error (a bug: one line, the traceback with ``-v``), or an
  output that could not be built (``report``);
* 2: bad input: a usage error, a file that is missing, unreadable, malformed
  or too large, a folder that cannot be written, a full disk;
* 3: ``process`` ran, but no frame could be measured (results.json is written).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click
import rich.markup
from rich.progress import BarColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

from bodymetry.errors import BodymetryError
from bodymetry.log import PROGRESS_LOGGER, console, setup_logging

__all__ = [
    "DEMO_SESSION",
    "EXIT_CAVEATS",
    "EXIT_INPUT",
    "EXIT_INTERNAL",
    "EXIT_NO_FRAMES",
    "LogProgress",
    "console",
    "describe_error",
    "friendly_errors",
    "labelled_progress",
    "reported_errors",
    "setup_logging",
    "warnings_to_log",
]

log = logging.getLogger(__name__)

#: The bundled demo recording (a studio session with ground truth).
DEMO_SESSION = Path(__file__).resolve().parents[2] / "recordings" / "demo"

#: Exit status of an internal error (a bug).
EXIT_INTERNAL = 1
#: Exit status of bad input: files, folders, options (click's own usage errors too).
EXIT_INPUT = 2
#: Exit status of ``process`` when no frame of the run could be measured.
EXIT_NO_FRAMES = 3
#: Exit status of ``process`` when the run measured, with caveats: thin or ambiguous
#: evidence (:mod:`bodymetry.estimation.caveats`).
EXIT_CAVEATS = 5


def _one_line(text: str) -> str:
    # Messages of OpenCV and YAML span lines; the report is one line.
    return " ".join(str(text).split())


def _optional_error_type(module: str, name: str) -> type[BaseException] | None:
    """``module.name`` if that module is already imported (an error of it can only
    come from code that imported it, and ``--help`` stays free of the import)."""
    mod = sys.modules.get(module)
    err = getattr(mod, name, None)
    return err if isinstance(err, type) and issubclass(err, BaseException) else None


def describe_error(exc: BaseException) -> tuple[str, int]:
    """The one-line message and the exit status for an exception reaching the CLI.

    Parameters
    ----------
    exc
        The exception.

    Returns
    -------
    message : str
        ``"error: ..."`` naming the file where the exception knows it, or
        ``"internal error: ..."`` for anything that is not a problem with the
        input (a bug).
    status : int
        :data:`EXIT_INPUT` or :data:`EXIT_INTERNAL`.
    """
    yaml_error = _optional_error_type("yaml", "YAMLError")
    cv2_error = _optional_error_type("cv2", "error")
    if isinstance(exc, BodymetryError):
        # An error listing several problems keeps one line per problem.
        lines = [_one_line(line) for line in str(exc).splitlines() if line.strip()]
        return "\n  ".join([f"error: {lines[0]}", *lines[1:]]) if lines else "error", EXIT_INPUT
    elif isinstance(exc, OSError):
        # The user's paths: a folder that cannot be written, a missing file, a full disk.
        why = exc.strerror or str(exc) or type(exc).__name__
        if exc.filename is not None:
            text = f"{exc.filename}: {why}"
            if exc.filename2 is not None:
                text = f"{exc.filename} -> {exc.filename2}: {why}"
        else:
            text = why
    elif isinstance(exc, json.JSONDecodeError):
        text = f"not valid JSON: {exc}"
    elif isinstance(exc, UnicodeDecodeError):
        text = f"not {exc.encoding} text: {exc.reason} at byte {exc.start}"
    elif yaml_error is not None and isinstance(exc, yaml_error):
        text = f"not valid YAML: {exc}"
    elif cv2_error is not None and isinstance(exc, cv2_error):
        # Mostly an image or video OpenCV cannot decode or process.
        where = getattr(exc, "func", "") or ""
        what = getattr(exc, "err", "") or str(exc)
        text = f"OpenCV could not process an image or video: {what}" + (
            f" (in {where})" if where else ""
        )
    else:
        return (
            _one_line(
                f"internal error: {type(exc).__name__}: {exc} (run with -v for the traceback)"
            ),
            EXIT_INTERNAL,
        )
    return _one_line(f"error: {text}"), EXIT_INPUT


def _verbosity() -> int:
    """``-v`` count of the running command line (0 outside one)."""
    ctx = click.get_current_context(silent=True)
    return int(ctx.find_root().params.get("verbose") or 0) if ctx is not None else 0


@contextlib.contextmanager
def reported_errors(verbose: int | None = None) -> Iterator[None]:
    """Turn an exception of the block into one line on stderr and an exit status.

    Click's own exceptions (usage errors, ``--help``, aborts) and a broken pipe
    pass through to click, which reports them.

    Parameters
    ----------
    verbose
        ``-v`` count; 1 or more prints the traceback before the line. Default:
        the running command line's.
    """
    try:
        yield
    except (click.ClickException, click.exceptions.Exit, click.Abort, BrokenPipeError):
        raise
    except Exception as exc:
        message, status = describe_error(exc)
        if verbose is None:
            verbose = _verbosity()
        if verbose > 0:
            traceback.print_exception(exc, file=sys.stderr)
            message = message.replace(" (run with -v for the traceback)", "")
        head, _, rest = message.partition(": ")
        # Text, not markup (paths and user input may contain brackets), on one line
        # whatever the terminal width.
        console.print(
            f"[bold red]{head}:[/] {rich.markup.escape(rest)}", highlight=False, soft_wrap=True
        )
        sys.exit(status)


def friendly_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Run a command's body under :func:`reported_errors`.

    The command group applies the same handler to every command; this keeps a
    command object invoked on its own (tests, other groups) reporting alike.
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with reported_errors():
            return func(*args, **kwargs)

    return wrapper


@contextlib.contextmanager
def warnings_to_log() -> Iterator[None]:
    """Show Python warnings of the block as log records, not as raw warning text.

    Numeric ``RuntimeWarning`` (numpy: mean of an empty slice, invalid value)
    goes to the debug log (``-vv``): the code guards its empty cases, and a
    remaining one is not something the user can act on. Other warnings become
    one ``WARNING`` line. Filters are left alone (``-W error`` still raises).
    """
    original = warnings.showwarning

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: Any = None,
        line: str | None = None,
    ) -> None:
        if issubclass(category, RuntimeWarning):
            log.debug("%s: %s (%s:%s)", category.__name__, message, filename, lineno)
        else:
            log.warning("%s: %s", category.__name__, message)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = original


# --- progress ------------------------------------------------------------------------------
def _duration(seconds: float) -> str:
    """``"45 s"``, ``"2 min"``, ``"1 h 05 min"``."""
    if seconds < 59.5:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    if minutes < 60:
        return f"{minutes} min"
    return f"{minutes // 60} h {minutes % 60:02d} min"


class LogProgress:
    """Progress as log lines, for a stderr that is no terminal (log file, CI, scheduler).

    One line when a label starts, then at most one every ``interval`` seconds,
    and one when it completes::

        training: rendering examples 1200/3597 (33 %), eta 2 min

    Parameters
    ----------
    logger
        Where the lines go (level INFO).
    clock
        Seconds, monotonic (injectable for tests).
    interval
        The least time between two lines of a label (seconds).
    """

    def __init__(
        self,
        logger: logging.Logger | None = None,
        clock: Callable[[], float] = time.monotonic,
        interval: float = 10.0,
    ) -> None:
        self.logger = logger or logging.getLogger(PROGRESS_LOGGER)
        self.clock = clock
        self.interval = interval
        # label -> [start time, done at start, last line's time, last done, completed]
        self._state: dict[str, list[Any]] = {}

    def __call__(self, label: str, done: int, total: int) -> None:
        now = self.clock()
        state = self._state.get(label)
        if state is None or done < state[3]:  # new, or the label counts again from the start
            self._state[label] = [now, done, now, done, done >= total]
            self._line(label, done, total, None)
            return
        start, done0, last, _, completed = state
        state[3] = done
        if completed:
            return
        if done >= total:
            state[2], state[4] = now, True
            self.logger.info(
                "%s %d/%d (100 %%), took %s", label, done, total, _duration(now - start)
            )
        elif now - last >= self.interval:
            state[2] = now
            rate = (done - done0) / (now - start) if now > start else 0.0
            self._line(label, done, total, (total - done) / rate if rate > 0 else None)

    def _line(self, label: str, done: int, total: int, eta: float | None) -> None:
        pct = 100 * done // total if total > 0 else 100
        tail = f", eta {_duration(eta)}" if eta is not None else ""
        self.logger.info("%s %d/%d (%d %%)%s", label, done, total, pct, tail)


@contextlib.contextmanager
def labelled_progress(
    terminal: bool | None = None, **log_options: Any
) -> Iterator[Callable[[str, int, int], None]]:
    """Progress on stderr, one per label; yields ``update(label, done, total)``.

    Parameters
    ----------
    terminal
        Rich progress bars (True) or log lines (False, see :class:`LogProgress`).
        Default: bars when stderr is a terminal; a log file or a CI console
        would get nothing useful from bars redrawn in place.
    **log_options
        For :class:`LogProgress` (``clock``, ``interval``, ``logger``).
    """
    if terminal is None:
        terminal = console.is_terminal
    if not terminal:
        yield LogProgress(**log_options)
        return
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


#: ``--quality``: the row of the preset table (bodymetry.estimation.fit.PRESETS).
quality_option = click.option(
    "--quality",
    type=click.Choice(["fast", "default", "best"]),
    default="default",
    show_default=True,
    help="Particles, annealing layers and image scale.",
)

#: ``--cache``: the trained-model cache folder (train and process share it).
cache_option = click.option(
    "--cache",
    "cache_dir",
    default=None,
    type=click.Path(file_okay=False, path_type=Path),
    help="Model cache folder (default: $BODYMETRY_CACHE or ~/.cache/bodymetry).",
)
