"""``analysis.json``: what was analysed, how, with which software, and how well it went.

:func:`analysis_metadata` builds the content (plain JSON types only),
:func:`write_analysis` writes it atomically and :func:`read_analysis` reads it back.
The quality summary (:func:`quality_summary`) is computed from the contractions
table itself, so it always agrees with ``contractions.csv``.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import importlib
import json
import math
import os
import platform
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis._version import __version__
from faceanalysis.io.outputs import write_text_atomic

__all__ = [
    "FORMAT",
    "LOST_REASONS",
    "analysis_metadata",
    "check_analysed_input",
    "frame_ranges",
    "hidden_frames_of",
    "input_metadata",
    "input_name",
    "lost_reasons_text",
    "quality_summary",
    "read_analysis",
    "summary_line",
    "write_analysis",
]

#: Identifies the layout of ``analysis.json``; bumped when keys change meaning.
FORMAT = "faceanalysis.analysis.pipeline/1"

#: Why a frame is lost (``quality.lost_reasons``): code -> (in a count's words, what it
#: means). The tracker gives each lost frame one (``Tracks.lost_reasons``).
LOST_REASONS: dict[str, tuple[str, str]] = {
    "undecodable": ("undecodable", "the frame could not be decoded"),
    "no_face": ("without a face", "no face found (or the landmark model not confident of one)"),
    "other_face": ("with only someone else's face",
                   "the followed face not found, another face elsewhere in the picture (a "
                   "face far from where the followed one was last seen is someone else's)"),
    "hand": ("under a hand", "a hand over the face, and too few points left"),
    "contours": ("with too few contours held",
                 "too few points held (contours lost: an occluder, or off their features)"),
    "edge": ("with the face at the picture's edge",
             "the face cut off by the picture's edge before the contours were placed (they "
             "wait a limited number of frames for it to come in)"),
    "fading": ("while the picture brightened",
               "before the face was first found, the next frame brighter (a fade-in, a "
               "camera's exposure settling): the contours wait for the light to settle"),
}


def lost_reasons_text(counts) -> str:
    """Lost frames per reason in words, e.g. for ``quality.lost_reasons``.

    Examples
    --------
    >>> lost_reasons_text({"hand": 168, "no_face": 1})
    '168 under a hand, 1 without a face'
    """
    return ", ".join(f"{n} {LOST_REASONS[code][0] if code in LOST_REASONS else code}"
                     for code, n in counts.items())


def summary_line(metadata: dict, rows: int) -> str:
    """What an analysis found, in a line: frames, lost frames and why, the neutral frame,
    and how many controls are measured (``faceanalysis analyze`` ends with it).

    Examples
    --------
    >>> line = summary_line({
    ...     "quality": {"frames_total": 3, "frames_lost": 1, "lost_reasons": {"hand": 1}},
    ...     "identifiability": {"controls": {"a": {"identifiable": True}},
    ...                         "mirror": {"frames_not_reproduced": {"a": [2]}}}}, 3)
    >>> line.startswith("analysed 3 frames (1 lost: 1 under a hand; all 1 controls measured")
    True
    >>> line.endswith("but 1 value not reproduced mirrored, flagged 0)")
    True
    >>> summary_line({"quality": {"frames_total": 1, "frames_lost": 0}}, 1)
    'analysed 1 frame (0 lost; all 0 controls measured)'
    >>> summary_line({"quality": {"frames_total": 9, "frames_lost": 0},
    ...               "parameters": {"neutral_frame": 4}}, 9)
    'analysed 9 frames (0 lost; neutral frame 4; all 0 controls measured)'
    >>> summary_line({"quality": {"frames_total": 3, "frames_lost": 0},
    ...               "input": {"kind": "images", "fps_origin": "default", "frame_count": 3}}, 3)
    'analysed 3 photographs (0 lost; all 0 controls measured)'
    """
    from faceanalysis.io.video import is_photographs

    q = metadata.get("quality") or {}
    ident = metadata.get("identifiability") or {}
    controls = ident.get("controls", {})
    told = sum(bool(c.get("identifiable")) for c in controls.values())
    measured = (f"all {told} controls measured" if told == len(controls) else
                f"{told} of {len(controls)} controls measured, the others flagged 0 in "
                f"<control>_identifiable")
    by_frame = (ident.get("mirror") or {}).get("frames_not_reproduced") or {}
    if by_frame:
        n = sum(len(frames) for frames in by_frame.values())
        measured += f", but {n} value{'s' if n > 1 else ''} not reproduced mirrored, flagged 0"
    lost = f"{q.get('frames_lost', 0)} lost"
    reasons = q.get("lost_reasons") or {}
    if reasons:
        lost += ": " + lost_reasons_text(reasons)
    total = q.get("frames_total", rows)
    # every value is measured from the neutral frame: say which, so that it gets looked at
    neutral = (metadata.get("parameters") or {}).get("neutral_frame")
    if neutral is not None:
        lost += f"; neutral frame {neutral}"
    unit = "photograph" if is_photographs(metadata.get("input")) else "frame"
    return f"analysed {total} {unit}{'' if total == 1 else 's'} ({lost}; {measured})"


#: Longest list of lost-frame ranges kept in the summary (the count is always exact).
MAX_LOST_RANGES = 1000


def _jsonable(value, key: str = "value"):
    """Convert numpy/pandas/path values to plain JSON types; NaN and inf become None."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return str(value)
    if isinstance(value, np.dtype):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v, f"{key}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        # e.g. trackers.SnakeParams passed in tracker_options
        return _jsonable(dataclasses.asdict(value), key)
    if isinstance(value, np.ndarray):
        return [_jsonable(v, key) for v in value.tolist()]
    if isinstance(value, (list, tuple, set, frozenset)):
        items = sorted(value) if isinstance(value, (set, frozenset)) else value
        return [_jsonable(v, key) for v in items]
    raise ValueError(f"{key}: cannot store a {type(value).__name__} in analysis.json")


