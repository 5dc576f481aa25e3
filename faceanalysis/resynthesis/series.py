"""The contraction time series a resynthesis plays: read from a table, an analysis folder or an
:class:`~faceanalysis.analysis.results.Analysis`, with every cell checked (row and column named).

Lost frames (``success == 0``) hold the last good contractions and head frame.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV
from faceanalysis.io.table import FIDUCIALS, HEAD_COLUMNS, JAW, MUSCLES, numeric_column
from faceanalysis.io.video import is_photographs

log = logging.getLogger(__name__)


_DEFAULT_FPS = 30.0


# ----------------------------------------------------------------------------- input
@dataclass
class Series:
    """The drive: per-frame controls, bookkeeping and (optionally) head frames."""

    frames: np.ndarray            # (T,) frame numbers
    timestamps: np.ndarray        # (T,) seconds (may be NaN)
    success: np.ndarray           # (T,) bool
    controls: np.ndarray          # (T, M) muscles in MUSCLES order, lost rows held
    jaw: np.ndarray               # (T,)
    heads: np.ndarray | None      # (T, 4), lost rows held; None when absent
    fiducials: np.ndarray | None  # (T, 11, 2) image px; NaN when lost
    metadata: dict = field(default_factory=dict)
    table: pd.DataFrame | None = None
    folder: Path | None = None
    missing: tuple[str, ...] = ()

    @property
    def input_size(self) -> tuple[int, int] | None:
        size = (self.metadata.get("input") or {}).get("size")
        if size and len(size) == 2 and all(int(v) > 0 for v in size):
            return int(size[0]), int(size[1])
        return None

    @property
    def input_path(self) -> Path | None:
        p = (self.metadata.get("input") or {}).get("path")
        return Path(p) if p else None

    @property
    def neutral_row(self) -> int:
        """Row of the neutral frame (analysis.json's, else the first tracked row)."""
        nf = (self.metadata.get("parameters") or {}).get("neutral_frame")
        if nf is None:
            nf = (self.metadata.get("calibration") or {}).get("neutral_frame")
        if nf is not None:
            hits = np.flatnonzero(self.frames == int(nf))
            if hits.size and self.success[hits[0]]:
                return int(hits[0])
        if not self.success.any():
            raise ValueError("no tracked frame (success == 1) in the series")
        return int(np.argmax(self.success))

    def fps(self, override: float | None = None) -> float:
        """Frames per second to play the series at: ``override``, the analysed input's
        rate, one a second for photographs (as their overlay shows them), or the
        timestamps'."""
        if override is not None:
            return float(override)
        if is_photographs(self.metadata.get("input")):
            return 1.0
        f = (self.metadata.get("input") or {}).get("fps")
        if f and np.isfinite(f) and f > 0:
            return float(f)
        ts = self.timestamps
        if ts.size > 1 and np.isfinite(ts).all():
            d = np.diff(ts) / np.maximum(np.diff(self.frames), 1)
            d = d[d > 0]
            if d.size:
                return float(1.0 / np.median(d))
        return _DEFAULT_FPS


def same_path(a, b) -> bool:
    """Whether ``a`` and ``b`` name one file or folder (links and ``..`` resolved); False
    where either is missing (None or empty) or cannot be resolved.

    Examples
    --------
    >>> same_path("clips/../clip.mp4", "clip.mp4"), same_path(None, "clip.mp4")
    (True, False)
    """
    if not a or not b:
        return False
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def _label(frames, row: int) -> str:
    return f"line {row + 2} (frame {int(frames[row])})"


def _refuse_misspelt_controls(columns, where: str) -> None:
    """A column that is no control but reads like one (``zygomaticus_majr_l``) is a typo that
    would leave its muscle at rest without a word: name it, and the control it resembles."""
    import difflib

    known = {*MUSCLES, JAW}
    for column in columns:
        if column in known:
            continue
        close = difflib.get_close_matches(column, known, n=1, cutoff=0.85)
        if close:
            raise ValueError(f"{where}: unknown column {column!r} (did you mean "
                             f"{close[0]!r}?)")


def series_from_table(df: pd.DataFrame, where: str, metadata: dict | None = None
                       ) -> Series:
    """Validate a contractions table (complete or partial) into a :class:`Series`."""
    from synth.model import MAX_JAW_ROTATION

    if not isinstance(df, pd.DataFrame):
        raise ValueError(f"{where}: expected a table, got {type(df).__name__}")
    if len(df) == 0:
        raise ValueError(f"{where}: the table has no rows")
    df = df.copy()
    df.columns = [str(c).strip() for c in df.columns]
    n = len(df)
    frames = np.arange(n)
    if "frame" in df.columns:
        frames = numeric_column(df, "frame", where)
        if not np.isfinite(frames).all() or (frames != np.round(frames)).any():
            r = int(np.flatnonzero(~np.isfinite(frames) | (frames != np.round(frames)))[0])
            raise ValueError(f"{where}: line {r + 2}, column frame: not an integer frame number")
        frames = frames.astype(np.int64)
        if n > 1 and (np.diff(frames) <= 0).any():
            r = int(np.flatnonzero(np.diff(frames) <= 0)[0]) + 1
            raise ValueError(f"{where}: {_label(frames, r)}, column frame: frame numbers must "
                             "increase")
    success = np.ones(n, bool)
    if "success" in df.columns:
        s = numeric_column(df, "success", where)
        bad = ~np.isin(s, (0.0, 1.0))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{where}: {_label(frames, r)}, column success: {s[r]!r} is not "
                             "0 or 1")
        success = s == 1.0
    timestamps = np.full(n, np.nan)
    if "timestamp" in df.columns:
        timestamps = numeric_column(df, "timestamp", where)
    _refuse_misspelt_controls(df.columns, where)
    present = [m for m in MUSCLES if m in df.columns]
    if not present and JAW not in df.columns:
        raise ValueError(f"{where}: no muscle columns (e.g. {MUSCLES[0]}) and no {JAW} column")
    if "success" not in df.columns:
        # a table cut down to a few columns: a row with every control empty is a lost frame,
        # as contractions.csv writes one; a row with some filled is tracked
        given = np.stack([numeric_column(df, c, where) for c in (*present, JAW)
                          if c in df.columns], axis=1)
        success = ~np.isnan(given).all(axis=1)
    missing = tuple(m for m in MUSCLES if m not in df.columns)
    controls = np.zeros((n, len(MUSCLES)))
    jaw = np.zeros(n)
    for j, name in enumerate((*MUSCLES, JAW)):
        if name not in df.columns:
            continue
        v = numeric_column(df, name, where)
        hi = MAX_JAW_ROTATION if name == JAW else 1.0
        lost_nan = np.isnan(v) & ~success
        with np.errstate(invalid="ignore"):
            bad = ~lost_nan & (~np.isfinite(v) | (v < 0.0) | (v > hi))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            tracked = ("success == 1" if "success" in df.columns
                       else "other controls are given on that line")
            problem = (f"an empty cell in a tracked frame ({tracked})" if np.isnan(v[r])
                       else f"{v[r]:g} is outside [0, {hi:g}]")
            raise ValueError(f"{where}: {_label(frames, r)}, column {name}: {problem}")
        if name == JAW:
            jaw = v
        else:
            controls[:, j] = v
    # lost frames hold the last good value (rest before the first good one)
    controls, jaw = _hold(controls, success), _hold(jaw[:, None], success)[:, 0]
    heads = None
    if all(c in df.columns for c in HEAD_COLUMNS):
        h = np.stack([numeric_column(df, c, where) for c in HEAD_COLUMNS], axis=1)
        good = success & np.isfinite(h).all(axis=1) & (h[:, 2] > 0)
        if good.any():
            heads = _hold(h, good, first=h[int(np.argmax(good))])
    fiducials = None
    cols = [f"fid_{name}_{a}" for name in FIDUCIALS for a in "xy"]
    if all(c in df.columns for c in cols):
        fiducials = np.stack([numeric_column(df, c, where) for c in cols],
                             axis=1).reshape(n, len(FIDUCIALS), 2)
        fiducials[~success] = np.nan
    return Series(frames=frames, timestamps=timestamps, success=success, controls=controls,
                   jaw=jaw, heads=heads, fiducials=fiducials, metadata=dict(metadata or {}),
                   table=df, missing=missing)


