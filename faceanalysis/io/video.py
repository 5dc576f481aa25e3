"""Streaming frame input: video files that OpenCV can read, folders of images, and frames
already in memory.

:func:`open_video` returns a :class:`VideoSource`, an iterable of :class:`Frame` objects
that decodes one frame at a time, so memory stays flat however long the video is. Frames
already in memory (an array, or a list of arrays, in RGB as imageio and scikit-image read
them) come in as :class:`Frames`. Frame rate and timestamps come from the container unless
the caller gives ``fps``. Frames that fail to decode in the middle of a stream are yielded
with ``ok=False`` (the caller counts them as lost and goes on); a stream that stops decoding
before the end announced by its container (a truncated file) ends the iteration with a
warning and is recorded in :attr:`VideoSource.missing_tail`.

:mod:`faceanalysis.io.frames` normalises the frames (grey, BGR, BGRA; 8-bit, 16-bit or
float) for the trackers and for drawing. The analysis opens its input with
``eight_bit=True``: every frame is brought to 8 bits where it is read
(:func:`~faceanalysis.io.frames.to_uint8`), so that the same picture stored at 8 or 16
bits gives the same analysis.

:func:`read_ahead` decodes in a background thread while the caller works on the
frames already decoded (decoding releases the interpreter lock, so on a machine with
two cores it costs the analysis almost nothing).
"""

from __future__ import annotations

import logging
import math
import os
import queue
import re
import threading
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

# FFmpeg prints its own decoder complaints straight to stderr ("moov atom not found",
# "marker does not match f_code"); this module reports the same problems through
# logging and one-line errors instead. A user who wants them sets the variable.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from faceanalysis.io.frames import check_float_range, fit_image, to_uint8  # noqa: E402

__all__ = [
    "DEFAULT_FPS",
    "IMAGE_SUFFIXES",
    "MIN_FACE_SIZE",
    "VIDEO_EXTENSIONS",
    "Frame",
    "Frames",
    "VideoSource",
    "as_video",
    "is_photographs",
    "missing_input",
    "open_video",
    "read_ahead",
    "read_image",
]

log = logging.getLogger(__name__)

#: Frame rate assumed for a folder of images (or a video without one) when no ``fps`` is given.
DEFAULT_FPS = 30.0

#: File name suffixes read from an image folder (compared case-insensitively).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
#: File name suffixes taken as videos when a folder or a glob pattern is expanded
#: (camcorders write MPEG transport streams, .mts and .m2ts; older phones .3gp).
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv",
                    ".flv", ".mts", ".m2ts", ".ts", ".3gp", ".ogv")

# Reads tried when opening a video before deciding it has no decodable frame.
_FIRST_FRAME_ATTEMPTS = 250

#: Smallest frame side (pixels) on which the face trackers can work; see ``min_size``.
MIN_FACE_SIZE = 64

# Leading bytes of common video containers: a file that carries one of them but
# that OpenCV cannot open is an empty or damaged video, not "not a video".
_CONTAINER_MAGIC: tuple[tuple[int, bytes], ...] = (
    (4, b"ftyp"), (4, b"moov"), (4, b"mdat"), (4, b"wide"), (4, b"free"), (4, b"skip"),
    (0, b"RIFF"), (0, b"\x1aE\xdf\xa3"), (0, b"\x00\x00\x01\xba"), (0, b"\x00\x00\x01\xb3"),
    (0, b"FLV"), (0, b"OggS"), (0, b"\x30\x26\xb2\x75"),
)


@dataclass(frozen=True)
class Frame:
    """One frame of a :class:`VideoSource`.

    Attributes
    ----------
    index : int
        Frame number in the whole file or folder (0-based), also when ``start > 0``.
    timestamp : float
        Seconds from the start of the file: the container's presentation time
        when it is sane, else ``index / fps``.
    image : ndarray or None
        The pixels as decoded, ``(H, W)`` grey or ``(H, W, 3|4)`` BGR(A), dtype
        ``uint8`` or ``uint16`` (image folders keep their bit depth unless the source
        was opened with ``eight_bit=True``). ``None`` when ``ok`` is false.
    ok : bool
        False when the frame could not be decoded; such a frame is lost, not fatal.
    """

    index: int
    timestamp: float
    image: np.ndarray | None
    ok: bool = True


def is_photographs(input_meta) -> bool:
    """Whether an input (:func:`faceanalysis.io.report.input_metadata`) is taken as
    photographs rather than a video's frames: an image, or a folder of images, given without
    a frame rate. The analysis then reads and fits each on its own (no tracking from the
    last, no temporal prior; each may have its own size), the plot shows one mark per
    photograph instead of a time series, and the overlay shows each for a second.

    Examples
    --------
    >>> is_photographs({"kind": "images", "fps_origin": "default", "frame_count": 3})
    True
    >>> is_photographs({"kind": "images", "fps_origin": "default", "frame_count": 1})
    True
    >>> is_photographs({"kind": "images", "fps_origin": "user", "frame_count": 3})
    False
    >>> is_photographs({"kind": "video", "fps_origin": "container", "frame_count": 3})
    False
    """
    return (isinstance(input_meta, Mapping) and input_meta.get("kind") == "images"
            and input_meta.get("fps_origin") == "default")


