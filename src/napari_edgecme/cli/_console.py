"""What ``edgecme`` tells the user, on stderr, and how it exits.

The exit statuses, the errors a user can fix (:class:`CLIError`), the one-line progress bar
and the console that prints warnings, summaries and errors.
"""

from __future__ import annotations

import contextlib
import math
import shutil
import sys
import time

from ..core._validation import first_line
from ..core.progress import Progress, drive

PROG = "edgecme"

#: Exit statuses.
EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: Exit status of ``batch`` when some photos failed.
EXIT_FAILED = 1


class CLIError(Exception):
    """A problem the user can fix (bad input, bad option, missing folder): exit status 2."""


class _UsageError(CLIError):
    """Raised by the argument parser instead of printing usage and exiting."""


class ProgressBar:
    """A one-line text progress bar for the engine's :class:`Progress` records.

    Call it with each record (it is a valid ``callback`` for the engine's plain
    functions). The line is redrawn in place with a carriage return at most every
    ``min_interval`` seconds (and always at 100 %); a new ``stage`` ends the previous
    line and starts a new one, so a run leaves one finished line per stage::

        estimate   [############--------]  60%  0:07  scale 3/5, iteration 2/5

    Parameters
    ----------
    stream : text stream
        Where to draw (the CLI uses stderr, and only when it is a terminal).
    width : int, optional
        Line width (default: the terminal's width).
    min_interval : float
        Least time between redraws (seconds).
    clock : callable
        Monotonic time source (tests pass a fake one).
    """

    BAR = 20

    def __init__(self, stream, width: int | None = None, min_interval: float = 0.1,
                 clock=time.monotonic):
        self.stream = stream
        self.width = width
        self.min_interval = min_interval
        self.clock = clock
        self._record: Progress | None = None
        self._start = 0.0
        self._last_draw = -math.inf
        self._shown = 0  # characters of the line currently on screen

    def __call__(self, record: Progress) -> None:
        self.update(record)

    def update(self, record: Progress) -> None:
        now = self.clock()
        if self._record is not None and record.stage != self._record.stage:
            self.finish()
        if self._record is None:
            self._start = now
        self._record = record
        if now - self._last_draw >= self.min_interval or record.step >= record.total:
            self._draw(now)

    def line(self, record: Progress, elapsed: float) -> str:
        """The text of the bar for ``record`` after ``elapsed`` seconds."""
        filled = round(record.fraction * self.BAR)
        minutes, seconds = divmod(int(elapsed), 60)
        text = (f"{record.stage:<10} [{'#' * filled}{'-' * (self.BAR - filled)}] "
                f"{100 * record.fraction:3.0f}%  {minutes}:{seconds:02d}  {record.message}")
        width = self.width or shutil.get_terminal_size((80, 24)).columns
        return text[:max(width - 1, 10)]

    def _draw(self, now: float) -> None:
        text = self.line(self._record, now - self._start)
        self.stream.write("\r" + text + " " * max(0, self._shown - len(text)))
        self.stream.flush()
        self._shown = len(text)
        self._last_draw = now

    def clear(self) -> None:
        """Erase the line on screen (before another message is printed)."""
        if self._shown:
            self.stream.write("\r" + " " * self._shown + "\r")
            self.stream.flush()
            self._shown = 0
            self._last_draw = -math.inf

    def finish(self) -> None:
        """Draw the current stage's last state and end its line."""
        if self._record is not None:
            self._draw(self.clock())
            self.stream.write("\n")
            self.stream.flush()
        self._record = None
        self._shown = 0
        self._last_draw = -math.inf


class _Console:
    """Everything the CLI tells the user, on stderr: progress, warnings, summaries, errors."""

    def __init__(self, quiet: bool = False, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        isatty = getattr(self.stream, "isatty", None)
        self.bar = (ProgressBar(self.stream) if not quiet and isatty is not None and isatty()
                    else None)

    def _print(self, text: str) -> None:
        if self.bar is not None:
            self.bar.clear()
        print(text, file=self.stream, flush=True)

    def info(self, message: str) -> None:
        if not self.quiet:
            self._print(f"{PROG}: {message}")

    def warn(self, message: str) -> None:
        self._print(f"{PROG}: warning: {message}")

    def error(self, message: str) -> None:
        self._print(f"{PROG}: error: {message}")

    def progress(self, record: Progress) -> None:
        """Callback for the engine's progress records."""
        if self.bar is not None:
            self.bar.update(record)

    @contextlib.contextmanager
    def stage(self):
        """``with console.stage() as callback:`` a stage reporting through ``callback``.

        The bar ends its line when the stage ends, and is wiped if it raises.
        """
        try:
            yield self.progress
        except BaseException:
            if self.bar is not None:
                self.bar.clear()
            raise
        if self.bar is not None:
            self.bar.finish()

    def run(self, generator):
        """Drive an engine ``iter_*`` generator with the progress bar; return its result."""
        with self.stage() as callback:
            return drive(generator, callback)

    def showwarning(self, message, category, filename, lineno, file=None, line=None):
        """Replacement for :func:`warnings.showwarning`: one ``edgecme: warning:`` line."""
        text = str(message).strip().splitlines()[0] if str(message).strip() else ""
        if not issubclass(category, UserWarning):
            text = f"{category.__name__}: {text}"
        self.warn(text)


def oserror_message(err: OSError) -> str:
    what = err.strerror or first_line(err)
    return f"{what}: {err.filename}" if err.filename else what