def _hold(values: np.ndarray, good: np.ndarray, first=None) -> np.ndarray:
    """Rows where ``good`` is false take the last good row (``first``, else 0, before any)."""
    out = np.array(values, dtype=float)
    idx = np.where(good, np.arange(len(good)), -1)
    idx = np.maximum.accumulate(idx)
    fill = np.zeros(out.shape[1]) if first is None else np.asarray(first, float)
    held = np.where((idx >= 0)[:, None], out[np.maximum(idx, 0)], fill[None, :])
    return held


def _read_metadata(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        log.warning("ignoring unreadable %s (%s)", path, exc)
        return {}


def load_series(source) -> Series:
    """An Analysis, analysis folder, contractions CSV or DataFrame -> :class:`Series`."""
    from faceanalysis.analysis.pipeline import Analysis

    if isinstance(source, Analysis):
        s = series_from_table(source.table, "analysis", source.metadata)
        return s
    if isinstance(source, pd.DataFrame):
        return series_from_table(source, "table")
    if not isinstance(source, (str, os.PathLike)):
        raise ValueError(f"source must be an Analysis, a DataFrame, a contractions.csv or an "
                         f"analysis folder, got {type(source).__name__}")
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    folder = path if path.is_dir() else path.parent
    csv = path / CONTRACTIONS_CSV if path.is_dir() else path
    if not csv.is_file():
        raise FileNotFoundError(f"{csv}: no such file (expected an analysis folder or a "
                                "contractions.csv)")
    meta = _read_metadata(folder / ANALYSIS_JSON)
    from faceanalysis.io.table import read_contractions, read_csv_table, required_columns

    try:
        head = read_csv_table(csv, nrows=0)
    except pd.errors.EmptyDataError:
        raise ValueError(f"{csv}: file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError):
        raise ValueError(f"{csv}: not a CSV table (expected contractions.csv or an analysis "
                         "folder)") from None
    if all(c in [str(h).strip() for h in head.columns] for c in required_columns()):
        df = read_contractions(csv)            # full table: validated, names row and column
    else:
        try:
            df = read_csv_table(csv)
        except pd.errors.EmptyDataError:
            raise ValueError(f"{csv}: file is empty") from None
        except (pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise ValueError(f"{csv}: not a CSV table ({str(exc).strip()[:80]})") from None
    s = series_from_table(df, str(csv), meta)
    s.folder = folder
    return s


@dataclass
class FrameState:
    """One resynthesised frame: the image and the geometry behind it."""

    row: int
    frame: int
    image: np.ndarray                 # (H, W, 3) uint8 RGB, the resynthesis
    output: np.ndarray                # what the video gets (side by side when asked)
    vertices: np.ndarray              # (N, 3) skin, model cm
    inner: np.ndarray                 # (P, 3)
    fiducials: np.ndarray             # (11, 2) projected, output px
    seconds: float                    # equilibrium + rendering time
    photometric_mae: float | None = None  # vs the input frame (personalised, side by side)
    #: mean distance (output px) of the 11 resynthesised fiducials from the tracked ones of
    #: the series on this frame; None where the series has no tracked fiducials (lost
    #: frame, no fiducial columns, or a view other than the input's framing)
    fiducial_error_px: float | None = None
