"""The ``contractions.csv`` table: column names, writing, reading and validation.

One row per frame, columns in this fixed order (see DESIGN.md):

``frame, timestamp, success, confidence``
    frame number (0-based, in the input), seconds, 1 if the face was tracked
    in this frame else 0, tracking confidence in [0, 1];
``head_x, head_y, head_scale, head_roll``
    head reference frame in the image: origin (pixels, x right, y down), scale
    (pixels per model centimetre) and roll (radians, counter-clockwise in the image);
``fid_<name>_x, fid_<name>_y``
    the 11 fiducial points of :data:`FIDUCIALS` in image pixels;
one column per muscle of :data:`MUSCLES`
    contraction in [0, 1];
``jaw_rotation``
    radians, positive opens the mouth;
``AU01_r`` ... ``AU27_r``
    FACS action-unit intensities in [0, 5] (OpenFace-style names), derived from
    the muscles by :func:`au_intensities`.

Values that are unknown (a lost frame, an action unit without a muscle mapping)
are empty cells, read back as NaN.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.outputs import atomic_path

__all__ = [
    "AU_COLUMNS",
    "AU_NUMBERS",
    "FIDUCIALS",
    "FIDUCIAL_COLUMNS",
    "FRAME_COLUMNS",
    "HEAD_COLUMNS",
    "JAW",
    "MUSCLES",
    "MUSCLE_BASES",
    "au_intensities",
    "contraction_columns",
    "empty_table",
    "read_contractions",
    "write_contractions",
]

#: The 11 fiducial points of 004 section V-D, ``_l`` = subject's left.
FIDUCIALS: tuple[str, ...] = (
    "brow_inner_l", "brow_mid_l", "brow_outer_l",
    "brow_inner_r", "brow_mid_r", "brow_outer_r",
    "mouth_corner_l", "mouth_corner_r",
    "furrow_top_l", "furrow_top_r",
    "chin",
)

#: Paired muscles, without their ``_l``/``_r`` suffix, in DESIGN.md order.
MUSCLE_BASES: tuple[str, ...] = (
    "frontalis_inner", "frontalis_major", "frontalis_outer", "corrugator",
    "zygomaticus_major", "zygomaticus_minor", "levator_labii_nasi", "levator_labii",
    "depressor_anguli", "depressor_labii", "mentalis", "buccinator", "risorius",
)

#: Every muscle column: each pair left then right, then the sphincters.
MUSCLES: tuple[str, ...] = tuple(
    f"{base}_{side}" for base in MUSCLE_BASES for side in ("l", "r")
) + ("orbicularis_oris", "orbicularis_oculi_l", "orbicularis_oculi_r")

#: Jaw rotation column (radians), written after the muscles.
JAW = "jaw_rotation"

#: Per-frame bookkeeping columns.
FRAME_COLUMNS: tuple[str, ...] = ("frame", "timestamp", "success", "confidence")

#: Head reference frame columns.
HEAD_COLUMNS: tuple[str, ...] = ("head_x", "head_y", "head_scale", "head_roll")

#: ``fid_<name>_x``, ``fid_<name>_y`` for every fiducial.
FIDUCIAL_COLUMNS: tuple[str, ...] = tuple(
    f"fid_{name}_{axis}" for name in FIDUCIALS for axis in ("x", "y"))

#: FACS action units reported, in column order.
AU_NUMBERS: tuple[int, ...] = (1, 2, 4, 6, 9, 10, 12, 14, 15, 16, 17, 20, 23, 25, 26, 27)

#: ``AU01_r`` ... intensities in [0, 5].
AU_COLUMNS: tuple[str, ...] = tuple(f"AU{n:02d}_r" for n in AU_NUMBERS)

# Decimals written per column: pixels to 1/1000, seconds to the microsecond,
# contractions and radians to 1e-6, AU intensities and confidence to 1e-4.
_DECIMALS: dict[str, int] = {
    "timestamp": 6, "confidence": 4,
    **{c: 3 for c in ("head_x", "head_y", "head_scale")},
    "head_roll": 6,
    **{c: 3 for c in FIDUCIAL_COLUMNS},
    **{c: 6 for c in MUSCLES},
    JAW: 6,
    **{c: 4 for c in AU_COLUMNS},
}
_INTEGER_COLUMNS = ("frame", "success")
_RANGES: dict[str, tuple[float, float]] = {
    "confidence": (0.0, 1.0), **{m: (0.0, 1.0) for m in MUSCLES},
    **{a: (0.0, 5.0) for a in AU_COLUMNS},
}


def contraction_columns() -> list[str]:
    """All columns of ``contractions.csv``, in file order.

    Examples
    --------
    >>> cols = contraction_columns()
    >>> cols[:5], len(cols)
    (['frame', 'timestamp', 'success', 'confidence', 'head_x'], 76)
    """
    return [*FRAME_COLUMNS, *HEAD_COLUMNS, *FIDUCIAL_COLUMNS, *MUSCLES, JAW, *AU_COLUMNS]


def empty_table(n: int, *, frames: Sequence[int] | None = None,
                timestamps: Sequence[float] | None = None) -> pd.DataFrame:
    """A table of ``n`` lost frames to be filled in by the pipeline.

    Parameters
    ----------
    n : int
        Number of rows.
    frames : sequence of int, optional
        Frame numbers; ``0 .. n-1`` by default.
    timestamps : sequence of float, optional
        Seconds; NaN by default.

    Returns
    -------
    DataFrame
        Every column of :func:`contraction_columns`; ``success`` 0, every other
        measurement NaN.

    Examples
    --------
    >>> t = empty_table(3)
    >>> t["frame"].tolist(), int(t["success"].sum()), bool(t["zygomaticus_major_l"].isna().all())
    ([0, 1, 2], 0, True)
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    frame = np.arange(n) if frames is None else np.asarray(frames, dtype=np.int64)
    if frame.shape != (n,):
        raise ValueError(f"frames has {frame.size} entries, expected {n}")
    data: dict[str, np.ndarray] = {c: np.full(n, np.nan) for c in contraction_columns()}
    data["frame"] = frame.astype(np.int64)
    data["success"] = np.zeros(n, dtype=np.int64)
    if timestamps is not None:
        ts = np.asarray(timestamps, dtype=float)
        if ts.shape != (n,):
            raise ValueError(f"timestamps has {ts.size} entries, expected {n}")
        data["timestamp"] = ts
    return pd.DataFrame(data, columns=contraction_columns())


