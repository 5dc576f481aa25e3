"""Options shared by several subcommands, defined once."""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path


class UsageError(ValueError):
    """Arguments that are each valid but do not go together (e.g. ``--end`` before ``--start``).

    :func:`faceanalysis.cli.main.main` reports it as argparse does: the command's usage
    line, the message, exit status 2.
    """


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (frame rates, thresholds)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0 (weights)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def image_point(text: str) -> tuple[float, float]:
    """argparse type: a point ``X,Y`` of two finite numbers (pixels)."""
    parts = text.replace(" ", "").split(",")
    try:
        x, y = (float(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be X,Y (two numbers, pixels), got {text!r}"
                                         ) from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"must be two finite numbers, got {text!r}")
    return x, y


def non_negative_int(text: str) -> int:
    """argparse type: a whole number >= 0 (frame numbers, seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1 (counts of frames, workers, identities)."""
    value = non_negative_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_output_options(parser: argparse.ArgumentParser, *, required: bool = True) -> None:
    """``-o/--output`` and ``--overwrite``: results are never overwritten silently."""
    parser.add_argument("-o", "--output", type=Path, required=required, metavar="OUT",
                        help="output folder")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results already in OUT")


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar, warnings and errors only")


def progress_wanted(args: argparse.Namespace) -> bool:
    """A progress bar on stderr: unless ``--quiet``, and only on a terminal. Redrawn in
    place, a bar written to a log file or a pipe (a batch job's, CI's) leaves a line of
    control characters per update between the warnings."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a record is emitted.

    ``logging.StreamHandler()`` keeps the stream it was made with: after ``main`` ran under
    a replaced stderr (``contextlib.redirect_stderr``, a notebook's, pytest's capture)
    every later record of the process went to that stream, closed by then, and printed
    "--- Logging error ---" instead of the message.
    """

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


#: The toolkit's own loggers, which ``-v`` opens to debug messages.
OWN_LOGGERS = ("faceanalysis", "trackers", "synth")


def configure_logging(verbosity: int = 0, quiet: bool = False) -> None:
    """Logs go to stderr so that stdout stays clean for tables and JSON.

    ``-v`` shows the toolkit's own debug messages, ``-vv`` every library's too (one -v
    printed some 200 lines of Matplotlib's font matching for each plot).
    """
    level = logging.WARNING if quiet else (logging.DEBUG if verbosity > 1 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s: %(message)s", force=True,
                        handlers=[_StderrHandler()])
    own = logging.DEBUG if verbosity == 1 and not quiet else logging.NOTSET
    for name in OWN_LOGGERS:
        logging.getLogger(name).setLevel(own)
