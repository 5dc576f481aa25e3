"""The ``contractions.csv`` table: column names, writing, reading and validation.

One row per frame, columns in this fixed order (docs/outputs.md describes each):

``frame, timestamp, success, confidence``
    frame number (0-based, in the input), seconds, 1 if the face was tracked
    in this frame else 0, tracking confidence in [0, 1];
``head_x, head_y, head_scale, head_roll``
    head reference frame in the image, as the trackers measure it
    (``trackers.fiducials.HeadFrame``): origin (pixels, x right, y down), reference
    length (pixels) and roll (radians; the head's x axis, toward the subject's left,
    points along ``(cos roll, sin roll)`` in image coordinates);
``fid_<name>_x, fid_<name>_y``
    the 11 fiducial points of :data:`FIDUCIALS` in image pixels;
one column per muscle of :data:`MUSCLES`
    contraction in [0, 1];
``jaw_rotation``
    radians, positive opens the mouth;
``AU01_r`` ... ``AU27_r``
    FACS action-unit intensities in [0, 5] (OpenFace-style names), derived from
    the muscles by :func:`au_intensities` (through :func:`synth.facs.muscles_to_aus`);
``<control>_identifiable``, ``AUxx_identifiable``
    1 where the frame's value is measured: the seen points tell the control apart from
    the others at the video's tracking noise and the frame observes it; 0 where it leans
    on the estimator's prior or holds an earlier value (:func:`with_identifiable_columns`).

Values that are unknown (a lost frame, an action unit without a muscle mapping)
are empty cells, read back as NaN.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.io.outputs import atomic_path
from synth.facs import JAW, MUSCLE_NAMES, PAIRED_MUSCLES
from trackers.fiducials import FIDUCIAL_NAMES

__all__ = [
    "AU_COLUMNS",
    "AU_NUMBERS",
    "FIDUCIALS",
    "FIDUCIAL_COLUMNS",
    "FRAME_COLUMNS",
    "HEAD_COLUMNS",
    "IDENTIFIABLE_COLUMNS",
    "POSE_COLUMNS",
    "EYE_COLUMNS",
    "JAW",
    "MUSCLES",
    "MUSCLE_BASES",
    "au_dependencies",
    "au_intensities",
    "contraction_columns",
    "empty_table",
    "head_turn",
    "measured_values",
    "read_contractions",
    "read_csv_table",
    "required_columns",
    "with_au_columns",
    "with_identifiable_columns",
    "write_contractions",
]

# The names belong to the packages that define them: the trackers' fiducials, the face
# model's muscles and jaw. The table re-exports them under its column-oriented names.
FIDUCIALS: tuple[str, ...] = FIDUCIAL_NAMES
MUSCLE_BASES: tuple[str, ...] = PAIRED_MUSCLES
MUSCLES: tuple[str, ...] = MUSCLE_NAMES

#: Per-frame bookkeeping columns.
FRAME_COLUMNS: tuple[str, ...] = ("frame", "timestamp", "success", "confidence")

#: Head reference frame columns.
HEAD_COLUMNS: tuple[str, ...] = ("head_x", "head_y", "head_scale", "head_roll")

#: Head pose beyond the image plane: pitch and yaw in degrees relative to the tracker's
#: first frame (the landmark tracker; empty with the snakes tracker).
POSE_COLUMNS: tuple[str, ...] = ("head_pitch", "head_yaw")

#: How far each eye is open (the subject's left, then right): its lid gap over the neutral
#: frame's, 0 closed, above 1 wider than at rest (the landmark tracker; empty with the
#: snakes tracker).
EYE_COLUMNS: tuple[str, ...] = ("eye_openness_l", "eye_openness_r")

#: ``fid_<name>_x``, ``fid_<name>_y`` for every fiducial.
FIDUCIAL_COLUMNS: tuple[str, ...] = tuple(
    f"fid_{name}_{axis}" for name in FIDUCIALS for axis in ("x", "y"))

#: FACS action units reported, in column order.
AU_NUMBERS: tuple[int, ...] = (1, 2, 4, 6, 9, 10, 12, 14, 15, 16, 17, 20, 23, 25, 26, 27)

#: ``AU01_r`` ... intensities in [0, 5].
AU_COLUMNS: tuple[str, ...] = tuple(f"AU{n:02d}_r" for n in AU_NUMBERS)

#: ``<control>_identifiable`` for every muscle and the jaw, then ``AUxx_identifiable``:
#: 1 where that column's value is measured, 0 where it is not (empty on lost frames).
IDENTIFIABLE_COLUMNS: tuple[str, ...] = (
    *(f"{c}_identifiable" for c in (*MUSCLES, JAW)),
    *(f"AU{n:02d}_identifiable" for n in AU_NUMBERS))

# Decimals written per column: pixels to 1/1000, seconds to the microsecond,
# contractions and radians to 1e-6, AU intensities and confidence to 1e-4.
_DECIMALS: dict[str, int] = {
    "timestamp": 6, "confidence": 4,
    **{c: 3 for c in ("head_x", "head_y", "head_scale")},
    "head_roll": 6,
    **{c: 3 for c in POSE_COLUMNS},
    **{c: 4 for c in EYE_COLUMNS},
    **{c: 3 for c in FIDUCIAL_COLUMNS},
    **{c: 6 for c in MUSCLES},
    JAW: 6,
    **{c: 4 for c in AU_COLUMNS},
}
_INTEGER_COLUMNS = ("frame", "success")
_FLAG_COLUMNS = frozenset(("success", *IDENTIFIABLE_COLUMNS))
_RANGES: dict[str, tuple[float, float]] = {
    "confidence": (0.0, 1.0), **{m: (0.0, 1.0) for m in MUSCLES},
    **{a: (0.0, 5.0) for a in AU_COLUMNS},
}


def heads_from_table(table: pd.DataFrame) -> np.ndarray:
    """Head frames ``(T, 4)`` from a contractions table (NaN where ``success == 0``).

    Examples
    --------
    >>> t = pd.DataFrame({"head_x": [1.0, 2.0], "head_y": [0.0, 0.0], "head_scale": [9.0, 9.0],
    ...                   "head_roll": [0.0, 0.0], "success": [1, 0]})
    >>> heads_from_table(t)[:, 0].tolist()
    [1.0, nan]
    """
    missing = [c for c in HEAD_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"table lacks head-frame columns {missing}")
    h = table[list(HEAD_COLUMNS)].to_numpy(float).copy()
    if "success" in table.columns:
        h[table["success"].to_numpy() == 0] = np.nan
    return h


def head_turn(table: pd.DataFrame, neutral_frame) -> np.ndarray:
    """Per row, degrees the head is turned out of the image plane from the neutral frame's
    pose (the hypotenuse of the pitch and yaw differences); NaN without a pose.

    Examples
    --------
    >>> t = pd.DataFrame({"frame": [0, 1, 2], "head_pitch": [1.0, 4.0, np.nan],
    ...                   "head_yaw": [2.0, 6.0, 0.0]})
    >>> head_turn(t, 0).tolist()
    [0.0, 5.0, nan]
    """
    turn = np.full(len(table), np.nan)
    if not set(POSE_COLUMNS) <= set(table.columns):
        return turn
    rows = np.flatnonzero(table["frame"].to_numpy() == neutral_frame)
    if not rows.size:
        return turn
    pose = table[list(POSE_COLUMNS)].to_numpy(float)
    return np.hypot(*(pose - pose[rows[0]]).T)


def contraction_columns() -> list[str]:
    """All columns of ``contractions.csv``, in file order.

    Examples
    --------
    >>> cols = contraction_columns()
    >>> cols[:5], len(cols)
    (['frame', 'timestamp', 'success', 'confidence', 'head_x'], 126)
    """
    return [*FRAME_COLUMNS, *HEAD_COLUMNS, *POSE_COLUMNS, *EYE_COLUMNS, *FIDUCIAL_COLUMNS,
            *MUSCLES, JAW,
            *AU_COLUMNS, *IDENTIFIABLE_COLUMNS]


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


def au_intensities(contractions: pd.DataFrame) -> pd.DataFrame:
    """FACS action-unit intensities (0..5) for every frame of a contractions table.

    An adapter to :func:`synth.facs.muscles_to_aus` (the model's own inverse of
    its action-unit-to-muscle table): jaw action units (25, 26, 27) come from
    ``jaw_rotation``, the others from a bounded least-squares fit of the muscle
    contractions; intensities are then put on the 0..5 scale of ``AUxx_r``.

    Parameters
    ----------
    contractions : DataFrame
        Columns named like :data:`MUSCLES` and ``jaw_rotation``; missing columns
        count as 0, other columns are ignored. Not modified.

    Returns
    -------
    DataFrame
        The :data:`AU_COLUMNS`, same index as ``contractions``; an action unit is NaN
        on a frame where a control it depends on (:func:`au_dependencies`) is NaN
        (all of them on a lost frame): a frame without its brows still has ``AU12_r``.

    Raises
    ------
    ValueError
        If a muscle or jaw value is infinite.

    Examples
    --------
    >>> import pandas as pd
    >>> table = pd.DataFrame({"zygomaticus_major_l": [0.0, 0.4, float("nan")],
    ...                       "zygomaticus_major_r": [0.0, 0.4, float("nan")]})
    >>> au_intensities(table)["AU12_r"].round(3).tolist()
    [0.0, 2.0, nan]
    """
    from synth.facs import muscles_to_aus

    columns = [c for c in (*MUSCLES, JAW) if c in contractions.columns]
    values = contractions[columns].apply(pd.to_numeric, errors="coerce").astype(float)
    if np.isinf(values.to_numpy()).any():
        raise ValueError("contractions hold infinite values; cannot derive action units")
    empty = values.isna().to_numpy()                                     # (T, C)
    some = ~empty.all(axis=1) if columns else np.ones(len(values), bool)
    out = pd.DataFrame(np.nan, index=contractions.index, columns=list(AU_COLUMNS))
    if some.any():
        # An empty control enters the fit as 0: the fit is separable over the groups of
        # action units that share muscles, so this moves only the action units that
        # depend on it, which are then emptied.
        est = muscles_to_aus(values.loc[some].fillna(0.0), aus=AU_NUMBERS)
        deps = au_dependencies()
        for n in AU_NUMBERS:
            needs = [j for j, c in enumerate(columns) if c in deps[n]]
            lost = empty[some][:, needs].any(axis=1)
            v = 5.0 * est[f"AU{n:02d}"].to_numpy() + 0.0
            out.loc[some, f"AU{n:02d}_r"] = np.where(lost, np.nan, v)
    return out


def au_dependencies() -> dict[int, frozenset[str]]:
    """The controls each action unit of :data:`AU_NUMBERS` is derived from.

    Jaw action units (25, 26, 27) come from ``jaw_rotation`` alone; the others from
    the muscles of :data:`synth.facs.ACTION_UNITS`, together with those of every action
    unit that shares a muscle with them (e.g. AU 1 and AU 2 share the frontalis major),
    since :func:`synth.facs.muscles_to_aus` fits such action units jointly.

    Examples
    --------
    >>> deps = au_dependencies()
    >>> sorted(deps[12]), sorted(deps[26])
    (['zygomaticus_major_l', 'zygomaticus_major_r'], ['jaw_rotation'])
    >>> "frontalis_outer_l" in deps[1]
    True
    """
    from synth.facs import ACTION_UNITS

    jaw_aus = {25, 26, 27}
    own = {n: frozenset(ACTION_UNITS[n]) - {JAW} for n in AU_NUMBERS if n not in jaw_aus}
    deps = {n: frozenset({JAW}) for n in AU_NUMBERS if n in jaw_aus}
    for n, muscles in own.items():
        group, grown = set(muscles), True
        while grown:
            linked = set().union(*(m for m in own.values() if m & group))
            grown = not linked <= group
            group |= linked
        deps[n] = frozenset(group)
    return deps


def with_au_columns(table: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``table`` with its ``AUxx_r`` columns computed by :func:`au_intensities`."""
    out = table.copy()
    out[list(AU_COLUMNS)] = au_intensities(table)
    return out


