"""Input options shared by the subcommands that read a video: VIDEO, --fps, --start, --end.

Not a subcommand (it is not listed in ``SUBCOMMANDS``); subcommands call
:func:`add_input_options` from ``configure`` and :func:`open_input` from ``run``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from faceanalysis.cli._common import UsageError, non_negative_int, positive_float

if TYPE_CHECKING:
    from faceanalysis.io.video import VideoSource


def add_input_options(parser: argparse.ArgumentParser, *, positional: bool = True) -> None:
    """Add ``VIDEO`` (unless ``positional`` is false), ``--fps``, ``--start`` and ``--end``."""
    if positional:
        parser.add_argument("video", type=Path, metavar="VIDEO",
                            help="video file (anything OpenCV/FFmpeg reads), folder of images "
                                 "(png, jpg, tif, bmp; natural order) or a single image")
    group = parser.add_argument_group("input")
    group.add_argument("--fps", type=positive_float, metavar="FPS",
                       help="frame rate; overrides the container's and sets timestamps to "
                            "frame/FPS (image folders: 30 by default)")
    group.add_argument("--start", type=non_negative_int, default=0, metavar="FRAME",
                       help="first frame to analyse, 0-based (default 0)")
    group.add_argument("--end", type=non_negative_int, metavar="FRAME",
                       help="stop before this frame (exclusive; default: the last frame)")
    parser.set_defaults(_usage_checks=(check_input_options,))


def check_input_options(args: argparse.Namespace) -> None:
    """Refuse options of :func:`add_input_options` that do not go together.

    Raises
    ------
    UsageError
        If ``--end`` is not after ``--start``.
    """
    start, end = getattr(args, "start", 0) or 0, getattr(args, "end", None)
    if end is not None and end <= start:
        raise UsageError(f"--end {end} must be after --start {start} (the range "
                         "[start, end) would hold no frame)")


def open_input(args: argparse.Namespace, *, path: Path | None = None,
               any_size: bool = False) -> VideoSource:
    """Open ``args.video`` (or ``path``) with the options of :func:`add_input_options`;
    frames smaller than a face is looked for in are refused unless ``any_size``."""
    # the decoder (OpenCV, NumPy) loads here, not with the command line: ``--help`` and
    # ``--version`` stay instant
    from faceanalysis.io.video import MIN_FACE_SIZE, open_video

    return open_video(path if path is not None else args.video, fps=args.fps,
                      start=args.start, end=args.end,
                      min_size=None if any_size else MIN_FACE_SIZE)
