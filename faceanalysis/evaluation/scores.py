"""Scores of an analysis against ground truth: per control, the jaw and the fiducials.

:func:`evaluate` scores one analysis against one synthetic sequence's ground truth;
:func:`compare` is the same with the aligned arrays kept for :func:`pool`, which pools
the scores of many sequences (the standard suite, :mod:`faceanalysis.evaluation.suite`).

Scores (pooled over all tracked frames of all sequences):

* per control: RMSE (contraction units; jaw in radians) and Pearson r;
* jaw: RMSE in degrees;
* fiducials: mean distance in pixels between tracked and projected fiducials.
"""

from __future__ import annotations

import filecmp
import json
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV
from faceanalysis.io.table import FIDUCIALS, JAW, MUSCLES, read_csv_table

__all__ = ["compare", "evaluate", "format_table", "pool", "public"]


def _load_table(source, name: str) -> pd.DataFrame:
    if isinstance(source, pd.DataFrame):
        return source
    path = Path(source)
    if path.is_dir():
        path = path / name
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    return read_csv_table(path)


def _frames_text(frames: np.ndarray) -> str:
    n = len(frames)
    if not n:
        return "0 frames"
    return f"{n} frame{'s' if n != 1 else ''} ({int(frames.min())}-{int(frames.max())})"


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _folder(source) -> Path | None:
    """The folder of a table given as a path (None for a DataFrame)."""
    if isinstance(source, pd.DataFrame):
        return None
    path = Path(source)
    return path if path.is_dir() else path.parent


def _sequence_mismatch(truth, estimate) -> str | None:
    """Why ``truth`` and ``estimate`` describe different sequences, or None.

    Uses what both folders say about their input: the synthetic sequence's ``meta.json``
    (video, size, frames) and the analysis's ``analysis.json`` (input path, size, frame
    count). Nothing is concluded where either is absent.
    """
    t_dir, e_dir = _folder(truth), _folder(estimate)
    if t_dir is None or e_dir is None:
        return None
    meta = _read_json(t_dir / "meta.json")
    analysis = _read_json(e_dir / ANALYSIS_JSON)
    if meta is None or analysis is None or not isinstance(analysis.get("input"), dict):
        return None
    source = analysis["input"]
    for key_t, key_e, what in (("size", "size", "size"), ("frames", "frame_count", "frames")):
        a, b = meta.get(key_t), source.get(key_e)
        if a is not None and b is not None and a != b:
            return (f"the truth's video ({t_dir / 'meta.json'}) has {what} {a}, the analysed "
                    f"input ({source.get('path')}) {b}")
    video = (meta.get("files") or {}).get("video") or meta.get("video")
    analysed = source.get("path")
    if video and analysed:
        t_video, e_video = (t_dir / video).resolve(), Path(analysed).resolve()
        if (t_video != e_video and t_video.is_file() and e_video.is_file()
                and not filecmp.cmp(t_video, e_video, shallow=False)):
            return f"the analysis read {e_video}, not the truth's video {t_video}"
    return None


def _check_same_sequence(t: pd.DataFrame, e: pd.DataFrame, truth, estimate) -> None:
    tf = np.unique(t["frame"].to_numpy())
    ef = np.unique(e["frame"].to_numpy())
    hint = "; pass allow_partial=True (--allow-partial) to score only the frames they share"
    if len(t) != len(e) or not np.array_equal(tf, ef):
        raise ValueError(f"truth has {_frames_text(tf)} but the estimate has "
                         f"{_frames_text(ef)}: not the same sequence or range{hint}")
    why = _sequence_mismatch(truth, estimate)
    if why is not None:
        raise ValueError(f"truth and estimate ({len(tf)} frames each) are not the same "
                         f"sequence: {why}{hint}")


