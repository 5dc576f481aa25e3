"""Options shared by several subcommands, defined once."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path


def add_output_options(parser: argparse.ArgumentParser, *, required: bool = True) -> None:
    """``-o/--output`` and ``--overwrite``: results are never overwritten silently."""
    parser.add_argument("-o", "--output", type=Path, required=required, metavar="OUT",
                        help="output folder")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results already in OUT")


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar, warnings and errors only")


def configure_logging(verbosity: int = 0, quiet: bool = False) -> None:
    """Logs go to stderr so that stdout stays clean for tables and JSON."""
    level = logging.WARNING if quiet else (logging.DEBUG if verbosity > 0 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s: %(message)s", force=True)