def au_intensities(contractions: pd.DataFrame,
                   action_units: Mapping[int, Mapping[str, float]]) -> pd.DataFrame:
    """Action-unit intensities (0..5) that best explain each frame's contractions.

    Each action unit ``k`` at full intensity (5) activates muscles by the
    amounts ``action_units[k]`` (a FACS table such as ``synth.facs.ACTION_UNITS``;
    ``jaw_rotation`` may appear, in radians). Per frame, the intensities ``I`` solve
    the bounded least-squares problem ``min ||A I / 5 - c||^2`` with
    ``0 <= I <= 5``, where ``c`` are the frame's muscle and jaw values; this
    shares a muscle between action units that use it instead of counting it twice.

    Parameters
    ----------
    contractions : DataFrame
        Columns named like :data:`MUSCLES` (and optionally ``jaw_rotation``);
        missing muscles count as 0.
    action_units : mapping
        AU number -> {muscle or ``jaw_rotation``: activation at full intensity}.

    Returns
    -------
    DataFrame
        One column per :data:`AU_COLUMNS` entry, same index as ``contractions``.
        Action units absent from ``action_units`` and frames with any NaN among
        the used muscles are NaN.

    Examples
    --------
    >>> import pandas as pd
    >>> table = pd.DataFrame({"zygomaticus_major_l": [0.0, 0.4], "zygomaticus_major_r": [0.0, 0.4]})
    >>> aus = au_intensities(table, {12: {"zygomaticus_major_l": 0.8, "zygomaticus_major_r": 0.8}})
    >>> aus["AU12_r"].round(3).tolist()
    [0.0, 2.5]
    """
    known = set(MUSCLES) | {JAW}
    used_aus = [n for n in AU_NUMBERS if n in action_units]
    names = sorted({m for n in used_aus for m in action_units[n]})
    unknown = [m for m in names if m not in known]
    if unknown:
        raise ValueError(f"action_units names unknown muscles: {', '.join(unknown)}")
    out = pd.DataFrame(np.nan, index=contractions.index, columns=list(AU_COLUMNS))
    if not used_aus or not names:
        return out
    A = np.array([[float(action_units[n].get(m, 0.0)) for n in used_aus] for m in names])
    c = np.column_stack([
        pd.to_numeric(contractions[m], errors="coerce").to_numpy(float)
        if m in contractions else np.zeros(len(contractions)) for m in names])
    valid = np.isfinite(c).all(axis=1)
    x = _bounded_lsq_batch(A, c[valid], upper=1.0)
    values = np.full((len(contractions), len(used_aus)), np.nan)
    values[valid] = 5.0 * x + 0.0  # no negative zeros
    for k, n in enumerate(used_aus):
        out[f"AU{n:02d}_r"] = values[:, k]
    return out