def frame_ranges(frames) -> list[list[int]]:
    """Group sorted frame numbers into inclusive ``[first, last]`` runs of consecutive ones.

    Examples
    --------
    >>> frame_ranges([3, 4, 5, 9, 11, 12])
    [[3, 5], [9, 9], [11, 12]]
    """
    frames = np.asarray(frames, dtype=int)
    if frames.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(frames) != 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [frames.size - 1]])
    return [[int(frames[s]), int(frames[e])] for s, e in zip(starts, ends)]


def hidden_frames_of(metadata) -> np.ndarray | None:
    """The frames on which the face could not be seen, from an ``analysis.json``'s
    ``quality.hidden_ranges``; None where it does not say (an older analysis).

    Examples
    --------
    >>> hidden_frames_of({"quality": {"hidden_ranges": [[3, 5], [9, 9]]}}).tolist()
    [3, 4, 5, 9]
    >>> hidden_frames_of({}) is None
    True
    """
    ranges = ((metadata or {}).get("quality") or {}).get("hidden_ranges")
    if ranges is None:
        return None
    return np.array([f for a, b in ranges for f in range(int(a), int(b) + 1)], dtype=int)


def quality_summary(table: pd.DataFrame, *, frames_missing: int = 0) -> dict:
    """How many frames were tracked and lost, and how confident the tracking was.

    Parameters
    ----------
    table : DataFrame
        Contractions table with ``frame``, ``success`` and (optionally) ``confidence``.
    frames_missing : int, keyword-only
        Frames that are not rows of ``table`` because the decoder never delivered
        them (the missing tail of a truncated file); added to ``frames_lost``.
        Frames that failed to decode mid-stream are rows with ``success == 0``
        and are counted through ``table``.

    Returns
    -------
    dict
        ``first_frame`` and ``last_frame`` (the rows' frame numbers),
        ``frames_total`` (rows + ``frames_missing``), ``frames_tracked``,
        ``frames_lost`` (including ``frames_missing``), ``lost_fraction``,
        ``lost_ranges`` (inclusive ``[first, last]`` frame numbers of lost rows, at
        most 1000 of them), ``lost_ranges_truncated``, ``frames_missing``,
        ``mean_confidence`` and
        ``min_confidence`` over tracked frames (None when nothing was tracked).

    Examples
    --------
    >>> import pandas as pd
    >>> t = pd.DataFrame({"frame": [0, 1, 2, 3, 4, 5], "success": [1, 0, 0, 1, 0, 1],
    ...                   "confidence": [0.9, 0.0, 0.0, 0.7, 0.1, 0.8]})
    >>> q = quality_summary(t)
    >>> q["frames_tracked"], q["frames_lost"], q["lost_ranges"], round(q["mean_confidence"], 2)
    (3, 3, [[1, 2], [4, 4]], 0.8)
    """
    for column in ("frame", "success"):
        if column not in table:
            raise ValueError(f"table has no '{column}' column")
    if isinstance(frames_missing, bool) or not isinstance(frames_missing, (int, np.integer)) \
            or frames_missing < 0:
        raise ValueError(f"frames_missing must be a non-negative integer, got {frames_missing!r}")
    success = pd.to_numeric(table["success"], errors="coerce").to_numpy(float) > 0
    frames = pd.to_numeric(table["frame"], errors="coerce").to_numpy(float)
    lost_frames = np.sort(frames[~success].astype(np.int64))
    ranges = frame_ranges(lost_frames)
    n_total = int(len(table))
    n_tracked = int(success.sum())
    n_lost = n_total - n_tracked + int(frames_missing)
    mean_conf = min_conf = None
    if "confidence" in table and n_tracked:
        conf = pd.to_numeric(table["confidence"], errors="coerce").to_numpy(float)[success]
        conf = conf[np.isfinite(conf)]
        if conf.size:
            mean_conf, min_conf = float(conf.mean()), float(conf.min())
    denominator = n_total + int(frames_missing)
    finite = frames[np.isfinite(frames)]
    return {
        "first_frame": int(finite.min()) if finite.size else None,
        "last_frame": int(finite.max()) if finite.size else None,
        "frames_total": denominator,
        "frames_tracked": n_tracked,
        "frames_lost": n_lost,
        "lost_fraction": (n_lost / denominator) if denominator else None,
        "lost_ranges": ranges[:MAX_LOST_RANGES],
        "lost_ranges_truncated": len(ranges) > MAX_LOST_RANGES,
        "frames_missing": int(frames_missing),
        "mean_confidence": mean_conf,
        "min_confidence": min_conf,
    }


