"""Atomic video writing with OpenCV: ``.mp4`` (``mp4v``), else Motion-JPEG ``.avi``.

Frames go to a hidden temporary file beside the target (:func:`synth.files.atomic_path`)
that is renamed on success, so an interrupted run (exception, Ctrl-C, crash) never leaves
a file under the final name. :class:`VideoWriter` takes RGB frames by default (the
renderer's order) and BGR ones (OpenCV's) with ``channel_order='bgr'``.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from synth.files import atomic_path

__all__ = ["VideoWriter", "to_uint8"]

log = logging.getLogger(__name__)

_CHANNEL_ORDERS = ("rgb", "bgr")
# (suffix, fourcc) tried in order for a .mp4 (or suffix-less) target.
_FALLBACKS = ((".mp4", "mp4v"), (".avi", "MJPG"))
_CODEC_FOR_SUFFIX = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG",
                     ".mkv": "MJPG"}
_CODEC_NAMES = {"mp4v": "MPEG-4 part 2", "MJPG": "Motion-JPEG"}


class _Aborted(Exception):
    """Thrown into :func:`~synth.files.atomic_path` to drop the temporary file."""


def to_uint8(frame) -> np.ndarray:
    """Convert a grey or colour frame of any supported pixel type to 8 bits.

    Parameters
    ----------
    frame : array_like
        ``(H, W)`` or ``(H, W, 1)`` grey, ``(H, W, 2)`` grey + alpha, ``(H, W, 3)``
        colour or ``(H, W, 4)`` colour + alpha, in any channel order (kept). Integer
        frames are scaled by 255 over the largest value of their type (``uint16``: by
        1/257, full range), booleans to 0 or 255, floats are taken to be in [0, 1]:
        multiplied by 255, rounded and clipped (NaN gives 0). Not modified.

    Returns
    -------
    ndarray
        ``(H, W)`` grey or ``(H, W, 3)`` colour ``uint8``; alpha is dropped. A
        ``uint8`` frame comes back as a view of the input, not a copy.

    Raises
    ------
    ValueError
        For another shape, or a pixel type that is neither integer, boolean nor float.

    Examples
    --------
    >>> import numpy as np
    >>> to_uint8(np.array([[0, 257, 65535]], np.uint16)).tolist()
    [[0, 1, 255]]
    >>> to_uint8(np.array([[-0.5, 0.5, 2.0]])).tolist()
    [[0, 128, 255]]
    >>> to_uint8(np.zeros((4, 6, 4), np.float32)).shape
    (4, 6, 3)
    """
    image = np.asarray(frame)
    if image.ndim == 3 and image.shape[2] in (1, 2):
        image = image[..., 0]
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        image = image[..., :3]
    elif image.ndim != 2:
        raise ValueError(f"a frame must be (H, W) grey or (H, W, 3|4) colour, "
                         f"got shape {image.shape}")
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.bool_:
        scale = 1.0
    elif np.issubdtype(image.dtype, np.integer):
        scale = float(np.iinfo(image.dtype).max)
    elif np.issubdtype(image.dtype, np.floating):
        scale = 1.0
    else:
        raise ValueError(f"unsupported pixel type {image.dtype}; use integer or float frames")
    values = np.nan_to_num(image.astype(np.float64) * (255.0 / scale), nan=0.0)
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


class VideoWriter:
    """Write frames to a video file atomically.

    Parameters
    ----------
    path : path-like
        Final file name. ``.mp4`` (or no suffix) asks for MPEG-4 part 2 (``mp4v``) and
        falls back to Motion-JPEG ``.avi`` beside it when no ``mp4v`` encoder is
        available; ``.m4v`` and ``.mov`` use ``mp4v``, ``.avi`` and ``.mkv`` ``MJPG``,
        without fallback. :attr:`path` holds the name actually used.
    fps : float
        Frame rate, positive.
    size : tuple of int
        ``(width, height)`` in pixels of every frame.
    channel_order : {'rgb', 'bgr'}, keyword-only
        Order of the colour channels of the frames given to :meth:`write`: ``'rgb'``
        (default; the renderer's order) or ``'bgr'`` (OpenCV's). Grey frames are grey
        either way.
    codecs : sequence of (suffix, fourcc), keyword-only
        Containers and codecs to try in order instead of those chosen from the suffix of
        ``path``; the suffix of ``path`` is replaced by the one that works.

    Attributes
    ----------
    path : Path
        The final file (suffix possibly changed by the fallback).
    fourcc : str
        The codec used.
    n_written : int
        Frames written so far.
    note : str or None
        Why a fallback was used, if it was (also logged at INFO level).

    Raises
    ------
    ValueError
        For a bad ``fps``, ``size``, ``channel_order``, ``codecs`` or suffix, when a
        target exists and is not a regular file (a folder...), or when no codec works.

    Notes
    -----
    Frames may be grey, grey + alpha, colour or colour + alpha, ``uint8``, ``uint16``
    (or any integer type) or float in [0, 1]; see :func:`to_uint8`. Closing a writer to
    which no frame was written raises :class:`ValueError` and leaves no file. Used as a
    context manager, the file appears under its final name only if the block finishes
    without an exception; otherwise (and after :meth:`abort`, or when the writer is
    dropped unclosed) the temporary file is removed and an earlier file under the final
    name is left as it was.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "overlay.mp4"
    >>> with VideoWriter(out, fps=25, size=(64, 48)) as writer:
    ...     for i in range(5):
    ...         writer.write(np.full((48, 64, 3), (50 * i, 0, 0), np.uint8))  # reds
    >>> writer.path.exists(), writer.n_written
    (True, 5)

    OpenCV images (BGR), 16-bit here:

    >>> with VideoWriter(out, 25, (64, 48), channel_order="bgr") as writer:
    ...     writer.write(np.full((48, 64, 3), (0, 0, 65535), np.uint16))  # red
    >>> writer.close() == out
    True
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], *,
                 channel_order: str = "rgb", codecs=None):
        self._writer: cv2.VideoWriter | None = None
        self._commit = None            # the atomic_path context of the temporary file
        self._tmp: Path | None = None
        self._aborted = False
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
        if channel_order not in _CHANNEL_ORDERS:
            raise ValueError(f"channel_order must be one of "
                             f"{', '.join(map(repr, _CHANNEL_ORDERS))}, got {channel_order!r}")
        self.fps = float(fps)
        self.size = (width, height)
        self.channel_order = channel_order
        self.n_written = 0
        self.note: str | None = None
        self.path = path
        candidates = self._candidates(path, codecs)
        for target, _ in candidates:
            if target.exists() and not target.is_file():
                raise ValueError(f"{target} exists and is not a regular file; refusing to "
                                 "replace it")
        failed = []
        for target, fourcc in candidates:
            commit = atomic_path(target)
            tmp = commit.__enter__()
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), self.fps,
                                     self.size, True)
            if writer.isOpened():
                self._writer, self._commit, self._tmp = writer, commit, tmp
                self.path, self.fourcc = target, fourcc
                break
            writer.release()
            commit.__exit__(_Aborted, _Aborted(), None)
            failed.append(f"{fourcc} ({target.suffix})")
        else:
            raise ValueError(f"{path}: no video encoder available (tried {', '.join(failed)})")
        if failed:
            self.note = (f"codec {failed[0]} unavailable for {path.name}; wrote "
                         f"{self.path.name} with {fourcc} "
                         f"({_CODEC_NAMES.get(fourcc, 'fallback')}) instead")
            log.info("%s", self.note)

    @staticmethod
    def _candidates(path: Path, codecs) -> list[tuple[Path, str]]:
        if codecs is not None:
            try:
                out = [(path.with_suffix(suffix), str(fourcc)) for suffix, fourcc in codecs]
            except (TypeError, ValueError):
                raise ValueError(f"codecs must be (suffix, fourcc) pairs, got {codecs!r}") from None
            if not out or any(len(fourcc) != 4 for _, fourcc in out):
                raise ValueError(f"codecs must be (suffix, fourcc) pairs with four-letter "
                                 f"codes, got {codecs!r}")
            return out
        suffix = path.suffix.lower()
        if suffix in (".mp4", ""):
            return [(path.with_suffix(ext), fourcc) for ext, fourcc in _FALLBACKS]
        if suffix in _CODEC_FOR_SUFFIX:
            return [(path, _CODEC_FOR_SUFFIX[suffix])]
        raise ValueError(f"{path}: unsupported video suffix {path.suffix!r}; use "
                         f"{', '.join(sorted(_CODEC_FOR_SUFFIX))}")

    def write(self, frame) -> None:
        """Append one frame: ``(H, W)`` or ``(H, W, 1|2|3|4)``, any supported type.

        Raises
        ------
        ValueError
            If the frame is not ``size``, has an unsupported shape or type, or the
            writer is closed.
        """
        if self._writer is None:
            raise ValueError(f"{self.path}: writer is closed")
        image = to_uint8(frame)
        if (image.shape[1], image.shape[0]) != self.size:
            raise ValueError(f"{self.path}: frame {self.n_written} is "
                             f"{image.shape[1]}x{image.shape[0]}, expected "
                             f"{self.size[0]}x{self.size[1]}")
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        elif self.channel_order == "rgb":
            image = np.ascontiguousarray(image[..., ::-1])
        else:
            image = np.ascontiguousarray(image)
        self._writer.write(image)
        self.n_written += 1

    def close(self) -> Path:
        """Finish the file and move it to :attr:`path`; returns the path.

        Closing again returns the path again.

        Raises
        ------
        ValueError
            If no frame was written (nothing is left on disk), or after :meth:`abort`.
        """
        if self._aborted:
            raise ValueError(f"{self.path}: writer was aborted; no video created")
        if self._writer is None:
            return self.path
        self._writer.release()
        self._writer = None
        commit, self._commit = self._commit, None
        if self.n_written == 0 or self._tmp.stat().st_size == 0:
            commit.__exit__(_Aborted, _Aborted(), None)
            raise ValueError(f"{self.path}: no frames were written; no video created")
        commit.__exit__(None, None, None)
        return self.path

    def abort(self) -> None:
        """Drop the partial file; the final file (if any, from an earlier run) is untouched.

        Does nothing after :meth:`close`.
        """
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._commit is not None:
            commit, self._commit = self._commit, None
            self._aborted = True
            commit.__exit__(_Aborted, _Aborted(), None)

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