class Frames:
    """Frames already in memory, as a video: what :func:`open_video` and the analysis take
    instead of a file.

    Parameters
    ----------
    frames : array_like
        An array ``(T, H, W)`` (grey) or ``(T, H, W, C)`` with ``C`` 3 (RGB) or 4 (RGBA), or
        a sequence of ``T`` arrays ``(H, W)`` / ``(H, W, C)`` of one shape and type; ``uint8``,
        ``uint16``, or floats in [0, 1]. Kept by reference, not copied, and never modified.
    fps : float, optional
        Frame rate (default :data:`DEFAULT_FPS`, which :func:`open_video`'s ``fps``
        overrides).
    channel_order : {'rgb', 'bgr'}, keyword-only
        Colour order: RGB (default) as imageio, scikit-image and PIL give it, or BGR as
        OpenCV's ``VideoCapture`` and ``imread`` do.
    name : str, keyword-only
        What messages call them (default ``"frames"``).

    Examples
    --------
    >>> import numpy as np
    >>> clip = Frames(np.zeros((5, 80, 96, 3), np.uint8), fps=25)
    >>> len(clip), clip.size, str(clip)
    (5, (96, 80), '<frames: 5 frames of 96x80>')
    >>> with open_video(clip, start=1, end=3) as video:
    ...     [(f.index, f.timestamp, f.image.shape) for f in video]
    [(1, 0.04, (80, 96, 3)), (2, 0.08, (80, 96, 3))]
    """

    def __init__(self, frames, fps: float | None = None, *, channel_order: str = "rgb",
                 name: str = "frames"):
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        if isinstance(frames, (str, bytes, os.PathLike)):
            raise ValueError(f"frames must be arrays, not a path ({frames!r}): open a file "
                             "with open_video(path)")
        if isinstance(frames, np.ndarray):
            if frames.ndim not in (3, 4):
                raise ValueError(f"frames must have shape (T, H, W) or (T, H, W, C), got "
                                 f"{frames.shape}")
            if frames.ndim == 3 and frames.shape[2] in (3, 4):
                # a grey video 3 or 4 pixels wide is no face video: one colour picture
                raise ValueError(f"frames of shape {frames.shape} look like one (H, W, C) "
                                 "picture, not a video: pass frames[None] or [picture]")
            items = frames
        else:
            try:
                items = [np.asarray(f) for f in frames]
            except TypeError:
                raise ValueError(f"frames must be an array or a sequence of arrays, got "
                                 f"{type(frames).__name__}") from None
            for i, f in enumerate(items):
                if f.shape != items[0].shape or f.dtype != items[0].dtype:
                    raise ValueError(f"frame {i} is {f.shape} {f.dtype}, frame 0 "
                                     f"{items[0].shape} {items[0].dtype}: every frame must "
                                     "have the same shape and type (photographs of several "
                                     "sizes: analyse the folder they are in, without fps)")
        if len(items) == 0:
            raise ValueError("frames: no frame")
        first = np.asarray(items[0])
        if first.ndim not in (2, 3) or (first.ndim == 3 and first.shape[2] not in (1, 3, 4)):
            raise ValueError(f"each frame must be (H, W) grey or (H, W, 3|4) RGB(A), got "
                             f"{first.shape}")
        if not (first.dtype in (np.uint8, np.uint16) or first.dtype.kind == "f"):
            raise ValueError(f"frames must be uint8, uint16 or floats in [0, 1], got "
                             f"{first.dtype}")
        if first.dtype.kind == "f":
            # the first frame now, so that floats in 0..255 fail at the call; the others
            # are checked as they are read
            try:
                check_float_range(first)
            except ValueError as error:
                raise ValueError(f"frames: frame 0: {error}") from None
        self._items = items
        self.channel_order = channel_order
        self.fps = None if fps is None else _check_fps(fps)
        self.name = str(name)
        self.shape = first.shape
        self.dtype = first.dtype

    def __len__(self) -> int:
        return len(self._items)

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return int(self.shape[1]), int(self.shape[0])

    def __str__(self) -> str:
        return f"<{self.name}: {len(self)} frames of {self.size[0]}x{self.size[1]}>"

    __repr__ = __str__

    def image(self, index: int) -> np.ndarray:
        """Frame ``index`` in OpenCV's layout (grey, BGR or BGRA), as a decoder gives it."""
        # always a new array: what reads the frames may draw on them, the caller's stay
        f = np.asarray(self._items[index])
        if f.ndim == 3 and f.shape[2] == 1:
            return f[:, :, 0].copy()
        if f.ndim == 3 and self.channel_order == "rgb":
            code = cv2.COLOR_RGB2BGR if f.shape[2] == 3 else cv2.COLOR_RGBA2BGRA
            if f.dtype.kind == "f" and f.dtype != np.float32:
                return np.ascontiguousarray(f[..., [2, 1, 0, 3][:f.shape[2]]])
            return cv2.cvtColor(np.ascontiguousarray(f), code)
        return f.copy()