def with_identifiable_columns(table: pd.DataFrame, identifiable, *,
                              observed: np.ndarray | None = None) -> pd.DataFrame:
    """A copy of ``table`` with its :data:`IDENTIFIABLE_COLUMNS` set.

    Parameters
    ----------
    table : DataFrame
        A contractions table (``success`` and the control columns).
    identifiable : collection of str
        The controls the video's seen points tell apart at its tracking noise
        (``analysis.json`` ``identifiability``). A control outside it, or one the estimator
        does not estimate, is never flagged measured.
    observed : ndarray of bool, shape (T, 27), optional
        Per frame and control of ``(*MUSCLES, JAW)``, whether the estimator observed it on
        that frame (a control whose points were lost holds an earlier value). All by default.

    Returns
    -------
    DataFrame
        ``<control>_identifiable`` is 1 on a tracked frame where the control is identifiable
        and observed, else 0; ``AUxx_identifiable`` is 1 where every control the action unit
        is derived from (:func:`au_dependencies`) is; lost frames are empty.

    Examples
    --------
    >>> t = empty_table(2)
    >>> t.loc[1, "success"] = 1
    >>> out = with_identifiable_columns(t, {"zygomaticus_major_l", "zygomaticus_major_r"})
    >>> out["zygomaticus_major_l_identifiable"].tolist(), out["AU12_identifiable"].tolist()
    ([nan, 1.0], [nan, 1.0])
    >>> out["AU01_identifiable"].tolist()
    [nan, 0.0]
    """
    controls = (*MUSCLES, JAW)
    n = len(table)
    if observed is None:
        observed = np.ones((n, len(controls)), dtype=bool)
    observed = np.asarray(observed, dtype=bool)
    if observed.shape != (n, len(controls)):
        raise ValueError(f"observed must have shape (T={n}, {len(controls)}), "
                         f"got {observed.shape}")
    unknown = sorted(set(identifiable) - set(controls))
    if unknown:
        raise ValueError(f"unknown controls {unknown}; choose from {', '.join(controls)}")
    success = table["success"].to_numpy() == 1
    identifiable = set(identifiable)
    known = np.array([c in identifiable for c in controls])
    flags = observed & known[None, :]
    deps = au_dependencies()
    au_flags = [flags[:, [j for j, c in enumerate(controls) if c in deps[n_au]]].all(axis=1)
                for n_au in AU_NUMBERS]
    values = np.column_stack([flags, *au_flags]).astype(float)
    values[~success] = np.nan
    # one block for all the flags: setting 46 columns one by one fragments the frame
    kept = table.drop(columns=[c for c in IDENTIFIABLE_COLUMNS if c in table.columns])
    return pd.concat([kept, pd.DataFrame(values, index=table.index,
                                         columns=list(IDENTIFIABLE_COLUMNS))], axis=1)