def compare(truth, estimate, *, controls=None, allow_partial: bool = False) -> dict:
    """Score an estimated contractions table against ground truth.

    Parameters
    ----------
    truth : DataFrame or path
        ``truth.csv`` of a synthetic sequence (or its folder).
    estimate : DataFrame or path
        ``contractions.csv`` of its analysis (or the analysis folder).
    controls : sequence of str, optional
        Controls to score (default: every muscle and the jaw present in both).
    allow_partial : bool
        Score the frames the two tables share even when their frames differ (an analysis
        of a subrange) or their folders describe different inputs. By default both are
        refused.

    Returns
    -------
    dict
        ``frames``, ``frames_compared``, ``controls`` (name -> rmse, r, truth_max),
        ``jaw_rmse_deg``, ``fiducial_error_px`` (mean), ``fiducial_error_by_point``, and the
        aligned arrays under ``_pairs`` (for pooling; not JSON). Where the estimate flags its
        values (``<control>_identifiable``), each control also has ``identifiable`` (the
        share of compared frames flagged measured), and the report has
        ``identifiable_controls`` (flagged on at least half the frames and moving in the
        truth) with their ``identifiable_median_rmse``, ``identifiable_max_rmse`` and
        ``identifiable_median_r``.

    Raises
    ------
    ValueError
        Unless ``allow_partial``: if the tables hold different frames (the message names
        both counts and ranges), or if the truth's ``meta.json`` and the analysis's
        ``analysis.json`` name different inputs.
    """
    t = _load_table(truth, "truth.csv")
    e = _load_table(estimate, CONTRACTIONS_CSV)
    for df, what in ((t, "truth"), (e, "estimate")):
        if "frame" not in df.columns:
            raise ValueError(f"{what} table has no 'frame' column")
    if not allow_partial:
        _check_same_sequence(t, e, truth, estimate)
    merged = t.merge(e, on="frame", suffixes=("_t", "_e"))
    if merged.empty:
        raise ValueError("truth and estimate share no frame numbers")
    ok = merged["success_e"].to_numpy() == 1 if "success_e" in merged else \
        np.ones(len(merged), bool)
    if controls is None:
        controls = [c for c in (*MUSCLES, JAW) if c in t.columns and c in e.columns]
    pairs = {c: (merged[f"{c}_t"].to_numpy(float)[ok], merged[f"{c}_e"].to_numpy(float)[ok])
             for c in controls}
    fid_t = np.stack([merged[[f"fid_{n}_x_t", f"fid_{n}_y_t"]].to_numpy(float)
                      for n in FIDUCIALS], axis=1)[ok]
    fid_e = np.stack([merged[[f"fid_{n}_x_e", f"fid_{n}_y_e"]].to_numpy(float)
                      for n in FIDUCIALS], axis=1)[ok]
    visible = np.ones(fid_t.shape[:2], bool)
    vis_cols = [f"fid_{n}_visible" for n in FIDUCIALS]
    if all(c in merged.columns for c in vis_cols):
        visible = merged[vis_cols].to_numpy()[ok].astype(bool)
    dist = np.hypot(*(fid_e - fid_t).transpose(2, 0, 1))
    pairs["_fiducials"] = (dist, visible)
    flags = {}
    for c in controls:
        col = f"{c}_identifiable"
        if col not in e.columns:
            continue
        # suffixed by the merge where the truth has the column too
        values = merged[col + "_e" if col in t.columns else col].to_numpy(float)[ok]
        if np.isfinite(values).any():
            flags[c] = values
    if flags:
        pairs["_identifiable"] = flags
    report = _scores(pairs)
    report.update(frames=int(len(merged)), frames_compared=int(ok.sum()))
    report["_pairs"] = pairs
    return report


def _pearson(a: np.ndarray, b: np.ndarray) -> float | None:
    if a.size < 3 or np.std(a) < 1e-9 or np.std(b) < 1e-9:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _scores(pairs: dict) -> dict:
    controls = {}
    for name, pair in pairs.items():
        if name.startswith("_"):
            continue
        t, e = pair
        good = np.isfinite(t) & np.isfinite(e)
        t, e = t[good], e[good]
        controls[name] = {
            "rmse": float(np.sqrt(np.mean((t - e) ** 2))) if t.size else None,
            "r": _pearson(t, e),
            "truth_max": float(np.max(t)) if t.size else None,
            "estimate_max": float(np.max(e)) if e.size else None,
        }
    flags = pairs.get("_identifiable")
    if flags:
        for name, f in flags.items():
            f = f[np.isfinite(f)]
            controls[name]["identifiable"] = float(f.mean()) if f.size else None
    out = {"controls": controls}
    out.update(_identifiable_summary(controls))
    jaw = controls.get(JAW)
    out["jaw_rmse_deg"] = None if not jaw or jaw["rmse"] is None else float(
        np.degrees(jaw["rmse"]))
    if "_fiducials" not in pairs:          # exact measurements (faceanalysis.evaluation.ceiling)
        out["fiducial_error_px"] = None
        out["fiducial_error_by_point"] = None
        return out
    dist, visible = pairs["_fiducials"]
    valid = visible & np.isfinite(dist)
    out["fiducial_error_px"] = float(dist[valid].mean()) if valid.any() else None
    out["fiducial_error_by_point"] = {
        n: (float(dist[:, j][valid[:, j]].mean()) if valid[:, j].any() else None)
        for j, n in enumerate(FIDUCIALS)}
    return out


