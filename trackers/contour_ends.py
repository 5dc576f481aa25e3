"""Relocate the free ends of open contours on the ends of the features they follow.

A contour's end on a dark line creeps inward during relaxation and stops short of the
feature's end (see the module docstring of :mod:`trackers.tracking`, "Ends").
:func:`refine_end` finds that end from the potential (and, for thin lines, the grey
level) along the contour's end tangent; ``_move_end_nb`` then extends or cuts the
contour to it. The :class:`~trackers.tracking.Tracker` calls both kernels after each
relaxation, for the contours whose ``LayoutContour.ends`` ask for it. Kept apart from
the tracker because it is one self-contained measurement with its own tests.
"""

from __future__ import annotations

import numba
import numpy as np

from trackers.polyline import _arc_length_nb
from trackers.quality import _length_nb
from trackers.sampling import bilinear_nb as _bil

__all__ = ["refine_end"]

# half-angle of the fan of directions searched for an open mouth's corner (radians)
_CORNER_FAN = float(np.deg2rad(45.0))


def refine_end(points, potential, sigma: float, *, origin=(0.0, 0.0), end: int = 0,
               gray=None, gray_origin=None, inset: bool = True, fan: float = 0.0,
               step: bool = False, steady: bool = False):
    """Relocate one end of an open contour on the end of the dark line it follows.

    The potential is sampled along the contour (inside) and along its end tangent
    (outside); the end is put where the ravine has risen to half its reference
    depth, provided the ravine then fades out (to a quarter of that depth within
    ``3 * sigma``; a line that merely weakens has no end there).

    Parameters
    ----------
    points : array_like (n, 2)
        Contour nodes (x, y).
    potential : ndarray (H, W)
        Valley (or edge) potential the contour lies in.
    sigma : float
        Width of that potential, pixels.
    origin : (x, y)
        Image position of ``potential[0, 0]``.
    end : {0, -1}
        Which end.
    gray : ndarray (H, W), optional
        Grey image; with ``inset`` the end is moved back by the line's half-width,
        measured across the line from ``gray``.
    gray_origin : (x, y), optional
        Image position of ``gray[0, 0]`` (default: ``origin``).
    inset : bool
        Treat the feature as a band: reference depth taken just inside the end and
        the end moved back by the half-width (needs ``gray``). Otherwise a thin line:
        reference depth = deepest point inside, no inset.
    fan : float
        Half-angle in degrees of a fan of search directions around the end tangent;
        the farthest end found wins (the corner of an open mouth lies off the
        tangent of a contour that follows the mouth's lower border). 0: tangent only.
    step : bool
        Locate a thin line's end on the grey level instead (needs ``gray``, excludes
        ``inset``): the half-level crossing of the strongest dark-to-bright step
        along the line, searched from the ravine's end (or, where the ravine runs on
        without fading, from the contour's end) back into the line over 10 sigma,
        then moved back by the line's half-width onto its centre line. A step that
        rises less than half-way from the line to the skin beside it (a line that
        merely weakens) is no end. For line ends beyond which the ravine runs on
        into shading or texture (the furrows' tops).
    steady : bool
        Return an end from which the search would stay put (see :func:`_steady_end`),
        as the tracker does: where the end found depends on where the search starts,
        relocating it again from the end found would move it back.

    Returns
    -------
    ndarray (2,) or None
        The new end, or None when no clear ravine end is found.

    Examples
    --------
    >>> import numpy as np
    >>> from trackers.potentials import valley_potential
    >>> img = np.full((40, 80), 200, np.uint8); img[19:22, 10:60] = 40
    >>> P = valley_potential(img, 1.5)
    >>> pts = np.c_[np.linspace(20, 55, 16), np.full(16, 20.0)]
    >>> refine_end(pts, P, 1.5, end=-1, inset=False).tolist()  # the band ends at x = 59.5
    [59.5, 20.0]

    A shadow prolongs a line drawn to x = 58: its ravine runs on, the grey step does not.

    >>> import cv2
    >>> img = np.full((40, 100), 200, np.uint8); img[18:23, 60:95] = 140
    >>> _ = cv2.line(img, (10, 20), (58, 20), 40, 3)
    >>> P = valley_potential(img, 1.5)
    >>> pts = np.c_[np.linspace(20, 70, 20), np.full(20, 20.0)]
    >>> refine_end(pts, P, 1.5, end=-1, inset=False) is None
    True
    >>> q = refine_end(pts, P, 1.5, end=-1, inset=False, step=True, gray=img)
    >>> bool(abs(q[0] - 58) < 1.0)
    True
    """
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
        raise ValueError(f"points must have shape (n >= 2, 2), got {p.shape}")
    if end not in (0, -1):
        raise ValueError(f"end must be 0 or -1, got {end}")
    if step and (gray is None or inset):
        raise ValueError("step=True needs gray and inset=False")
    if end == -1:
        p = p[::-1]
    P = np.ascontiguousarray(potential, dtype=np.float32)
    has_gray = gray is not None
    g = np.ascontiguousarray(gray, dtype=np.float32) if has_gray else np.zeros((2, 2), np.float32)
    go = origin if gray_origin is None else gray_origin
    p = np.ascontiguousarray(p)
    args = (P, float(origin[0]), float(origin[1]), float(sigma), bool(inset), g,
            float(go[0]), float(go[1]), has_gray, float(np.deg2rad(fan)), bool(step))
    ok, x, y = _refine_end_nb(p, *args)
    if ok and steady:
        x, y = _steady_end(p, x, y, args, float(sigma), False)
    return np.array([x, y]) if ok else None


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _path_xy(p, arc, tx, ty, s):
    if s >= 0.0:
        return p[0, 0] + s * tx, p[0, 1] + s * ty
    d = -s
    n = p.shape[0]
    if d >= arc[n - 1]:
        return p[n - 1, 0], p[n - 1, 1]
    i = 0
    while i < n - 2 and arc[i + 1] < d:
        i += 1
    seg = arc[i + 1] - arc[i]
    f = (d - arc[i]) / seg if seg > 0 else 0.0
    return p[i, 0] + f * (p[i + 1, 0] - p[i, 0]), p[i, 1] + f * (p[i + 1, 1] - p[i, 1])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma):
    """Half width at half depth of the dark line through (cx, cy), normal to (tx, ty)."""
    nx, ny = -ty, tx
    m = int(np.floor(5.0 * sigma / 0.25))
    cnt = 2 * m + 1
    r = np.empty(cnt)
    v = np.empty(cnt)
    for i in range(cnt):
        r[i] = (i - m) * 0.25
        v[i] = _bil(gray, cx + r[i] * nx, cy + r[i] * ny, gox, goy)
        if np.isnan(v[i]):
            return np.nan
    i0 = -1
    best = np.inf
    outer = []
    for i in range(cnt):
        if abs(r[i]) <= 1.5 * sigma and v[i] < best:
            best = v[i]
            i0 = i
        if abs(r[i]) >= 3.5 * sigma:
            outer.append(v[i])
    if i0 < 0 or len(outer) == 0:
        return np.nan
    top = np.median(np.array(outer))
    if top - best < 5.0:
        return np.nan
    half = 0.5 * (top + best)
    hi = i0
    while hi < cnt - 1 and v[hi] < half:
        hi += 1
    lo = i0
    while lo > 0 and v[lo] < half:
        lo -= 1
    if v[hi] < half or v[lo] < half:
        return np.nan
    right = r[hi - 1] + (half - v[hi - 1]) / (v[hi] - v[hi - 1]) * (r[hi] - r[hi - 1])
    left = r[lo + 1] + (half - v[lo + 1]) / (v[lo] - v[lo + 1]) * (r[lo] - r[lo + 1])
    hw = 0.5 * (right - left)
    return hw if np.isfinite(hw) else np.nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _flanks_nb(gray, cx, cy, nx, ny, gox, goy, sigma):
    """Grey level beside a line through (cx, cy) running across (nx, ny): the median
    of the samples 3.5 to 5 sigma out on both sides (NaN off the image)."""
    m = int(np.floor(5.0 * sigma / 0.5))
    outer = []
    for i in range(-m, m + 1):
        r = i * 0.5
        if abs(r) >= 3.5 * sigma:
            v = _bil(gray, cx + r * nx, cy + r * ny, gox, goy)
            if np.isnan(v):
                return np.nan
            outer.append(v)
    if len(outer) == 0:
        return np.nan
    return np.median(np.array(outer))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _gray_step_end_nb(p, arc, tx, ty, s_coarse, sigma, gray, gox, goy, s_min):
    """Arc position of a thin dark line's end: the half-level crossing of the
    strongest dark-to-bright step of the grey level along the path, searched from
    ``s_coarse + 0.75 sigma`` back to ``10 sigma`` before ``s_coarse`` (not beyond
    ``s_min``).

    The ravine of a Hessian potential outlives the line's end: at scale sigma it
    decays over about 2 sigma, and skin texture or a shadow in the line's
    prolongation keeps it at half depth for several pixels more (on the face
    model's renders the ravine of a furrow ran on up to 6 px past the drawn line's
    top, and never faded). The grey level steps from line to skin within a pixel
    or two. Returns NaN when no step of at least 5 grey levels is found.
    """
    w = max(2.0 * sigma, 2.0)
    reach = min(10.0 * sigma, -s_min)
    lo = s_coarse - reach - w
    hi = s_coarse + 0.75 * sigma + w
    if lo < s_min:
        lo = s_min
    cnt = int(np.floor((hi - lo) / 0.25)) + 1
    k = int(round(w / 0.25))
    if cnt < 2 * k + 2:
        return np.nan
    nx, ny = -ty, tx
    g = np.empty(cnt)
    ss = np.empty(cnt)
    for i in range(cnt):
        ss[i] = lo + i * 0.25
        x, y = _path_xy(p, arc, tx, ty, ss[i])
        acc = 0.0
        for o in (-0.5 * sigma, 0.0, 0.5 * sigma):
            v = _bil(gray, x + o * nx, y + o * ny, gox, goy)
            if np.isnan(v):
                return np.nan
            acc += v
        g[i] = acc / 3.0
    csum = np.zeros(cnt + 1)
    for i in range(cnt):
        csum[i + 1] = csum[i] + g[i]
    best = 5.0
    ib = -1
    for i in range(k, cnt - k + 1):
        if ss[i] > s_coarse + 0.75 * sigma:
            break
        d = (csum[i + k] - csum[i]) / k - (csum[i] - csum[i - k]) / k
        if d > best:
            best = d
            ib = i
    if ib < 0:
        return np.nan
    # a step in a line that merely weakens (a real furrow fading out, texture) is
    # no end: it must rise at least half-way from the line to the skin beside it
    # (on the face model's renders 0.5-0.9 of the way; on real furrows mostly less)
    cx, cy = _path_xy(p, arc, tx, ty, ss[ib] - w)
    rise = (best / (_flanks_nb(gray, cx, cy, nx, ny, gox, goy, sigma)
                    - (csum[ib] - csum[ib - k]) / k))
    if not 0.5 <= rise <= 1.5:
        return np.nan
    half = 0.5 * ((csum[ib + k] - csum[ib]) / k + (csum[ib] - csum[ib - k]) / k)
    # the half-level crossing next to the step
    j = ib
    while j > ib - k + 1 and g[j - 1] >= half:
        j -= 1
    while j < ib + k - 1 and g[j] < half:
        j += 1
    if g[j] == g[j - 1]:
        return ss[j]
    f = (half - g[j - 1]) / (g[j] - g[j - 1])
    f = min(max(f, 0.0), 1.0)
    return ss[j - 1] + f * 0.25


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _refine_end_nb(p, P, ox, oy, sigma, inset, gray, gox, goy, has_gray, fan, step):
    n = p.shape[0]
    k = min(3, n - 1)
    tx = p[0, 0] - p[k, 0]
    ty = p[0, 1] - p[k, 1]
    norm = np.sqrt(tx * tx + ty * ty)
    if norm < 1e-9:
        return False, 0.0, 0.0
    tx /= norm
    ty /= norm
    if fan <= 0.0:
        ok, s_end, x, y = _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy,
                                         has_gray, tx, ty, step)
        return ok, x, y
    # a fan of directions around the tangent: the farthest end of the dark region
    best = -np.inf
    bx = 0.0
    by = 0.0
    found = False
    m = 6
    for j in range(-m, m + 1):
        a = fan * j / m
        ca, sa = np.cos(a), np.sin(a)
        ok, s_end, x, y = _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy,
                                         has_gray, ca * tx - sa * ty, sa * tx + ca * ty, step)
        # prefer the tangent itself among (nearly) equal reaches
        score = s_end - 0.05 * abs(j)
        if ok and score > best:
            best = score
            bx = x
            by = y
            found = True
    return found, bx, by


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy, has_gray, tx, ty, step):
    n = p.shape[0]
    arc = np.zeros(n)
    for i in range(1, n):
        arc[i] = arc[i - 1] + np.sqrt((p[i, 0] - p[i - 1, 0]) ** 2 + (p[i, 1] - p[i - 1, 1]) ** 2)
    length = arc[n - 1]
    s_in = 0.45 * length if not inset else min(5.0 * sigma, 0.45 * length)
    s_out = 5.0 * sigma
    i_first = -int(np.floor(s_in / 0.25))
    i_last = int(np.floor(s_out / 0.25 + 1e-9))
    cnt = i_last - i_first + 1
    s = np.empty(cnt)
    v = np.empty(cnt)
    any_inside = False
    nx = -ty
    ny = tx
    off = 1.5 * sigma
    for i in range(cnt):
        s[i] = (i_first + i) * 0.25
        x, y = _path_xy(p, arc, tx, ty, s[i])
        v[i] = _bil(P, x, y, ox, oy)
        if s[i] <= 0 and not np.isnan(v[i]):
            any_inside = True
        elif s[i] > 0 and v[i] < 0 and not inset:
            # (thin lines) beyond the end only a ravine running along the tangent counts: its
            # flanks across are shallow; a line crossing the path (a furrow next to a
            # mouth corner) is as deep on both flanks and is not a continuation
            a = _bil(P, x + off * nx, y + off * ny, ox, oy)
            b = _bil(P, x - off * nx, y - off * ny, ox, oy)
            if not (a > 0.7 * v[i] and b > 0.7 * v[i]):
                v[i] = 0.0
    if not any_inside:
        return False, 0.0, 0.0, 0.0
    if inset:
        vals = []
        i0 = -1
        for i in range(cnt):
            if s[i] <= 0 and s[i] >= -2.5 * sigma and s[i] <= -1.0 * sigma:
                i0 = i
                if not np.isnan(v[i]):
                    vals.append(v[i])
        if i0 < 0 or len(vals) == 0:
            return False, 0.0, 0.0, 0.0
        depth = np.median(np.array(vals))
    else:
        i0 = -1
        depth = np.inf
        for i in range(cnt):
            if s[i] <= 0 and not np.isnan(v[i]) and v[i] < depth:
                depth = v[i]
                i0 = i
    if not np.isfinite(depth) or depth >= -1e-3:
        return False, 0.0, 0.0, 0.0
    half = 0.5 * depth
    # the end: the first rise above half depth after which the ravine does not come
    # back within 3 sigma (a gap, a highlight on a lip, is no end) and that rises on
    # to a quarter of the depth (a line that merely weakens has no end there)
    s_end = np.nan
    for m in range(i0 + 1, cnt):
        if np.isnan(v[m]) or np.isnan(v[m - 1]):
            break
        if not (v[m] > half and v[m - 1] <= half):
            continue
        f = (half - v[m - 1]) / (v[m] - v[m - 1])
        cand = s[m - 1] + f * (s[m] - s[m - 1])
        resumes = False
        fades = False
        for i in range(m, cnt):
            if s[i] > cand + 3.0 * sigma:
                break
            if np.isnan(v[i]):
                continue
            if v[i] <= half:
                resumes = True
                break
            if v[i] >= 0.25 * depth:
                fades = True
        if resumes:
            continue
        if fades:
            s_end = cand
        break
    if step and has_gray:
        # where the ravine never fades the search starts from the contour's end: the
        # grey step only ever moves an end back along the ravine (on real furrows,
        # which fade gradually, extending on a step made the contours wander)
        s_step = _gray_step_end_nb(p, arc, tx, ty, s_end if np.isfinite(s_end) else 0.0,
                                   sigma, gray, gox, goy, s[0])
        if np.isfinite(s_step):
            s_end = s_step
        if np.isfinite(s_end):
            # the half-level point of a round-capped stroke lies one half-width
            # beyond its centre line's end (one measurement, capped: the band's
            # two-step measurement below moved the real furrows' tops more)
            cx, cy = _path_xy(p, arc, tx, ty, s_end - 2.0 * sigma)
            hw = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
            if not np.isnan(hw):
                s_end -= min(hw, 2.0 * sigma)
    if not np.isfinite(s_end):
        return False, 0.0, 0.0, 0.0
    if inset and has_gray:
        # measure the width just behind the rounded cap of the band (whose radius is
        # the half-width itself): first 2 sigma inside, then half a sigma behind
        # the cap that this first estimate implies (a tapering band is narrower
        # near its end than 2 sigma inside)
        cx, cy = _path_xy(p, arc, tx, ty, s_end - 2.0 * sigma)
        hw = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
        if not np.isnan(hw):
            cx, cy = _path_xy(p, arc, tx, ty, s_end - hw - 0.5 * sigma)
            hw2 = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
            if not np.isnan(hw2):
                hw = hw2
            s_end -= hw
    x, y = _path_xy(p, arc, tx, ty, s_end)
    return True, s_end, x, y


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _trim_start_nb(p, s):
    """Polyline ``p`` without arc length ``s`` from its start."""
    n = p.shape[0]
    cum = _arc_length_nb(p)
    if s >= cum[n - 1]:
        return p[n - 2:].copy()
    i = 0
    while i + 1 < n and cum[i + 1] <= s:
        i += 1
    seg = np.hypot(p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1])
    t = (s - cum[i]) / max(seg, 1e-12)
    out = np.empty((n - i, 2))
    out[0, 0] = p[i, 0] + t * (p[i + 1, 0] - p[i, 0])
    out[0, 1] = p[i, 1] + t * (p[i + 1, 1] - p[i, 1])
    out[1:] = p[i + 1:]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _move_end_nb(ref, qx, qy, sigma, settle, exact=False):
    """Contour ``ref`` (its end to move first) with that end moved to ``(qx, qy)``:
    extended along the end, or cut back where the end now lies (by at most 2 sigma a
    frame unless ``settle``): at the node nearest to it, or with ``exact`` at the
    point of the polyline nearest to it. An empty array when the move is refused (too
    small, too far, or cutting away half the contour)."""
    n = ref.shape[0]
    none = np.empty((0, 2))
    dx, dy = qx - ref[0, 0], qy - ref[0, 1]
    j = min(3, n - 1)
    tx, ty = ref[0, 0] - ref[j, 0], ref[0, 1] - ref[j, 1]
    tn = max(np.hypot(tx, ty), 1e-9)
    tx /= tn
    ty /= tn
    s = dx * tx + dy * ty
    if abs(s) < 1e-3 or s > 5 * sigma:
        return none
    if s < 0:
        # retract: cut the contour where the end now lies
        arc = 0.0
        best = np.inf
        cut = 0.0
        for i in range(n):
            if i > 0:
                arc += np.hypot(ref[i, 0] - ref[i - 1, 0], ref[i, 1] - ref[i - 1, 1])
            d = np.hypot(ref[i, 0] - qx, ref[i, 1] - qy)
            if d < best:
                best = d
                cut = arc
            if exact and i + 1 < n:
                ex, ey = ref[i + 1, 0] - ref[i, 0], ref[i + 1, 1] - ref[i, 1]
                seg2 = ex * ex + ey * ey
                if seg2 > 1e-24:
                    u = ((qx - ref[i, 0]) * ex + (qy - ref[i, 1]) * ey) / seg2
                    if 0.0 < u < 1.0:
                        d = np.hypot(ref[i, 0] + u * ex - qx, ref[i, 1] + u * ey - qy)
                        if d < best:
                            best = d
                            cut = arc + u * np.sqrt(seg2)
        if cut > 0.45 * arc:
            return none
        if cut > 2.0 * sigma and not settle:
            # features shorten slowly: at most 2 sigma per frame, so that a transient
            # gap (a highlight) cannot cut a contour in half (the first frame, where
            # the layout may be far off, excepted)
            out = _trim_start_nb(ref, 2.0 * sigma)
        elif cut > 0:
            rest = _trim_start_nb(ref, cut)
            out = np.empty((rest.shape[0], 2))
            out[0, 0] = qx
            out[0, 1] = qy
            out[1:] = rest[1:]
        else:
            out = ref
    else:
        out = np.empty((n + 1, 2))
        out[0, 0] = qx
        out[0, 1] = qy
        out[1:] = ref
    if out.shape[0] < 2 or _length_nb(out, False) < 2.0:
        return none
    return out


