"""Eye openness and eye closures (blinks) from the lids the landmark tracker traces.

The face model has no eyelids that close, so eye closure is not one of its controls: it is
measured directly, as each eye's lid gap (:mod:`trackers.landmarks.eyes`) over the neutral
frame's.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BLINK_MAX_S", "CLOSED_LEVEL", "eye_closures", "eye_openness"]

#: Both eyes' lid gaps below this share of their open gap (the 90th percentile over the
#: measured frames: open eyes, even where the gaze is down most of the time): the eyes are
#: closed. On a real talking face, closed lids read 0.1-0.35 of it (a single frame of a blink
#: catches them closing) and a downward glance 0.4-0.55 (the lids follow the gaze); a share
#: of the neutral frame's gap would take the glance for closed eyes wherever the neutral
#: frame's eyes are wide.
CLOSED_LEVEL = 0.4
#: A closure this long or shorter is a blink.
BLINK_MAX_S = 0.5


def eye_openness(gaps, neutral: int) -> np.ndarray:
    """Each eye's lid gap over its gap on the neutral row.

    Parameters
    ----------
    gaps : array_like, shape (T, 2)
        Lid gaps per frame and eye (any unit; NaN where not measured).
    neutral : int
        The neutral frame's row.

    Returns
    -------
    ndarray, shape (T, 2)
        1 as open as on the neutral frame, 0 closed; NaN where either is not measured.

    Examples
    --------
    >>> eye_openness([[0.08, 0.10], [0.02, 0.05], [np.nan, 0.1]], 0).round(2).tolist()
    [[1.0, 1.0], [0.25, 0.5], [nan, 1.0]]
    """
    g = np.asarray(gaps, dtype=float)
    if g.ndim != 2 or g.shape[1] != 2:
        raise ValueError(f"gaps must have shape (T, 2), got {g.shape}")
    if not 0 <= neutral < len(g):
        raise ValueError(f"neutral row {neutral} is outside the {len(g)} rows")
    ref = g[neutral]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ref > 0, g / ref, np.nan)


def eye_closures(openness, frames, timestamps, *, level: float = CLOSED_LEVEL,
                 blink_max_s: float = BLINK_MAX_S) -> dict | None:
    """The runs of frames on which both eyes are closed, and the blinks among them.

    Parameters
    ----------
    openness : array_like, shape (T, 2)
        :func:`eye_openness` (NaN on frames not measured; they end a run).
    frames : array_like, shape (T,)
        Frame numbers.
    timestamps : array_like, shape (T,)
        Seconds (NaN where unknown: durations and rates are then None).
    level : float, keyword-only
        Both eyes' openness below this share of their 90th percentile over the measured
        frames (their open gap): closed.
    blink_max_s : float, keyword-only
        A closure lasting at most this long is a blink.

    Returns
    -------
    dict or None
        ``closed_level`` (of the open gap), ``blink_max_s``, ``closures`` (each ``first``
        and ``last`` frame, ``duration_s`` and ``blink``), ``blinks`` (how many),
        ``blinks_per_minute`` (over the measured frames' time) and ``frames_measured``;
        None when no frame was measured.

    Examples
    --------
    >>> o = np.ones((12, 2)); o[3:5] = 0.1; o[7:10] = 0.2
    >>> s = eye_closures(o, np.arange(12), np.arange(12) / 4)
    >>> [(c["first"], c["last"], c["duration_s"], c["blink"]) for c in s["closures"]]
    [(3, 4, 0.5, True), (7, 9, 0.75, False)]
    >>> s["blinks"], s["blinks_per_minute"]
    (1, 20.0)
    """
    o = np.asarray(openness, dtype=float)
    frames = np.asarray(frames)
    t = np.asarray(timestamps, dtype=float)
    if o.ndim != 2 or o.shape[1] != 2 or frames.shape != (len(o),) or t.shape != (len(o),):
        raise ValueError(f"openness must have shape (T, 2) and frames and timestamps (T,), "
                         f"got {o.shape}, {frames.shape} and {t.shape}")
    if not (np.isfinite(level) and level > 0 and np.isfinite(blink_max_s) and blink_max_s > 0):
        raise ValueError(f"level and blink_max_s must be positive, got {level}, {blink_max_s}")
    measured = np.isfinite(o).all(axis=1)
    if not measured.any():
        return None
    steps = np.diff(t[np.isfinite(t)])
    period = float(np.median(steps)) if steps.size and np.median(steps) > 0 else None
    typical = np.percentile(o[measured], 90, axis=0)
    closed = measured & (o < level * typical).all(axis=1)
    edges = np.diff(np.r_[0, closed.astype(np.int8), 0])
    closures = []
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
        duration = (None if period is None or not np.isfinite(t[[a, b]]).all()
                    else round(float(t[b] - t[a]) + period, 4))
        closures.append({"first": int(frames[a]), "last": int(frames[b]),
                         "duration_s": duration,
                         "blink": duration is not None and duration <= blink_max_s + 1e-9})
    blinks = sum(c["blink"] for c in closures)
    minutes = None if period is None else measured.sum() * period / 60.0
    return {"closed_level": float(level), "blink_max_s": float(blink_max_s),
            "closures": closures, "blinks": int(blinks),
            "blinks_per_minute": None if not minutes else round(float(blinks / minutes), 2),
            "frames_measured": int(measured.sum())}