def identifiable_column(column: str) -> str:
    """The flag column that says where ``column``'s value is measured.

    Examples
    --------
    >>> identifiable_column("zygomaticus_major_l"), identifiable_column("AU12_r")
    ('zygomaticus_major_l_identifiable', 'AU12_identifiable')
    """
    if column.startswith("AU") and column.endswith("_r"):
        return column[:-2] + "_identifiable"
    return f"{column}_identifiable"


def measured_values(table: pd.DataFrame, columns=None) -> pd.DataFrame:
    """The values of a contractions table that are measured, the others empty.

    A value is kept on a tracked frame (``success`` 1) unless its flag
    (:data:`IDENTIFIABLE_COLUMNS`, :func:`identifiable_column`) is 0 there: a value the
    points could not tell apart, that holds an earlier frame's because its points were
    lost, or that the estimator reports at rest. A table without flags (``truth.csv``, an
    older analysis) keeps every tracked frame's values. The input is not modified.

    Parameters
    ----------
    table : DataFrame
        A contractions table (:func:`read_contractions`, ``Analysis.table``).
    columns : sequence of str, optional
        The value columns to return (default: every muscle, ``jaw_rotation`` and every
        ``AUxx_r`` the table has).

    Returns
    -------
    DataFrame
        ``columns``, indexed as ``table``.

    Examples
    --------
    >>> t = empty_table(3)
    >>> t["success"] = [1, 1, 0]
    >>> t["zygomaticus_major_l"] = [0.2, 0.6, float("nan")]
    >>> t["zygomaticus_major_l_identifiable"] = [1, 0, float("nan")]
    >>> measured_values(t, ["zygomaticus_major_l"])["zygomaticus_major_l"].tolist()
    [0.2, nan, nan]
    """
    if columns is None:
        columns = [c for c in (*MUSCLES, JAW, *AU_COLUMNS) if c in table]
    columns = list(columns)
    missing = [c for c in ("success", *columns) if c not in table]
    if missing:
        raise ValueError(f"table has no column(s) {', '.join(missing)}")
    tracked = pd.to_numeric(table["success"], errors="coerce").to_numpy(float) == 1
    out = pd.DataFrame(index=table.index)
    for column in columns:
        keep = tracked.copy()
        flag = identifiable_column(column)
        if flag in table:
            f = pd.to_numeric(table[flag], errors="coerce").to_numpy(float)
            keep &= ~(f == 0)               # an empty flag: not known, the value stays
        out[column] = pd.to_numeric(table[column], errors="coerce").where(keep)
    return out