def input_metadata(source) -> dict:
    """Describe an input: a :class:`faceanalysis.io.video.VideoSource` or a plain mapping.

    A mapping is copied as is (it must be JSON-compatible); a ``VideoSource`` gives ``path``
    (absolute; None for frames in memory), ``kind``, ``size`` ``[width, height]``, ``fps``,
    ``fps_origin``, ``frame_count``, ``frame_range`` ``[start, end)`` (``end``: the real end
    when the frame count is known, else None = to the end), ``dtype``, ``channels``,
    ``frames_undecodable``, ``missing_tail`` and, where photographs of other sizes than the
    first were placed on its canvas, ``placed`` (frame -> file, size, scale, offset).
    """
    if isinstance(source, Mapping):
        return dict(source)
    end = getattr(source, "end", None)
    if end is None and getattr(source, "frame_count", None) is not None:
        end = max(int(source.frame_count), int(getattr(source, "start", 0) or 0))
    required = ("path", "kind", "size", "fps", "fps_origin", "frame_count", "start", "end")
    missing = [name for name in required if not hasattr(source, name)]
    if missing:
        raise ValueError(f"input description lacks {', '.join(missing)}")
    return {
        # (frames in memory have no path)
        "path": None if source.path is None else str(Path(source.path).resolve()),
        "kind": source.kind,
        "size": list(source.size),
        "fps": source.fps,
        "fps_origin": source.fps_origin,
        "frame_count": source.frame_count,
        "frame_range": [source.start, end],
        "dtype": str(getattr(source, "dtype", "")) or None,
        "channels": getattr(source, "channels", None),
        "frames_undecodable": getattr(source, "n_failed", 0),
        "missing_tail": getattr(source, "missing_tail", 0),
        **({"placed": {str(i): dict(p) for i, p in sorted(source.placed.items())}}
           if getattr(source, "placed", None) else {}),
    }


def input_name(described) -> str:
    """The input's file or folder name from its description (:func:`input_metadata`),
    ``'frames in memory'`` where it has no path: what titles and summaries call it.

    Examples
    --------
    >>> input_name({"path": "/data/clips/smile.mp4"}), input_name({"path": None})
    ('smile.mp4', 'frames in memory')
    """
    path = (described or {}).get("path")
    return Path(path).name if path else "frames in memory"


def check_analysed_input(video, recorded, *, analysis) -> None:
    """Raise ValueError when ``video`` is not the input an analysis was made from.

    Commands that read a video beside its analysis (``validate``, ``classify --analysis``,
    ``resynth --input``) apply the analysis's frames to the video's: another video would be
    compared frame by frame with values measured on a different face. The video must have
    the size and, where both are known, the frame count that ``recorded`` (the ``input`` of
    ``analysis.json``) gives; a copy or a moved file passes. Nothing is checked when
    nothing was recorded (an analysis of frames in memory, a table on its own).

    Parameters
    ----------
    video : path-like
        The video given with the analysis.
    recorded : mapping or None
        ``analysis.json``'s ``input``.
    analysis : str
        What messages call the analysis (its folder).
    """
    if not isinstance(recorded, Mapping) or recorded.get("kind") not in ("video", "images"):
        return
    size, count = recorded.get("size"), recorded.get("frame_count")
    if size is None:
        return
    from faceanalysis.io.video import open_video

    with open_video(video) as source:
        got_size, got_count = list(source.size), source.frame_count
    if got_size == list(size) and (count is None or got_count is None or got_count == count):
        return

    def described(size, count) -> str:
        return f"{size[0]}x{size[1]}" + ("" if count is None else f", {count} frames")

    made_from = Path(str(recorded.get("path") or "")).name or "another input"
    raise ValueError(f"{video} ({described(got_size, got_count)}) is not the input the "
                     f"analysis in {analysis} was made from ({made_from}, "
                     f"{described(size, count)}): give the analysed video")


