"""Entry point of the ``faceanalysis`` command.

Each subcommand is a module of this package exposing ``HELP`` (one line),
``configure(parser)`` and ``run(args) -> int``. Commands stay thin: they translate
arguments and call the library. Exit codes: 0 success, 1 failure (a one-line
message, no traceback), 2 usage error (argparse), 130 interrupted (Ctrl-C), 143
terminated (SIGTERM: ``timeout``, a job scheduler). SIGTERM is turned into an exception
like Ctrl-C, so that the same clean-up runs: temporary files are removed and a folder
created for a run that wrote nothing is removed again.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from faceanalysis._version import __version__
from faceanalysis.errors import FaceAnalysisError

# Subcommand name -> module under faceanalysis.cli. Order is the order of --help.
SUBCOMMANDS: dict[str, str] = {
    "analyze": "analyze",
    "demo": "demo",
    "evaluate": "evaluate",
    "info": "info",
    "models": "models",
    "batch": "batch",
    "probe": "probe",
    "synth": "synth",
    "templates": "templates",
    "validate": "validate",
    "classify": "classify",
    "resynth": "resynth",
}


def _signal_in_chain(exc: BaseException):
    """Terminated or KeyboardInterrupt when one of them caused ``exc``, else None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, Terminated):
            return Terminated
        if isinstance(exc, KeyboardInterrupt):
            return KeyboardInterrupt
        exc = exc.__cause__ or exc.__context__
    return None


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that ``finally`` blocks and context managers
    clean up as they do for Ctrl-C (a ``KeyboardInterrupt``)."""


@contextlib.contextmanager
def _sigterm_raises():
    """Raise :class:`Terminated` on SIGTERM for the duration of the block.

    Only the first SIGTERM raises; later ones are ignored until the block ends, so that
    the clean-up it started can finish (``kill -9`` still stops the process at once).
    Nothing is changed outside the main thread, or where SIGTERM is ignored already.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous is signal.SIG_IGN:
        yield
        return

    def handler(signum, frame):
        if frame is not None and (frame.f_code.co_filename.startswith("<frozen importlib")
                                  or frame.f_code.co_name == "__del__"):
            # an exception raised here can be swallowed (the import lock's weakref
            # callback, a finaliser ignore it) and the run would go on to the end:
            # deliver the signal again a moment later, outside them
            threading.Timer(0.01, os.kill, (os.getpid(), signum)).start()
            return
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated(signum)

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: every subcommand's options, or, with ``only``, those of
    that subcommand alone (the others listed with their help line; ``""``: none), so that a
    command loads what its options name (estimators, flow methods, renderers) and
    ``--help`` and ``--version`` load nothing of the kind."""
    parser = argparse.ArgumentParser(
        prog="faceanalysis",
        description="Analyse facial motion in video into muscle contractions, resynthesise "
                    "it with a physics-based face model, and validate the loop.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"faceanalysis {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output on stderr: the toolkit's debug messages (-vv: every "
                             "library's too)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name, module_name in SUBCOMMANDS.items():
        module = importlib.import_module(f"faceanalysis.cli.{module_name}")
        sp = sub.add_parser(name, help=module.HELP,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        if only is None or only == name:
            module.configure(sp)
        sp.set_defaults(_run=module.run, _parser=sp)
    return parser


def _command(argv: list[str]) -> str:
    """The subcommand ``argv`` names (its first argument not an option: the top-level
    options take no value), or ``""`` where it names none of :data:`SUBCOMMANDS`."""
    first = next((a for a in argv if not a.startswith("-")), "")
    return first if first in SUBCOMMANDS else ""


def _message(exc: BaseException) -> str:
    """One line for an error; OSErrors name their path instead of ``[Errno N]``."""
    if isinstance(exc, OSError) and exc.errno is not None and exc.filename is not None:
        path = Path(exc.filename)
        if exc.errno == errno.ENOTDIR:
            blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
            if blocking is not None:
                return f"{path}: {blocking} is a file, not a folder"
            return f"{path}: a part of this path is a file, not a folder"
        return f"{path}: {exc.strerror or type(exc).__name__}"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=_command(argv))
    args = parser.parse_args(argv)
    if getattr(args, "_run", None) is None:
        parser.print_help(sys.stderr)
        return 2
    from faceanalysis.cli._common import UsageError, configure_logging

    try:
        for check in getattr(args, "_usage_checks", ()):
            check(args)
    except UsageError as exc:
        args._parser.error(str(exc))  # usage line and message on stderr, exit 2
    configure_logging(args.verbose, getattr(args, "quiet", False))
    try:
        with _sigterm_raises():
            return int(args._run(args) or 0)
    except UsageError as exc:
        args._parser.error(str(exc))
    except Terminated:
        print("faceanalysis: terminated (SIGTERM)", file=sys.stderr)
        return 128 + int(signal.SIGTERM)
    except (FaceAnalysisError, ValueError, FileNotFoundError, FileExistsError,
            NotADirectoryError, IsADirectoryError, PermissionError) as exc:
        message = _message(exc)
        print(f"faceanalysis: error: {message}", file=sys.stderr)
        logging.getLogger(__name__).debug("details", exc_info=True)
        return 1
    except KeyboardInterrupt:
        print("faceanalysis: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        # a signal that arrives inside compiled code (a Numba dispatcher loading its
        # cache) comes back wrapped, e.g. as a SystemError whose context is ours
        signalled = _signal_in_chain(exc)
        if signalled is Terminated:
            print("faceanalysis: terminated (SIGTERM)", file=sys.stderr)
            return 128 + int(signal.SIGTERM)
        if signalled is KeyboardInterrupt:
            print("faceanalysis: interrupted", file=sys.stderr)
            return 130
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