def _bounded_lsq_batch(A: np.ndarray, C: np.ndarray, *, upper: float,
                       tol: float = 1e-10, max_iter: int = 20000) -> np.ndarray:
    """Solve ``min ||A x - c||`` with ``0 <= x <= upper`` for every row ``c`` of ``C``.

    Accelerated projected gradient (FISTA with restart), vectorised over rows.
    """
    n_rows, n_vars = C.shape[0], A.shape[1]
    if n_rows == 0:
        return np.zeros((0, n_vars))
    G = A.T @ A
    B = C @ A  # (rows, vars) = A^T c per row
    L = float(np.linalg.eigvalsh(G).max())
    if L <= 0:
        return np.zeros((n_rows, n_vars))
    x = np.clip(np.linalg.lstsq(A, C.T, rcond=None)[0].T, 0.0, upper)
    y, t = x.copy(), 1.0
    for _ in range(max_iter):
        x_new = np.clip(y - (y @ G - B) / L, 0.0, upper)
        step = np.abs(x_new - x).max()
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        y = x_new + ((t - 1.0) / t_new) * (x_new - x)
        # Adaptive restart keeps the momentum from overshooting.
        restart = ((y - x_new) * (x_new - x)).sum(axis=1) < 0
        y[restart] = x_new[restart]
        x, t = x_new, t_new
        if step < tol:
            break
    return x


def _check_frame(df: pd.DataFrame, path) -> None:
    missing = [c for c in contraction_columns() if c not in df.columns]
    if missing:
        shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6
                                          else "")
        raise ValueError(f"{path}: missing columns {shown}")


