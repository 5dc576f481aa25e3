"""The files of a corpus run (``faceanalysis batch``): which inputs it takes, the output
folder name of each, and the finished marker that tells a valid result from one to redo.

A video's folder is finished when its marker ``_finished.json`` (written last) records the
input's size and modification time and the options used, and every output file it lists is
present with its recorded size; :func:`is_complete` checks exactly that, so a rerun skips
the videos whose results are still valid.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from faceanalysis.io.outputs import (
    ANALYSIS_JSON,
    CONTRACTIONS_CSV,
    CONTRACTIONS_PNG,
    OVERLAY_MP4,
    SUMMARY_CSV,
)
from faceanalysis.io.video import IMAGE_SUFFIXES, VIDEO_EXTENSIONS, missing_input

__all__ = ["MARKER", "VIDEO_EXTENSIONS", "completion_problem", "discover_inputs",
           "expected_outputs", "is_complete", "output_names"]

#: The finished marker, written last into each video's output folder.
MARKER = "_finished.json"
MARKER_FORMAT = 1
_GLOB_CHARS = set("*?[")


# --------------------------------------------------------------------------- inputs

def discover_inputs(patterns: str | os.PathLike | Iterable[str | os.PathLike], *,
                    extensions: Sequence[str] = VIDEO_EXTENSIONS) -> list[Path]:
    """Expand files, folders and glob patterns into a list of inputs: video files, and
    folders of images (a sequence each, as :func:`faceanalysis.io.video.open_video` reads
    one).

    Parameters
    ----------
    patterns : path-like or iterable of path-like
        Each item is a file (taken as given, whatever its suffix), a folder (the files
        directly inside it whose suffix is in ``extensions``; use ``"DIR/**/*.mp4"`` for
        subfolders; a folder with no such file but with images is itself one input) or a
        glob pattern (``*``, ``?``, ``[...]``; ``**`` spans folders), whose matches are
        filtered by ``extensions`` (a folder of images among them is kept).
    extensions : sequence of str, keyword-only
        Suffixes, with the dot, that count as videos when expanding folders and patterns
        (compared case-insensitively).

    Returns
    -------
    list of Path
        Absolute paths (symbolic links kept, so that a linked clip keeps its name),
        without duplicates, in the order of ``patterns`` (sorted within a folder or
        pattern).

    Raises
    ------
    FileNotFoundError
        If an item names nothing that exists, or a folder or pattern yields no video.
    ValueError
        If ``patterns`` is empty.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> for name in ("b.mp4", "a.avi", "notes.txt"):
    ...     _ = (d / name).write_bytes(b"")
    >>> [p.name for p in discover_inputs([d])]
    ['a.avi', 'b.mp4']
    >>> [p.name for p in discover_inputs([str(d / "*.mp4"), d / "notes.txt"])]
    ['b.mp4', 'notes.txt']
    """
    if isinstance(patterns, (str, os.PathLike)):
        patterns = [patterns]
    patterns = list(patterns)
    if not patterns:
        raise ValueError("no inputs given: name video files, folders or glob patterns")
    suffixes = tuple(s.lower() for s in extensions)

    def is_video(p: Path) -> bool:
        return p.is_file() and p.suffix.lower() in suffixes

    def is_sequence(p: Path) -> bool:
        """A folder of images and no video: one input, its images the frames."""
        if not p.is_dir():
            return False
        files = [f for f in p.iterdir() if f.is_file()]
        return (not any(is_video(f) for f in files)
                and any(f.suffix.lower() in IMAGE_SUFFIXES for f in files))

    found: list[Path] = []
    seen: set[Path] = set()
    for item in patterns:
        text = os.fspath(item)
        path = Path(text).expanduser()
        if path.is_file():
            matches = [path]
        elif path.is_dir():
            matches = ([path] if is_sequence(path)
                       else sorted(p for p in path.iterdir() if is_video(p)))
            if not matches:
                raise FileNotFoundError(
                    f"{text}: folder holds no video file ({', '.join(suffixes)}) and no "
                    f"images; use '{Path(text) / '**' / '*.mp4'}' to search its subfolders, "
                    f"'{Path(text) / '*'}' for its folders of images")
        elif _GLOB_CHARS & set(text):
            hits = sorted(Path(p) for p in glob.glob(os.path.expanduser(text), recursive=True))
            matches = [p for p in hits if is_video(p) or is_sequence(p)]
            if not matches:
                what = (f"matches {len(hits)} path(s) but no video file ({', '.join(suffixes)}) "
                        "or folder of images" if hits else "matches no file")
                raise FileNotFoundError(f"pattern {text!r} {what}")
        else:
            raise missing_input(text)
        for p in matches:
            real = p.resolve()
            if real not in seen:  # the same file reached twice (or through a link)
                seen.add(real)
                # absolute but links kept: a linked clip keeps its own name
                found.append(Path(os.path.abspath(p)))
    return found


def short_hash(path: Path) -> str:
    return hashlib.sha1(os.fsencode(path)).hexdigest()[:8]


def output_names(inputs: Sequence[str | os.PathLike]) -> list[str]:
    """Name of each input's output folder: its stem, made unique where stems clash.

    A stem shared by several inputs (compared case-insensitively, as some filesystems
    do) gets ``-`` and 8 hex digits of a hash of the absolute input path appended, so
    that names never collide and stay the same from run to run for the same inputs.
    The stem ``summary`` and stems starting with ``.`` or ``_`` are reserved for the
    runner's own files: they are hashed too, with the leading dots and underscores
    removed, so that no output folder is hidden.

    Parameters
    ----------
    inputs : sequence of path-like
        The videos, e.g. from :func:`discover_inputs`.

    Returns
    -------
    list of str
        One folder name per input, in order.

    Examples
    --------
    >>> output_names(["/data/a/clip.mp4", "/data/b/clip.mp4", "/data/b/other.avi"])[2]
    'other'
    >>> [n[:5] for n in output_names(["/data/a/clip.mp4", "/data/b/clip.mp4"])]
    ['clip-', 'clip-']
    """
    paths = [Path(os.path.abspath(os.fspath(p))) for p in inputs]
    counts: dict[str, int] = {}
    for p in paths:
        counts[p.stem.lower()] = counts.get(p.stem.lower(), 0) + 1
    names = []
    for p in paths:
        stem = p.stem
        reserved = stem.startswith((".", "_")) or stem.lower() == Path(SUMMARY_CSV).stem
        if counts[stem.lower()] > 1 or reserved:
            stem = f"{stem.lstrip('._') or 'video'}-{short_hash(p)}"
        names.append(stem)
    return names


# --------------------------------------------------------------------------- markers

def expected_outputs(options: Mapping | None = None) -> tuple[str, ...]:
    """Files that a finished video's folder must hold, for the given analysis options.

    Examples
    --------
    >>> expected_outputs()
    ('contractions.csv', 'analysis.json', 'contractions.png')
    >>> expected_outputs({"overlay": True})[-1]
    'overlay.mp4'

    ``overlay.mp4`` may be ``overlay.avi`` where OpenCV has no MP4 encoder (the video
    writer falls back to Motion-JPEG); either counts.
    """
    files = (CONTRACTIONS_CSV, ANALYSIS_JSON, CONTRACTIONS_PNG)
    if options and options.get("overlay"):
        files += (OVERLAY_MP4,)
    return files


# an expected output and the names it may have (codec fallbacks of the video writer)
_ALTERNATIVES = {OVERLAY_MP4: (OVERLAY_MP4, "overlay.avi")}


def missing_outputs(present, options: Mapping | None) -> list[str]:
    """Expected outputs of which no acceptable name is in ``present`` (a set of names)."""
    return [name for name in expected_outputs(options)
            if not any(alt in present for alt in _ALTERNATIVES.get(name, (name,)))]


def canonical_options(options: Mapping | None) -> dict:
    """Options as plain JSON values (paths and other objects as strings), keys sorted."""
    return json.loads(json.dumps(dict(options or {}), sort_keys=True, default=str))


def input_signature(path: Path) -> dict:
    """Size and modification time of an input; of a folder of images, the bytes of its
    images and the latest time among them and the folder (an image added, removed or
    changed in place all show)."""
    st = path.stat()
    if not path.is_dir():
        return {"size": int(st.st_size), "mtime_ns": int(st.st_mtime_ns)}
    images = [f.stat() for f in path.iterdir()
              if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES]
    return {"size": sum(int(i.st_size) for i in images),
            "mtime_ns": max([int(st.st_mtime_ns), *(int(i.st_mtime_ns) for i in images)])}


def completion_problem(out_dir: str | os.PathLike, input_path: str | os.PathLike, *,
                       options: Mapping | None = None) -> str | None:
    """Why ``out_dir`` is not a finished result for ``input_path``, or None if it is.

    Parameters
    ----------
    out_dir : path-like
        A video's output folder.
    input_path : path-like
        The video it should hold the results of.
    options : mapping, optional, keyword-only
        The analysis options of the current run; when given they must equal the ones
        recorded in the marker.

    Returns
    -------
    str or None
        A one-line reason (missing marker, input changed, options differ, an output
        file missing or of another size), or None when the folder is complete.
    """
    out_dir = Path(out_dir)
    marker_path = out_dir / MARKER
    if not marker_path.is_file():
        return f"{marker_path} is missing"
    try:
        marker = json.loads(marker_path.read_text())
        signature = {"size": int(marker["input"]["size"]),
                     "mtime_ns": int(marker["input"]["mtime_ns"])}
        recorded_options = marker["options"]
        outputs = dict(marker["outputs"])
        record = marker["record"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"{marker_path} is unreadable ({type(exc).__name__}: {exc})"
    if marker.get("format") != MARKER_FORMAT:
        return f"{marker_path} has format {marker.get('format')!r}, not {MARKER_FORMAT}"
    if not isinstance(record, dict) or record.get("status") != "ok":
        return f"{marker_path} does not record a successful analysis"
    try:
        current = input_signature(Path(input_path))
    except OSError as exc:
        return f"{input_path}: cannot read ({exc.strerror or exc})"
    if current != signature:
        return (f"{input_path} changed since {out_dir} was written "
                f"(size/modification time differ)")
    if options is not None and canonical_options(options) != recorded_options:
        return f"{out_dir} was made with other options ({json.dumps(recorded_options)})"
    for name in missing_outputs(set(outputs), recorded_options):
        return f"{marker_path} lists no {name}"
    for name, size in outputs.items():
        f = out_dir / name
        if not f.is_file():
            return f"{f} is missing"
        if f.stat().st_size != size:
            return f"{f} has {f.stat().st_size} bytes, the marker says {size}"
    return None


def is_complete(out_dir: str | os.PathLike, input_path: str | os.PathLike, *,
                options: Mapping | None = None) -> bool:
    """True when ``out_dir`` holds the finished results of ``input_path``.

    The finished marker must exist, match the input's current size and modification
    time (and ``options`` when given), and every output file it lists must be present
    with the recorded size. See :func:`completion_problem` for the reason when not.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> video = d / "clip.mp4"
    >>> _ = video.write_bytes(b"not really a video")
    >>> is_complete(d / "clip", video)
    False
    """
    return completion_problem(out_dir, input_path, options=options) is None
