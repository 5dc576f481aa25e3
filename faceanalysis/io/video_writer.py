"""Atomic video output: frames go to a hidden temporary file that is renamed on success.

An interrupted run (exception, Ctrl-C, crash) never leaves a file under the
final name: the temporary file is named ``.<stem>.<random>.partial.<suffix>``
and is removed on failure.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from faceanalysis.io.video import to_bgr_uint8

__all__ = ["VideoWriter"]

log = logging.getLogger(__name__)

# (fourcc, suffix) tried in order when the requested suffix is .mp4.
_FALLBACKS = (("mp4v", ".mp4"), ("MJPG", ".avi"))
_CODEC_FOR_SUFFIX = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG",
                     ".mkv": "MJPG"}


class VideoWriter:
    """Write frames to a video file atomically.

    Parameters
    ----------
    path : path-like
        Final file name; ``.mp4`` (MPEG-4 part 2, ``mp4v``) by default. If no
        ``mp4v`` encoder is available the video is written as Motion-JPEG
        ``.avi`` beside it instead, with a log message; :attr:`path` then holds
        the name actually used.
    fps : float
        Frame rate, positive.
    size : tuple of int
        ``(width, height)`` in pixels of every frame.

    Attributes
    ----------
    path : Path
        The final file (suffix possibly changed by the fallback).
    n_written : int
        Frames written so far.

    Notes
    -----
    Frames may be grey or BGR(A), ``uint8``, ``uint16`` or float in [0, 1]; they
    are converted with :func:`faceanalysis.io.video.to_bgr_uint8`. Closing a writer
    to which no frame was written raises :class:`ValueError` and leaves no file.
    Used as a context manager, the file appears under its final name only if the
    block finishes without an exception.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "overlay.mp4"
    >>> with VideoWriter(out, fps=25, size=(64, 48)) as writer:
    ...     for i in range(5):
    ...         writer.write(np.full((48, 64), 50 * i, np.uint8))
    >>> writer.path.exists(), writer.n_written
    (True, 5)
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int]):
        path = Path(path)
        if not (isinstance(fps, (int, float, np.number)) and not isinstance(fps, bool)
                and np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number, got {fps!r}")
        try:
            width, height = (int(v) for v in size)
        except (TypeError, ValueError):
            raise ValueError(f"size must be (width, height), got {size!r}") from None
        if width < 1 or height < 1:
            raise ValueError(f"size must be positive, got {size!r}")
        self.fps = float(fps)
        self.size = (width, height)
        self.n_written = 0
        self._writer: cv2.VideoWriter | None = None
        self._tmp: Path | None = None
        suffix = path.suffix.lower()
        if suffix in (".mp4", ""):
            candidates = [(fourcc, path.with_suffix(ext)) for fourcc, ext in _FALLBACKS]
        elif suffix in _CODEC_FOR_SUFFIX:
            candidates = [(_CODEC_FOR_SUFFIX[suffix], path)]
        else:
            raise ValueError(f"{path}: unsupported video suffix {path.suffix!r}; use "
                             f"{', '.join(sorted(_CODEC_FOR_SUFFIX))}")
        for _, target in candidates:
            if target.exists() and not target.is_file():
                raise ValueError(f"{target} exists and is not a regular file; refusing to "
                                 "replace it")
        path.parent.mkdir(parents=True, exist_ok=True)
        for fourcc, target in candidates:
            tmp = self._temp_name(target)
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), self.fps,
                                     self.size, True)
            if writer.isOpened():
                if target != path:
                    log.info("no %s encoder for %s; writing Motion-JPEG %s instead",
                             candidates[0][0], path, target)
                self._writer, self._tmp, self.path, self.fourcc = writer, tmp, target, fourcc
                break
            writer.release()
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        else:
            raise ValueError(f"{path}: no video encoder available "
                             f"(tried {', '.join(f for f, _ in candidates)})")

    @staticmethod
    def _temp_name(target: Path) -> Path:
        fd, name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{target.suffix}",
                                    dir=target.parent)
        os.close(fd)
        return Path(name)

    def write(self, frame) -> None:
        """Append one frame (``(H, W)`` or ``(H, W, 3|4)``, any supported dtype)."""
        if self._writer is None:
            raise ValueError(f"{self.path}: writer is closed")
        image = to_bgr_uint8(frame)
        if (image.shape[1], image.shape[0]) != self.size:
            raise ValueError(f"{self.path}: frame {self.n_written} is "
                             f"{image.shape[1]}x{image.shape[0]}, expected "
                             f"{self.size[0]}x{self.size[1]}")
        self._writer.write(image)
        self.n_written += 1

    def close(self) -> Path:
        """Finish the file and move it to :attr:`path`; returns the path.

        Raises
        ------
        ValueError
            If no frame was written (nothing is left on disk).
        """
        if self._writer is None:
            return self.path
        self._writer.release()
        self._writer = None
        tmp, self._tmp = self._tmp, None
        if self.n_written == 0 or tmp.stat().st_size == 0:
            tmp.unlink()
            raise ValueError(f"{self.path}: no frames were written; no video created")
        os.replace(tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the partial file; the final file (if any, from an earlier run) is untouched."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                self._tmp.unlink()
            self._tmp = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __del__(self):
        # A writer dropped without close() must not leave a temporary file behind.
        with contextlib.suppress(Exception):
            self.abort()
