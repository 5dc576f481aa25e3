"""The canonical design plane of the generated face, and its feature curves.

The face mesh is designed on a 2-D plane in centimetres of the default face (``X`` =
subject's left, ``Y`` = up, origin between the eye centres; see :mod:`synth.mesh`).
This module holds the plane's feature levels and outlines (eyes, mouth line, lips,
brows, hairline, nasolabial furrow, the face outline), the small polyline helpers used
on it, and the painted feature curves in uv (:data:`~synth.face_mesh.FEATURE_CURVE_NAMES`).
Everything here is fixed: it depends neither on the resolution nor on the identity.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.interpolate import PchipInterpolator

from synth.face_mesh import FEATURE_CURVE_NAMES, _readonly

X_EXT = 8.4            # u = (X + X_EXT) / (2 X_EXT)
Y_TOP = 8.8            # v = (Y_TOP - Y) / (Y_TOP - Y_BOT)
Y_BOT = -12.0

_OUTLINE_Y = np.array([-12.0, -11.85, -11.4, -10.5, -9.0, -7.4, -5.5, -3.0, 0.0, 3.0, 6.0, 8.8])
_OUTLINE_W = np.array([0.0, 1.05, 2.5, 4.0, 5.5, 6.6, 7.4, 7.8, 8.0, 8.0, 7.75, 7.3])
_hw = PchipInterpolator(_OUTLINE_Y, _OUTLINE_W)

EYE_C = 3.35           # eye centre |X|
EYE_A = 1.4            # half length of the palpebral fissure
EYE_BU = 0.5           # upper-lid height above the centre
EYE_BL = 0.4           # lower-lid depth below the centre
EYE_TILT = 0.06        # outer canthus higher by this much
MOUTH_Y = -7.6         # mouth line at the midline
MOUTH_W = 2.45         # half width of the mouth (corner |X|)
MOUTH_CURVE = 0.12     # corners higher than the centre by this much
UL_H = 0.72            # upper vermilion height at the midline (cupid's bow dip)
UL_PEAK = 0.84         # upper vermilion height at the bow peaks
LL_H = 0.95            # lower vermilion depth at the midline
Y_HAIR = 6.6           # hairline at the midline
BROW_INNER, BROW_MID, BROW_OUTER = 1.45, 3.4, 5.45   # |X| of the eyebrow's ends and middle
BROW_Y = 2.3           # eyebrow height at its middle
Y_NASION = 0.6
Y_TIP = -4.6
Y_SUBNASALE = -5.75
Y_CHIN = -10.4
Y_SULCUS = -9.15
Y_JAW_ANGLE = -7.4
ALAR = (1.55, -5.05)
FURROW_TOP = (2.05, -4.5)


def _mouth_y(ax):
    ax = np.minimum(np.abs(ax), MOUTH_W)
    return MOUTH_Y + MOUTH_CURVE * (ax / MOUTH_W) ** 2


def _brow_y(ax):
    return BROW_Y - 0.13 * (np.asarray(ax) - BROW_MID) ** 2


def _hairline_y(ax):
    ax = np.asarray(ax, dtype=float)
    return Y_HAIR - 0.045 * ax**2 - 0.9 * np.clip((ax - 5.0) / 2.0, 0, None) ** 2


def _eye_margin(t):
    """Point of the left-eye margin at angle ``t`` (0 = outer canthus, pi/2 = top)."""
    s, c = np.sin(t), np.cos(t)
    x = EYE_C + EYE_A * c
    b = np.where(s >= 0, EYE_BU, EYE_BL)
    # slightly pointed canthi
    y = b * s * (1.0 - 0.18 * c**2) + EYE_TILT * c
    return np.stack([x, y], axis=-1)


def _upper_lip_y(ax):
    """Upper vermilion border height above the mouth line (cupid's bow)."""
    ax = np.abs(ax)
    r = np.clip(ax / MOUTH_W, 0, 1)
    bow = UL_H + (UL_PEAK - UL_H) * np.sin(np.clip(ax / 0.9, 0, 1) * np.pi / 2) ** 2
    return bow * np.sqrt(np.clip(1 - r**2.2, 0, 1))


def _lower_lip_y(ax):
    r = np.clip(np.abs(ax) / MOUTH_W, 0, 1)
    return -LL_H * np.sqrt(np.clip(1 - r**2.0, 0, 1)) * (1 - 0.1 * r)


_FURROW = np.array([FURROW_TOP, (2.5, -5.5), (2.95, -6.6), (3.3, -7.7), (3.45, -8.6)])


def _smoothstep(e0, e1, x):
    t = np.clip((np.asarray(x, dtype=float) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _resample(poly: np.ndarray, spacing: float, *, closed: bool = False) -> np.ndarray:
    """Points at equal arc length along a dense polyline, both ends included."""
    if closed:
        poly = np.vstack([poly, poly[:1]])
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(1, int(math.ceil(s[-1] / spacing - 1e-9)))
    target = np.linspace(0.0, s[-1], n + 1)
    out = np.stack([np.interp(target, s, poly[:, 0]), np.interp(target, s, poly[:, 1])], axis=1)
    return out[:-1] if closed else out


def _seg_dist(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of points ``p`` (n, 2) to an open polyline, and the arc parameter in [0, 1]."""
    best = np.full(len(p), np.inf)
    best_s = np.zeros(len(p))
    lengths = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    total = lengths.sum()
    acc = 0.0
    for a, b, ln in zip(poly[:-1], poly[1:], lengths):
        d = b - a
        t = np.clip(((p - a) @ d) / (d @ d), 0, 1)
        dist = np.linalg.norm(p - (a + t[:, None] * d), axis=1)
        better = dist < best
        best[better] = dist[better]
        best_s[better] = (acc + t[better] * ln) / total
        acc += ln
    return best, best_s


def _to_uv(p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return np.stack([(p[:, 0] + X_EXT) / (2 * X_EXT), (Y_TOP - p[:, 1]) / (Y_TOP - Y_BOT)], 1)


@functools.lru_cache(maxsize=1)
def _feature_curves() -> dict[str, np.ndarray]:
    out = {}
    x = np.linspace(-7.0, 7.0, 57)
    xh = x[_hairline_y(np.abs(x)) > _hairline_y(7.0) - 1e-9]
    out["hairline"] = np.stack([xh, _hairline_y(np.abs(xh))], 1)
    xb = np.linspace(BROW_INNER, BROW_OUTER, 21)
    out["brow_l"] = np.stack([xb, _brow_y(xb)], 1)
    out["furrow_l"] = _resample(_FURROW, 0.2)
    t = np.linspace(0, 2 * np.pi, 25)
    out["nostril_l"] = np.stack([0.62 + 0.3 * np.cos(t), -5.5 + 0.15 * np.sin(t)], 1)
    xm = np.linspace(-MOUTH_W, MOUTH_W, 41)
    upper_top = np.stack([xm, _mouth_y(xm) + _upper_lip_y(xm)], 1)
    out["upper_lip"] = np.vstack([upper_top, np.stack([xm, _mouth_y(xm)], 1)[::-1][1:]])
    lower_bot = np.stack([xm, _mouth_y(xm) + _lower_lip_y(xm)], 1)
    out["lower_lip"] = np.vstack([np.stack([xm, _mouth_y(xm)], 1), lower_bot[::-1][1:]])
    out["mouth_line"] = np.stack([xm, _mouth_y(xm)], 1)
    tc = np.linspace(0, 2 * np.pi, 33)
    out["chin_boss"] = np.stack([1.5 * np.cos(tc), Y_CHIN + 0.8 * np.sin(tc)], 1)
    te = np.linspace(0, 2 * np.pi, 49)
    out["eye_l"] = _eye_margin(te)
    mirror = np.array([-1.0, 1.0])
    for name in ("brow", "furrow", "nostril", "eye"):
        out[f"{name}_r"] = out[f"{name}_l"] * mirror
    res = {}
    for name in FEATURE_CURVE_NAMES:
        res[name] = _readonly(_to_uv(out[name]))
    return res