def as_video(video):
    """``video`` as :func:`open_video` and the analysis take it: frames in memory (an
    array, a sequence of arrays) as :class:`Frames`; a path or :class:`Frames` as given."""
    if isinstance(video, (str, bytes, os.PathLike, Frames)):
        return video
    return Frames(video)


def _natural_key(name: str) -> list:
    """Sort key that orders ``img2`` before ``img10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def _looks_like_container(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head[:1] == b"\x47" and path.suffix.lower() in (".ts", ".m2ts", ".mts"):
        return True
    return any(head[offset:offset + len(magic)] == magic for offset, magic in _CONTAINER_MAGIC)


def _not_a_video(path: Path) -> str | None:
    """What ``path`` is where its first bytes announce a format that holds no video OpenCV
    reads (a video container may hold sound too: only formats without pictures count, and
    the still-image containers of phones), else None."""
    with open(path, "rb") as fh:
        head = fh.read(12)
    brand = head[8:12] if head[4:8] == b"ftyp" else b""
    audio = ("WAVE" if head[:4] == b"RIFF" and head[8:12] == b"WAVE"
             else "MP3" if head[:3] == b"ID3"       # its tag (a bare frame sync is too weak)
             else "FLAC" if head[:4] == b"fLaC"
             else "MPEG-4 audio" if brand in (b"M4A ", b"M4B ", b"M4P ", b"F4A ")
             else None)
    if audio is not None:
        return f"an audio file ({audio}): it holds no video"
    if brand in (b"heic", b"heix", b"heim", b"heis", b"hevc", b"mif1", b"msf1", b"avif",
                 b"avis"):
        return (f"a HEIF/AVIF image ({brand.decode()}, as phones take photographs), which "
                "OpenCV cannot read: convert it to JPEG or PNG")
    return None


def _check_fps(fps) -> float:
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) \
            or not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    return float(fps)


def _check_int(value, name: str, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


class VideoSource:
    """Frames of a video file or of an image folder, decoded one at a time.

    Do not instantiate directly; use :func:`open_video`. Iterating yields
    :class:`Frame` objects for the frames ``start <= index < end``; each
    iteration starts again from ``start``. The source is also a context
    manager: leaving the ``with`` block releases any decoder still open.

    Frames before ``start`` are decoded and dropped rather than seeked over,
    because seeking is not frame-accurate for every codec; a large ``start``
    therefore costs decoding time. Timestamps are the container's presentation
    times when they increase, else the previous one plus ``1 / fps``; with a
    user-given ``fps`` they are ``index / fps``.

    Attributes
    ----------
    path : Path or None
        The file or folder; None for frames in memory.
    kind : {'video', 'images', 'frames'}
        What ``path`` is: a video file, or an image folder (or a single image); 'frames':
        frames in memory (:class:`Frames`).
    name : str
        What messages call the input: the path, or the frames' label.
    fps : float
        Frame rate used for timestamps that the container does not give.
    fps_origin : {'user', 'container', 'default'}
        Where ``fps`` came from.
    size : tuple of int
        ``(width, height)`` in pixels of the first frame.
    dtype : numpy dtype
        Pixel type of the first frame as stored (``uint8`` for videos, ``uint8`` or
        ``uint16`` for images), also when ``eight_bit`` converts the frames.
    eight_bit : bool
        Frames are delivered as ``uint8`` (:func:`faceanalysis.io.frames.to_uint8`).
    channels : int
        1 (grey), 3 (BGR) or 4 (BGRA) for the first frame.
    start, end : int, int or None
        The frame range; ``end`` is exclusive and ``None`` means "to the end".
    frame_count : int or None
        Frames in the whole file as announced by the container (exact for folders);
        ``None`` when unknown.
    n_failed : int
        Frames that could not be decoded so far (mid-stream ones and the missing tail).
    missing_tail : int
        Frames announced by the container at the end of the range that never decoded
        (a truncated or damaged file); counted in ``n_failed``, not yielded.
    placed : dict
        Photographs of another size than the first, so far: frame index -> ``file``,
        its own ``size``, and the ``scale`` and ``offset`` that placed it on the first's
        canvas (:func:`faceanalysis.io.frames.fit_image`); their pixel coordinates are
        the canvas's. (Frames of a video of another size are lost instead.)
    """

    def __init__(self, path: Path, kind: str, *, fps: float, fps_origin: str, size: tuple,
                 dtype: np.dtype, channels: int, start: int, end: int | None,
                 frame_count: int | None, files: list[Path] | None = None,
                 eight_bit: bool = False, frames: Frames | None = None):
        self.path = path
        self._frames = frames
        self.eight_bit = bool(eight_bit)
        self.kind = kind
        self.fps = fps
        self.fps_origin = fps_origin
        self.size = size
        self.dtype = dtype
        self.channels = channels
        self.start = start
        self.end = end
        self.frame_count = frame_count
        self.n_failed = 0
        self.missing_tail = 0
        self.placed: dict[int, dict] = {}
        self._files = files
        self._capture: cv2.VideoCapture | None = None

    # -- properties -------------------------------------------------------------------------
    @property
    def n_frames(self) -> int | None:
        """Frames in the range ``[start, end)`` as announced; ``None`` when unknown.

        For videos this comes from the container and is an estimate: a damaged
        file may deliver fewer frames (see :attr:`missing_tail`).
        """
        stop = self.end if self.end is not None else self.frame_count
        return None if stop is None else max(stop - self.start, 0)

    @property
    def photographs(self) -> bool:
        """Images given without a frame rate: photographs, each fitted on its own, which
        may each have their own size (:func:`is_photographs`)."""
        return is_photographs({"kind": self.kind, "fps_origin": self.fps_origin})

    @property
    def name(self) -> str:
        return str(self._frames) if self._frames is not None else str(self.path)

    def __repr__(self) -> str:
        return (f"VideoSource({self.name!r}, kind={self.kind!r}, size={self.size}, "
                f"fps={self.fps:g}, start={self.start}, end={self.end}, "
                f"n_frames={self.n_frames})")

    def __len__(self) -> int:
        n = self.n_frames
        if n is None:
            raise TypeError(f"{self.name}: the number of frames is unknown")
        return n

    # -- context manager --------------------------------------------------------------------
    def __enter__(self) -> VideoSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the decoder if an iteration left it open."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    # -- iteration --------------------------------------------------------------------------
    def __iter__(self) -> Iterator[Frame]:
        self.n_failed = 0
        self.missing_tail = 0
        self.placed = {}
        if self.kind == "images":
            return self._iter_images()
        if self.kind == "frames":
            return self._iter_frames()
        return self._iter_video()

    def _pixels(self, image: np.ndarray, index: int, file: Path | None = None) -> np.ndarray:
        """``image`` as the frames are delivered; a ValueError names the input and frame."""
        if not self.eight_bit:
            return image
        try:
            return to_uint8(image)
        except ValueError as error:           # floats outside [0, 1]
            where = f"{file} (frame {index})" if file is not None else f"{self.name}: frame {index}"
            raise ValueError(f"{where}: {error}") from None

    def _iter_frames(self) -> Iterator[Frame]:
        stop = len(self._frames) if self.end is None else self.end
        for index in range(self.start, stop):
            image = self._frames.image(index)
            yield Frame(index, index / self.fps, self._pixels(image, index), True)

    def _iter_images(self) -> Iterator[Frame]:
        files = self._files or []
        stop = len(files) if self.end is None else self.end
        width, height = self.size
        for index in range(self.start, stop):
            name = files[index]
            image = read_image(name)
            timestamp = index / self.fps
            if image is None:
                log.warning("%s: cannot decode image; frame %d marked lost", name, index)
            elif image.shape[:2] != (height, width) and self.photographs:
                # photographs may each have their own size: measured on the first's canvas
                own = image.shape[1], image.shape[0]
                image, scale, offset = fit_image(image, (width, height))
                self.placed[index] = {"file": Path(name).name, "size": list(own),
                                      "scale": list(scale), "offset": list(offset)}
            elif image.shape[:2] != (height, width):
                log.warning("%s: image is %dx%d, not %dx%d like the first; frame %d marked lost",
                            name, image.shape[1], image.shape[0], width, height, index)
                image = None
            if image is None:
                self.n_failed += 1
                yield Frame(index, timestamp, None, False)
            else:
                yield Frame(index, timestamp, self._pixels(image, index, name), True)

    def _max_failed_run(self) -> int:
        # Damage can take out a whole group of pictures (up to ~10 s in common encodings).
        return max(250, int(10 * self.fps))

    def _iter_video(self) -> Iterator[Frame]:
        self.close()
        capture = seek_video(self.path, self.start) if self.start >= SEEK_FROM else None
        index = 0 if capture is None else self.start   # the next frame out of the decoder
        if capture is None:
            capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            raise ValueError(f"{self.path}: cannot be opened as a video any more")
        self._capture = capture
        # A frame count from the container can be an estimate: it decides whether failed
        # reads are damage or the end of the file, but only ``end`` stops the reading.
        expected = self.end if self.end is not None else self.frame_count
        use_container_time = self.fps_origin != "user"
        max_run = self._max_failed_run()
        failed_run = 0     # reads that failed since the last good frame
        previous: float | None = None
        n_yielded = 0
        try:
            while self.end is None or index + failed_run < self.end:
                # Frames before start that no seek stepped over are decoded and dropped.
                if index + failed_run < self.start:
                    ok, image = capture.grab(), None
                else:
                    ok, image = capture.read()
                    ok = ok and image is not None
                if not ok:
                    failed_run += 1
                    if failed_run >= max_run or (
                            expected is not None and index + failed_run > expected):
                        break
                    continue
                # Reads that failed before this good one are frames lost mid-stream.
                if failed_run and index + failed_run > self.start:
                    first, last = max(index, self.start), index + failed_run - 1
                    which = f"frame {first}" if first == last else f"frames {first}-{last}"
                    log.warning("%s: %s could not be decoded; marked lost", self.path, which)
                for _ in range(failed_run):
                    if index >= self.start:
                        timestamp = (index / self.fps if previous is None
                                     else previous + 1.0 / self.fps)
                        self.n_failed += 1
                        n_yielded += 1
                        yield Frame(index, timestamp, None, False)
                        previous = timestamp
                    index += 1
                failed_run = 0
                if index < self.start:
                    index += 1
                    continue
                timestamp = self._timestamp(capture, index, previous, use_container_time)
                n_yielded += 1
                yield Frame(index, timestamp, self._pixels(image, index), True)
                previous = timestamp
                index += 1
        finally:
            capture.release()
            if self._capture is capture:
                self._capture = None
        if n_yielded == 0:
            raise ValueError(f"{self.path}: no frame from {self.start} on could be decoded; "
                             f"decoding stops at frame {index}")
        if expected is not None and index < expected:
            self.missing_tail = expected - index
            self.n_failed += self.missing_tail
            level = logging.WARNING if self.missing_tail > 2 else logging.INFO
            log.log(level, "%s: frames %d-%d of %d could not be decoded (truncated or "
                    "damaged file); the analysis ends at frame %d",
                    self.path, index, expected - 1, expected, index - 1)

    def _timestamp(self, capture, index: int, previous: float | None, use_container: bool
                   ) -> float:
        fallback = index / self.fps if previous is None else previous + 1.0 / self.fps
        if not use_container:
            return index / self.fps
        t = capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        if not math.isfinite(t) or t < 0:
            return fallback
        if previous is None:
            # A first timestamp of 0 after skipping frames means the backend has none.
            return fallback if (index > 0 and t == 0.0) else t
        return t if t > previous else fallback


#: Reading a video file from this frame on or later seeks to it (:func:`seek_video`) instead
#: of decoding every frame before it; nearer the start, decoding them costs less than the seek.
SEEK_FROM = 250
# Time stamps (ms) closer than this are the same picture's.
_SAME_MS = 1e-3


def display_stamps(path) -> np.ndarray | None:
    """Time stamps (ms) of a video file's pictures in display order, read from the
    container without decoding (about 7 us a picture): the ``n``-th is frame ``n``'s.

    None where the stamps cannot be trusted to number the frames: the backend is not
    FFmpeg's, a stamp is missing or repeated, or a picture comes before the first one the
    decoder gives (an edit list that drops pictures, or damage at the start).

    Examples
    --------
    >>> import tempfile, cv2, numpy as np
    >>> path = tempfile.mkdtemp() + "/clip.avi"
    >>> writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48))
    >>> for i in range(4):
    ...     writer.write(np.zeros((48, 64, 3), np.uint8))
    >>> writer.release()
    >>> display_stamps(path).tolist()
    [0.0, 40.0, 80.0, 120.0]
    """
    first = cv2.VideoCapture(str(path))
    try:
        if (not first.isOpened() or first.getBackendName() != "FFMPEG"
                or not first.grab()):
            return None
        t0 = first.get(cv2.CAP_PROP_POS_MSEC)
    finally:
        first.release()
    raw = cv2.VideoCapture(str(path))
    try:
        # the encoded pictures as the container stores them, not decoded
        if (not raw.isOpened() or raw.getBackendName() != "FFMPEG"
                or not raw.set(cv2.CAP_PROP_FORMAT, -1)):
            return None
        stamps = []
        while raw.grab():
            stamps.append(raw.get(cv2.CAP_PROP_POS_MSEC))
    finally:
        raw.release()
    stamps = np.sort(np.asarray(stamps, dtype=float))
    if (not len(stamps) or not np.isfinite(stamps).all() or abs(stamps[0] - t0) > _SAME_MS
            or np.any(np.diff(stamps) <= _SAME_MS)):
        return None
    return stamps


def seek_video(path, start: int) -> cv2.VideoCapture | None:
    """A capture of the video file ``path`` whose next read is its frame ``start``
    (0-based, in display order, as decoding from the first frame counts them), or None
    where that cannot be made sure of.

    Decoding every frame before ``start`` costs 0.5 ms a frame at 640x360 and 3 ms at
    1920x1080 (an hour of 30 frames/s video: 1-5 minutes); a seek lands on a keyframe and
    decodes from there. Seeking by frame number is not exact for every file (variable frame
    rates, streams that do not start at time 0), so the frame is found by its time stamp:
    :func:`display_stamps` gives frame ``start - 1``'s, the capture seeks to a second before
    it and reads on until a picture carries exactly that stamp. None (decode from the first
    frame instead) where the stamps cannot be trusted, where the container holds another
    number of pictures than its header counts (damage the demuxer stepped over: reading from
    the first frame then numbers the later frames otherwise than the file's index does), or
    where that stamp is not met.

    Examples
    --------
    >>> import tempfile, cv2, numpy as np
    >>> path = tempfile.mkdtemp() + "/clip.avi"
    >>> writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48))
    >>> for i in range(40):
    ...     writer.write(np.full((48, 64, 3), 6 * i, np.uint8))
    >>> writer.release()
    >>> capture = seek_video(path, 30)
    >>> round(capture.read()[1].mean() / 6)      # frame i was written at grey level 6 i
    30
    """
    start = int(start)
    if start < 1:
        return None
    stamps = display_stamps(path)
    if stamps is None or len(stamps) <= start:
        return None
    capture = cv2.VideoCapture(str(path))
    count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
    if math.isfinite(count) and round(count) == len(stamps):
        target = stamps[start - 1]
        capture.set(cv2.CAP_PROP_POS_MSEC, max(0.0, target - 1000.0))
        while capture.grab():
            t = capture.get(cv2.CAP_PROP_POS_MSEC)
            if abs(t - target) <= _SAME_MS:
                return capture
            if t > target:
                break
    capture.release()
    return None


#: EXIF orientation (tag 274) -> how the stored pixels are turned upright, as numpy ops on
#: an (H, W[, C]) array: 2 mirrored, 3 turned half round, 4 upside down, 5 transposed,
#: 6 to be turned a quarter clockwise, 7 transversed, 8 a quarter anticlockwise.
_UPRIGHT = {
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: np.rot90(a, 2).swapaxes(0, 1),
    8: lambda a: np.rot90(a, 1),
}
_ORIENTATION_TAG = 0x0112


def read_image(path) -> np.ndarray | None:
    """An image file as OpenCV decodes it, unchanged (grey, BGR or BGRA; 8 or 16 bits), and
    upright: turned by its EXIF orientation as a photo viewer shows it (a phone stores a
    portrait photograph on its side with a tag saying so; OpenCV applies the tag only when
    it converts the pixels, not to an image read unchanged). None where it cannot be decoded.

    Examples
    --------
    >>> import tempfile
    >>> from PIL import Image
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     exif = Image.Exif()
    ...     exif[0x0112] = 6                     # stored on its side: turn a quarter clockwise
    ...     Image.new("RGB", (40, 30)).save(f"{tmp}/p.jpg", exif=exif.tobytes())
    ...     read_image(f"{tmp}/p.jpg").shape
    (40, 30, 3)
    """
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        return None
    turn = _UPRIGHT.get(_exif_orientation(path))
    return image if turn is None else np.ascontiguousarray(turn(image))


def _exif_orientation(path) -> int:
    """The EXIF orientation tag of an image file (1, upright, where it has none)."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        # Pillow guards its own decoding against huge images; only the header is read here
        # (OpenCV decodes the pixels), so its size warning and error do not apply
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                return int(im.getexif().get(_ORIENTATION_TAG, 1))
    except (OSError, UnidentifiedImageError, ValueError, TypeError,
            Image.DecompressionBombError):
        return 1