def write_contractions(df: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write ``df`` as ``contractions.csv``, atomically, in the fixed column order.

    Parameters
    ----------
    df : DataFrame
        Must hold every column of :func:`contraction_columns`; further columns
        are written after them in their own order. Not modified.
    path : path-like
        Target file.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If columns are missing, or values are invalid (see :func:`read_contractions`).

    Notes
    -----
    Floats are rounded per column (pixels to 3 decimals, contractions, radians
    and seconds to 6, AU intensities and confidence to 4) and written as the
    shortest decimal that reads back as that value; NaN is an empty cell. The file
    appears only when complete.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "contractions.csv"
    >>> t = empty_table(2, timestamps=[0.0, 0.04])
    >>> t.loc[1, ["success", "confidence", "zygomaticus_major_l"]] = [1, 0.9, 0.25]
    >>> _ = write_contractions(t, path)
    >>> read_contractions(path).loc[1, "zygomaticus_major_l"]
    np.float64(0.25)
    """
    path = Path(path)
    _check_frame(df, path)
    _validate(df, path)
    columns = contraction_columns()
    extra = [c for c in df.columns if c not in set(columns)]
    out = {}
    for column in columns + extra:
        if column in _INTEGER_COLUMNS:
            out[column] = pd.to_numeric(df[column]).astype(np.int64)
        elif column in _DECIMALS:
            values = pd.to_numeric(df[column]).astype(float)
            # Rounded doubles print as their shortest decimal, so this fixes the precision
            # and keeps pandas' fast float writer; 0.0 instead of -0.0.
            out[column] = values.round(_DECIMALS[column]) + 0.0
        else:
            out[column] = df[column]
    with atomic_path(path) as tmp:
        pd.DataFrame(out, index=df.index).to_csv(tmp, index=False, lineterminator="\n",
                                                 na_rep="")
    return path


def _row_label(df: pd.DataFrame, position: int) -> str:
    frame = df["frame"].iloc[position] if "frame" in df else None
    line = position + 2  # header is line 1
    try:
        return f"line {line} (frame {int(float(frame))})"
    except (TypeError, ValueError):
        return f"line {line}"


def _validate(df: pd.DataFrame, path) -> pd.DataFrame:
    """Convert every known column to numbers, raising on the first bad cell."""
    numeric: dict[str, np.ndarray] = {}
    for column in contraction_columns():
        raw = df[column]
        if pd.api.types.is_numeric_dtype(raw):
            values = raw.to_numpy(dtype=float)
        else:
            converted = pd.to_numeric(raw, errors="coerce")
            blank = raw.isna() | (raw.astype(str).str.strip() == "")
            bad = converted.isna() & ~blank
            if bad.any():
                pos = int(np.flatnonzero(bad.to_numpy())[0])
                raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                                 f"{str(raw.iloc[pos])!r} is not a number")
            values = converted.to_numpy(dtype=float)
        if column in ("frame", "timestamp", "success") and np.isnan(values).any():
            pos = int(np.flatnonzero(np.isnan(values))[0])
            raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                             "empty cell")
        if column in _INTEGER_COLUMNS:
            wrong = values != np.round(values)
            if column == "success":
                wrong |= ~np.isin(values, (0.0, 1.0))
            if wrong.any():
                pos = int(np.flatnonzero(wrong)[0])
                expected = "0 or 1" if column == "success" else "an integer"
                raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                                 f"{values[pos]:g} is not {expected}")
        if column in _RANGES:
            lo, hi = _RANGES[column]
            with np.errstate(invalid="ignore"):
                wrong = (values < lo) | (values > hi) | np.isinf(values)
            if wrong.any():
                pos = int(np.flatnonzero(wrong)[0])
                raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                                 f"{values[pos]:g} is outside [{lo:g}, {hi:g}]")
        numeric[column] = values
    frames = numeric["frame"]
    if frames.size > 1 and (np.diff(frames) <= 0).any():
        pos = int(np.flatnonzero(np.diff(frames) <= 0)[0]) + 1
        raise ValueError(f"{path}: {_row_label(df, pos)}, column frame: frame numbers must "
                         "increase")
    return pd.DataFrame(numeric, index=df.index)


def read_contractions(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate a ``contractions.csv`` file.

    Parameters
    ----------
    path : path-like
        The file.

    Returns
    -------
    DataFrame
        Columns of :func:`contraction_columns` (then any further ones in file
        order); ``frame`` and ``success`` as integers, the rest as floats, empty
        cells as NaN.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a table, required columns are missing (named), a cell
        is not a number, ``success`` is not 0/1, frame numbers do not increase, or
        a value is out of range (contractions and confidence outside [0, 1], AU
        intensities outside [0, 5]); the message names the line, frame and column.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, expected a contractions.csv file")
    try:
        # Numeric columns parse in C; a column holding any non-number stays text and
        # is checked cell by cell in _validate, which names the offending cell.
        raw = pd.read_csv(path, keep_default_na=False, na_values=[""], low_memory=False)
    except pd.errors.EmptyDataError:
        raise ValueError(f"{path}: file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"{path}: not a CSV table ({first})") from None
    raw.columns = [str(c).strip() for c in raw.columns]
    _check_frame(raw, path)
    numeric = _validate(raw, path)
    out = numeric.copy()
    out["frame"] = out["frame"].astype(np.int64)
    out["success"] = out["success"].astype(np.int64)
    for column in raw.columns:
        if column not in out.columns:
            values = pd.to_numeric(raw[column], errors="coerce")
            keep_numeric = values.notna().sum() == raw[column].notna().sum()
            out[column] = values if keep_numeric else raw[column]
    return out