def _with_optional(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with empty pose, eye and identifiability columns where it has none: tables
    written before these were measured, the snakes tracker's (no pose) and a synthetic
    sequence's ``truth.csv`` are still tables."""
    missing = [c for c in (*POSE_COLUMNS, *EYE_COLUMNS, *IDENTIFIABLE_COLUMNS)
               if c not in df.columns]
    if not missing:
        return df
    df = df.copy()
    for c in missing:
        df[c] = np.nan
    return df


def required_columns() -> list[str]:
    """The columns a contractions table must have: :func:`contraction_columns` less the
    pose, eye and identifiability columns, which a table may lack (read back empty).

    Examples
    --------
    >>> len(required_columns()), "head_pitch" in required_columns()
    (76, False)
    """
    optional = {*POSE_COLUMNS, *EYE_COLUMNS, *IDENTIFIABLE_COLUMNS}
    return [c for c in contraction_columns() if c not in optional]


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
    df = _with_optional(df)
    _check_frame(df, path)
    _validate(df, path)
    columns = contraction_columns()
    extra = [c for c in df.columns if c not in set(columns)]
    out = {}
    for column in columns + extra:
        if column in _INTEGER_COLUMNS:
            out[column] = pd.to_numeric(df[column]).astype(np.int64)
        elif column in _FLAG_COLUMNS:
            out[column] = pd.to_numeric(df[column]).astype("Int64")   # 0, 1 or empty
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


def numeric_column(df: pd.DataFrame, column: str, where) -> np.ndarray:
    """The cells of ``df[column]`` as floats (empty cells NaN), or a ``ValueError`` naming
    ``where``, the line, the frame and the column of the first cell that is not a number.

    Examples
    --------
    >>> t = pd.DataFrame({"frame": [0, 1], "jaw_rotation": ["0.1", "wide"]})
    >>> numeric_column(t, "jaw_rotation", "t.csv")
    Traceback (most recent call last):
    ...
    ValueError: t.csv: line 3 (frame 1), column jaw_rotation: 'wide' is not a number
    """
    raw = df[column]
    if pd.api.types.is_numeric_dtype(raw):
        return raw.to_numpy(dtype=float)
    converted = pd.to_numeric(raw, errors="coerce")
    blank = raw.isna() | (raw.astype(str).str.strip() == "")
    bad = converted.isna() & ~blank
    if bad.any():
        pos = int(np.flatnonzero(bad.to_numpy())[0])
        raise ValueError(f"{where}: {_row_label(df, pos)}, column {column}: "
                         f"{str(raw.iloc[pos])!r} is not a number")
    return converted.to_numpy(dtype=float)


def _validate(df: pd.DataFrame, path) -> pd.DataFrame:
    """Convert every known column to numbers, raising on the first bad cell."""
    numeric: dict[str, np.ndarray] = {}
    for column in contraction_columns():
        values = numeric_column(df, column, path)
        if column in ("frame", "timestamp", "success") and np.isnan(values).any():
            pos = int(np.flatnonzero(np.isnan(values))[0])
            raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                             "empty cell")
        if column in _INTEGER_COLUMNS:
            wrong = values != np.round(values)
            if wrong.any():
                pos = int(np.flatnonzero(wrong)[0])
                raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                                 f"{values[pos]:g} is not an integer")
        if column in _FLAG_COLUMNS:
            wrong = ~np.isin(values, (0.0, 1.0)) & ~np.isnan(values)
            if wrong.any():
                pos = int(np.flatnonzero(wrong)[0])
                raise ValueError(f"{path}: {_row_label(df, pos)}, column {column}: "
                                 f"{values[pos]:g} is not 0 or 1")
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