def _identifiable_summary(controls: dict) -> dict:
    """Median RMSE and r over the controls the estimate flags measured on most of the
    frames (``<control>_identifiable``) and that move in the truth; empty when the
    estimate carries no flags."""
    if not any("identifiable" in s for s in controls.values()):
        return {}
    names = [n for n, s in controls.items()
             if (s.get("identifiable") or 0) >= 0.5 and (s.get("truth_max") or 0) > 1e-6]
    rmse = [controls[n]["rmse"] for n in names if controls[n]["rmse"] is not None]
    r = [controls[n]["r"] for n in names if controls[n]["r"] is not None]
    return {"identifiable_controls": names,
            "identifiable_median_rmse": float(np.median(rmse)) if rmse else None,
            "identifiable_max_rmse": float(np.max(rmse)) if rmse else None,
            "identifiable_median_r": float(np.median(r)) if r else None}


def pool(reports: list[dict]) -> dict:
    """Pool several :func:`compare` reports (all frames of all sequences together)."""
    if not reports:
        raise ValueError("nothing to pool")
    names = [k for k in reports[0]["_pairs"] if not k.startswith("_")]
    pairs = {n: (np.concatenate([r["_pairs"][n][0] for r in reports]),
                 np.concatenate([r["_pairs"][n][1] for r in reports])) for n in names}
    if all("_fiducials" in r["_pairs"] for r in reports):
        pairs["_fiducials"] = tuple(np.concatenate([r["_pairs"]["_fiducials"][k]
                                                    for r in reports]) for k in (0, 1))
    if all("_identifiable" in r["_pairs"] for r in reports):
        flagged = set.intersection(*(set(r["_pairs"]["_identifiable"]) for r in reports))
        pairs["_identifiable"] = {n: np.concatenate([r["_pairs"]["_identifiable"][n]
                                                     for r in reports]) for n in flagged}
    out = _scores(pairs)
    out["frames"] = int(sum(r["frames"] for r in reports))
    out["frames_compared"] = int(sum(r["frames_compared"] for r in reports))
    out["sequences"] = len(reports)
    return out


def public(report: dict) -> dict:
    """The report without its private arrays (JSON-ready)."""
    return {k: v for k, v in report.items() if not k.startswith("_")}


def format_table(reports: dict[str, dict], *, controls=None) -> str:
    """Markdown table of per-control RMSE and r, one column pair per estimator."""
    names = list(reports)
    first = reports[names[0]]["controls"]
    controls = controls or [c for c in first if any(
        (reports[n]["controls"].get(c, {}).get("truth_max") or 0) > 1e-6
        or (reports[n]["controls"].get(c, {}).get("estimate_max") or 0) > 1e-6 for n in names)]
    head = "| control | " + " | ".join(f"{n} RMSE | {n} r" for n in names) + " |"
    lines = [head, "|---|" + "---:|---:|" * len(names)]
    for c in controls:
        cells = []
        for n in names:
            s = reports[n]["controls"].get(c, {})
            rmse, r = s.get("rmse"), s.get("r")
            cells.append("-" if rmse is None else f"{rmse:.3f}")
            cells.append("-" if r is None else f"{r:.3f}")
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    for label, key in (("jaw error (deg)", "jaw_rmse_deg"),
                       ("fiducial error (px)", "fiducial_error_px")):
        cells = " | ".join(f"{_fmt(reports[n].get(key))} | " for n in names)
        lines.append(f"| {label} | {cells}|")
    if any("identifiable_controls" in reports[n] for n in names):
        cells = []
        for n in names:
            rep = reports[n]
            count = len(rep.get("identifiable_controls", ()))
            cells += [f"{_fmt(rep.get('identifiable_median_rmse'))} ({count})",
                      _fmt(rep.get("identifiable_median_r"))]
        lines.append("| median over the controls flagged identifiable (count) | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def evaluate(truth, estimate, *, controls=None, allow_partial: bool = False) -> dict:
    """Score an analysis against the ground truth of a synthetic sequence.

    Parameters
    ----------
    truth : DataFrame or path
        ``truth.csv`` of a synthetic sequence (``faceanalysis synth``), or its folder.
    estimate : DataFrame or path
        ``contractions.csv`` of its analysis, or the analysis folder.
    controls : sequence of str, optional
        Controls to score (default: every muscle and the jaw present in both).
    allow_partial : bool
        Score the shared frames of tables of different frames or inputs (see
        :func:`compare`); refused by default.

    Returns
    -------
    dict
        Plain JSON types: ``frames``, ``frames_compared``, ``controls`` (name -> rmse,
        r, truth_max), ``jaw_rmse_deg``, ``fiducial_error_px`` and
        ``fiducial_error_by_point``.

    Raises
    ------
    ValueError
        If truth and estimate hold different frames or inputs, unless ``allow_partial``.
    """
    return public(compare(truth, estimate, controls=controls, allow_partial=allow_partial))
