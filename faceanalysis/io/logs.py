"""Logging helpers shared by the commands and the library."""

from __future__ import annotations

import contextlib
import logging

__all__ = ["quiet_logger"]


@contextlib.contextmanager
def quiet_logger(name: str, level: int):
    """Raise the logger ``name``'s level to at least ``level`` for the duration of a block.

    Examples
    --------
    >>> with quiet_logger("faceanalysis", logging.ERROR):
    ...     logging.getLogger("faceanalysis").level
    40
    """
    log = logging.getLogger(name)
    previous = log.level
    log.setLevel(max(int(level), previous))
    try:
        yield
    finally:
        log.setLevel(previous)