def _delimiter(path) -> str:
    """The header line's delimiter: ',' as written, ';' or a tab as a spreadsheet may re-save."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as file:
            header = file.readline()
    except OSError:
        return ","
    if "," in header:
        return ","
    return ";" if ";" in header else "\t" if "\t" in header else ","


def read_csv_table(path: str | os.PathLike, *, nrows: int | None = None) -> pd.DataFrame:
    """Read a CSV table as written, or as a spreadsheet re-saved it.

    Comma-separated tables are read as they are. A table whose header is separated by
    semicolons is read with decimal commas too (``0,25``), as spreadsheets save "CSV" where
    the comma is the decimal separator, and one separated by tabs as such. Empty cells
    are NaN; a column any of whose cells is not a number stays text, for the validation to
    name the cell.

    Parameters
    ----------
    path : path-like
        The file.
    nrows : int, optional, keyword-only
        Read only this many rows (0: the header).

    Returns
    -------
    DataFrame

    Raises
    ------
    pandas.errors.EmptyDataError, pandas.errors.ParserError, UnicodeDecodeError
        As :func:`pandas.read_csv`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = path.write_text("frame;zygomaticus_major_l\\n0;0,25\\n1;\\n")
    >>> read_csv_table(path).to_dict("list")
    {'frame': [0, 1], 'zygomaticus_major_l': [0.25, nan]}
    """
    sep = _delimiter(path)
    options = dict(keep_default_na=False, na_values=[""], low_memory=False, nrows=nrows)
    if sep != ";":
        return pd.read_csv(path, sep=sep, **options)
    raw = pd.read_csv(path, sep=sep, dtype=str, **options)
    columns = {}
    for column in raw.columns:
        text = raw[column].str.replace(",", ".", regex=False)
        values = pd.to_numeric(text, errors="coerce")
        columns[column] = values if values.notna().sum() == text.notna().sum() else raw[column]
    return pd.DataFrame(columns, index=raw.index)


def read_contractions(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate a ``contractions.csv`` file.

    Parameters
    ----------
    path : path-like
        The file: as written, or re-saved by a spreadsheet (see :func:`read_csv_table`).

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
        raw = read_csv_table(path)
    except pd.errors.EmptyDataError:
        raise ValueError(f"{path}: file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"{path}: not a CSV table ({first})") from None
    raw.columns = [str(c).strip() for c in raw.columns]
    raw = _with_optional(raw)
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
