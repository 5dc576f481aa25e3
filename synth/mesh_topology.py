"""The triangulation of the face's design plane at a resolution.

A graded point set, dense around the eyes and the mouth, is triangulated on the
canonical plane (:mod:`synth.mesh_plane`) with the eye margins, the mouth line and the
outline kept as edges; the eye openings are cut out, the mouth line is split into two
coinciding rows of vertices so that the lips can part, and the landmark vertices are
picked. The result (``_Layout``) depends on the resolution only, which is why every
identity made at one resolution shares its triangles, uv and landmark indices.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from matplotlib.path import Path as _MplPath
from scipy.spatial import Delaunay, cKDTree

from synth.face_mesh import LANDMARK_NAMES
from synth.mesh_plane import (
    ALAR,
    BROW_INNER,
    BROW_MID,
    BROW_OUTER,
    EYE_A,
    EYE_BL,
    EYE_BU,
    EYE_C,
    EYE_TILT,
    FURROW_TOP,
    LL_H,
    MOUTH_W,
    MOUTH_Y,
    UL_H,
    X_EXT,
    Y_BOT,
    Y_CHIN,
    Y_HAIR,
    Y_JAW_ANGLE,
    Y_NASION,
    Y_SUBNASALE,
    Y_TIP,
    Y_TOP,
    _brow_y,
    _eye_margin,
    _hairline_y,
    _hw,
    _mouth_y,
    _resample,
)

_FIXED, _RING, _GRID = 0, 1, 2   # point kinds: constraint (never moved/removed), ring, grid


@dataclass
class _Layout:
    P: np.ndarray              # (N, 2) canonical positions (seam duplicates included)
    triangles: np.ndarray
    mirror: np.ndarray
    seam: np.ndarray
    boundary: np.ndarray
    landmarks: dict
    lower: np.ndarray          # (N,) bool: lower-lip copies and vertices below the mouth line
    eye_margin_l: np.ndarray   # vertex indices of the left eye margin, in order


def _outline_half(h: float) -> tuple[np.ndarray, np.ndarray]:
    """Half outline (X >= 0) from the top midline to the chin bottom; and its closed polygon."""
    top = np.array([[0.0, Y_TOP], [float(_hw(Y_TOP)), Y_TOP]])
    ys1 = np.linspace(Y_TOP, Y_JAW_ANGLE, 600)
    ys2 = np.linspace(Y_JAW_ANGLE, Y_BOT, 600)
    side1 = np.stack([_hw(ys1), ys1], axis=1)
    side2 = np.stack([_hw(ys2), ys2], axis=1)
    side2[-1, 0] = 0.0
    pts = np.vstack([
        _resample(top, h),
        _resample(side1, h)[1:],
        _resample(side2, h)[1:],
    ])
    pts[np.abs(pts[:, 0]) < 1e-12, 0] = 0.0
    dense = np.vstack([top, side1[1:], side2[1:]])
    return pts, dense


@functools.lru_cache(maxsize=8)
def _layout(resolution: float) -> _Layout:
    h0 = 0.56 / resolution           # grid spacing away from the features
    e_eye = 0.17 / resolution         # spacing along the eye margin
    e_mouth = 0.16 / resolution       # spacing along the mouth line
    growth = 1.3

    pts: list[np.ndarray] = []
    kinds: list[np.ndarray] = []
    tags: dict[str, object] = {}

    def add(p, kind):
        start = sum(len(q) for q in pts)
        p = np.atleast_2d(np.asarray(p, dtype=float))
        pts.append(p)
        kinds.append(np.full(len(p), kind))
        return np.arange(start, start + len(p))

    # outline ----------------------------------------------------------------------------
    outline, outline_dense = _outline_half(0.9 * h0)
    idx_outline = add(outline, _FIXED)
    domain_half = _MplPath(np.vstack([outline_dense, [[0.0, Y_BOT]]]))

    # eye margin and rings (left eye) ------------------------------------------------------
    tq = [np.linspace(q * np.pi / 2, (q + 1) * np.pi / 2, 400) for q in range(4)]
    margin = np.vstack([_resample(_eye_margin(t), e_eye)[:-1] for t in tq])
    idx_margin = add(margin, _FIXED)
    tags["eye_outer"], tags["eye_centre"] = idx_margin[0], None
    n_q = [len(_resample(_eye_margin(t), e_eye)) - 1 for t in tq]
    tags["eye_centre"] = idx_margin[n_q[0]]
    tags["eye_inner"] = idx_margin[n_q[0] + n_q[1]]
    eye_zone = None
    spacing, d = e_eye, 0.0
    tt = np.linspace(0, 2 * np.pi, 1600, endpoint=False)
    while spacing < 0.95 * h0:
        gap = 0.9 * spacing
        if d + gap > 1.45:
            break
        d += gap
        spacing *= growth
        base = _eye_margin(tt)
        c = np.array([EYE_C, 0.0])
        dirs = base - c
        # offset outward: inflate the ellipse-like margin by d in both axes
        ring = c + dirs * 0.0
        ring[:, 0] = EYE_C + (EYE_A + d) * np.cos(tt)
        bb = np.where(np.sin(tt) >= 0, EYE_BU, EYE_BL) + d
        ring[:, 1] = bb * np.sin(tt) * (1 - 0.18 * np.cos(tt) ** 2 * EYE_A / (EYE_A + d)) \
            + EYE_TILT * np.cos(tt)
        rp = _resample(ring, min(spacing, h0), closed=True)
        rp = rp[rp[:, 0] > 0.25 * h0]
        add(rp, _RING)
        eye_zone = ring
    eye_zone_path = _MplPath(eye_zone) if eye_zone is not None else None

    # mouth seam and rings (X >= 0 half) ---------------------------------------------------
    xs = _resample(np.stack([np.linspace(0, MOUTH_W, 400), np.zeros(400)], 1), e_mouth)[:, 0]
    seam = np.stack([xs, _mouth_y(xs)], axis=1)
    seam[0, 0] = 0.0
    idx_seam = add(seam, _FIXED)
    spacing, d = e_mouth, 0.0
    mouth_zone = None
    while spacing < 0.95 * h0:
        gap = 0.9 * spacing
        if d + gap > 1.5:
            break
        d += gap
        spacing *= growth
        rings = []
        for lo, hi in ((0.0, np.pi / 2), (np.pi / 2, np.pi), (np.pi, 1.5 * np.pi),
                       (1.5 * np.pi, 2 * np.pi)):
            if lo >= np.pi / 2 and hi <= 1.5 * np.pi:
                continue  # X < 0 quarters come from the mirror
            t = np.linspace(lo, hi, 400)
            x = (MOUTH_W + d) * np.cos(t)
            # lower rings a little further apart (lower lip is taller)
            k = 1.0 if lo < np.pi else 1.1
            y = _mouth_y(x) + k * d * np.sin(t)
            q = _resample(np.stack([x, y], 1), min(spacing, h0))
            rings.append(q)
        rp = np.vstack(rings)
        rp[np.abs(rp[:, 0]) < 1e-9, 0] = 0.0
        rp = np.unique(np.round(rp, 12), axis=0)
        add(rp, _RING)
        t = np.linspace(0, 2 * np.pi, 800, endpoint=False)
        x = (MOUTH_W + d) * np.cos(t)
        y = _mouth_y(x) + np.where(np.sin(t) >= 0, 1.0, 1.1) * d * np.sin(t)
        mouth_zone = np.stack([x, y], 1)
    mouth_zone_path = _MplPath(mouth_zone) if mouth_zone is not None else None

    # grid: hex lattice with vertical columns, symmetric about X = 0 -------------------------
    dx = h0 * math.sqrt(3) / 2
    cols = np.arange(0, int(X_EXT / dx) + 2)
    gx, gy = [], []
    for j in cols:
        y = np.arange(Y_BOT - h0, Y_TOP + h0, h0) + (0.5 * h0 if j % 2 else 0.0)
        gx.append(np.full(len(y), j * dx))
        gy.append(y)
    grid = np.stack([np.concatenate(gx), np.concatenate(gy)], 1)
    grid = grid[domain_half.contains_points(grid, radius=-1e-9) | (grid[:, 0] == 0)]
    grid = grid[(grid[:, 1] < Y_TOP - 0.4 * h0) & (grid[:, 1] > Y_BOT + 0.4 * h0)]
    grid = grid[grid[:, 0] <= _hw(grid[:, 1]) - 0.45 * h0]
    special = np.vstack(pts)
    keep = cKDTree(special).query(grid)[0] > 0.7 * h0
    if eye_zone_path is not None:
        keep &= ~eye_zone_path.contains_points(grid)
    if mouth_zone_path is not None:
        keep &= ~mouth_zone_path.contains_points(grid)
    add(grid[keep], _GRID)

    P = np.vstack(pts)
    kind = np.concatenate(kinds)

    # landmarks away from constraints: move the nearest free point onto them ---------------
    free_lm = {
        "brow_inner": (BROW_INNER, float(_brow_y(BROW_INNER))),
        "brow_mid": (BROW_MID, float(_brow_y(BROW_MID))),
        "brow_outer": (BROW_OUTER, float(_brow_y(BROW_OUTER))),
        "furrow_top": FURROW_TOP,
        "chin": (0.0, Y_CHIN),
        "nasion": (0.0, Y_NASION),
        "nose_tip": (0.0, Y_TIP),
        "subnasale": (0.0, Y_SUBNASALE),
        "lip_upper_centre": (0.0, MOUTH_Y + UL_H),
        "lip_lower_centre": (0.0, MOUTH_Y - LL_H),
        "hairline_centre": (0.0, Y_HAIR),
        "hairline": (5.3, float(_hairline_y(5.3))),
        "alar": ALAR,
    }
    lm_half: dict[str, int] = {}
    movable = kind != _FIXED
    for name, q in free_lm.items():
        q = np.asarray(q, dtype=float)
        cand = np.flatnonzero(movable)
        if q[0] == 0.0:
            cand = cand[P[cand, 0] == 0.0] if np.any(P[cand, 0] == 0.0) else cand
        j = cand[np.argmin(np.linalg.norm(P[cand] - q, axis=1))]
        P[j] = q
        kind[j] = _FIXED
        movable[j] = False
        lm_half[name] = int(j)
    # jaw angle: the outline point nearest to the outline at Y_JAW_ANGLE
    oi = idx_outline[np.argmin(np.abs(P[idx_outline, 1] - Y_JAW_ANGLE))]
    lm_half["jaw_angle"] = int(oi)
    lm_half["mouth_corner"] = int(idx_seam[-1])
    lm_half["eye_centre"] = int(tags["eye_centre"])
    lm_half["eye_inner"] = int(tags["eye_inner"])
    lm_half["eye_outer"] = int(tags["eye_outer"])

    # Gabriel filter: keep constraint segments as Delaunay edges ---------------------------
    segs = []
    m = idx_margin
    segs.append(np.stack([m, np.roll(m, -1)], 1))
    segs.append(np.stack([idx_seam[:-1], idx_seam[1:]], 1))
    segs.append(np.stack([idx_outline[:-1], idx_outline[1:]], 1))
    segs = np.vstack(segs)
    mid = 0.5 * (P[segs[:, 0]] + P[segs[:, 1]])
    rad = 0.5 * np.linalg.norm(P[segs[:, 1]] - P[segs[:, 0]], axis=1)
    tree = cKDTree(P)
    drop = np.zeros(len(P), dtype=bool)
    for c, r in zip(mid, rad):
        for j in tree.query_ball_point(c, 1.08 * r):
            if kind[j] != _FIXED:
                drop[j] = True
    # also drop free points that crowd each other (closer than 0.35 of the local spacing)
    keep_idx = np.flatnonzero(~drop)
    remap = np.full(len(P), -1)
    remap[keep_idx] = np.arange(len(keep_idx))
    P, kind = P[keep_idx], kind[keep_idx]
    idx_outline, idx_margin, idx_seam = remap[idx_outline], remap[idx_margin], remap[idx_seam]
    lm_half = {k: int(remap[v]) for k, v in lm_half.items()}
    if (idx_outline < 0).any() or (idx_margin < 0).any() or (idx_seam < 0).any():
        raise RuntimeError("internal error: a constraint point was removed")

    # triangulate the half ---------------------------------------------------------------------
    dl = Delaunay(P)
    if len(dl.coplanar):
        raise RuntimeError("internal error: degenerate point set in the face triangulation")
    tri = dl.simplices.astype(np.int64)
    cen = P[tri].mean(axis=1)
    inside = domain_half.contains_points(cen)
    eye_path = _MplPath(P[idx_margin])
    inside &= ~eye_path.contains_points(cen)
    a = P[tri[:, 1]] - P[tri[:, 0]]
    b = P[tri[:, 2]] - P[tri[:, 0]]
    area = 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    inside &= np.abs(area) > 1e-10
    tri, area = tri[inside], area[inside]
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    used = np.zeros(len(P), dtype=bool)
    used[tri.ravel()] = True
    if not used.all():
        # isolated points (inside a removed region): drop them
        keep_idx = np.flatnonzero(used)
        remap = np.full(len(P), -1)
        remap[keep_idx] = np.arange(len(keep_idx))
        P, kind = P[keep_idx], kind[keep_idx]
        tri = remap[tri]
        idx_outline, idx_margin, idx_seam = (remap[idx_outline], remap[idx_margin],
                                             remap[idx_seam])
        lm_half = {k: int(remap[v]) for k, v in lm_half.items()}

    # mirror -------------------------------------------------------------------------------------
    n_h = len(P)
    on_mid = P[:, 0] == 0.0
    off = np.flatnonzero(~on_mid)
    mirror = np.arange(n_h + len(off))
    mirror[off] = n_h + np.arange(len(off))
    mirror[n_h:] = off
    Pm = P[off] * np.array([-1.0, 1.0])
    Pf = np.vstack([P, Pm])
    tri_m = mirror[tri][:, [0, 2, 1]]
    T = np.vstack([tri, tri_m])

    # split the mouth seam -------------------------------------------------------------------
    seam_half = idx_seam[:-1]                      # exclude the corner
    seam_all = np.unique(np.concatenate([seam_half, mirror[seam_half]]))
    n_f = len(Pf)
    dup = np.full(n_f, -1)
    dup[seam_all] = n_f + np.arange(len(seam_all))
    cen = Pf[T].mean(axis=1)
    below = (cen[:, 1] < _mouth_y(cen[:, 0])) & (np.abs(cen[:, 0]) < MOUTH_W + 1.0)
    Tl = T[below]
    repl = dup[Tl] >= 0
    Tl[repl] = dup[Tl[repl]]
    T[below] = Tl
    Pf = np.vstack([Pf, Pf[seam_all]])
    mirror = np.concatenate([mirror, dup[mirror[seam_all]]])
    seam_pairs = np.stack([seam_all, dup[seam_all]], 1)
    order = np.argsort(Pf[seam_pairs[:, 0], 0], kind="stable")
    seam_pairs = seam_pairs[order]
    lower = np.zeros(len(Pf), dtype=bool)
    lower[n_f:] = True

    boundary = np.zeros(len(Pf), dtype=bool)
    boundary[idx_outline] = True
    boundary[mirror[idx_outline]] = True

    landmarks: dict[str, int] = {}
    for name, j in lm_half.items():
        if name in ("brow_inner", "brow_mid", "brow_outer", "furrow_top", "hairline",
                    "jaw_angle", "mouth_corner", "eye_centre", "eye_inner", "eye_outer",
                    "alar"):
            landmarks[name + "_l"] = int(j)
            landmarks[name + "_r"] = int(mirror[j])
        else:
            landmarks[name] = int(j)
    landmarks = {name: landmarks[name] for name in LANDMARK_NAMES}

    return _Layout(
        P=Pf, triangles=T.astype(np.int32), mirror=mirror.astype(np.int64),
        seam=seam_pairs.astype(np.int64), boundary=boundary, landmarks=landmarks,
        lower=lower, eye_margin_l=idx_margin.astype(np.int64),
    )