#: The image folders whose videos have been said to be left unread (:func:`_open_images`).
_SAID_VIDEOS_BESIDE: set = set()


def _named(names: list[str], noun: str) -> str:
    """``"2 videos (a.mp4, b.mp4)"``: a count and the first three names."""
    shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
    return f"{len(names)} {noun}{'s' if len(names) != 1 else ''} ({shown})"


#: A URL's scheme, as a path shows it (``Path`` folds ``https://`` to ``https:/``); two
#: letters at least, so that a Windows drive (``C:/``) is not one.
_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+):/+")


def missing_input(path) -> FileNotFoundError:
    """The error for an input ``path`` that does not exist: a URL or stream (which the
    toolkit does not download) is named as one."""
    text = os.fsdecode(path)
    url = _URL.match(text)
    if url:
        text = _URL.sub(lambda m: f"{m.group(1)}://", text, count=1)
        return FileNotFoundError(f"{text}: a URL or stream; the toolkit reads local files "
                                 "(a video, a folder of images, an image): download it first")
    return FileNotFoundError(f"{text}: no such file or folder")


def _open_images(path: Path, fps: float | None) -> dict:
    if path.is_dir():
        entries = [p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")]
        files = sorted((p for p in entries if p.suffix.lower() in IMAGE_SUFFIXES),
                       key=lambda p: _natural_key(p.name))
        videos = sorted((p.name for p in entries if p.suffix.lower() in VIDEO_EXTENSIONS),
                        key=_natural_key)
        if not files:
            heif = sorted(p.name for p in entries
                          if p.suffix.lower() in (".heic", ".heif", ".avif"))
            hint = "" if not heif else (
                f"; its {len(heif)} HEIF/AVIF photograph{'s' if len(heif) > 1 else ''} "
                f"({heif[0]}{', ...' if len(heif) > 1 else ''}), as phones take them, cannot "
                "be read: convert them to JPEG or PNG")
            if videos:
                hint += (f"; it holds {_named(videos, 'video')}: give a video's own path, or "
                         "analyse each with 'faceanalysis batch'")
            raise ValueError(f"{path}: folder holds no images "
                             f"({', '.join(IMAGE_SUFFIXES)}){hint}")
        if videos and (path.resolve(), tuple(videos)) not in _SAID_VIDEOS_BESIDE:
            # a folder of frames is read as one input; a video beside them is not a frame.
            # Said once a process: an analysis opens its input more than once.
            _SAID_VIDEOS_BESIDE.add((path.resolve(), tuple(videos)))
            log.warning("%s: the folder's images are read as the frames (%d); %s in it %s "
                        "not read (give a video's own path to analyse it)", path, len(files),
                        _named(videos, "video"), "is" if len(videos) == 1 else "are")
    else:  # a single image is a one-frame sequence
        files = [path]
    first = None
    for name in files:
        first = read_image(name)
        if first is not None:
            break
    if first is None:
        if files == [path]:
            raise ValueError(f"{path}: cannot decode image")
        raise ValueError(f"{path}: none of its {len(files)} images can be decoded")
    if fps is None and len(files) > 1:
        # (the analysis says what it makes of it: photographs)
        log.debug("%s: no frame rate for an image folder; timestamps at %g fps", path,
                  DEFAULT_FPS)
    return dict(kind="images", fps=DEFAULT_FPS if fps is None else fps,
                fps_origin="default" if fps is None else "user", first=first,
                frame_count=len(files), files=files)


def _open_frames(frames: Frames, fps: float | None) -> dict:
    rate = fps if fps is not None else frames.fps
    if rate is None and len(frames) > 1:
        log.info("%s: no frame rate given; assuming %g fps (fps=...)", frames, DEFAULT_FPS)
    return dict(kind="frames", fps=DEFAULT_FPS if rate is None else rate,
                fps_origin="default" if rate is None else "user", first=frames.image(0),
                frame_count=len(frames), files=None)


def _open_file(path: Path, fps: float | None) -> dict:
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: file is empty (0 bytes)")
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            what = _not_a_video(path)
            if what is not None:
                raise ValueError(f"{path}: {what}")
            if _looks_like_container(path):
                raise ValueError(f"{path}: video has no decodable frames "
                                 "(empty, truncated or damaged)")
            raise ValueError(f"{path}: not a video that OpenCV can read")
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        container_fps = capture.get(cv2.CAP_PROP_FPS)
        frame_count = int(round(count)) if math.isfinite(count) and 0 < count < 2**40 else None
        # The first decodable frame gives the size; damage may hide the first few.
        attempts = min(frame_count or 1, _FIRST_FRAME_ATTEMPTS)
        ok, first = False, None
        for _ in range(attempts):
            ok, first = capture.read()
            if ok and first is not None:
                break
    finally:
        capture.release()
    if not ok or first is None:
        if frame_count is None and count == 0:
            raise ValueError(f"{path}: video has zero frames")
        raise ValueError(f"{path}: video has no decodable frames (empty, truncated or damaged)")
    fps_origin = "user"
    if fps is None:
        if math.isfinite(container_fps) and 0 < container_fps <= 1000:
            fps, fps_origin = float(container_fps), "container"
        else:
            log.warning("%s: the container gives no frame rate; assuming %g fps (use --fps)",
                        path, DEFAULT_FPS)
            fps, fps_origin = DEFAULT_FPS, "default"
    return dict(kind="video", fps=fps, fps_origin=fps_origin, first=first,
                frame_count=frame_count, files=None)


_DONE = object()


class _Failed:
    __slots__ = ("error",)

    def __init__(self, error: Exception):
        self.error = error


def read_ahead(frames: Iterable, depth: int = 4) -> Iterator:
    """Iterate over ``frames`` with up to ``depth`` items produced ahead in a thread.

    The items and their order are those of ``frames``; an exception raised while
    producing them is raised here, at the item where it happened. Memory stays
    bounded: at most ``depth`` items wait. Stopping early (``break``, an exception
    in the loop, closing the generator) stops the thread and closes the iterator of
    ``frames`` (a :class:`VideoSource` then releases its decoder).

    Parameters
    ----------
    frames : iterable
        E.g. a :class:`VideoSource`; its ``iter()`` is called in the thread.
    depth : int
        Items decoded ahead (at least 1).

    Yields
    ------
    The items of ``frames``.

    Examples
    --------
    >>> list(read_ahead(range(5), depth=2))
    [0, 1, 2, 3, 4]
    >>> def broken():
    ...     yield 1
    ...     raise ValueError("frame 1: damaged")
    >>> it = read_ahead(broken())
    >>> next(it)
    1
    >>> next(it)
    Traceback (most recent call last):
    ...
    ValueError: frame 1: damaged
    """
    return _read_ahead(frames, _check_int(depth, "depth", minimum=1))


def _read_ahead(frames: Iterable, depth: int) -> Iterator:
    waiting: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                waiting.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce():
        outcome = _DONE
        try:
            it = iter(frames)
            try:
                for item in it:
                    if not put(item):
                        break
            finally:
                close = getattr(it, "close", None)
                if close is not None:
                    close()
        except Exception as exc:  # noqa: BLE001 - handed over to the consumer
            outcome = _Failed(exc)
        finally:
            put(outcome)

    worker = threading.Thread(target=produce, name="read_ahead", daemon=True)
    worker.start()
    try:
        while True:
            item = waiting.get()
            if item is _DONE:
                return
            if isinstance(item, _Failed):
                raise item.error
            yield item
    finally:
        stop.set()
        worker.join()


def open_video(path: str | os.PathLike | Frames, *, fps: float | None = None,
               start: int = 0, end: int | None = None, min_size: int | None = None,
               eight_bit: bool = False) -> VideoSource:
    """Open a video file, an image folder or frames in memory for streaming.

    Parameters
    ----------
    path : path-like, Frames or array_like
        A video file that OpenCV (FFmpeg) can read, a folder of images
        (``.png``, ``.jpg``, ``.tif``, ``.bmp``, ``.webp``; sorted naturally, so ``f2``
        comes before ``f10``) or a single image (one frame). Images are read unchanged
        (grey and 16-bit stay so) and turned upright by their EXIF orientation. Or frames
        in memory: :class:`Frames`, or what it takes (an array ``(T, H, W[, C])`` or a
        sequence of arrays, RGB); they come out in OpenCV's layout (BGR), as a decoder's
        do.
    fps : float, optional
        Frame rate. Overrides the container's, and then timestamps are
        ``index / fps``. Image folders default to :data:`DEFAULT_FPS`.
    start : int, optional
        First frame to yield (0-based).
    end : int, optional
        Frame at which to stop (exclusive); ``None`` reads to the end.
    min_size : int, optional
        Refuse frames whose width or height is smaller than this many pixels
        (the analysis passes :data:`MIN_FACE_SIZE`).
    eight_bit : bool, keyword-only
        Deliver every frame as ``uint8`` in its own layout (16-bit divided by 257 and
        rounded, see :func:`faceanalysis.io.frames.to_uint8`). The analysis reads its
        input this way, so that the same picture at any bit depth gives the same result.
        False (default): images keep their bit depth.

    Returns
    -------
    VideoSource
        Iterable of :class:`Frame`; also a context manager.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    PermissionError
        If ``path`` cannot be read.
    ValueError
        If ``path`` is not a readable video or image folder, has no frames, if
        ``start``/``end``/``fps`` are invalid or out of range, or if frames are
        smaller than ``min_size``.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np, cv2
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> for i in range(5):
    ...     _ = cv2.imwrite(str(folder / f"f{i}.png"), np.full((80, 96), 40 * i, np.uint8))
    >>> with open_video(folder, fps=10, start=1, end=4) as video:
    ...     print(video.size, video.n_frames)
    ...     for frame in video:
    ...         print(frame.index, frame.timestamp, frame.image.shape)
    (96, 80) 3
    1 0.1 (80, 96)
    2 0.2 (80, 96)
    3 0.3 (80, 96)
    """
    frames = None if isinstance(path, (str, bytes, os.PathLike)) else as_video(path)
    if fps is not None:
        fps = _check_fps(fps)
    start = _check_int(start, "start", minimum=0)
    if end is not None:
        end = _check_int(end, "end", minimum=0)
        if end <= start:
            raise ValueError(f"end ({end}) must be greater than start ({start})")
    if frames is not None:
        path, info = None, _open_frames(frames, fps)
    else:
        path = Path(os.fsdecode(path))
        if not path.exists():
            raise missing_input(path)
        if not os.access(path, os.R_OK):
            raise PermissionError(f"{path}: permission denied")
        if path.is_dir() or path.suffix.lower() in IMAGE_SUFFIXES:
            info = _open_images(path, fps)
        else:
            info = _open_file(path, fps)
    where = path if frames is None else frames
    first = info["first"]
    height, width = first.shape[:2]
    channels = 1 if first.ndim == 2 else first.shape[2]
    if min_size is not None and min(width, height) < min_size:
        raise ValueError(f"{where}: frames are {width}x{height} pixels; the analysis needs at "
                         f"least {min_size} on each side")
    frame_count = info["frame_count"]
    if frame_count is not None:
        if start >= frame_count:
            raise ValueError(f"start ({start}) is beyond the last frame ({frame_count - 1}) "
                             f"of {where}")
        if end is not None and end > frame_count:
            raise ValueError(f"end ({end}) is beyond the {frame_count} frames of {where}")
    return VideoSource(path, info["kind"], fps=info["fps"], fps_origin=info["fps_origin"],
                       size=(width, height), dtype=first.dtype, channels=channels,
                       start=start, end=end, frame_count=frame_count, files=info["files"],
                       eight_bit=eight_bit, frames=frames)