#: module -> its distribution on PyPI (None: the module is imported for its version, as
#: OpenCV's several distributions all install ``cv2``)
_LIBRARIES = {"numpy": "numpy", "scipy": "scipy", "cv2": None, "skimage": "scikit-image",
              "pandas": "pandas", "matplotlib": "matplotlib", "numba": "numba",
              "dask": "dask", "distributed": "distributed", "torch": "torch",
              "kornia": "kornia"}


def software_versions() -> dict[str, str | None]:
    """Version of the toolkit, Python and every library it can use (None if absent).

    A library the process has not imported is read from its installed metadata instead
    of being imported (importing dask, distributed and torch for their version numbers
    alone took 0.3 s or more of an analysis).
    """
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"faceanalysis": __version__, "python": platform.python_version()}
    for name, dist in _LIBRARIES.items():
        module = sys.modules.get(name)
        if module is None and dist is not None:
            try:
                out[name] = version(dist)
            except PackageNotFoundError:
                out[name] = None
            continue
        if module is None:
            try:
                module = importlib.import_module(name)
            except ImportError:
                out[name] = None
                continue
        out[name] = getattr(module, "__version__", "unknown")
    return out


def analysis_metadata(source, table: pd.DataFrame | None = None, *,
                      parameters: Mapping | None = None,
                      versions: Mapping[str, str | None] | None = None,
                      command: Sequence[str] | None = None,
                      elapsed_s: float | None = None,
                      extra: Mapping | None = None) -> dict:
    """Build the content of ``analysis.json``.

    Parameters
    ----------
    source : VideoSource or mapping
        The input (see :func:`input_metadata`).
    table : DataFrame, optional
        The contractions table; gives the ``quality`` section. The missing tail
        of a truncated video (``source.missing_tail``) counts as lost.
    parameters : mapping, optional
        The analysis parameters (tracker, estimator, calibration settings...).
    versions : mapping, optional
        Software versions; :func:`software_versions` by default.
    command : sequence of str, optional
        The command line, if run from one.
    elapsed_s : float, optional
        Wall-clock duration of the analysis.
    extra : mapping, optional
        Further top-level sections (e.g. calibration results); may not replace
        the standard keys.

    Returns
    -------
    dict
        Plain JSON types only: ``format``, ``created`` (UTC, ISO 8601), ``input``,
        ``parameters``, ``versions``, ``quality`` (None without ``table``), and
        ``command`` / ``elapsed_s`` when given.

    Raises
    ------
    ValueError
        If a value cannot be stored in JSON (the message names its key) or
        ``extra`` collides with a standard key.

    Examples
    --------
    >>> import pandas as pd
    >>> t = pd.DataFrame({"frame": [0, 1, 2], "success": [1, 1, 0], "confidence": [1, .8, 0]})
    >>> meta = analysis_metadata({"path": "clip.mp4", "fps": 30.0}, t,
    ...                          parameters={"estimator": "joint"}, versions={"faceanalysis": "x"})
    >>> meta["quality"]["frames_lost"], meta["parameters"]["estimator"]
    (1, 'joint')
    """
    if versions is None:
        versions = software_versions()
    info = input_metadata(source)
    missing = int(info.get("missing_tail") or 0)
    meta = {
        "format": FORMAT,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "input": info,
        "parameters": dict(parameters or {}),
        "versions": dict(versions),
        "quality": (quality_summary(table, frames_missing=missing)
                    if table is not None else None),
    }
    if command is not None:
        meta["command"] = list(command)
    if elapsed_s is not None:
        meta["elapsed_s"] = float(elapsed_s)
    for key, value in (extra or {}).items():
        if key in meta:
            raise ValueError(f"extra section {key!r} would replace a standard key")
        meta[key] = value
    return {key: _jsonable(value, key) for key, value in meta.items()}


def write_analysis(metadata: Mapping, path: str | os.PathLike) -> Path:
    """Write ``metadata`` as indented JSON, atomically; returns the path.

    Raises
    ------
    ValueError
        If a value cannot be stored in JSON (the message names its key).
    """
    data = _jsonable(metadata, "analysis")
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    return write_text_atomic(path, text)


def read_analysis(path: str | os.PathLike) -> dict:
    """Read an ``analysis.json`` written by :func:`write_analysis`.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If it is not JSON, not an object, or of an unknown format.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not an analysis.json file (format {FORMAT} expected)")
    return data
