"""FACS control: action units to muscle contractions, expressions to action units, timing.

Three tables and a few functions turn a request such as "surprise, 40 frames, emphasis 0.8"
into a contraction time series for the face model:

- :data:`ACTION_UNITS`: FACS action unit number -> ``{muscle: activation}``.  Muscle
  activations are contractions in [0, 1] at full intensity; the entry ``jaw_rotation`` is in
  radians (positive opens the mouth).
- :data:`EXPRESSIONS`: the six primary expressions -> ``{action unit: intensity}`` (Ekman &
  Friesen's EMFACS prototypes, restricted to what the model's muscles can produce).
- :func:`envelope`: onset-apex-offset timing curves with a cosine ease.

Combination rule (:func:`aus_to_contractions`): contributions of several action units to the
same muscle add up and the sum is clipped to [0, 1]; jaw contributions add up and are clipped
to [0, :data:`MAX_JAW_ROTATION`].

Muscle names: paired muscles end in ``_l`` (subject's left) / ``_r``.

Notes on the mapping (Ekman, Friesen & Hager, *FACS Manual*, 2002):

- AU 5 (upper lid raiser, levator palpebrae superioris) is **not** available: the model has no
  levator palpebrae, so the surprise and fear prototypes are used without it.
- AU 6 (cheek raiser) and AU 7 (lid tightener) are the orbital and palpebral parts of the same
  orbicularis oculi; the model has one sphincter per eye, so both drive it (AU 7 more weakly).
- AU 18, 22, 23 and 24 all act through the single orbicularis oris sphincter.
- AU 25 (lips part) is a small jaw opening plus some lower-lip depression; AU 26 (jaw drop)
  opens the jaw by 0.15 rad and AU 27 (mouth stretch) by 0.30 rad.

Why one module of a little over 600 lines: the tables and the functions that read them
forwards (action units to contractions), over time (timelines) and backwards (contractions
to action units) are one vocabulary, and callers use it as one namespace
(``from synth import facs``, then ``facs.EXPRESSIONS``, ``facs.expression_timeline``);
split, each function would stand apart from the tables it reads.

Examples
--------
>>> df = expression_timeline("surprise", 40, emphasis=0.8)
>>> df.shape
(40, 30)
>>> round(float(df["frontalis_inner_l"].max()), 2)
0.8
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

import numpy as np
import pandas as pd

__all__ = [
    "PAIRED_MUSCLES",
    "MUSCLE_NAMES",
    "JAW",
    "TIMELINE_COLUMNS",
    "MAX_JAW_ROTATION",
    "ACTION_UNITS",
    "AU_NAMES",
    "CORE_AUS",
    "EXPRESSIONS",
    "envelope",
    "aus_to_contractions",
    "expression_aus",
    "au_timeline",
    "expression_timeline",
    "muscles_to_aus",
    "to_facs_scale",
    "from_facs_scale",
    "facs_letter",
    "au_column",
]

#: Muscles that come in left/right pairs.
PAIRED_MUSCLES = (
    "frontalis_inner", "frontalis_major", "frontalis_outer", "corrugator",
    "zygomaticus_major", "zygomaticus_minor", "levator_labii_nasi", "levator_labii",
    "depressor_anguli", "depressor_labii", "mentalis", "buccinator", "risorius",
)
#: Every muscle of the model (no jaw), in a fixed order.
MUSCLE_NAMES = tuple(f"{m}_{side}" for m in PAIRED_MUSCLES for side in ("l", "r")) + (
    "orbicularis_oris", "orbicularis_oculi_l", "orbicularis_oculi_r",
)
#: Name of the jaw degree of freedom (radians, positive opens the mouth).
JAW = "jaw_rotation"
#: Columns of a contraction time series: every muscle, then the jaw.
TIMELINE_COLUMNS = MUSCLE_NAMES + (JAW,)
#: Largest jaw rotation a combination of action units may ask for (radians).
MAX_JAW_ROTATION = 0.5

#: Jaw opening of AU 25 / AU 26 / AU 27 at full intensity (radians).
JAW_AU25, JAW_AU26, JAW_AU27 = 0.05, 0.15, 0.30


def _both(**activations: float) -> dict[str, float]:
    """Expand ``{muscle: a}`` of paired muscles to ``{muscle_l: a, muscle_r: a}``."""
    out: dict[str, float] = {}
    for name, value in activations.items():
        if name in PAIRED_MUSCLES or name == "orbicularis_oculi":
            out[f"{name}_l"] = value
            out[f"{name}_r"] = value
        else:
            out[name] = value
    return out


#: Action unit -> {muscle: activation at full intensity}; ``jaw_rotation`` in radians.
ACTION_UNITS: dict[int, dict[str, float]] = {
    1: _both(frontalis_inner=1.0, frontalis_major=0.3),          # inner brow raiser
    2: _both(frontalis_outer=1.0, frontalis_major=0.5),          # outer brow raiser
    4: _both(corrugator=1.0),                                    # brow lowerer
    6: _both(orbicularis_oculi=0.7),                             # cheek raiser
    7: _both(orbicularis_oculi=0.35),                            # lid tightener
    9: _both(levator_labii_nasi=1.0),                            # nose wrinkler
    10: _both(levator_labii=1.0),                                # upper lip raiser
    11: _both(zygomaticus_minor=1.0),                            # nasolabial deepener
    12: _both(zygomaticus_major=1.0),                            # lip corner puller
    14: _both(buccinator=1.0),                                   # dimpler
    15: _both(depressor_anguli=1.0),                             # lip corner depressor
    16: _both(depressor_labii=1.0),                              # lower lip depressor
    17: _both(mentalis=1.0),                                     # chin raiser
    18: {"orbicularis_oris": 0.7},                               # lip pucker
    20: _both(risorius=1.0),                                     # lip stretcher
    22: {"orbicularis_oris": 0.5},                               # lip funneler
    23: {"orbicularis_oris": 1.0},                               # lip tightener
    24: {"orbicularis_oris": 0.8, "mentalis_l": 0.2, "mentalis_r": 0.2},  # lip pressor
    25: {**_both(depressor_labii=0.3), JAW: JAW_AU25},           # lips part
    26: {JAW: JAW_AU26},                                         # jaw drop
    27: {JAW: JAW_AU27},                                         # mouth stretch
}

#: Action unit -> FACS name.
AU_NAMES: dict[int, str] = {
    1: "inner brow raiser", 2: "outer brow raiser", 4: "brow lowerer", 6: "cheek raiser",
    7: "lid tightener", 9: "nose wrinkler", 10: "upper lip raiser",
    11: "nasolabial deepener", 12: "lip corner puller", 14: "dimpler",
    15: "lip corner depressor", 16: "lower lip depressor", 17: "chin raiser",
    18: "lip pucker", 20: "lip stretcher", 22: "lip funneler", 23: "lip tightener",
    24: "lip pressor", 25: "lips part", 26: "jaw drop", 27: "mouth stretch",
}

#: The action units estimated by :func:`muscles_to_aus` by default (one per muscle group).
CORE_AUS = (1, 2, 4, 6, 9, 10, 12, 14, 15, 16, 17, 20, 23, 25, 26, 27)

#: Primary expressions -> {action unit: intensity in [0, 1]} (EMFACS prototypes without AU 5).
EXPRESSIONS: dict[str, dict[int, float]] = {
    "happiness": {6: 0.7, 12: 1.0, 25: 0.4},
    "sadness": {1: 0.8, 4: 0.5, 15: 0.8, 17: 0.4},
    "surprise": {1: 1.0, 2: 1.0, 25: 0.8, 26: 0.8},
    "fear": {1: 0.9, 2: 0.6, 4: 0.6, 20: 0.9, 25: 0.6, 26: 0.5},
    "anger": {4: 1.0, 7: 0.7, 23: 0.9, 17: 0.3},
    "disgust": {9: 0.9, 10: 0.7, 15: 0.5, 16: 0.4, 17: 0.4},
}

_FACS_LETTERS = "ABCDE"


# ----------------------------------------------------------------------------------------------
# Validation helpers
# ----------------------------------------------------------------------------------------------

_AU_KEY = re.compile(r"^(?:AU)?0*(\d+)(?:_?([LRlr]))?$")


def _parse_au(key) -> tuple[int, str | None]:
    """``12`` / ``"AU12"`` / ``"12L"`` / ``"AU12_r"`` -> (12, None | "l" | "r")."""
    if isinstance(key, (bool, np.bool_)):
        raise ValueError(f"unknown action unit {key!r}; valid: {sorted(ACTION_UNITS)}")
    if isinstance(key, (int, np.integer)):
        au, side = int(key), None
    elif isinstance(key, str) and _AU_KEY.match(key.strip()):
        m = _AU_KEY.match(key.strip())
        au, side = int(m.group(1)), (m.group(2).lower() if m.group(2) else None)
    else:
        raise ValueError(f"unknown action unit {key!r}; valid: {sorted(ACTION_UNITS)} "
                         "(optionally as 'AU12', or '12L' / '12R' for one side)")
    if au not in ACTION_UNITS:
        raise ValueError(f"unknown action unit {key!r}; valid: {sorted(ACTION_UNITS)}")
    return au, side


def _check_unit(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}") from None
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return v


def _check_emphasis(emphasis) -> float:
    try:
        e = float(emphasis)
    except (TypeError, ValueError):
        raise ValueError(f"emphasis must be a number in [0, 2], got {emphasis!r}") from None
    if not (math.isfinite(e) and 0.0 <= e <= 2.0):
        raise ValueError(f"emphasis must be in [0, 2], got {emphasis!r}")
    return e


def _check_expression(name) -> str:
    if not isinstance(name, str) or name.strip().lower() not in EXPRESSIONS:
        raise ValueError(f"unknown expression {name!r}; valid: {sorted(EXPRESSIONS)}")
    return name.strip().lower()


# ----------------------------------------------------------------------------------------------
# Intensity scales
# ----------------------------------------------------------------------------------------------


def to_facs_scale(intensity):
    """Intensity in [0, 1] -> FACS/OpenFace ``AUxx_r`` scale 0..5 (``5 * intensity``).

    Examples
    --------
    >>> to_facs_scale(0.6)
    3.0
    """
    x = np.asarray(intensity, dtype=float)
    if np.any(~np.isfinite(x)) or np.any((x < 0) | (x > 1)):
        raise ValueError("intensity must be in [0, 1]")
    out = 5.0 * x
    return float(out) if out.ndim == 0 else out


def from_facs_scale(value):
    """FACS/OpenFace scale 0..5 -> intensity in [0, 1] (``value / 5``).

    Examples
    --------
    >>> from_facs_scale(2.5)
    0.5
    """
    x = np.asarray(value, dtype=float)
    if np.any(~np.isfinite(x)) or np.any((x < 0) | (x > 5)):
        raise ValueError("FACS intensity must be in [0, 5]")
    out = x / 5.0
    return float(out) if out.ndim == 0 else out


def facs_letter(intensity: float) -> str:
    """FACS intensity letter for an intensity in [0, 1]: '' (absent), A (trace) ... E (maximum).

    The letters split (0, 1] into five equal bands: A = (0, 0.2], B = (0.2, 0.4], ... E.

    Examples
    --------
    >>> facs_letter(0.0), facs_letter(0.5), facs_letter(1.0)
    ('', 'C', 'E')
    """
    v = _check_unit("intensity", intensity)
    if v == 0.0:
        return ""
    return _FACS_LETTERS[min(4, int(math.ceil(v * 5.0 - 1e-9)) - 1)]


def au_column(au: int) -> str:
    """OpenFace-style column name of an action unit intensity, e.g. ``AU01_r``.

    Examples
    --------
    >>> au_column(1)
    'AU01_r'
    """
    a, _ = _parse_au(au)
    return f"AU{a:02d}_r"


# ----------------------------------------------------------------------------------------------
# Forward: AUs -> muscles
# ----------------------------------------------------------------------------------------------


def aus_to_contractions(aus: Mapping, *, emphasis: float = 1.0) -> dict[str, float]:
    """Muscle contractions (and jaw rotation) for a set of action-unit intensities.

    Parameters
    ----------
    aus : mapping
        ``{action unit: intensity in [0, 1]}``.  Keys are AU numbers (``12``) or strings
        (``"AU12"``, ``"12"``); a trailing ``L`` / ``R`` (``"12L"``, ``"AU12_r"``) activates the
        subject's left / right side only.
    emphasis : float, optional
        Multiplies every intensity (then clipped to 1); in [0, 2].

    Returns
    -------
    dict
        ``{name: value}`` for every name in :data:`TIMELINE_COLUMNS`: contractions in [0, 1],
        ``jaw_rotation`` in radians in [0, :data:`MAX_JAW_ROTATION`].  Contributions to the same
        muscle add up and are clipped.

    Examples
    --------
    >>> c = aus_to_contractions({12: 0.5})
    >>> c["zygomaticus_major_l"], c["zygomaticus_major_r"], c["jaw_rotation"]
    (0.5, 0.5, 0.0)
    >>> aus_to_contractions({"12L": 1.0})["zygomaticus_major_r"]
    0.0
    """
    if not isinstance(aus, Mapping):
        raise ValueError(f"aus must be a mapping {{AU: intensity}}, got {type(aus).__name__}")
    e = _check_emphasis(emphasis)
    total = dict.fromkeys(TIMELINE_COLUMNS, 0.0)
    for key, value in aus.items():
        au, side = _parse_au(key)
        x = min(1.0, _check_unit(f"intensity of AU{au}", value) * e)
        for muscle, act in ACTION_UNITS[au].items():
            if side is not None and muscle.endswith(("_l", "_r")) and muscle[-1] != side:
                continue
            total[muscle] += act * x
    for name in MUSCLE_NAMES:
        total[name] = float(min(1.0, total[name]))
    total[JAW] = float(min(MAX_JAW_ROTATION, total[JAW]))
    return total


def expression_aus(name: str, *, emphasis: float = 1.0) -> dict[int, float]:
    """Action-unit intensities of a primary expression, scaled by ``emphasis`` (clipped to 1).

    Examples
    --------
    >>> expression_aus("happiness", emphasis=0.5)[12]
    0.5
    """
    key = _check_expression(name)
    e = _check_emphasis(emphasis)
    return {au: float(min(1.0, v * e)) for au, v in EXPRESSIONS[key].items()}


# ----------------------------------------------------------------------------------------------
# Timing
# ----------------------------------------------------------------------------------------------


def _frames(name: str, value, n_span: float) -> float:
    """An int is a number of frames; a float in [0, 1] is a fraction of ``n_span``."""
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a number of frames (int) or a fraction (float)")
    if isinstance(value, (int, np.integer)):
        if value < 0:
            raise ValueError(f"{name} must be >= 0 frames, got {value}")
        return float(value)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an int (frames) or a float fraction, "
                         f"got {value!r}") from None
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise ValueError(f"{name} as a fraction must be in [0, 1], got {value!r}")
    return v * n_span


def envelope(n_frames: int, *, onset=0.3, apex=0.4, offset=0.3, delay=0,
             ease: str = "cosine") -> np.ndarray:
    """Onset-apex-offset timing curve, one value in [0, 1] per frame.

    The curve is 0 for ``delay`` frames, rises to 1 over ``onset`` frames, holds for ``apex``
    frames, falls back to 0 over ``offset`` frames and stays 0 afterwards.  Durations given as
    ``int`` are frames; as ``float`` they are fractions of ``n_frames - 1`` (the span from the
    first to the last frame), so the defaults (0.3, 0.4, 0.3) start and end at exactly 0.

    Parameters
    ----------
    n_frames : int
        Number of frames (>= 1).
    onset, apex, offset, delay : int or float, optional
        Phase durations (frames or fractions, see above).
    ease : {"cosine", "linear", "smoothstep"}, optional
        Shape of the rise and fall: ``0.5 - 0.5 cos(pi t)`` (default), ``t``, or
        ``3t^2 - 2t^3``.

    Returns
    -------
    (n_frames,) ndarray

    Examples
    --------
    >>> np.round(envelope(5, onset=2, apex=0, offset=2), 2)
    array([0. , 0.5, 1. , 0.5, 0. ])
    """
    if isinstance(n_frames, (bool, np.bool_)) or not isinstance(n_frames, (int, np.integer)):
        raise ValueError(f"n_frames must be a positive integer, got {n_frames!r}")
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    eases = {
        "cosine": lambda t: 0.5 - 0.5 * np.cos(np.pi * t),
        "linear": lambda t: t,
        "smoothstep": lambda t: t * t * (3 - 2 * t),
    }
    if ease not in eases:
        raise ValueError(f"ease must be one of {sorted(eases)}, got {ease!r}")
    span = float(max(n_frames - 1, 0))
    d = _frames("delay", delay, span)
    on = _frames("onset", onset, span)
    ap = _frames("apex", apex, span)
    off = _frames("offset", offset, span)
    if d + on + ap + off > span + 1e-6 and n_frames > 1:
        raise ValueError(
            f"delay + onset + apex + offset = {d + on + ap + off:g} frames exceeds the "
            f"{span:g} frames between the first and the last of {n_frames} frames"
        )
    f = eases[ease]
    tau = np.arange(n_frames, dtype=float)
    out = np.zeros(n_frames)
    rise = (tau > d) & (tau < d + on)
    out[rise] = f((tau[rise] - d) / on)
    hold = (tau >= d + on) & (tau <= d + on + ap)
    out[hold] = 1.0
    t_fall = d + on + ap
    fall = (tau > t_fall) & (tau < t_fall + off)
    out[fall] = f(1.0 - (tau[fall] - t_fall) / off)
    if n_frames == 1:
        out[:] = 1.0 if on == 0 else 0.0
    return np.clip(out, 0.0, 1.0)


def au_timeline(aus: Mapping, n_frames: int, *, emphasis: float = 1.0, onset=0.3, apex=0.4,
                offset=0.3, delay=0, ease: str = "cosine") -> pd.DataFrame:
    """Contraction time series for a set of action units following one timing envelope.

    Every frame is :func:`aus_to_contractions` of the intensities times the envelope value,
    so contractions rise and fall together.

    Parameters
    ----------
    aus : mapping
        ``{action unit: apex intensity in [0, 1]}`` (see :func:`aus_to_contractions`).
    n_frames : int
        Number of frames.
    emphasis : float, optional
        Scales every intensity (clipped to 1), in [0, 2].
    onset, apex, offset, delay, ease
        Timing, see :func:`envelope`.

    Returns
    -------
    pandas.DataFrame
        Index ``frame`` (0..n_frames-1); columns :data:`TIMELINE_COLUMNS` (contractions in
        [0, 1], ``jaw_rotation`` in radians).

    Examples
    --------
    >>> df = au_timeline({12: 1.0}, 11, onset=5, apex=0, offset=5)
    >>> float(df["zygomaticus_major_l"].iloc[5])
    1.0
    """
    env = envelope(n_frames, onset=onset, apex=apex, offset=offset, delay=delay, ease=ease)
    if not isinstance(aus, Mapping):
        raise ValueError(f"aus must be a mapping {{AU: intensity}}, got {type(aus).__name__}")
    e = _check_emphasis(emphasis)
    parsed = [(key, _check_unit(f"intensity of {key!r}", v)) for key, v in aus.items()]
    rows = np.empty((n_frames, len(TIMELINE_COLUMNS)))
    for k, level in enumerate(env):
        c = aus_to_contractions({key: min(1.0, v * e) * level for key, v in parsed})
        rows[k] = [c[name] for name in TIMELINE_COLUMNS]
    df = pd.DataFrame(rows, columns=list(TIMELINE_COLUMNS))
    df.index.name = "frame"
    return df


def expression_timeline(name: str, n_frames: int, *, emphasis: float = 1.0, onset=0.3,
                        apex=0.4, offset=0.3, delay=0, ease: str = "cosine") -> pd.DataFrame:
    """Contraction time series of a primary expression.

    ``expression_timeline("surprise", 40, emphasis=0.8)`` rises from neutral over the first
    30 % of the clip, holds the apex (80 % of the prototype intensities) for 40 % and returns
    to neutral at the last frame.

    Parameters
    ----------
    name : str
        One of :data:`EXPRESSIONS` (happiness, sadness, surprise, fear, anger, disgust).
    n_frames : int
        Number of frames.
    emphasis : float, optional
        Scales the prototype's action-unit intensities (each clipped to 1), in [0, 2].
    onset, apex, offset, delay, ease
        Timing, see :func:`envelope`.

    Returns
    -------
    pandas.DataFrame
        As :func:`au_timeline`.

    Examples
    --------
    >>> df = expression_timeline("happiness", 30)
    >>> bool(df["zygomaticus_major_l"].max() == 1.0 and df.iloc[0].abs().sum() == 0)
    True
    """
    aus = expression_aus(name, emphasis=emphasis)
    return au_timeline(aus, n_frames, onset=onset, apex=apex, offset=offset, delay=delay,
                       ease=ease)


# ----------------------------------------------------------------------------------------------
# Inverse: muscles -> AUs
# ----------------------------------------------------------------------------------------------


def _au_matrix(aus: tuple[int, ...]) -> np.ndarray:
    A = np.zeros((len(MUSCLE_NAMES), len(aus)))
    row = {name: i for i, name in enumerate(MUSCLE_NAMES)}
    for j, au in enumerate(aus):
        for muscle, act in ACTION_UNITS[au].items():
            if muscle != JAW:
                A[row[muscle], j] = act
    return A


def muscles_to_aus(contractions, *, aus=CORE_AUS, ridge: float = 1e-8):
    """Estimate action-unit intensities from muscle contractions.

    Method:

    - Jaw action units come from ``jaw_rotation`` alone: AU 25 (lips part) =
      ``jaw / 0.05 rad``, AU 26 (jaw drop) = ``jaw / 0.15 rad`` fading out as AU 27 (mouth
      stretch) = ``(jaw - 0.15) / 0.15`` takes over (FACS scores 27 instead of 26), all
      clipped to [0, 1].
    - The other action units solve a bounded, ridge-regularised linear least-squares problem
      ``min ||A x - c||^2 + ridge ||x||^2`` with ``0 <= x <= 1``, where column ``j`` of ``A`` is
      the muscle pattern of action unit ``j`` (its jaw part removed) and ``c`` the contraction
      vector.  For contractions made by :func:`aus_to_contractions` from non-overlapping AUs
      without saturation the intensities are recovered (the default ridge is tiny; it only
      makes the solution unique when AUs drive the same muscles, e.g. 6 and 7, which then
      share the evidence).  AU 25's lower-lip
      part is explained by AU 16.

    Parameters
    ----------
    contractions : mapping or pandas.DataFrame
        ``{muscle: contraction}`` for one frame (missing muscles count as 0, unknown names
        raise ``ValueError``), or a DataFrame with one row per frame and muscle columns (other
        columns are ignored).
    aus : sequence of int, optional
        Action units to estimate (default :data:`CORE_AUS`).
    ridge : float, optional
        Regularisation weight (>= 0); larger values shrink the intensities.

    Returns
    -------
    dict or pandas.DataFrame
        ``{AU: intensity in [0, 1]}``, or a DataFrame with columns ``AU01``, ``AU02``, ... with
        the input's index.  Use :func:`to_facs_scale` for the 0..5 scale.

    Examples
    --------
    >>> est = muscles_to_aus(aus_to_contractions({12: 0.6, 4: 0.3, 26: 1.0}))
    >>> round(est[12], 2), round(est[4], 2), round(est[26], 2), round(est[1], 2)
    (0.6, 0.3, 1.0, 0.0)
    """
    from scipy.optimize import lsq_linear

    au_list = tuple(_parse_au(a)[0] for a in aus)
    if len(set(au_list)) != len(au_list):
        raise ValueError(f"aus contains duplicates: {list(aus)}")
    ridge = float(ridge)
    if not (math.isfinite(ridge) and ridge >= 0):
        raise ValueError(f"ridge must be >= 0, got {ridge!r}")
    jaw_aus = {25, 26, 27}
    lin = tuple(a for a in au_list if a not in jaw_aus and any(
        m != JAW for m in ACTION_UNITS[a]))

    if isinstance(contractions, pd.DataFrame):
        frame = contractions
        C = np.zeros((len(frame), len(MUSCLE_NAMES)))
        for i, name in enumerate(MUSCLE_NAMES):
            if name in frame.columns:
                C[:, i] = frame[name].to_numpy(dtype=float)
        jaw = (frame[JAW].to_numpy(dtype=float) if JAW in frame.columns
               else np.zeros(len(frame)))
        single = False
    elif isinstance(contractions, Mapping):
        unknown = sorted(set(contractions) - set(TIMELINE_COLUMNS))
        if unknown:
            raise ValueError(f"unknown muscle name(s) {unknown}; valid: {list(TIMELINE_COLUMNS)}")
        C = np.array([[float(contractions.get(n, 0.0)) for n in MUSCLE_NAMES]])
        jaw = np.array([float(contractions.get(JAW, 0.0))])
        single = True
    else:
        raise ValueError("contractions must be a mapping or a pandas DataFrame, got "
                         f"{type(contractions).__name__}")
    if not np.all(np.isfinite(C)) or not np.all(np.isfinite(jaw)):
        raise ValueError("contractions contain NaN or infinite values")

    out = np.zeros((len(C), len(au_list)))
    col = {a: j for j, a in enumerate(au_list)}
    if lin:
        A = _au_matrix(lin)
        # unconstrained ridge solution for every frame at once; frames whose solution leaves
        # [0, 1] are solved again with the bounds (BVLS)
        gram = A.T @ A + ridge * np.eye(len(lin))
        X = np.linalg.lstsq(gram, A.T @ C.T, rcond=None)[0].T
        bad = np.flatnonzero(np.any((X < -1e-9) | (X > 1 + 1e-9), axis=1))
        if len(bad):
            A_aug = np.vstack([A, math.sqrt(ridge) * np.eye(len(lin))]) if ridge > 0 else A
            for i in bad:
                b = np.concatenate([C[i], np.zeros(len(lin))]) if ridge > 0 else C[i]
                X[i] = lsq_linear(A_aug, b, bounds=(0.0, 1.0), method="bvls").x
        for j, a in enumerate(lin):
            out[:, col[a]] = X[:, j]
    a27 = np.clip((jaw - JAW_AU26) / (JAW_AU27 - JAW_AU26), 0, 1)
    jaw_values = {
        25: np.clip(jaw / JAW_AU25, 0, 1),
        26: np.clip(jaw / JAW_AU26, 0, 1) * (1 - a27),
        27: a27,
    }
    for a in au_list:
        if a in jaw_aus:
            out[:, col[a]] = jaw_values[a]
    out = np.clip(out, 0.0, 1.0)
    if single:
        return {a: float(out[0, col[a]]) for a in au_list}
    return pd.DataFrame(out, index=contractions.index,
                        columns=[f"AU{a:02d}" for a in au_list])
