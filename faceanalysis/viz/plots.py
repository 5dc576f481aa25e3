"""Time-series plot of estimated contractions (``contractions.png``, like Fig. 8 of 004).

Uses matplotlib's object-oriented API with the Agg canvas: no display and no
global ``pyplot`` state, so it is safe in headless runs and worker processes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from faceanalysis.io.outputs import atomic_path
from faceanalysis.io.report import lost_reasons_text
from faceanalysis.io.table import EYE_COLUMNS, JAW, MUSCLE_BASES, MUSCLES

__all__ = ["plot_contractions", "save_figure"]

# One colour per muscle (pairs share it); fixed, so a muscle has the same colour in every plot.
_BASES = MUSCLE_BASES + ("orbicularis_oris", "orbicularis_oculi")
_PALETTE = (
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
    "#bcbd22", "#7f7f7f", "#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#a6761d",
)
_COLOURS = dict(zip(_BASES, _PALETTE))

#: Muscles whose largest contraction is below this are left out of the default plot.
ACTIVE_THRESHOLD = 0.02


def _base(muscle: str) -> tuple[str, str]:
    """Split ``zygomaticus_major_l`` into ("zygomaticus_major", "l")."""
    if muscle.endswith(("_l", "_r")):
        return muscle[:-2], muscle[-1]
    return muscle, ""


def save_figure(fig: Figure, path: str | os.PathLike, *, dpi: int = 150) -> Path:
    """Save ``fig`` atomically; the format follows the suffix (``.png``, ``.pdf``, ``.svg``)."""
    path = Path(path)
    if not path.suffix:
        raise ValueError(f"{path}: give a suffix such as .png, .pdf or .svg")
    if fig.canvas is None or not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix[1:].lower(), facecolor="white")
    return path


def _spans(x: np.ndarray, marked: np.ndarray) -> list[tuple[float, float]]:
    """``(start, width)`` of each run of marked frames (lost, turned), half a frame wider
    on each side."""
    if not marked.any():
        return []
    step = float(np.nanmedian(np.diff(x))) if len(x) > 1 else 1.0
    idx = np.flatnonzero(marked)
    breaks = np.flatnonzero(np.diff(idx) != 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return [(x[a] - step / 2, x[b] - x[a] + step) for a, b in zip(starts, ends)]


def _choose_muscles(df: pd.DataFrame, muscles: Sequence[str] | None) -> list[str]:
    if muscles is None:
        chosen = []
        for m in MUSCLES:
            if m in df:
                values = pd.to_numeric(df[m], errors="coerce").to_numpy(float)
                if np.isfinite(values).any() and np.nanmax(values) >= ACTIVE_THRESHOLD:
                    chosen.append(m)
        return chosen
    if isinstance(muscles, str):
        muscles = [muscles]
    unknown = [m for m in muscles if m not in MUSCLES]
    if unknown:
        raise ValueError(f"unknown muscles: {', '.join(unknown)}; valid names are in "
                         "faceanalysis.io.table.MUSCLES")
    absent = [m for m in muscles if m not in df]
    if absent:
        raise ValueError(f"muscles not in the table: {', '.join(absent)}")
    return list(muscles)


#: Opacity of the controls the points cannot tell apart.
_FADED = 0.35


def _lost_label(n: int, reasons) -> str:
    """The legend's entry for ``n`` lost frames and their reasons (counts, or None).

    Examples
    --------
    >>> _lost_label(5, None), _lost_label(5, {"hand": 5})
    ('lost frames (5)', 'lost frames (5 under a hand)')
    >>> _lost_label(7, {"hand": 5, "no_face": 1})
    'lost frames (7: 5 under a hand, 1 without a face)'
    """
    if not reasons:
        return f"lost frames ({n})"
    text = lost_reasons_text(reasons)
    if sum(reasons.values()) == n:
        return f"lost frames ({text})"
    return f"lost frames ({n}: {text})"             # some of them without a known reason


_EYE_COLOUR = "#2f6f8f"


def plot_contractions(df: pd.DataFrame, path: str | os.PathLike | None = None, *,
                      muscles: Sequence[str] | None = None, title: str | None = None,
                      layout: str = "auto", dpi: int = 150,
                      not_identifiable: Sequence[str] = (),
                      turned: Sequence[bool] | np.ndarray | None = None,
                      lost_reasons: dict | None = None,
                      cuts: Sequence[int] = (),
                      photographs: bool = False) -> Figure:
    """Plot muscle contractions over time, one line per muscle.

    Left and right muscles of a pair share a colour: solid for the subject's
    left (``_l``), dashed for the right (``_r``). ``jaw_rotation`` is drawn in
    degrees, on a secondary axis (``layout="single"``) or in its own bottom panel
    (``layout="stacked"``). Frames where tracking failed (``success == 0``) are
    shaded grey; those whose head is turned too far for the estimates (``turned``)
    hatched.

    Parameters
    ----------
    df : DataFrame
        A contractions table (see :mod:`faceanalysis.io.table`); needs ``frame``
        or ``timestamp`` and the muscle columns to draw. Not modified.
    path : path-like, optional
        If given, the figure is saved there atomically (format from the suffix).
    muscles : sequence of str, optional
        Muscle columns to draw, in legend order. By default every muscle whose
        largest contraction reaches 0.02.
    title : str, optional
        Figure title; "Estimated muscle contractions" by default.
    layout : {'auto', 'single', 'stacked'}, keyword-only
        ``single``: every muscle on one axis, like Fig. 8 of 004. ``stacked``: one
        panel per muscle (pair) sharing the time axis, readable when many muscles
        are active, and one for the eyes' openness where ``df`` has it
        (``eye_openness_l``/``_r``, ``--eyes``). ``auto`` (default) stacks when more
        than five muscles (pairs) are drawn or the eyes were measured.
    dpi : int, keyword-only
        Resolution of the saved file (150 by default).
    not_identifiable : sequence of str, keyword-only
        Controls the tracked points cannot tell apart (``analysis.json``
        ``identifiability``): drawn faded, and the legend says so, so that a reader does
        not take them for measurements as good as the others.
    turned : sequence of bool, keyword-only, optional
        Per row of ``df``, whether the head is turned out of the image plane beyond
        what the estimates hold for (:data:`faceanalysis.analysis.pipeline.MAX_HEAD_TURN`
        from the neutral frame's pose; their ``confidence`` is lowered): hatched, so that
        a reader does not read them as a frontal face's values.
    lost_reasons : dict, keyword-only, optional
        How many frames were lost for each reason (``analysis.json``
        ``quality.lost_reasons``): the legend says why (e.g. "lost frames (168 under a
        hand)").
    cuts : sequence of int, keyword-only
        Frame numbers where a new shot begins (``analysis.json`` ``quality.shot_cuts``):
        a vertical line each, so that a reader sees where the face may be another
        person's or seen from another camera. Frames ``df`` does not hold are left out.
    photographs : bool, keyword-only
        The rows are photographs, not a video's frames
        (:func:`faceanalysis.io.video.is_photographs`): one mark per photograph and
        muscle over the frame numbers, with no line between photographs, which would
        read as motion between them.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        If a requested muscle is not a known muscle or not in ``df``, if ``df``
        has neither ``frame`` nor ``timestamp``, or if ``layout`` is unknown.

    Examples
    --------
    >>> import numpy as np, pandas as pd
    >>> t = np.linspace(0, 2, 61)
    >>> df = pd.DataFrame({"frame": np.arange(61), "timestamp": t, "success": 1,
    ...                    "zygomaticus_major_l": np.sin(np.pi * t / 2) ** 2,
    ...                    "zygomaticus_major_r": 0.8 * np.sin(np.pi * t / 2) ** 2})
    >>> fig = plot_contractions(df)
    >>> [line.get_linestyle() for line in fig.axes[0].lines]
    ['-', '--']
    """
    if layout not in ("auto", "single", "stacked"):
        raise ValueError(f"layout must be 'auto', 'single' or 'stacked', got {layout!r}")
    if turned is not None:
        turned = np.asarray(turned, dtype=bool)
        if turned.shape != (len(df),):
            raise ValueError(f"turned must have one value per row of the table ({len(df)}), "
                             f"got shape {turned.shape}")
    if "timestamp" not in df and "frame" not in df:
        raise ValueError("table has neither a 'frame' nor a 'timestamp' column")
    chosen = _choose_muscles(df, muscles)
    faded = set(not_identifiable)

    timestamps = (pd.to_numeric(df["timestamp"], errors="coerce").to_numpy(float)
                  if "timestamp" in df else None)
    photographs = photographs and "frame" in df
    if photographs:
        x, xlabel = pd.to_numeric(df["frame"]).to_numpy(float), "photograph (frame)"
    elif timestamps is not None and len(timestamps) and np.isfinite(timestamps).all():
        x, xlabel = timestamps, "time (s)"
    else:
        x, xlabel = pd.to_numeric(df["frame"]).to_numpy(float), "frame"
    # how the left and right muscles and the jaw are drawn: lines over time, or for
    # photographs marks (left filled, right hollow), which no line joins
    style = ({"l": dict(ls="none", marker="o", ms=6),
              "r": dict(ls="none", marker="o", ms=6, mfc="white"),
              "jaw": dict(ls="none", marker="x", ms=6)} if photographs
             else {"l": dict(ls="-"), "r": dict(ls="--"), "jaw": dict(ls=":")})

    bases: list[str] = []
    for m in chosen:
        if _base(m)[0] not in bases:
            bases.append(_base(m)[0])
    jaw = None
    if JAW in df:
        jaw = np.degrees(pd.to_numeric(df[JAW], errors="coerce").to_numpy(float))
        if not (np.isfinite(jaw).any() and np.nanmax(np.abs(jaw)) > 0):
            jaw = None
    eyes = None
    if all(c in df for c in EYE_COLUMNS):
        eyes = df[list(EYE_COLUMNS)].apply(pd.to_numeric, errors="coerce").to_numpy(float)
        if not np.isfinite(eyes).any():
            eyes = None
    stacked = layout == "stacked" or (layout == "auto" and (len(bases) > 5
                                                            or eyes is not None))
    if not stacked:
        eyes = None

    if stacked:
        n_panels = max(1, len(bases)) + (eyes is not None) + (jaw is not None)
        fig = Figure(figsize=(10, min(1.1 + 0.85 * n_panels, 40)), layout="constrained")
        FigureCanvasAgg(fig)
        axes = list(fig.subplots(n_panels, 1, sharex=True, squeeze=False)[:, 0])
        muscle_axes = {base: axes[k] for k, base in enumerate(bases)} if bases else {}
        main = axes[0]
    else:
        fig = Figure(figsize=(10, 4.8), layout="constrained")
        FigureCanvasAgg(fig)
        main = fig.add_subplot()
        axes = [main]
        muscle_axes = dict.fromkeys(bases, main)

    handles: list = []
    top: dict[int, float] = {}
    for m in chosen:
        values = pd.to_numeric(df[m], errors="coerce").to_numpy(float)
        base, side = _base(m)
        ax = muscle_axes[base]
        colour = _COLOURS.get(base, "#333333")
        ax.plot(x, values, color=colour, lw=1.4 if stacked else 1.6,
                **style["r" if side == "r" else "l"], label=m,
                alpha=_FADED if m in faded else 1.0)
        if np.isfinite(values).any():
            top[id(ax)] = max(top.get(id(ax), 0.0), float(np.nanmax(values)))
    for base in ([] if stacked else bases):  # stacked panels carry their own labels
        handles.append(Line2D([], [], color=_COLOURS.get(base, "#333333"), lw=2,
                              label=base.replace("_", " ")))
    for base, ax in muscle_axes.items():
        ax.set_ylim(0, min(1.05, max(0.1, 1.1 * top.get(id(ax), 0.0))))
        if stacked:
            ax.set_ylabel(base.replace("_", " "), rotation=0, ha="right", va="center",
                          fontsize=8)
            ax.tick_params(labelsize=7)
    if not stacked:
        main.set_ylabel("contraction (0-1)")
    else:
        fig.supylabel("contraction (0-1) per muscle", fontsize=9)
    if not chosen:
        main.set_ylim(0, 1)
        main.text(0.5, 0.5, f"no muscle reaches a contraction of {ACTIVE_THRESHOLD:g}",
                  transform=main.transAxes, ha="center", va="center", color="#666666")

    if eyes is not None:
        eax = axes[max(1, len(bases))]
        for j, ls in enumerate(("-", "--")):
            eax.plot(x, eyes[:, j], color=_EYE_COLOUR, lw=1.3, ls=ls, label=EYE_COLUMNS[j])
        eax.set_ylim(0, max(1.2, 1.1 * float(np.nanmax(eyes))))
        eax.set_ylabel("eyes open\n(1: as neutral)", rotation=0, ha="right", va="center",
                       fontsize=8)
        eax.tick_params(labelsize=7)

    if jaw is not None:
        jax = axes[-1] if stacked else main.twinx()
        jax.plot(x, jaw, color="black", lw=1.3, **style["jaw"])
        jax.set_ylabel("jaw (deg)" if stacked else "jaw rotation (degrees)",
                       **(dict(rotation=0, ha="right", va="center", fontsize=8) if stacked
                          else {}))
        span = max(1.0, float(np.nanmax(np.abs(jaw))))
        jax.set_ylim(min(0.0, float(np.nanmin(jaw)) * 1.1), span * 1.1)
        if stacked:
            jax.tick_params(labelsize=7)
        handles.append(Line2D([], [], color="black", lw=1.3, **style["jaw"],
                              label="jaw rotation (deg)"))

    tracked = np.ones(len(df), bool)
    if "success" in df:
        tracked = pd.to_numeric(df["success"], errors="coerce").to_numpy(float) > 0
        spans = _spans(x, ~tracked)
        if spans:
            for ax in axes:
                ax.broken_barh(spans, (0, 1), transform=ax.get_xaxis_transform(),
                               color="#999999", alpha=0.3, lw=0, zorder=0)
            handles.append(Patch(color="#999999", alpha=0.3,
                                 label=_lost_label(int((~tracked).sum()), lost_reasons)))
    if turned is not None:
        turned = turned & tracked         # a lost frame is shaded as lost, not hatched
    if turned is not None and turned.any():
        for ax in axes:
            ax.broken_barh(_spans(x, turned), (0, 1), transform=ax.get_xaxis_transform(),
                           facecolor="none", edgecolor="#c08a3e", hatch="///", alpha=0.5,
                           lw=0, zorder=0)
        handles.append(Patch(facecolor="none", edgecolor="#c08a3e", hatch="///", alpha=0.5,
                             label=f"head turned ({int(turned.sum())})"))
    if len(cuts) and "frame" in df:
        rows = np.flatnonzero(np.isin(pd.to_numeric(df["frame"]).to_numpy(), list(cuts)))
        if rows.size:
            for ax in axes:
                for r in rows:
                    ax.axvline(x[r], color="#7a3ec0", lw=1.2, ls=(0, (4, 2)), zorder=1)
            handles.append(Line2D([], [], color="#7a3ec0", lw=1.2, ls=(0, (4, 2)),
                                  label=f"shot cut ({rows.size})"))
    for ax in axes:
        ax.grid(True, color="#dddddd", lw=0.6)
        ax.set_axisbelow(True)
        if len(x):
            lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
            if photographs:
                ax.set_xlim(lo - 0.5, hi + 0.5)
                if len(x) <= 40:
                    ax.set_xticks(x)
            else:
                ax.set_xlim(lo, hi if hi > lo else lo + 1)
    axes[-1].set_xlabel(xlabel)
    if faded & set(chosen):
        handles.append(Line2D([], [], color="#555555", lw=1.6, alpha=_FADED,
                              label="faded: not identifiable"))
    if chosen:
        handles.append(Line2D([], [], color="#555555", lw=1.6, label="left (_l)",
                              **style["l"]))
        handles.append(Line2D([], [], color="#555555", lw=1.6, label="right (_r)",
                              **style["r"]))
    if handles:
        fig.legend(handles=handles, loc="outside right upper", frameon=False, fontsize=9)
    main_title = title if title is not None else "Estimated muscle contractions"
    if stacked:
        fig.suptitle(main_title)
    else:
        main.set_title(main_title)
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig
