"""Video writing with OpenCV: .mp4 (mp4v) when the codec works, else .avi (MJPG).

Files are written to a temporary name beside the target and renamed on success, so an
interrupted run never leaves a file that looks complete.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

__all__ = ["VideoWriter", "atomic_write_bytes", "atomic_write_text"]

log = logging.getLogger(__name__)


def _tmp_beside(target: Path) -> Path:
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{target.suffix}",
                                dir=target.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(name, 0o666 & ~umask)      # mkstemp makes 0600; give the usual permissions
    return Path(name)


def atomic_write_bytes(target, data: bytes) -> Path:
    """Write ``data`` to ``target`` through a temporary file and an atomic rename."""
    target = Path(target)
    tmp = _tmp_beside(target)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return target


def atomic_write_text(target, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``target`` atomically."""
    return atomic_write_bytes(target, text.encode("utf-8"))


class VideoWriter:
    """Write RGB (or grey) uint8 frames to ``stem.mp4``, falling back to ``stem.avi``.

    Parameters
    ----------
    path : path-like
        Target file; its suffix is replaced by the container actually used
        (``.mp4`` with the ``mp4v`` codec, else ``.avi`` with ``MJPG``).
    fps : float
    size : (width, height)
    codecs : sequence of (suffix, fourcc)
        Tried in order.

    Attributes
    ----------
    path : Path
        The file written (known after the first frame is accepted).
    note : str or None
        Why a fallback was used, if it was.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with VideoWriter(d / "v.mp4", 10, (32, 24)) as w:
    ...     for i in range(3):
    ...         w.write(np.full((24, 32, 3), 40 * i, np.uint8))
    >>> w.path.exists() and w.frames == 3
    True
    """

    def __init__(self, path, fps: float, size, *, codecs=((".mp4", "mp4v"), (".avi", "MJPG"))):
        if fps <= 0:
            raise ValueError(f"fps={fps} must be positive")
        w, h = (int(v) for v in size)
        if w < 1 or h < 1:
            raise ValueError(f"video size {size} must be positive")
        self.target = Path(path)
        self.fps = float(fps)
        self.size = (w, h)
        self.codecs = tuple(codecs)
        self.note: str | None = None
        self.frames = 0
        self._writer = None
        self._tmp: Path | None = None
        self.path: Path | None = None
        self._open()

    def _open(self) -> None:
        failures = []
        for suffix, fourcc in self.codecs:
            target = self.target.with_suffix(suffix)
            tmp = _tmp_beside(target)
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), self.fps,
                                     self.size, True)
            if writer.isOpened():
                # probe: some builds open but fail on the first frame
                self._writer, self._tmp, self.path = writer, tmp, target
                if failures:
                    self.note = (f"codec {failures[0]} unavailable; wrote {target.name} "
                                 f"({fourcc}) instead")
                    log.warning(self.note)
                return
            writer.release()
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            failures.append(f"{fourcc} ({suffix})")
        raise ValueError(f"no video codec works here (tried {', '.join(failures)})")

    def write(self, frame: np.ndarray) -> None:
        """Append one RGB (H, W, 3) or grey (H, W) uint8 frame."""
        if self._writer is None:
            raise ValueError("the video writer is closed")
        f = np.asarray(frame)
        if f.dtype != np.uint8:
            raise ValueError(f"frames must be uint8, got {f.dtype}")
        if f.shape[:2] != (self.size[1], self.size[0]):
            raise ValueError(f"frame shape {f.shape[:2]} differs from the video's "
                             f"{(self.size[1], self.size[0])}")
        bgr = cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f[..., ::-1]
        self._writer.write(np.ascontiguousarray(bgr))
        self.frames += 1

    def close(self, *, keep: bool = True) -> None:
        """Finish the file (renamed into place when ``keep``) or discard it."""
        if self._writer is None:
            return
        self._writer.release()
        self._writer = None
        try:
            if keep and self.frames and self._tmp.stat().st_size > 0:
                os.replace(self._tmp, self.path)
            elif keep:
                raise ValueError(f"no frames could be written to {self.path}")
        finally:
            with contextlib.suppress(FileNotFoundError):
                self._tmp.unlink()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(keep=exc_type is None)
        return False