#: Iterations of the bisection that finds a steady end between a contour's end and an
#: end found past it (:func:`_steady_end`).
STEADY_END_STEPS = 4


def _steady_end(ref, x, y, args, sigma, settle):
    """A contour end that searching again from where it is would leave in place.

    ``(x, y)`` is the end :func:`refine_end`'s kernel found for the polyline ``ref``
    (its end first; ``args`` the kernel's other arguments). Where a band's end is
    ambiguous (a brow's inner head running into the shading beside the nose), the end
    found depends on where the search starts and can overshoot: started short, it
    lands past the place, started past it, short. Relocated afresh on each frame, such
    an end swings between the two from one frame to the next on a still face, and the
    fit reads the swing as a muscle switching on and off. The search is run once more
    from the end found; when it goes back by more than a quarter of ``sigma``, the end
    is put where the search from it stays put, found by bisection between the two
    (the probes cut the contour exactly, not at a node).
    """
    moved = _move_end_nb(ref, x, y, sigma, settle, True)
    if moved.shape[0] < 4:
        return x, y
    ok, x2, y2 = _refine_end_nb(moved, *args)
    if not ok:
        return x, y
    j = min(3, len(ref) - 1)
    t = ref[0] - ref[j]
    t = t / max(float(np.hypot(*t)), 1e-9)
    s1 = float((x - ref[0, 0]) * t[0] + (y - ref[0, 1]) * t[1])
    s2 = float((x2 - ref[0, 0]) * t[0] + (y2 - ref[0, 1]) * t[1])
    if abs(s2 - s1) <= 0.25 * sigma or (s2 - s1) * s1 >= 0:
        return x, y
    # the search from s1 points back toward 0 and the one from 0 toward s1: the end
    # that stays put lies between; across the line, interpolate between the two
    lo, hi = 0.0, 1.0
    for _ in range(STEADY_END_STEPS):
        m = 0.5 * (lo + hi)
        qx, qy = ref[0, 0] + m * (x - ref[0, 0]), ref[0, 1] + m * (y - ref[0, 1])
        moved = _move_end_nb(ref, qx, qy, sigma, settle, True) if m * abs(s1) > 1e-3 else ref
        if moved.shape[0] < 4:
            break
        ok, xm, ym = _refine_end_nb(moved, *args)
        if not ok:
            break
        sm = float((xm - ref[0, 0]) * t[0] + (ym - ref[0, 1]) * t[1])
        if (sm - m * s1) * s1 > 0:
            lo = m
        else:
            hi = m
    m = 0.5 * (lo + hi)
    return ref[0, 0] + m * (x - ref[0, 0]), ref[0, 1] + m * (y - ref[0, 1])
